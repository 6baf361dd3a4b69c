"""What a rollout does at the walls of the box and at static boundaries (ramps made of static particles).

A learned model only *predicts* an acceleration; nothing in it stops a particle from leaving the box or
tunnelling through a ramp, and once a particle is past a wall its (clipped) wall feature looks like that of a
particle on the wall, so nothing pushes it back. The MPM solver that made the data never lets water do either
(:mod:`gnsx.mpm.solver`: positions are clamped into the wall box, a particle that crossed a ramp is put back
on its side). :class:`Boundary` applies the same two rules to the integrated positions of every rollout step,
for the learned model and for the physics-free baseline alike, so both are scored under the same physics:

1. **Static segments.** Static (kinematic) particles that lie within ``link_factor`` times their typical
   spacing of each other are joined into segments: a ramp of particles becomes a polyline, a container wall a
   chain. Each segment has a skin ``pushback`` thick on both sides. A dynamic particle whose step
   ``p_old -> p_new`` ends inside the skin or across the segment is put on the skin of the side it came from,
   keeping its motion along the line: its velocity into the ramp is lost (it lands and stays, as at the MPM's
   colliders) and no velocity out of the ramp is made, except for a particle that starts inside the skin
   (placed there), which is moved out by at most ``pushback``. Repeated up to :data:`MAX_PASSES` times for
   corners where two segments meet; a particle still crossing after that stays where it was.
2. **Walls.** Dynamic positions are clamped into the box ``bounds``; the velocity into the wall is lost with
   it, because the next velocity is a difference of positions.

Segments are 2D only (ramps are lines); in other dimensions only the walls apply. The geometry runs in float64
NumPy with a KD-tree over segment midpoints (only segments a particle can reach in one step are tested), so
a 2,300-particle frame with ~200 segments costs well under a millisecond on top of the model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from gnsx.core.constants import KINEMATIC_PARTICLE_ID

#: Two static particles closer than ``LINK_FACTOR`` times the median nearest-static-neighbour distance are
#: joined by a segment (1.5: the next particle along a ramp, never the one after it).
LINK_FACTOR = 1.5
#: Distance from a segment's line at which a particle pushed back is placed, in units of the static spacing
#: (the MPM solver uses 0.05 grid cells).
PUSHBACK = 0.05
#: Correction passes per step (a particle pushed off one segment may cross its neighbour at a corner).
MAX_PASSES = 3


@dataclass(frozen=True)
class Boundary:
    """Box walls and static segments of one scene.

    Attributes:
        bounds: ``[D, 2]`` float64 ``[lower, upper]`` of the box per dimension (data units).
        segments: ``[S, 2]`` int64 indices (into the scene's particles) of the two static particles joined by
            each segment; ``S = 0`` for a scene without static particles, or when ``D != 2``.
        pushback: distance (data units) off a segment's line at which a pushed-back particle is placed.
    """

    bounds: np.ndarray
    segments: np.ndarray
    pushback: float

    @classmethod
    def from_particles(
        cls,
        bounds,
        position: Tensor | np.ndarray,
        particle_type: Tensor | np.ndarray,
        link_factor: float = LINK_FACTOR,
    ) -> Boundary:
        """The boundary of a scene: its box and segments between neighbouring static particles.

        Args:
            bounds: ``[D, 2]`` box (data units).
            position: ``[N, D]`` positions of the scene's particles (only the static ones are read).
            particle_type: ``[N]`` int type ids; static = ``KINEMATIC_PARTICLE_ID``.
            link_factor: see :data:`LINK_FACTOR`.
        """
        bounds = np.asarray(bounds, dtype=np.float64)
        position = _numpy64(position)
        static = np.flatnonzero(np.asarray(_numpy(particle_type)) == KINEMATIC_PARTICLE_ID)
        segments = np.zeros((0, 2), dtype=np.int64)
        pushback = 0.0
        if position.shape[1] == 2 and len(static) >= 2:
            points = position[static]
            tree = cKDTree(points)
            nearest, _ = tree.query(points, k=2)
            gaps = nearest[:, 1][nearest[:, 1] > 0]  # duplicates (two ramps sharing an end) have no gap
            spacing = float(np.median(gaps)) if len(gaps) else 0.0
            if spacing > 0:
                pairs = tree.query_pairs(link_factor * spacing, output_type="ndarray").reshape(-1, 2)
                length = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)
                segments = static[pairs[length > 0]].astype(np.int64).reshape(-1, 2)
                pushback = PUSHBACK * spacing
        return cls(bounds=bounds, segments=segments, pushback=pushback)

    @property
    def num_segments(self) -> int:
        return int(self.segments.shape[0])

    def _candidates(
        self, start: np.ndarray, end: np.ndarray, position: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Pairs (step, segment) close enough to touch: ``(step, segment, a, b)``, ``a``/``b`` the segments'
        end points ``[K, 2]``. Only segments whose midpoint lies within the step length plus half the longest
        segment plus the pushback of the step's start are returned (a KD-tree query)."""
        empty = np.zeros(0, dtype=np.int64)
        none = (empty, empty, np.zeros((0, 2)), np.zeros((0, 2)))
        if self.num_segments == 0 or len(start) == 0:
            return none
        a, b = position[self.segments[:, 0]], position[self.segments[:, 1]]  # [S, 2]
        half_length = 0.5 * np.linalg.norm(b - a, axis=1).max()
        reach = np.linalg.norm(end - start, axis=1).max() + half_length + 2 * self.pushback
        candidates = cKDTree(0.5 * (a + b)).query_ball_point(start, reach)
        counts = np.fromiter((len(c) for c in candidates), dtype=np.int64, count=len(candidates))
        if counts.sum() == 0:
            return none
        step = np.repeat(np.arange(len(start)), counts)
        segment = np.fromiter((s for c in candidates for s in c), dtype=np.int64, count=int(counts.sum()))
        return step, segment, a[segment], b[segment]

    def _crossings(
        self, start: np.ndarray, end: np.ndarray, position: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Which steps cross which segment: the step's end lies in the other half-plane of the segment's line
        than its start, and the two segments intersect (end points included).

        Args:
            start, end: ``[M, 2]`` float64 step start and end points.
            position: ``[N, 2]`` float64 scene positions (the segments' end points are read from it).

        Returns:
            ``(step, segment)`` int64 index arrays, one entry per crossing.
        """
        step, segment, a, b = self._candidates(start, end, position)
        p, q = start[step], end[step]
        side_p, side_q = _cross(b - a, p - a), _cross(b - a, q - a)
        side_a, side_b = _cross(q - p, a - p), _cross(q - p, b - p)
        # Points on the line belong to the normal's side: the two half-planes partition the plane, so a step
        # onto the line and on through it counts once, wherever the float grid puts it.
        hit = ((side_p >= 0) != (side_q >= 0)) & (side_a * side_b <= 0)
        return step[hit], segment[hit]

    def _contacts(
        self, start: np.ndarray, end: np.ndarray, position: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Steps that reach a segment's skin, the band ``pushback`` thick on the side the step starts from.

        Returns:
            ``(step, segment, target)``: ``target`` ``[K, 2]`` is where the step ends instead, its motion
            along the segment kept and its distance from the line set to ``pushback`` on its side. A step
            that ends on the skin this way has no velocity into the segment next frame (it lands and stays);
            only a step that *starts* inside the skin (placed there) is moved out, by at most ``pushback``.
        """
        step, segment, a, b = self._candidates(start, end, position)
        length = np.linalg.norm(b - a, axis=1)
        tangent = (b - a) / length[:, None]
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        p, q = start[step], end[step]
        d_start = np.einsum("kd,kd->k", p - a, normal)
        d_end = np.einsum("kd,kd->k", q - a, normal)
        # The side a step comes from: its start's, or (starting exactly on the line) the one it moves to.
        side = np.where(d_start != 0, np.sign(d_start), np.where(d_end != 0, np.sign(d_end), 1.0))
        start_depth, end_depth = side * d_start, side * d_end  # > 0 on the step's own side
        # Where along the step it first reaches the skin (0: it starts inside), and whether that point lies
        # along the segment (its projection between the end points, give or take the skin).
        travel = np.maximum(start_depth - end_depth, 1e-300)
        lam = np.clip((start_depth - self.pushback) / travel, 0.0, 1.0)
        contact = p + lam[:, None] * (q - p)
        along = np.einsum("kd,kd->k", contact - a, tangent)
        on_segment = (along >= -self.pushback) & (along <= length + self.pushback)
        # A step that starts in the skin beside the segment's end and crosses the line onto the segment: judge
        # it where it crosses the line (the contact point above is its start, off the end).
        crosses = end_depth < 0
        lam_line = np.clip(start_depth / np.maximum(start_depth - end_depth, 1e-300), 0.0, 1.0)
        along_line = np.einsum("kd,kd->k", p + lam_line[:, None] * (q - p) - a, tangent)
        on_segment |= crosses & (along_line >= 0) & (along_line <= length)
        hit = (end_depth < self.pushback) & on_segment
        target = q[hit] + ((self.pushback - end_depth[hit]) * side[hit])[:, None] * normal[hit]
        return step[hit], segment[hit], target

    def count_crossings(self, start, end, particle_type, position=None) -> int:
        """Number of dynamic particles whose step ``start -> end`` crosses a static segment.

        Args:
            start, end: ``[N, 2]`` positions at two consecutive frames.
            particle_type: ``[N]``.
            position: ``[N, 2]`` positions the segments are read from (default ``start``).
        """
        start, end = _numpy64(start), _numpy64(end)
        dynamic = np.flatnonzero(np.asarray(_numpy(particle_type)) != KINEMATIC_PARTICLE_ID)
        scene = start if position is None else _numpy64(position)
        steps, _ = self._crossings(start[dynamic], end[dynamic], scene)
        return int(np.unique(steps).size)

    def apply(self, previous: Tensor, proposed: Tensor, dynamic: Tensor) -> Tensor:
        """Constrain one rollout step: particles that reach a segment stay on its skin, clamp into the box.

        Args:
            previous: ``[N, D]`` positions at the last frame (static rows hold the segments' end points).
            proposed: ``[N, D]`` integrated positions of the next frame.
            dynamic: ``[N]`` bool, the particles that move (static rows of ``proposed`` are returned as
                given).

        Returns:
            ``[N, D]`` constrained positions, dtype and device of ``proposed``.
        """
        constrained = proposed
        if self.num_segments > 0 and bool(dynamic.any()):
            constrained = self._push_back(previous, proposed, dynamic)
        bounds = torch.as_tensor(self.bounds, dtype=proposed.dtype, device=proposed.device)
        clamped = torch.minimum(torch.maximum(constrained, bounds[:, 0]), bounds[:, 1])
        return torch.where(dynamic[:, None], clamped, constrained)

    def _push_back(self, previous: Tensor, proposed: Tensor, dynamic: Tensor) -> Tensor:
        scene = _numpy64(previous)
        movers = np.flatnonzero(_numpy(dynamic))
        start = scene[movers]
        end = _numpy64(proposed)[movers]
        changed = np.zeros(len(movers), dtype=bool)
        for _ in range(MAX_PASSES):
            step, _, target = self._contacts(start, end, scene)
            if len(step) == 0:
                break
            # One correction per particle and pass, the first segment found (a corner is handled next pass).
            step, first = np.unique(step, return_index=True)
            end[step] = target[first]
            changed[step] = True
        else:
            # Still crossing after MAX_PASSES: the particle stays where it was.
            step, _ = self._crossings(start, end, scene)
            end[step] = start[step]
        if not changed.any():
            return proposed
        result = proposed.clone()
        rows = torch.as_tensor(movers[changed], device=proposed.device)
        result[rows] = torch.as_tensor(end[changed], dtype=proposed.dtype, device=proposed.device)
        return result


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``[M]`` z-component of the 2D cross product of ``[M, 2]`` vectors."""
    return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]


def _numpy(x) -> np.ndarray:
    return x.detach().cpu().numpy() if isinstance(x, Tensor) else np.asarray(x)


def _numpy64(x) -> np.ndarray:
    return _numpy(x).astype(np.float64)
