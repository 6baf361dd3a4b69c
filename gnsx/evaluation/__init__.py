"""Scoring a model's rollouts: metrics (MSE, EMD, kinetic energy, area: :mod:`~gnsx.evaluation.metrics`), their
spread (standard errors, intervals, paired comparisons: :mod:`~gnsx.evaluation.spread`), rollout health,
the scoring library that rolls out and scores trajectories against the physics-free baseline
(:mod:`~gnsx.evaluation.scoring`), inference timing and peak memory (:mod:`~gnsx.evaluation.timing`),
pictures and animations (:mod:`~gnsx.evaluation.render`), the ``evaluate.py`` pipeline
(:mod:`~gnsx.evaluation.evaluate`), scene rollouts behind ``simulate.py``, the hard-case suite, the MPM's own
predictability (:mod:`~gnsx.evaluation.sensitivity`) and the sweep report (:mod:`gnsx.evaluation.report`).
Training validates with this library, so nothing here imports :mod:`gnsx.training`."""
