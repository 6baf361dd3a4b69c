"""Training numerics: a NaN or Inf loss or gradient never reaches the weights.

:class:`~gnsx.training.system.GNSSystem` checks every step. A step whose loss is not finite is skipped: the training
step returns a zero loss built from the parameters alone (finite zeros for backward, nothing of the NaN
graph), and its gradients are dropped (set to None) before the optimizer, so Adam leaves every weight and
every moment alone. A step whose loss is finite but whose gradients are not has them dropped the same way,
before gradient clipping. Both are logged (``train/skipped_steps``), counted by :class:`SkippedSteps` and
kept in the checkpoint. More than ``max_in_a_row`` skipped steps in a row stop training with
:class:`Diverged`: the weights are still those of the last good step, and so are the checkpoints. The step
counter (and with it the LR schedule) still advances over a skipped step.

Under DDP the loss decision is made by all ranks together (any rank's non-finite loss skips the step on
every rank: a rank stepping alone would leave the replicas apart); gradients are already averaged over
ranks when they are checked, so every rank decides alike.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable

import torch

from gnsx.core.errors import RunFailed

log = logging.getLogger("gnsx")


class Diverged(RunFailed, RuntimeError):
    """Training or a test rollout became NaN or infinite; the message starts with ``"diverged:"``."""

    def __init__(self, what: str):
        super().__init__(f"diverged: {what}")


def finite_gradients(parameters: Iterable[torch.nn.Parameter]) -> bool:
    """Whether every gradient of ``parameters`` is finite (parameters without a gradient are ignored)."""
    grads = [p.grad.detach() for p in parameters if p.grad is not None]
    if not grads:
        return True
    norms = torch._foreach_norm(grads) if hasattr(torch, "_foreach_norm") else [g.norm() for g in grads]
    return bool(torch.isfinite(torch.stack(norms)).all())


def drop_gradients(parameters: Iterable[torch.nn.Parameter]) -> None:
    """Set every gradient to None: the optimizer then skips every parameter (weights and moments stay)."""
    for p in parameters:
        p.grad = None


class SkippedSteps:
    """Counts optimizer steps skipped for a non-finite loss or gradient.

    Args:
        max_in_a_row: more skipped steps than this in a row raise :class:`Diverged` (0: never stop).

    Attributes:
        total: steps skipped in the whole run (restored from checkpoints).
        in_a_row: steps skipped since the last good one.
        first: ``(step, reason)`` of the first step of the current run of skips.
    """

    def __init__(self, max_in_a_row: int = 20):
        if max_in_a_row < 0:
            raise ValueError(f"SkippedSteps: max_in_a_row must be >= 0, got {max_in_a_row}")
        self.max_in_a_row = int(max_in_a_row)
        self.total = 0
        self.in_a_row = 0
        self.first: tuple[int, str] | None = None

    def skip(self, step: int, reason: str) -> None:
        """Record that optimizer step ``step`` was skipped because of ``reason`` (e.g. ``"loss is nan"``).

        Raises:
            Diverged: more than ``max_in_a_row`` steps were skipped in a row.
        """
        self.total += 1
        self.in_a_row += 1
        if self.in_a_row == 1:
            self.first = (step, reason)
        log.warning("Step %d skipped, the weights untouched: %s (%d skipped in this run, %d in a row)",
                    step, reason, self.total, self.in_a_row)  # fmt: skip
        if self.max_in_a_row and self.in_a_row > self.max_in_a_row:
            first_step, first_reason = self.first
            raise Diverged(
                f"{self.in_a_row} steps in a row had a non-finite loss or gradient (from step {first_step}: "
                f"{first_reason}; train.max_skipped_steps={self.max_in_a_row}); no weight was updated by "
                "them, so the last checkpoint holds the last good weights"
            )

    def ok(self) -> None:
        """A step went through: the run of skips (if any) ends."""
        self.in_a_row = 0
        self.first = None
