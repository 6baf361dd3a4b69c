"""The perceptual believability study (the paper's survey, figure 10) as a tool anyone can run.

A study is a folder: pairs of animations of the same initial state by two methods (MPM ground truth, the
original GNS, the simplified GNS, ...), grouped by method pair, and ``study.json``, the manifest that lists
them. Participants pick the more realistic animation of each pair in a local web app; their answers go to
``answers.sqlite`` in the same folder; the analysis turns them into pick ratios per method pair with 95%
Wilson intervals, a binomial test against 50/50 and the figure 10 bar chart.

Modules, one concern each:

* :mod:`gnsx.study.scenes`: rollout files (``evaluate.py``'s ``.npz``) to scenes: which methods animated
  which initial state;
* :mod:`gnsx.study.build`: choosing the pairs, rendering the animations, writing the manifest;
* :mod:`gnsx.study.manifest`: the manifest's format, reading and checking it;
* :mod:`gnsx.study.assign`: a participant's seeded order of pairs and left/right sides;
* :mod:`gnsx.study.store`: the SQLite answers (what was shown to whom, and what they chose);
* :mod:`gnsx.study.pages` and :mod:`gnsx.study.app`: the web app (Flask);
* :mod:`gnsx.study.analysis`: ratios, intervals, tests, the chart and the reports;
* ``python -m gnsx.study build | serve | analyse``: the command line (:mod:`gnsx.study.__main__`).
"""
