"""Is a rollout still physical? NaN, speed, walls, ramps: the checks that turn a silent blow-up into a flag.

:func:`rollout_health` measures a ``[T, N, D]`` rollout; :func:`warn_if_unhealthy` prints one warning line for
a rollout that blew up. A rollout **blew up** when any dynamic position is not finite, or when a dynamic
particle moves faster than :data:`BLOW_UP_SPEED_STD` times the data's velocity standard deviation per frame.
The fastest water in the ``small`` preset's 100 training trajectories moves 0.0246 m per frame (9.8 m/s),
10.7 of its velocity standard deviations (median over trajectories: 5.7); 25 is more than twice anything the
model has seen, far beyond any splash, and the 374 m/s of the shipped model's worst unconstrained jet is
~160. Particles outside the box and steps through ramps are counted too (0 for a rollout run with the
:class:`gnsx.model.boundary.Boundary` on); they flag a blow-up only in the raw model (``constrain=False``).
"""

from __future__ import annotations

import sys

import numpy as np

from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.data.metadata import Metadata
from gnsx.evaluation.metrics import out_of_bounds
from gnsx.model.boundary import Boundary

#: A dynamic particle faster than this many velocity standard deviations (per frame) means a blow-up.
BLOW_UP_SPEED_STD = 25.0


def speed_limit(metadata: Metadata) -> float:
    """The blow-up speed in data units per frame: :data:`BLOW_UP_SPEED_STD` times the norm of ``vel_std``
    over ``sqrt(D)`` (the typical per-axis std)."""
    vel_std = np.asarray(metadata.vel_std, dtype=np.float64)
    return float(BLOW_UP_SPEED_STD * np.linalg.norm(vel_std) / np.sqrt(len(vel_std)))


def rollout_health(
    positions: np.ndarray, particle_type: np.ndarray, metadata: Metadata, first_frame: int = 1
) -> dict:
    """Physical sanity of a rollout.

    Args:
        positions: ``[T, N, D]`` positions (data units); frames before ``first_frame`` are inputs and only
            serve as the start of the first step.
        particle_type: ``[N]``; static particles are never counted, but their first-frame positions define
            the ramps' segments (:class:`Boundary`).
        metadata: bounds, ``dt`` (to report m/s) and ``vel_std`` (the blow-up speed).
        first_frame: first predicted frame (the model's ``input_frames``).

    Returns:
        ``nonfinite``: dynamic coordinates that are NaN or Inf (all frames); ``max_speed``: the fastest
        dynamic particle over the predicted frames, m/s (data units per second); ``speed_limit``: the blow-up
        speed, same units; ``out_of_bounds_final``: dynamic particles outside the box at the last frame;
        ``out_of_bounds_max``: the most at any frame; ``ramp_crossings``: steps of a dynamic particle
        through a static segment; ``blew_up``: non-finite positions or ``max_speed > speed_limit``.
    """
    positions = np.asarray(positions, dtype=np.float64)
    particle_type = np.asarray(particle_type)
    dynamic = particle_type != KINEMATIC_PARTICLE_ID
    first_frame = max(int(first_frame), 1)
    moving = positions[:, dynamic]
    nonfinite = int((~np.isfinite(moving)).sum())
    steps = np.diff(moving[first_frame - 1 :], axis=0)  # [T - first_frame, n, D]
    with np.errstate(invalid="ignore"):
        speeds = np.linalg.norm(steps, axis=-1)
    finite_speeds = speeds[np.isfinite(speeds)]
    max_step = float(finite_speeds.max()) if finite_speeds.size else 0.0
    limit = speed_limit(metadata)
    outside = out_of_bounds(positions[first_frame:], metadata.bounds_array(), dynamic)
    crossings = 0
    if nonfinite == 0 and positions.shape[-1] == 2:
        boundary = Boundary.from_particles(metadata.bounds_array(), positions[0], particle_type)
        if boundary.num_segments:
            for t in range(first_frame, len(positions)):
                crossings += boundary.count_crossings(positions[t - 1], positions[t], particle_type)
    return {
        "nonfinite": nonfinite,
        "max_speed": max_step / metadata.dt,
        "speed_limit": limit / metadata.dt,
        "out_of_bounds_final": int(outside[-1]) if len(outside) else 0,
        "out_of_bounds_max": int(outside.max()) if len(outside) else 0,
        "ramp_crossings": int(crossings),
        "blew_up": bool(nonfinite > 0 or max_step > limit),
    }


def describe(health: dict) -> str:
    """One line saying what went wrong (empty for a healthy rollout)."""
    if not health["blew_up"]:
        return ""
    if health["nonfinite"]:
        return f"{health['nonfinite']} positions are NaN or Inf"
    return (
        f"a particle reached {health['max_speed']:.3g} m/s, beyond the blow-up speed "
        f"{health['speed_limit']:.3g} m/s ({BLOW_UP_SPEED_STD:g} velocity standard deviations of the data)"
    )


def warn_if_unhealthy(health: dict, what: str) -> bool:
    """Print ``warning: <what> blew up: ...`` to stderr when the rollout blew up; returns ``blew_up``."""
    if health["blew_up"]:
        print(f"warning: {what} blew up: {describe(health)}", file=sys.stderr)
    return bool(health["blew_up"])
