"""Surviving a kill: atomic checkpoints, checkpoints by wall time, and a heartbeat in ``results.json``.

A training run killed with SIGKILL at any moment resumes with one override (``train.ckpt_path=<run dir>``)
and loses at most ``train.checkpoint_every_minutes`` of training:

* :class:`AtomicCheckpointIO` writes every checkpoint to a temporary file in the checkpoint's own folder,
  flushes it to disk and renames it onto the target (``os.replace``, atomic on one filesystem). A kill during
  a save leaves the previous ``last.ckpt`` whole (plus a stray ``.last.ckpt.*.tmp``, removed by the next run
  in that folder). Lightning's own writer goes through an fsspec transaction that stages the file in the
  system temp folder and *moves* it into place, which is a copy, not a rename, when that folder is on
  another filesystem: a kill during the copy leaves a truncated ``last.ckpt``.
* :func:`wall_clock_checkpoint` saves ``last.ckpt`` every N minutes of wall time, besides the step-based
  checkpoints (a slow run with the default 1,000-step interval could otherwise run an hour unsaved).
* :class:`Heartbeat` refreshes ``results.json``'s liveness fields (:mod:`gnsx.core.runstate`) every
  :data:`~gnsx.core.runstate.HEARTBEAT_S`, so the next run or the report can tell a killed job from a running one.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from datetime import timedelta
from pathlib import Path
from typing import Any

import torch
from lightning.pytorch.callbacks import Callback, ModelCheckpoint
from lightning.pytorch.plugins.io import TorchCheckpointIO

from gnsx.core.atomic import atomic_path
from gnsx.core.runstate import HEARTBEAT_S, liveness

#: Marks a ``map_location`` the caller did not give (None is a value torch.load takes).
_KEEP = object()


class AtomicCheckpointIO(TorchCheckpointIO):
    """Lightning checkpoint IO that writes by rename in the target's folder and reads with
    ``weights_only=True`` (see the module docstring)."""

    def save_checkpoint(self, checkpoint: dict[str, Any], path, storage_options: Any | None = None) -> None:
        if storage_options is not None:
            raise TypeError(f"{type(self).__name__} takes no storage_options")
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            torch.save(checkpoint, f)
            f.flush()
            os.fsync(f.fileno())

    def load_checkpoint(self, path, map_location: Any = _KEEP, weights_only: bool | None = None) -> dict:
        if map_location is _KEEP:  # Lightning's default: every tensor stays on the CPU
            return super().load_checkpoint(path, weights_only=True)
        return super().load_checkpoint(path, map_location=map_location, weights_only=True)


def remove_stale_temporaries(folder: Path) -> list[Path]:
    """Delete ``.<name>.ckpt.*.tmp`` files a killed save left in ``folder``; returns them."""
    stale = sorted(folder.glob(".*.ckpt.*.tmp")) if folder.is_dir() else []
    for path in stale:
        path.unlink(missing_ok=True)
    return stale


def wall_clock_checkpoint(folder: Path, minutes: float) -> ModelCheckpoint:
    """A callback that writes ``folder/last.ckpt`` every ``minutes`` of wall time (checked after each training
    step; under DDP rank 0's clock decides for all)."""
    return ModelCheckpoint(
        dirpath=folder,
        train_time_interval=timedelta(minutes=float(minutes)),
        save_top_k=0,
        save_last=True,
        enable_version_counter=False,
    )


class Heartbeat(Callback):
    """Calls ``beat(fields)`` with fresh liveness fields (and the global step) every ``every_s`` seconds of
    training, and at every checkpoint save; rank 0 only.

    Args:
        beat: receives ``{"pid", "pid_start", "host", "heartbeat", "global_step"}``; e.g. updates and
            rewrites ``results.json``.
    """

    def __init__(self, beat: Callable[[dict[str, Any]], None], every_s: float = HEARTBEAT_S):
        self.beat = beat
        self.every_s = every_s
        self._last = 0.0

    def _send(self, trainer) -> None:
        if trainer.is_global_zero:
            self._last = time.monotonic()
            self.beat({**liveness(), "global_step": int(trainer.global_step)})

    def on_train_start(self, trainer, pl_module) -> None:
        self._send(trainer)

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx: int) -> None:
        if time.monotonic() - self._last >= self.every_s:
            self._send(trainer)

    def on_save_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        self._send(trainer)
