"""WaterRamps-like scenes: what a scene is, how to sample one, and how to turn it into particles.

A :class:`Scene` is plain data (water blocks and ramp segments, metres and m/s) so a user can write one in a
YAML file and :meth:`Scene.from_dict` it. :func:`sample_scene` draws scenes in the spirit of DeepMind's
WaterRamps (as its rollouts look; ``gnsx.data.waterramps`` holds its metadata): one rectangular water block, an
initial velocity of order 1 m/s in a
random direction, and 1 to 4 static ramps of random length and small angle (sometimes vertical, possibly
overlapping each other, never inside or touching the water). :func:`scene_particles` fills the blocks with
randomly placed water particles (a jittered lattice, not a visible grid) and lines each ramp with static
particles every ``ramp_spacing``.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.core.errors import DataError

if TYPE_CHECKING:  # presets import this module; only type hints need the reverse import
    from gnsx.mpm.presets import Preset

#: Attempts at placing one ramp clear of the water block before giving up on that ramp.
_RAMP_TRIES = 200
#: Attempts at drawing a whole scene (block plus at least one ramp) before reporting the preset as infeasible.
_SCENE_TRIES = 100

Point = tuple[float, float]


@dataclass
class WaterBlock:
    """An axis-aligned rectangle of water moving as one at the start.

    Attributes:
        lower: ``(x, y)`` lower-left corner, m.
        upper: ``(x, y)`` upper-right corner, m.
        velocity: ``(vx, vy)`` initial velocity of every particle of the block, m/s.
    """

    lower: Point
    upper: Point
    velocity: Point = (0.0, 0.0)

    @property
    def size(self) -> tuple[float, float]:
        return (self.upper[0] - self.lower[0], self.upper[1] - self.lower[1])


@dataclass
class Scene:
    """One initial condition: water blocks and static ramps (segments), in the wall box.

    Attributes:
        blocks: the water blocks.
        ramps: segments ``((x0, y0), (x1, y1))``, m.
    """

    blocks: list[WaterBlock] = field(default_factory=list)
    ramps: list[tuple[Point, Point]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """Plain lists and floats (YAML/JSON-ready).

        Layout: ``{"blocks": [{"lower": [x, y], "upper": [x, y], "velocity": [vx, vy]}],
        "ramps": [[[x0, y0], [x1, y1]]]}``.
        """
        return {
            "blocks": [
                {
                    "lower": list(map(float, b.lower)),
                    "upper": list(map(float, b.upper)),
                    "velocity": list(map(float, b.velocity)),
                }
                for b in self.blocks
            ],
            "ramps": [[list(map(float, p0)), list(map(float, p1))] for p0, p1 in self.ramps],
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "scene") -> Scene:
        """Build a scene from :meth:`to_dict`'s layout (e.g. read from YAML), validating every field.

        Raises:
            DataError: naming the field (``scene.blocks[0].upper``) that is missing or malformed.
        """
        if not isinstance(d, Mapping):
            raise DataError(where, f"expected a mapping with 'blocks' and 'ramps', got {type(d).__name__}")
        _check_keys(d, ("blocks", "ramps"), where)
        blocks = []
        for i, b in enumerate(_as_list(d.get("blocks", []), f"{where}.blocks")):
            w = f"{where}.blocks[{i}]"
            if not isinstance(b, Mapping) or not {"lower", "upper"} <= set(b):
                raise DataError(w, "expected a mapping with 'lower', 'upper' and optional 'velocity'")
            _check_keys(b, ("lower", "upper", "velocity"), w)
            lower = _point(b["lower"], f"{w}.lower")
            upper = _point(b["upper"], f"{w}.upper")
            if not (lower[0] < upper[0] and lower[1] < upper[1]):
                raise DataError(w, f"lower {list(lower)} must be below and left of upper {list(upper)}")
            blocks.append(WaterBlock(lower, upper, _point(b.get("velocity", (0.0, 0.0)), f"{w}.velocity")))
        ramps = []
        for i, r in enumerate(_as_list(d.get("ramps", []), f"{where}.ramps")):
            w = f"{where}.ramps[{i}]"
            seg = _as_list(r, w)
            if len(seg) != 2:
                raise DataError(w, f"expected two end points [[x0, y0], [x1, y1]], got {r!r}")
            p0, p1 = _point(seg[0], f"{w}[0]"), _point(seg[1], f"{w}[1]")
            if p0 == p1:
                raise DataError(w, "the two end points coincide (zero-length ramp)")
            ramps.append((p0, p1))
        return cls(blocks, ramps)

    def ramp_array(self) -> np.ndarray:
        """``[R, 2, 2]`` float64 ramp segments, m."""
        return np.asarray(self.ramps, dtype=np.float64).reshape(-1, 2, 2)


# ---------------------------------------------------------------------------------------------- particles


def water_particles(
    scene: Scene, spacing: float, rng: np.random.Generator, *, jitter: float = 0.35, clearance: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Randomly placed water particles filling every block, with their initial velocities.

    Each block gets a lattice of ``floor(size / spacing)`` points per axis, centred in the block, and every
    point moves by a uniform random offset of up to ``jitter * spacing`` per axis: irregular like the real
    data, yet one particle per ``spacing^2`` of area (the solver's particle volume) and no overlaps.

    Args:
        scene: the scene.
        spacing: mean particle spacing, m.
        rng: the random generator (consumed: one draw per block).
        jitter: the largest offset per axis, as a fraction of ``spacing`` (below 0.5 keeps points in cells).
        clearance: particles closer than this to a ramp segment are dropped (no water may start inside a
            ramp's collider band), m.

    Returns:
        ``[N, 2]`` float64 positions (m) and ``[N, 2]`` float64 velocities (m/s).
    """
    positions, velocities = [], []
    for block in scene.blocks:
        (w, h), counts = block.size, []
        for extent in (w, h):
            counts.append(max(1, int(math.floor(extent / spacing + 1e-9))))
        nx, ny = counts
        # Centre the lattice in the block so leftovers are shared by both sides.
        x0 = block.lower[0] + 0.5 * (w - (nx - 1) * spacing)
        y0 = block.lower[1] + 0.5 * (h - (ny - 1) * spacing)
        gx, gy = np.meshgrid(x0 + spacing * np.arange(nx), y0 + spacing * np.arange(ny), indexing="ij")
        p = np.stack([gx.reshape(-1), gy.reshape(-1)], -1)
        p = p + rng.uniform(-jitter * spacing, jitter * spacing, size=p.shape)
        positions.append(p)
        velocities.append(np.broadcast_to(np.asarray(block.velocity, dtype=np.float64), p.shape))
    if not positions:
        return np.zeros((0, 2)), np.zeros((0, 2))
    position, velocity = np.concatenate(positions), np.concatenate(velocities)
    if clearance > 0 and scene.ramps:
        keep = segment_distance(position, scene.ramp_array()).min(1) >= clearance
        position, velocity = position[keep], velocity[keep]
    return position, velocity


def ramp_particles(scene: Scene, ramp_spacing: float = 0.01) -> np.ndarray:
    """Static particles along every ramp, end points included, about ``ramp_spacing`` apart.

    Returns:
        ``[M, 2]`` float64 positions, m.
    """
    rows = []
    for p0, p1 in scene.ramps:
        p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
        count = max(2, int(math.ceil(np.linalg.norm(p1 - p0) / ramp_spacing - 1e-9)) + 1)
        t = np.linspace(0.0, 1.0, count)[:, None]
        rows.append(p0 + t * (p1 - p0))
    return np.concatenate(rows) if rows else np.zeros((0, 2))


def scene_particles(
    scene: Scene,
    spacing: float,
    rng: np.random.Generator,
    *,
    ramp_spacing: float = 0.01,
    jitter: float = 0.35,
    clearance: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """All particles of a scene: water first (type 5), then ramps (type 3).

    Args: as :func:`water_particles` and :func:`ramp_particles`.

    Returns:
        ``[N, 2]`` float32 positions (m) and ``[N]`` int64 particle types.
    """
    water, _ = water_particles(scene, spacing, rng, jitter=jitter, clearance=clearance)
    ramps = ramp_particles(scene, ramp_spacing)
    position = np.concatenate([water, ramps]).astype(np.float32)
    particle_type = np.concatenate(
        [
            np.full(len(water), WATER_PARTICLE_ID, np.int64),
            np.full(len(ramps), KINEMATIC_PARTICLE_ID, np.int64),
        ]
    )
    return position, particle_type


# ---------------------------------------------------------------------------------------------- sampling


def sample_scene(rng: np.random.Generator, preset: Preset) -> Scene:
    """Draw a WaterRamps-like scene from the ranges of ``preset``.

    One water block (width, height in the preset's ranges, anywhere in the box at least ``wall_margin`` from
    the walls), speed uniform in ``speed_range`` in a uniformly random direction, then ``num_ramps_range``
    ramps: length uniform in ``ramp_length_range``, angle uniform in ``+-ramp_max_angle`` or vertical with
    probability ``vertical_ramp_probability``, centre uniform where the segment fits in the box. A ramp
    closer than ``preset.ramp_clearance`` to the block is redrawn (up to 200 times, then dropped); ramps may
    cross each other. A scene that ends up with no ramp is redrawn from scratch.

    Raises:
        ValueError: the preset's ranges make scenes impossible (e.g. a block wider than the box).
    """
    lo, hi = preset.bounds
    lo_m, hi_m = lo + preset.wall_margin, hi - preset.wall_margin
    if preset.block_width_range[1] > hi_m - lo_m or preset.block_height_range[1] > hi_m - lo_m:
        raise ValueError(f"preset {preset.name!r}: the largest block does not fit between the walls")
    if preset.ramp_length_range[1] > hi_m - lo_m:
        raise ValueError(f"preset {preset.name!r}: the longest ramp does not fit between the walls")
    for _ in range(_SCENE_TRIES):
        w = rng.uniform(*preset.block_width_range)
        h = rng.uniform(*preset.block_height_range)
        x = rng.uniform(lo_m, hi_m - w)
        y = rng.uniform(lo_m, hi_m - h)
        block = WaterBlock((x, y), (x + w, y + h), _launch_velocity(rng, preset))
        ramps = _sample_ramps(rng, preset, [block], lo_m, hi_m)
        if ramps is not None:
            return Scene([block], ramps)
    raise ValueError(
        f"preset {preset.name!r}: no scene with a ramp clear of the water in {_SCENE_TRIES} tries"
    )


def sample_rest_scene(rng: np.random.Generator, preset: Preset) -> Scene:
    """Draw a scene whose water starts at rest: a pool on the floor, wall to wall.

    Why: in :func:`sample_scene`'s scenes water is only ever falling or sloshing, so a model trained on them
    alone has never seen water that should stay still; a pool at rest then drifts ~180x the solver's speed
    (docs/hardcases.md). The pool's depth is uniform in ``preset.pool_depth_range``; with probability
    ``preset.rest_block_probability`` a block drawn as in :func:`sample_scene` (sizes, speeds) starts above
    the pool, at least ``preset.ramp_clearance`` clear of it, and falls in. Ramps are drawn as in
    :func:`sample_scene`, clear of all the water, so they hang above the pool.

    Raises:
        ValueError: the preset's ranges make scenes impossible (a pool deeper than the box).
    """
    lo, hi = preset.bounds
    lo_m, hi_m = lo + preset.wall_margin, hi - preset.wall_margin
    if preset.pool_depth_range[1] >= hi - lo:
        raise ValueError(f"preset {preset.name!r}: the deepest pool does not fit between the walls")
    for _ in range(_SCENE_TRIES):
        depth = rng.uniform(*preset.pool_depth_range)
        blocks = [WaterBlock((lo, lo), (hi, lo + depth))]
        if rng.uniform() < preset.rest_block_probability:
            w = rng.uniform(*preset.block_width_range)
            h = rng.uniform(*preset.block_height_range)
            y_min = lo + depth + preset.ramp_clearance
            if y_min + h <= hi_m:  # otherwise the pool leaves no room: the scene keeps the pool alone
                x = rng.uniform(lo_m, hi_m - w)
                y = rng.uniform(y_min, hi_m - h)
                blocks.append(WaterBlock((x, y), (x + w, y + h), _launch_velocity(rng, preset)))
        ramps = _sample_ramps(rng, preset, blocks, lo_m, hi_m)
        if ramps is not None:
            return Scene(blocks, ramps)
    raise ValueError(
        f"preset {preset.name!r}: no pool scene with a ramp clear of the water in {_SCENE_TRIES} tries"
    )


def sample_dam_scene(rng: np.random.Generator, preset: Preset) -> Scene:
    """Draw a dam break: one block of :func:`sample_scene`'s sizes at rest on the floor, against the left
    wall, the right wall or free on the floor (a third each), and ramps drawn as in :func:`sample_scene`,
    clear of it. With nothing holding its sides the block collapses and spreads: water that starts at rest
    and must move, the counterpart of :func:`sample_rest_scene`'s pools.

    Raises:
        ValueError: the preset's ranges make scenes impossible (a block wider than the box).
    """
    lo, hi = preset.bounds
    lo_m, hi_m = lo + preset.wall_margin, hi - preset.wall_margin
    if preset.block_width_range[1] > hi_m - lo_m or preset.block_height_range[1] > hi_m - lo_m:
        raise ValueError(f"preset {preset.name!r}: the largest block does not fit between the walls")
    for _ in range(_SCENE_TRIES):
        w = rng.uniform(*preset.block_width_range)
        h = rng.uniform(*preset.block_height_range)
        side = int(rng.integers(3))
        x = (lo, hi - w, rng.uniform(lo_m, hi_m - w))[side]
        # min(): hi - w + w may round past the wall
        blocks = [WaterBlock((x, lo), (min(x + w, hi), lo + h))]
        ramps = _sample_ramps(rng, preset, blocks, lo_m, hi_m)
        if ramps is not None:
            return Scene(blocks, ramps)
    raise ValueError(
        f"preset {preset.name!r}: no dam scene with a ramp clear of the water in {_SCENE_TRIES} tries"
    )


def _launch_velocity(rng: np.random.Generator, preset: Preset) -> Point:
    """A block's initial velocity, m/s: speed uniform in ``preset.speed_range``, direction uniform."""
    speed = rng.uniform(*preset.speed_range)
    angle = rng.uniform(0.0, 2.0 * math.pi)
    return (speed * math.cos(angle), speed * math.sin(angle))


def _sample_ramps(
    rng: np.random.Generator, preset: Preset, blocks: Sequence[WaterBlock], lo: float, hi: float
) -> list[tuple[Point, Point]] | None:
    """``num_ramps_range`` ramps clear of ``blocks`` (:func:`_sample_ramp`), or None when all were asked
    for and none could be placed."""
    num_ramps = int(rng.integers(preset.num_ramps_range[0], preset.num_ramps_range[1] + 1))
    ramps = []
    for _ in range(num_ramps):
        ramp = _sample_ramp(rng, preset, blocks, lo, hi)
        if ramp is not None:
            ramps.append(ramp)
    return ramps if ramps or num_ramps == 0 else None


def _sample_ramp(
    rng: np.random.Generator, preset: Preset, blocks: Sequence[WaterBlock], lo: float, hi: float
) -> tuple[Point, Point] | None:
    """One ramp inside ``[lo, hi]^2`` and at least ``preset.ramp_clearance`` from every block, or None."""
    for _ in range(_RAMP_TRIES):
        length = rng.uniform(*preset.ramp_length_range)
        if rng.uniform() < preset.vertical_ramp_probability:
            angle = 0.5 * math.pi
        else:
            angle = rng.uniform(-preset.ramp_max_angle, preset.ramp_max_angle)
        half = 0.5 * length * np.array([math.cos(angle), math.sin(angle)])
        reach = np.abs(half)
        centre = rng.uniform(lo + reach, hi - reach)
        p0, p1 = centre - half, centre + half
        gap = min(segment_rect_distance(p0, p1, np.asarray(b.lower), np.asarray(b.upper)) for b in blocks)
        if gap >= preset.ramp_clearance:
            return (float(p0[0]), float(p0[1])), (float(p1[0]), float(p1[1]))
    return None


# ---------------------------------------------------------------------------------------------- geometry


def segment_distance(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Euclidean distance of every point to every segment.

    Args:
        points: ``[N, 2]`` positions.
        segments: ``[R, 2, 2]`` segments ``(p0, p1)``.

    Returns:
        ``[N, R]`` distances, in the units of the inputs.
    """
    p0 = segments[None, :, 0]  # [1, R, 2]
    d = segments[None, :, 1] - p0
    rel = points[:, None, :] - p0  # [N, R, 2]
    t = np.clip((rel * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-300), 0.0, 1.0)
    return np.linalg.norm(rel - t[..., None] * d, axis=-1)


def segment_rect_distance(p0: np.ndarray, p1: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> float:
    """Distance between segment ``p0 p1`` and the filled rectangle ``[lower, upper]`` (0 if they meet)."""
    # Clip the segment against the rectangle (Liang-Barsky): any surviving part means they intersect.
    d = p1 - p0
    t0, t1 = 0.0, 1.0
    inside = True
    for axis in range(2):
        for p, q in ((-d[axis], p0[axis] - lower[axis]), (d[axis], upper[axis] - p0[axis])):
            if p == 0:
                if q < 0:
                    inside = False
            else:
                t = q / p
                if p < 0:
                    t0 = max(t0, t)
                else:
                    t1 = min(t1, t)
    if inside and t0 <= t1:
        return 0.0
    corners = np.array([lower, [lower[0], upper[1]], upper, [upper[0], lower[1]]])
    edges = np.stack([corners, np.roll(corners, -1, axis=0)], 1)  # [4, 2, 2]
    ends = np.stack([p0, p1])
    return float(
        min(segment_distance(ends, edges).min(), segment_distance(corners, np.stack([p0, p1])[None]).min())
    )


def _check_keys(d: Mapping[str, Any], allowed: Sequence[str], where: str) -> None:
    """Refuse keys outside ``allowed`` (a misspelt ``velocty`` would otherwise be ignored silently)."""
    unknown = sorted(str(key) for key in d if key not in allowed)
    if unknown:
        close = difflib.get_close_matches(unknown[0], allowed, n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        expected = ", ".join(f"'{key}'" for key in allowed)
        raise DataError(where, f"unknown key(s) {unknown}{hint}; expected {expected}")


def _as_list(value: Any, where: str) -> list:
    if not isinstance(value, Sequence) or isinstance(value, str):
        raise DataError(where, f"expected a list, got {value!r}")
    return list(value)


def _point(value: Any, where: str) -> Point:
    seq = _as_list(value, where)
    if len(seq) != 2:
        raise DataError(where, f"expected 2 numbers [x, y], got {value!r}")
    try:
        x, y = float(seq[0]), float(seq[1])
    except (TypeError, ValueError):
        raise DataError(where, f"expected 2 numbers [x, y], got {value!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise DataError(where, f"expected finite numbers, got {value!r}")
    return (x, y)
