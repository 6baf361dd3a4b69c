"""Errors that are part of gnsx's interface: one clear line naming the file, field or frame."""


class GnsxError(Exception):
    """Base class of gnsx's user-facing errors."""


class DataError(GnsxError, ValueError):
    """Bad or unreadable input data.

    The message always names where the problem is, e.g.
    ``data/train.tfrecord: trajectory 12, field 'position': frame 40 has NaN``.
    """

    def __init__(self, where: str, problem: str):
        self.where = str(where)
        self.problem = problem
        super().__init__(f"{self.where}: {problem}")
