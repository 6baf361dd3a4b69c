"""Training a learned simulator: the LightningModule (loss, noise, optimiser, validation rollouts:
:mod:`~gnsx.training.system`), the LR and noise schedules, the wall-clock budget, precision and numerics
(skipped non-finite steps), resilience (atomic checkpoints, heartbeats, resume), the checks of a run's config,
the train pipeline behind ``train.py`` (:mod:`~gnsx.training.pipeline`) and the export of shipped weights
(``python -m gnsx.training.export``)."""
