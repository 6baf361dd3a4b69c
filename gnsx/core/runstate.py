"""Is the run behind a ``results.json`` still alive? A killed job cannot say that it stopped, so a running job
says who it is and when it was last seen, and a reader decides.

While it runs, ``results.json`` holds ``"status": "running"`` with ``"pid"``, ``"pid_start"`` (the process's
start time, so a reused pid is not mistaken for it), ``"host"`` and ``"heartbeat"`` (Unix seconds, refreshed
every :data:`HEARTBEAT_S` by :class:`gnsx.training.resilience.Heartbeat`). :func:`effective_status` turns such a
record into ``"interrupted"`` when its process is gone (same host) or its heartbeat is older than
:data:`STALE_S` (another host); :func:`mark_interrupted` writes that verdict back. ``train.py`` applies it to
the run directory it starts in and to the run it resumes from; ``python -m gnsx.evaluation.report`` should read a job's
status through :func:`effective_status`.

Standard library only, so readers (the report) need neither torch nor Lightning.
"""

from __future__ import annotations

import json
import os
import socket
import time
from pathlib import Path
from typing import Any

from gnsx.core.atomic import write_json

#: Seconds between heartbeats of a running job.
HEARTBEAT_S = 30.0
#: A running job on another host whose heartbeat is older than this is taken for dead.
STALE_S = 10 * 60.0
INTERRUPTED = "interrupted"


def process_start(pid: int) -> float | None:
    """When process ``pid`` started (seconds since the epoch, psutil), or None if there is no such process.

    With the pid it names a process uniquely: a pid the OS reused belongs to a process started later.
    (Records written before 2026-12-06 hold clock ticks since boot instead; they never match, which reads
    their process as gone: right for the finished jobs they describe.)"""
    import psutil

    try:
        return psutil.Process(int(pid)).create_time()
    except (psutil.Error, ValueError, OverflowError):
        return None


def liveness() -> dict[str, Any]:
    """What a running job writes into its ``results.json``: pid, its start time, host and a heartbeat."""
    pid = os.getpid()
    return {
        "pid": pid,
        "pid_start": process_start(pid),
        "host": socket.gethostname(),
        "heartbeat": time.time(),
    }


def pid_alive(pid: int, start: float | None = None) -> bool:
    """Whether process ``pid`` runs on this host (and, when ``start`` is given, is the same process: it
    started then, :func:`process_start`); a zombie (finished, not yet reaped) does not run."""
    import psutil

    try:
        process = psutil.Process(int(pid))
        if start is not None and abs(process.create_time() - float(start)) > 0.01:
            return False  # the pid was reused
        return process.status() != psutil.STATUS_ZOMBIE
    except psutil.AccessDenied:
        return True  # exists, owned by someone else
    except (psutil.Error, ValueError, OverflowError, TypeError):
        return False


def effective_status(results: dict[str, Any], now: float | None = None) -> str:
    """``results["status"]``, except that a "running" job that is gone is ``"interrupted"``.

    Gone: on this host, its pid no longer runs (or is another process now); on another host (or without a
    pid), its heartbeat is older than :data:`STALE_S`. A record without pid or heartbeat (written before
    gnsx recorded them) stays "running": nothing tells.
    """
    status = results.get("status")
    if status != "running":
        return status
    pid, host, beat = results.get("pid"), results.get("host"), results.get("heartbeat")
    if pid is not None and host == socket.gethostname():
        return "running" if pid_alive(pid, results.get("pid_start")) else INTERRUPTED
    if isinstance(beat, int | float):
        age = (time.time() if now is None else now) - beat
        return INTERRUPTED if age > STALE_S else "running"
    return "running"


def interrupted_reason(results: dict[str, Any]) -> str:
    """The one-line error of an interrupted job: where it was last seen and how to resume it."""
    seen = results.get("heartbeat")
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(seen)) if isinstance(seen, int | float) else "?"
    step = results.get("global_step")
    at = f" at step {step}" if step is not None else ""
    run_dir = results.get("run_dir", "<run dir>")
    return (
        f"interrupted: process {results.get('pid')} on {results.get('host')} stopped without finishing "
        f"(killed?), last seen {when}{at}; resume with train.ckpt_path={run_dir}"
    )


def mark_interrupted(path: str | os.PathLike, **extra: Any) -> dict[str, Any] | None:
    """Rewrite a dead "running" ``results.json`` as ``"interrupted"`` (with a one-line ``"error"`` and
    ``extra``). Returns the updated record, or None when the file is missing, unreadable or not a dead job."""
    path = Path(path)
    try:
        results = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(results, dict) or results.get("status") != "running":
        return None
    if effective_status(results) != INTERRUPTED:
        return None
    results.update(status=INTERRUPTED, error=interrupted_reason(results), **extra)
    write_json(path, results)
    return results
