"""Training wall time (:class:`TrainingClock`), and fitting a run's steps and LR/noise schedule to a budget.

The demo trains for a fixed time on machines of unknown speed. A step-based schedule cut short by a time cap
stops with the learning rate still high and the noise still large, silently. :class:`TimeBudget` instead
measures the training rate over the first ``calibration_steps`` steps and, if ``max_steps`` would not fit in
the budget, shrinks the run to the steps that do fit and compresses the LR/noise schedule with it (its decay
start and end scale by the same factor), so the schedule completes whatever the machine's speed. It logs the
decision, stores it in the checkpoint (a resumed run keeps the fitted schedule) and warns at the end if a time
cap still stopped training before the fitted step count.

Why calibrate once rather than make the schedule a function of elapsed time: the schedule stays a pure
function of the step (reproducible, resumable, the same on every rank), and one measurement of a few hundred
steps is accurate to a few percent on an idle machine; ``safety`` absorbs the rest.
"""

from __future__ import annotations

import logging
import time
from contextlib import contextmanager

from lightning.pytorch.callbacks import Callback

log = logging.getLogger("gnsx")


def parse_duration(value: str | float | int | None) -> float | None:
    """Seconds of a Lightning ``max_time`` (``"DD:HH:MM:SS"``) or a number of seconds; None stays None."""
    if value is None:
        return None
    if isinstance(value, int | float):
        return float(value)
    parts = [float(p) for p in str(value).split(":")]
    if len(parts) != 4:
        raise ValueError(f"max_time must be 'DD:HH:MM:SS', got {value!r}")
    days, hours, minutes, seconds = parts
    return ((days * 24 + hours) * 60 + minutes) * 60 + seconds


def fitted_steps(max_steps: int, done: int, rate: float, remaining_s: float, safety: float) -> int:
    """Steps of the whole run that fit: ``done`` plus what ``rate`` steps/s make in ``safety * remaining_s``,
    at most ``max_steps``."""
    return int(min(max_steps, done + max(0.0, rate * remaining_s * safety)))


class Pause:
    """How long a :meth:`TrainingClock.paused` block took (``seconds``, set when it ends)."""

    seconds: float = 0.0


class TrainingClock(Callback):
    """Wall time and optimizer steps of ``trainer.fit``; ``steps_per_s`` leaves validation rollouts out.

    Readable after a failed fit too: an unfinished fit is timed up to its last finished step.
    """

    def __init__(self):
        self._start: float | None = None
        self._last: float | None = None
        self._first_step = 0
        self._last_step = 0
        self._validation_start: float | None = None
        self.validation_s = 0.0
        self.validations = 0
        self.trained_before_s = 0.0  # training seconds of the fits before a resume (kept in the checkpoint)

    def state_dict(self) -> dict:
        return {"trained_s": self.total_training_s()}

    def load_state_dict(self, state_dict: dict) -> None:
        self.trained_before_s = float(state_dict.get("trained_s") or 0.0)

    def total_training_s(self) -> float:
        """Training seconds of the whole run: this fit's and, after a resume, the earlier fits'."""
        return self.trained_before_s + self.training_s()

    def on_train_start(self, trainer, pl_module) -> None:
        self._start = self._last = time.perf_counter()
        self._first_step = self._last_step = trainer.global_step

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx: int) -> None:
        self._last, self._last_step = time.perf_counter(), trainer.global_step

    def training_s(self) -> float:
        """Seconds of this fit spent training so far: wall time since the start less validation runs (0
        before the start)."""
        if self._start is None:
            return 0.0
        running = time.perf_counter() - self._validation_start if self._validation_start is not None else 0.0
        return time.perf_counter() - self._start - self.validation_s - running

    @contextmanager
    def paused(self):
        """Time spent inside is counted as validation, not training (for validation run by a callback
        outside Lightning's loop, :class:`gnsx.training.curves.CurveValidation`). Yields a
        :class:`Pause` whose ``seconds`` is set on leaving."""
        pause = Pause()
        self._validation_start = time.perf_counter()
        try:
            yield pause
        finally:
            pause.seconds = time.perf_counter() - self._validation_start
            self.validation_s += pause.seconds
            self.validations += 1
            self._validation_start = None

    def on_validation_start(self, trainer, pl_module) -> None:
        self._validation_start = time.perf_counter()

    def on_validation_end(self, trainer, pl_module) -> None:
        if self._validation_start is not None:
            self.validation_s += time.perf_counter() - self._validation_start
            self.validations += 1
            self._validation_start = None

    def on_train_end(self, trainer, pl_module) -> None:
        self._last, self._last_step = time.perf_counter(), trainer.global_step

    def summary(self) -> dict[str, float | int | None]:
        """``train_wall_s`` (s, validation included), ``train_steps`` (optimizer steps of this fit, a resumed
        run counts only its own), ``steps_per_s`` (validation excluded; None before the first step),
        ``training_s`` (s of training of the whole run, validation excluded, earlier fits of a resumed run
        included), ``validation_s`` and ``validations`` (this fit's)."""
        if self._start is None:
            return {"train_wall_s": None, "train_steps": 0, "steps_per_s": None}
        timing = {"training_s": self.total_training_s(), "validation_s": self.validation_s,
                  "validations": self.validations}  # fmt: skip
        wall = self._last - self._start
        steps = self._last_step - self._first_step
        training = wall - self.validation_s
        return {
            "train_wall_s": wall,
            "train_steps": steps,
            "steps_per_s": steps / training if steps > 0 and training > 0 else None,
            **timing,
        }


class TimeBudget(TrainingClock):
    """Shrink ``max_steps`` (and the schedule with it) to what fits in ``budget_s`` seconds of ``fit``.

    Args:
        budget_s: wall-clock seconds for the whole fit (validation included); None disables the callback.
        calibration_steps: steps timed before deciding.
        safety: fraction of the remaining time planned for (validation runs and rate noise take the rest).
        count_validation: False makes ``budget_s`` training time only (validation runs excluded), the budget
            of an equal-budget comparison: a slower model's longer validation rollouts then cost it no
            training. This callback stops the fit when the training time reaches the budget (Lightning's
            ``max_time`` counts validation, so the pipeline does not set it), and a resumed run counts the
            training time before the interruption (kept in the checkpoint).

    The LightningModule must have ``set_schedule_scale(factor)`` (see
    :meth:`gnsx.training.system.GNSSystem.set_schedule_scale`).
    """

    def __init__(
        self,
        budget_s: float | None,
        calibration_steps: int = 200,
        safety: float = 0.9,
        count_validation: bool = True,
    ):
        if calibration_steps < 1:
            raise ValueError(f"TimeBudget: calibration_steps must be >= 1, got {calibration_steps}")
        if not 0 < safety <= 1:
            raise ValueError(f"TimeBudget: safety must be in (0, 1], got {safety}")
        super().__init__()
        self.budget_s = budget_s
        self.calibration_steps = calibration_steps
        self.safety = safety
        self.count_validation = count_validation
        self.stop_s = None if count_validation else budget_s  # training seconds at which this stops the fit
        self.replan_every = 500  # steps between re-plans when validation is not counted
        self.rate_window = 4  # re-plans the rate is measured over (~2,000 steps)
        self._marks: list[tuple[float, int]] = []  # (training seconds, step) at the calibration and re-plans
        self.planned_steps: int | None = None  # the configured max_steps
        self.fitted: int | None = None  # the step count the schedule was fitted to (None: not shrunk)

    # -- checkpoint state: a resumed run keeps its fitted schedule -------------------------------------------
    def state_dict(self) -> dict:
        return {**super().state_dict(), "planned_steps": self.planned_steps, "fitted": self.fitted}

    def load_state_dict(self, state_dict: dict) -> None:
        super().load_state_dict(state_dict)
        self.planned_steps = state_dict.get("planned_steps")
        self.fitted = state_dict.get("fitted")

    def _elapsed(self) -> float:
        """Seconds of the budget spent: the whole fit's wall time, or training time only."""
        if self.count_validation:
            return time.perf_counter() - self._start
        return self.total_training_s()

    def _apply(self, trainer, pl_module) -> None:
        # The epoch loop holds the step limit (FitLoop.max_steps is a read-only view of it).
        trainer.fit_loop.epoch_loop.max_steps = self.fitted
        pl_module.set_schedule_scale(self.fitted / self.planned_steps)

    def on_train_start(self, trainer, pl_module) -> None:
        super().on_train_start(trainer, pl_module)
        if self.planned_steps is None:
            self.planned_steps = int(trainer.max_steps)
        if self.fitted is not None:  # resumed: the schedule was fitted before the interruption
            self._apply(trainer, pl_module)

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx: int) -> None:
        super().on_train_batch_end(trainer, pl_module, outputs, batch, batch_idx)
        if self.stop_s is not None and self._start is not None and self.total_training_s() >= self.stop_s:
            if not trainer.should_stop:
                log.info("Time budget: %.0f s of training spent at step %d; stopping", self.stop_s,
                         trainer.global_step)  # fmt: skip
            trainer.should_stop = True
        if self.budget_s is None or self._start is None:
            return
        done = trainer.global_step - self._first_step
        if self.fitted is not None:
            if not self.count_validation and done > self.calibration_steps and done % self.replan_every == 0:
                self._replan(trainer, pl_module, done)
            return
        if done != self.calibration_steps:
            return
        rate = done / self.training_s()
        self._marks = [(0.0, self._first_step), (self.training_s(), trainer.global_step)]
        elapsed = self._elapsed()
        steps = fitted_steps(
            self.planned_steps, trainer.global_step, rate, self.budget_s - elapsed, self.safety
        )
        if steps >= self.planned_steps:
            log.info(
                "Time budget: %.1f steps/s, all %d steps fit in %.0f s",
                rate,
                self.planned_steps,
                self.budget_s,
            )
            self.budget_s = None  # nothing to do
            return
        self.fitted = max(steps, trainer.global_step + 1)
        self._apply(trainer, pl_module)
        factor = self.fitted / self.planned_steps
        log.warning(
            "Time budget: at %.1f steps/s only %d of %d steps fit in %.0f s; training %d steps with the LR "
            "and noise schedule compressed to them (x%.3f)",
            rate, self.fitted, self.planned_steps, self.budget_s, self.fitted, factor,
        )  # fmt: skip

    def _replan(self, trainer, pl_module, done: int) -> None:
        """Re-fit the steps to the budget with the recent training rate (count_validation=False), both ways:
        shrink when the rate fell, so the budget's cap never cuts the schedule, and grow (up to
        ``max_steps``) when it rose again, so a slow spell early in the run does not leave budget unused.
        The rate is measured over the last :attr:`rate_window` re-plans; the fit moves only when it is off by
        more than 1% (shrink) or 2% (grow), so the schedule moves rarely."""
        now = (self.training_s(), trainer.global_step)
        self._marks.append(now)
        then = self._marks[max(0, len(self._marks) - 1 - self.rate_window)]
        if now[0] <= then[0] or now[1] <= then[1]:
            return
        rate = (now[1] - then[1]) / (now[0] - then[0])
        steps = fitted_steps(
            self.planned_steps, trainer.global_step, rate, self.budget_s - self._elapsed(), self.safety
        )
        if steps < 0.99 * self.fitted or steps > 1.02 * self.fitted:
            log.warning("Time budget: at %.1f steps/s now, training %d steps instead of %d", rate, steps,
                        self.fitted)  # fmt: skip
            self.fitted = max(steps, trainer.global_step + 1)
            self._apply(trainer, pl_module)

    def on_validation_end(self, trainer, pl_module) -> None:
        """Re-plan with the measured cost of a validation run (shrink only, so a cap never cuts the run)."""
        super().on_validation_end(trainer, pl_module)
        if not self.count_validation:
            return  # validation costs no budget
        if self.validations == 0 or self.budget_s is None or self._start is None or self.fitted is None:
            return
        elapsed = time.perf_counter() - self._start
        done = trainer.global_step - self._first_step
        training_s = elapsed - self.validation_s
        if done <= 0 or training_s <= 0:
            return
        interval = trainer.val_check_interval if isinstance(trainer.val_check_interval, int) else None
        seconds_per_step = training_s / done
        if interval:  # each further step also brings 1/interval of a validation run
            seconds_per_step += self.validation_s / self.validations / interval
        remaining = self.budget_s - elapsed
        steps = fitted_steps(self.fitted, trainer.global_step, 1.0 / seconds_per_step, remaining, self.safety)
        if steps < self.fitted:
            log.warning("Time budget: validation runs cost %.1f s each; training %d steps instead of %d",
                        self.validation_s / self.validations, steps, self.fitted)  # fmt: skip
            self.fitted = max(steps, trainer.global_step + 1)
            self._apply(trainer, pl_module)

    def on_train_end(self, trainer, pl_module) -> None:
        super().on_train_end(trainer, pl_module)
        target = self.fitted if self.fitted is not None else self.planned_steps
        if target is not None and trainer.global_step < target:
            log.warning(
                "Training stopped at step %d of %d (a time cap, train.max_time, cut it short): the LR and "
                "noise schedule did not complete.",
                trainer.global_step, target,
            )  # fmt: skip
