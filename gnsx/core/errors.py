"""Errors that are part of gnsx's interface: one clear line naming the file, field, frame or override.

Every entry point turns a :class:`GnsxError` into ``error: <message>`` on stderr and exit status 2
(:mod:`gnsx.core.cli`), and a :class:`RunFailed` into the same line with exit status 1; anything else is a bug
and keeps its traceback.
"""


class GnsxError(Exception):
    """Base class of gnsx's user-facing errors: the message is one line that says where and what."""


class DataError(GnsxError, ValueError):
    """Bad or unreadable input data.

    The message always names where the problem is, e.g.
    ``data/train.tfrecord: trajectory 12, field 'position': frame 40 has NaN``.
    """

    def __init__(self, where: str, problem: str):
        self.where = str(where)
        self.problem = problem
        super().__init__(f"{self.where}: {problem}")


class CheckpointError(DataError):
    """A file that is not a usable checkpoint: not one at all, truncated, or of another model config."""


class ConfigError(DataError):
    """A bad setting; ``where`` names it as the override that sets it, e.g. ``train.max_steps=-1``."""


class RunFailed(Exception):
    """A run that failed for a reason that is not a bug and not bad input (e.g. training diverged): one
    line, exit status 1."""
