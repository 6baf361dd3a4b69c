"""Training a learned simulator: the LightningModule (loss, noise, optimiser, validation rollouts:
:mod:`~gnsx.training.system`), the LR and noise schedules, the wall-clock budget, precision and numerics
(skipped non-finite steps), resilience (atomic checkpoints, heartbeats, resume), the checks of a run's config,
the run behind ``train.py`` (:mod:`~gnsx.training.run`, with its input checks, builders, loggers, model settings,
job record and sweep extras in modules of their own) and the export of shipped weights
(``python -m gnsx.training.export``)."""
