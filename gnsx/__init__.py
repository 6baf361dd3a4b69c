"""gnsx: learned particle simulation (simplified and original GNS) as an experiment platform.

The package is layered; a module imports only its own layer or lower ones (``tests/test_layers.py`` checks
every import, those inside functions included)::

    core  <-  data, mpm  <-  model  <-  evaluation  <-  training  <-  perf, study

:mod:`gnsx.core` (errors, atomic writes, constants, run state, threads, CLI helpers) is the floor;
:mod:`gnsx.data` (formats, store, datamodule, rollout files) and :mod:`gnsx.mpm` (the reference solver, which
writes datasets in the data format) sit on it; :mod:`gnsx.model` is the GNS family and its rollout loop;
:mod:`gnsx.evaluation` scores, times and draws a model's rollouts; :mod:`gnsx.training` trains one (its
validation and checkpoint choice use the same scoring library, which is why evaluation sits below training);
:mod:`gnsx.perf` and :mod:`gnsx.study` are tools on top.
"""

from gnsx.core import resolvers as _resolvers  # noqa: F401  (the configs' ${steps_fraction:...})

__version__ = "0.1.0"
