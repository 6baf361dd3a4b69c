"""Dataset metadata in DeepMind's ``metadata.json`` schema, and the normalisation statistics behind it.

A ``metadata.json`` holds (WaterRamps values as an example)::

    {"bounds": [[0.1, 0.9], [0.1, 0.9]],       # [dim][lo, hi], data units (metres)
     "sequence_length": 600,                   # transitions per trajectory = frames - 1
     "default_connectivity_radius": 0.015,     # data units
     "dim": 2,
     "dt": 0.0025,                             # seconds between frames
     "vel_mean": [...], "vel_std": [...],      # [dim], per-frame position differences (NOT divided by dt)
     "acc_mean": [...], "acc_std": [...]}      # [dim], per-frame second differences (NOT divided by dt^2)

Any other key (DeepMind's ``context_mean``, LagrangeBench's ``periodic_boundary_conditions``, gnsx's
``"gnsx"`` generation facts) is kept verbatim in :attr:`Metadata.extra` and written back unchanged.
geoelements/gns files that split the metadata into ``"train"`` and ``"rollout"`` sections are read from their
``"train"`` section; the other sections stay in ``extra``.
"""

from __future__ import annotations

import json
import math
import numbers
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from gnsx.core.atomic import atomic_path
from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.core.errors import DataError
from gnsx.data.trajectory import Trajectory

#: The statistics keys, each a ``[dim]`` list.
STATISTICS_KEYS = ("vel_mean", "vel_std", "acc_mean", "acc_std")
#: Keys every metadata.json must hold besides the statistics.
GEOMETRY_KEYS = ("bounds", "sequence_length", "default_connectivity_radius", "dim", "dt")
_CORE_KEYS = GEOMETRY_KEYS + STATISTICS_KEYS


@dataclass
class Metadata:
    """One dataset's metadata (DeepMind's schema plus verbatim extras).

    Attributes:
        bounds: ``[dim][2]`` domain walls ``[lo, hi]`` per dimension, data units.
        sequence_length: transitions per trajectory (frames - 1); ``None`` only while being built.
        default_connectivity_radius: neighbour radius R, data units.
        dim: spatial dimension (2 for WaterRamps).
        dt: seconds between frames (informational: the model works in per-frame units, dt = 1).
        vel_mean, vel_std: ``[dim]`` mean/std of per-frame velocity ``p[t] - p[t-1]`` over non-static
            particles of the train split; ``None`` until computed.
        acc_mean, acc_std: ``[dim]`` mean/std of ``p[t+1] - 2 p[t] + p[t-1]``, same particles; ``None``
            until computed.
        extra: every other key of the JSON file, kept verbatim.
    """

    bounds: list[list[float]]
    sequence_length: int | None
    default_connectivity_radius: float
    dim: int
    dt: float
    vel_mean: list[float] | None = None
    vel_std: list[float] | None = None
    acc_mean: list[float] | None = None
    acc_std: list[float] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def has_statistics(self) -> bool:
        """Whether all four statistics are present."""
        return all(getattr(self, key) is not None for key in STATISTICS_KEYS)

    def bounds_array(self) -> np.ndarray:
        """The bounds as a float64 ``[dim, 2]`` array of ``[lo, hi]`` rows."""
        return np.asarray(self.bounds, dtype=np.float64).reshape(self.dim, 2)

    def with_statistics(self, statistics: Mapping[str, list[float]]) -> Metadata:
        """A copy with ``vel_mean``, ``vel_std``, ``acc_mean``, ``acc_std`` taken from ``statistics``."""
        return replace(self, **{key: list(statistics[key]) for key in STATISTICS_KEYS})

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready dict: DeepMind's keys first (``None`` ones omitted), then ``extra`` verbatim."""
        out: dict[str, Any] = {}
        for key in _CORE_KEYS:
            value = getattr(self, key)
            if value is not None:
                out[key] = value
        out.update(self.extra)
        return out

    def save(self, path: str | os.PathLike) -> None:
        """Write ``metadata.json`` atomically (temp file in the same folder, then ``os.replace``)."""
        path = Path(path)
        text = json.dumps(self.to_dict(), indent=2, default=_plain_or_fail) + "\n"
        with atomic_path(path) as tmp, open(tmp, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())

    @classmethod
    def load(cls, path: str | os.PathLike, *, partial: bool = False) -> Metadata:
        """Read and validate a ``metadata.json``.

        Raises:
            DataError: missing file, invalid JSON, or any problem :meth:`from_dict` reports, naming the file.
        """
        return cls.from_dict(read_metadata_json(path), where=str(path), partial=partial)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "metadata", *, partial: bool = False) -> Metadata:
        """Validate a metadata dict and build a :class:`Metadata`.

        Args:
            d: the parsed JSON object.
            where: names the source in error messages (the file path).
            partial: allow ``sequence_length`` and the four statistics to be absent or ``null`` (a dataset
                being written fills them in); a stored dataset's metadata is loaded with ``partial=False``.

        Raises:
            DataError: a missing key, a wrong type, a per-dim list whose length is not ``dim``, bounds with
                ``lo >= hi``, a non-positive ``dt``, radius or std, naming ``where`` and the key.
        """
        if not isinstance(d, Mapping):
            raise DataError(where, f"expected a JSON object, got {type(d).__name__}")
        # Callers building metadata in code may hand numpy arrays/scalars; JSON wants plain lists/numbers.
        d = {key: _plain(value) for key, value in _flatten_sections(d).items()}
        optional = {"sequence_length", *STATISTICS_KEYS} if partial else set()
        missing = [key for key in _CORE_KEYS if d.get(key) is None and key not in optional]
        if missing:
            raise DataError(where, f"missing key(s) {', '.join(repr(k) for k in missing)}")

        dim = _as_int(d["dim"], where, "dim", minimum=1)
        bounds = d["bounds"]
        if not isinstance(bounds, list | tuple) or len(bounds) != dim:
            raise DataError(where, f"key 'bounds': expected {dim} [lo, hi] pairs (dim={dim}), got {bounds!r}")
        pairs = []
        for axis, pair in enumerate(bounds):
            if not isinstance(pair, list | tuple) or len(pair) != 2:
                raise DataError(where, f"key 'bounds': entry {axis} must be [lo, hi], got {pair!r}")
            lo = _as_float(pair[0], where, f"bounds[{axis}][0]")
            hi = _as_float(pair[1], where, f"bounds[{axis}][1]")
            if not lo < hi:
                raise DataError(where, f"key 'bounds': entry {axis} has lo={lo} >= hi={hi}")
            pairs.append([lo, hi])

        sequence_length = None
        if d.get("sequence_length") is not None:
            sequence_length = _as_int(d["sequence_length"], where, "sequence_length", minimum=1)
        radius = _as_float(d["default_connectivity_radius"], where, "default_connectivity_radius")
        if radius <= 0:
            raise DataError(where, f"key 'default_connectivity_radius': must be > 0, got {radius}")
        dt = _as_float(d["dt"], where, "dt")
        if dt <= 0:
            raise DataError(where, f"key 'dt': must be > 0, got {dt}")

        statistics: dict[str, list[float] | None] = {}
        for key in STATISTICS_KEYS:
            value = d.get(key)
            if value is None:
                statistics[key] = None
                continue
            if not isinstance(value, list | tuple) or len(value) != dim:
                raise DataError(
                    where, f"key '{key}': expected a list of {dim} numbers (dim={dim}), got {value!r}"
                )
            numbers = [_as_float(v, where, f"{key}[{i}]") for i, v in enumerate(value)]
            if key.endswith("_std") and min(numbers) <= 0:
                raise DataError(where, f"key '{key}': every entry must be > 0, got {numbers}")
            statistics[key] = numbers

        extra = {key: value for key, value in d.items() if key not in _CORE_KEYS}
        return cls(
            bounds=pairs,
            sequence_length=sequence_length,
            default_connectivity_radius=radius,
            dim=dim,
            dt=dt,
            extra=extra,
            **statistics,
        )


def read_metadata_json(path: str | os.PathLike) -> dict[str, Any]:
    """Parse a ``metadata.json`` into a dict, unvalidated (DataError naming the file if unreadable)."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise DataError(str(path), "metadata file not found") from None
    except OSError as e:
        raise DataError(str(path), f"cannot read metadata: {e.strerror or e}") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise DataError(str(path), f"invalid JSON at line {e.lineno}, column {e.colno}: {e.msg}") from None
    if not isinstance(d, dict):
        raise DataError(str(path), f"expected a JSON object, got {type(d).__name__}")
    return d


def compute_statistics(
    trajectories: Iterable[Trajectory], where: str = "statistics"
) -> dict[str, list[float]]:
    """DeepMind's normalisation statistics, streamed over ``trajectories``.

    Velocities are ``v = p[t] - p[t-1]`` (``T - 1`` per trajectory) and accelerations
    ``a = p[t+1] - 2 p[t] + p[t-1]`` (``T - 2`` per trajectory): per-frame differences, *not* divided by dt,
    because the model works with dt = 1. Only non-static particles (type != ``KINEMATIC_PARTICLE_ID``) count:
    static particles never move and would pull the std towards zero. Means and population stds (ddof 0) are
    per dimension over all frames, particles and trajectories.

    Memory is one trajectory at a time: each trajectory's mean and sum of squared deviations (float64) are
    merged with Chan et al.'s pairwise update, which stays accurate where ``E[x^2] - E[x]^2`` would cancel.

    Args:
        trajectories: any iterable (a reader or a :class:`~gnsx.data.store.SplitReader`), read once.
        where: names the data in error messages.

    Returns:
        ``{"vel_mean", "vel_std", "acc_mean", "acc_std"}``, each a ``[dim]`` list of floats (data units per
        frame and per frame^2).

    Raises:
        DataError: no non-static particle with 2 (velocity) or 3 (acceleration) frames, or a std of 0.
    """
    velocity = _RunningMoments()
    acceleration = _RunningMoments()
    for traj in trajectories:
        dynamic = np.asarray(traj.particle_type) != KINEMATIC_PARTICLE_ID
        if not dynamic.any():
            continue
        # Dimension-major [D, T, N_dynamic] float64: the per-dimension reductions then run over contiguous
        # memory (about 2x faster than reducing the [T * N, D] layout along axis 0).
        position = np.ascontiguousarray(np.asarray(traj.position)[:, dynamic].transpose(2, 0, 1), np.float64)
        vel = position[:, 1:] - position[:, :-1]  # [D, T-1, N_dynamic]
        velocity.add(vel.reshape(vel.shape[0], -1))
        acc = vel[:, 1:] - vel[:, :-1]  # [D, T-2, N_dynamic]
        acceleration.add(acc.reshape(acc.shape[0], -1))
    out = {}
    for name, moments in (("vel", velocity), ("acc", acceleration)):
        if moments.count == 0:
            raise DataError(
                where,
                f"cannot compute {name}_mean/{name}_std: no non-static particle (type != "
                f"{KINEMATIC_PARTICLE_ID}) with enough frames",
            )
        std = np.sqrt(moments.m2 / moments.count)
        if (std <= 0).any():
            raise DataError(where, f"{name}_std is 0 in some dimension ({std.tolist()}): nothing moves")
        out[f"{name}_mean"] = moments.mean.tolist()
        out[f"{name}_std"] = std.tolist()
    return out


class _RunningMoments:
    """Streaming per-dimension mean and sum of squared deviations (Chan et al.'s parallel update)."""

    def __init__(self) -> None:
        self.count = 0
        self.mean: np.ndarray = np.zeros(0)
        self.m2: np.ndarray = np.zeros(0)

    def add(self, x: np.ndarray) -> None:
        """Merge the samples ``x`` ``[dim, num_samples]`` (float64)."""
        n = x.shape[1]
        if n == 0:
            return
        mean = x.mean(axis=1)
        deviation = x - mean[:, None]
        m2 = np.einsum("ij,ij->i", deviation, deviation)
        if self.count == 0:
            self.count, self.mean, self.m2 = n, mean, m2
            return
        total = self.count + n
        delta = mean - self.mean
        self.mean = self.mean + delta * (n / total)
        self.m2 = self.m2 + m2 + delta**2 * (self.count * n / total)
        self.count = total


def _flatten_sections(d: Mapping[str, Any]) -> dict[str, Any]:
    """geoelements/gns may nest the metadata as ``{"train": {...}, "rollout": {...}}``: read ``train``."""
    if "bounds" not in d and isinstance(d.get("train"), Mapping) and "bounds" in d["train"]:
        flat = dict(d["train"])
        flat.update({key: value for key, value in d.items() if key != "train"})
        return flat
    return dict(d)


def _plain(value: Any) -> Any:
    """numpy arrays/scalars to lists/numbers (JSON-ready); anything else unchanged."""
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    return value


def _plain_or_fail(value: Any) -> Any:
    # json.dumps calls this only for objects it cannot encode itself.
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    raise TypeError(f"metadata value of type {type(value).__name__} is not JSON serialisable")


def _as_int(value: Any, where: str, key: str, minimum: int) -> int:
    # JSON writers sometimes emit 600.0 for an integer; accept integral floats, reject bools and fractions.
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not float(value).is_integer():
        raise DataError(where, f"key '{key}': expected an integer, got {value!r}")
    if value < minimum:
        raise DataError(where, f"key '{key}': must be >= {minimum}, got {value!r}")
    return int(value)


def _as_float(value: Any, where: str, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise DataError(where, f"key '{key}': expected a finite number, got {value!r}")
    return float(value)
