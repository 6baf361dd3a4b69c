"""How every entry point answers bad input: one line ``error: <where>: <what>`` on stderr, exit status 2.

Two wrappers, one policy:

* :func:`run_main` wraps an argparse ``main(argv) -> int`` (``python -m gnsx.data``, ``gnsx.training.export``,
  ``gnsx.perf.throughput``; ``gnsx.evaluation.report`` and ``gnsx.perf.benchmark`` can adopt it the same way);
* :func:`run_hydra` runs a ``@hydra.main`` function as a script (``train.py``, ``evaluate.py``,
  ``simulate.py``). It sets ``HYDRA_FULL_ERROR=1`` so Hydra re-raises instead of printing its own
  multi-line report, and prints a composition error (bad override, unknown config group option) as one
  line; :func:`hydra_task` decorates the task function itself, so a :class:`~gnsx.core.errors.GnsxError` (or a
  missing mandatory value) it raises is printed once, before Hydra's "Error executing job" line, and a
  :class:`~gnsx.core.errors.RunFailed` (training diverged) is one line with exit status 1.

User errors are :class:`~gnsx.core.errors.GnsxError`, Hydra's composition errors and whatever extra types a caller
names. Anything else is a bug and keeps its traceback. ``--debug`` (removed from the arguments before they
are parsed) or ``GNSX_DEBUG=1`` shows the traceback of user errors too (for Hydra scripts, so does setting
``HYDRA_FULL_ERROR=1`` yourself).
"""

from __future__ import annotations

import argparse
import functools
import os
import re
import shutil
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from gnsx.core.errors import ConfigError, GnsxError, RunFailed

#: Exit status of every entry point on bad input (argparse's too).
EXIT_BAD_INPUT = 2
#: Exit status of a run that failed without a bug (:class:`~gnsx.core.errors.RunFailed`, e.g. diverged).
EXIT_RUN_FAILED = 1
DEBUG_FLAG = "--debug"
DEBUG_ENV = "GNSX_DEBUG"


def debug_requested(argv: list[str]) -> bool:
    """Whether tracebacks were asked for; removes ``--debug`` from ``argv`` (in place)."""
    flagged = DEBUG_FLAG in argv
    while DEBUG_FLAG in argv:
        argv.remove(DEBUG_FLAG)
    return flagged or os.environ.get(DEBUG_ENV, "") not in ("", "0")


def one_line(text: str) -> str:
    """A multi-line library message as one line: list items joined by commas, links and search paths
    dropped, whitespace collapsed."""
    lines = []
    for raw in str(text).splitlines():
        line = raw.strip()
        if not line or line.startswith("See https://") or line.startswith("Set the environment variable"):
            continue
        if line.startswith("Config search path"):
            break
        lines.append(line)
    out = ""
    for line in lines:
        if not out:
            out = line
        elif out.endswith(":"):
            out = f"{out} {line}"
        elif out.endswith(tuple(".!?")) or line[:1].isupper():
            sep = " " if out.endswith(tuple(".!?")) else ". "
            out = f"{out}{sep}{line}"
        else:
            out = f"{out}, {line}"
    return re.sub(r"\s+", " ", out).strip()


def user_message(error: BaseException, user_errors: tuple[type[BaseException], ...] = ()) -> str | None:
    """The one-line message of a user error, or None for anything else (a bug)."""
    if isinstance(error, (GnsxError, *user_errors)):
        return one_line(str(error))
    try:
        from hydra.errors import CompactHydraException
        from omegaconf.errors import MissingMandatoryValue
    except ImportError:  # pragma: no cover - Hydra is a dependency
        return None
    if isinstance(error, MissingMandatoryValue):
        key = getattr(error, "full_key", None) or "value"
        return f"{key}: missing; pass {key}=... on the command line"
    if isinstance(error, CompactHydraException):
        message = one_line(str(error))
        cause = error.__cause__
        if cause is not None:
            detail = next((line.strip() for line in str(cause).splitlines() if line.strip()), "")
            message = f"{message.rstrip('.')} ({detail})" if detail else message
        return message
    return None


def report(message: str) -> int:
    """Print ``error: message`` as one line on stderr; return :data:`EXIT_BAD_INPUT`."""
    print(f"error: {one_line(message)}", file=sys.stderr, flush=True)
    return EXIT_BAD_INPUT


class ArgumentParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``error: prog: message (see --help)``), exit status 2."""

    def error(self, message: str):  # noqa: D102 - argparse's hook
        report(f"{self.prog}: {message} (see --help)")
        sys.exit(EXIT_BAD_INPUT)


def run_main(
    main: Callable[[list[str]], int],
    argv: Sequence[str] | None = None,
    user_errors: tuple[type[BaseException], ...] = (),
) -> int:
    """Run an argparse ``main(argv)``; a user error becomes one line on stderr and status 2.

    Args:
        main: returns the exit status.
        argv: the arguments (default ``sys.argv[1:]``); ``--debug`` is taken out of them.
        user_errors: further exception types that mean bad input for this command (e.g. ``ValueError`` for
            a command whose only inputs are its flags).
    """
    args = list(sys.argv[1:] if argv is None else argv)
    debug = debug_requested(args)
    try:
        return main(args)
    except Exception as error:
        message = user_message(error, user_errors)
        if message is None or debug:
            raise
        return report(message)


def _debug_env() -> bool:
    return os.environ.get(DEBUG_ENV, "") not in ("", "0")


def hydra_task(task: Callable[[Any], Any]) -> Callable[[Any], Any]:
    """Decorate a Hydra task function (under ``@hydra.main``): a user error raised by the task prints one
    line and exits 2 from inside the task, before Hydra adds its own "Error executing job" report."""

    @functools.wraps(task)  # Hydra unwraps __wrapped__ to find the script's config path
    def run(cfg: Any) -> Any:
        try:
            return task(cfg)
        except RunFailed as error:
            if _debug_env():
                raise
            report(str(error))
            sys.exit(EXIT_RUN_FAILED)
        except Exception as error:
            message = user_message(error)
            if message is None or _debug_env():
                raise
            _remove_bare_run_dir()
            sys.exit(report(message))

    return run


def _remove_bare_run_dir() -> None:
    """Remove the run folder Hydra made for a task that failed on bad input, when it holds nothing but
    Hydra's own files (``.hydra/`` and the job's log, which repeats the console), and its parents up to the
    working folder once empty. A folder with anything else in it (an earlier run's checkpoints or results)
    is left as it is."""
    try:
        from hydra.core.hydra_config import HydraConfig

        hydra_cfg = HydraConfig.get()
        run_dir = Path(hydra_cfg.runtime.output_dir).resolve()
        job_log = f"{hydra_cfg.job.name}.log"
    except Exception:  # no Hydra context (a test calling the task directly)
        return
    cwd = Path.cwd().resolve()
    if not run_dir.is_dir() or cwd not in run_dir.parents:
        return
    if any(entry.name not in (".hydra", job_log) for entry in run_dir.iterdir()):
        return
    shutil.rmtree(run_dir, ignore_errors=True)
    for parent in run_dir.parents:
        if parent == cwd or any(parent.iterdir()):
            break
        parent.rmdir()


def run_hydra(main: Callable[[], Any]) -> None:
    """Run a ``@hydra.main`` function as a script; bad input exits 2 with one line (see the module doc).

    Composition errors (before the task runs) are caught here; the task's own with :func:`hydra_task`.
    """
    if debug_requested(sys.argv):
        os.environ[DEBUG_ENV] = "1"  # seen by hydra_task, and by DDP ranks that Lightning relaunches
    user_full_error = os.environ.get("HYDRA_FULL_ERROR", "") not in ("", "0")
    os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra re-raises instead of printing its multi-line report
    if _debug_env() or user_full_error:
        main()
        return
    try:
        main()
    except Exception as error:
        message = user_message(error)
        if message is None:
            raise
        sys.exit(report(message))


# -- checks shared by the entry points ----------------------------------------------------------------------
def check_output_path(path: str | os.PathLike, name: str) -> Path:
    """``path`` can be created as a file or folder: no part of it is an existing file, and it is not one.

    Raises:
        ConfigError: naming ``name`` (the flag or override) and the part that is a file.
    """
    path = Path(path)
    for parent in [path, *path.parents]:
        if parent.exists():
            if parent != path and not parent.is_dir():
                raise ConfigError(f"{name} {path}", f"{parent} is a file, not a folder")
            if not os.access(parent if parent.is_dir() else parent.parent, os.W_OK):
                raise ConfigError(f"{name} {path}", f"{parent} is not writable")
            break
    return path


def check_int(value: Any, name: str, minimum: int | None = None, allow_none: bool = False) -> int | None:
    """``value`` as an int of at least ``minimum`` (``None`` allowed with ``allow_none``).

    Raises:
        ConfigError: ``"<name>=<value>: expected an integer >= <minimum>"``.
    """
    if value is None and allow_none:
        return None
    bound = f" >= {minimum}" if minimum is not None else ""
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise ConfigError(f"{name}={value}", f"expected an integer{bound}")
    try:
        number = float(value)
    except ValueError:
        raise ConfigError(f"{name}={value}", f"expected an integer{bound}") from None
    if not number.is_integer():
        raise ConfigError(f"{name}={value}", f"expected an integer{bound}")
    if minimum is not None and number < minimum:
        raise ConfigError(f"{name}={value}", f"must be{bound}")
    return int(number)


def check_number(value: Any, name: str, positive: bool = False, allow_none: bool = False) -> float | None:
    """``value`` as a finite float (``> 0`` with ``positive``; ``None`` allowed with ``allow_none``)."""
    if value is None and allow_none:
        return None
    what = "a positive number" if positive else "a number"
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}={value}", f"expected {what}") from None
    if number != number or number in (float("inf"), float("-inf")) or (positive and number <= 0):
        raise ConfigError(f"{name}={value}", f"expected {what}")
    return number
