"""Dataset presets: everything that fixes a generated dataset (solver, scene ranges, sizes), by name.

Two presets ship:

* ``waterramps``: DeepMind's WaterRamps sizes (1000/100/100 trajectories x 601 frames, ~1.1k-2.3k particles,
  connectivity radius 0.015) on a 64^2 grid. Measured: ~3.8 s of CPU per trajectory, so ~40 minutes on 2
  idle cores.
* ``small``: a CPU recipe that keeps the MPM stable and cheap (32^2 grid, spacing 0.5 dx, 250 frames, radius 0.035):
  ~1 s of CPU per trajectory. 100/8/16 trajectories, ~2 minutes on 2 cores. Why these counts: 4 test
  trajectories could not rank models (random 4-subsets of 16 gave baseline ratios from 1.19x to 2.27x for
  one model), so the test split has 16 and validation 8; 20 training trajectories were overfitted within the
  demo's budget (one-step MSE 3.6e-9 train vs 6.1e-9 test), so the demo trains on 100, what its 15 minutes can
  generate and still train. ``conf/data/small_400.yaml`` (the shipped weights' data) asks the same preset for
  400: trajectory ``i`` of a split depends only on ``(seed, split, i)``, so both datasets share their
  validation and test trajectories and the first 100 training ones.

Change any field with ``dataclasses.replace`` or ``get_preset(name, **overrides)``, e.g.
``get_preset("small", trajectories={"train": 400, "valid": 8, "test": 16})``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from gnsx.core.constants import SPLITS
from gnsx.mpm.solver import SolverSettings


@dataclass(frozen=True)
class Preset:
    """A dataset recipe. Lengths in metres, speeds in m/s, angles in radians.

    Attributes:
        name: the preset's name (written to the metadata).
        grid: solver grid resolution, nodes per metre (``dx ~ 1 / grid``; see :class:`SolverSettings`).
        substeps: solver substeps per output frame.
        particle_spacing: initial water particle spacing; particle volume is its square.
        ramp_spacing: distance between the static particles written along each ramp.
        num_frames: frames per trajectory, the initial state included (``sequence_length`` is one less).
        trajectories: ``{split: count}`` for ``train``, ``valid``, ``test``.
        block_width_range, block_height_range: ``(min, max)`` water block size.
        speed_range: ``(min, max)`` initial speed of the block (direction uniform).
        num_ramps_range: ``(min, max)`` ramps per scene, both included.
        ramp_length_range: ``(min, max)`` ramp length.
        ramp_max_angle: non-vertical ramps get an angle uniform in ``[-ramp_max_angle, ramp_max_angle]``.
        vertical_ramp_probability: chance that a ramp is vertical.
        rest_fraction: chance that a *training* scene is a pool at rest
            (:func:`~gnsx.mpm.scenes.sample_rest_scene`) instead of a falling block; validation and test
            scenes never are, so presets that differ only here share those splits. Drawn from a stream of its
            own (:func:`~gnsx.mpm.generate.rest_rng`): 0 draws nothing, and a training scene that is not a
            pool is the same as with 0.
        dam_fraction: chance that a *training* scene is a dam break
            (:func:`~gnsx.mpm.scenes.sample_dam_scene`: a block at rest on the floor, which collapses)
            instead of a falling block; drawn from the same stream as ``rest_fraction`` (a pool below
            ``rest_fraction``, a dam in the next ``dam_fraction``),
            so adding dams keeps every pool and changes only the scenes it turns into dams. Why: pools alone
            teach that water at rest stays at rest, and slow a dam that should break (docs/decisions).
        pool_depth_range: ``(min, max)`` depth of those pools.
        rest_block_probability: chance that such a pool also gets a block falling into it.
        default_connectivity_radius: the neighbour radius written to the metadata.
        wall_margin: blocks and ramps keep at least this distance from the walls.
        jitter: water particles move up to ``jitter * particle_spacing`` per axis off their lattice point.
        collider_band: ramp collider band in cells (see :class:`SolverSettings`).
        stiffness: bulk modulus E of the water, Pa (sound speed ``sqrt(E / rho)``, 50 m/s for 2500).
        density_relaxation: relaxation time of the solver's volume correction, s (see
            :class:`~gnsx.mpm.solver.SolverSettings`; 0: off).
        viscosity: dynamic viscosity of the water, Pa s (2D: kg/s).
        frame_dt: seconds between frames.
        gravity: m/s^2, along -y.
        bounds: ``(lo, hi)`` walls on both axes.
        dtype: solver float type, ``"float32"`` or ``"float64"``.
    """

    name: str
    grid: int
    substeps: int
    particle_spacing: float
    num_frames: int
    trajectories: dict[str, int]
    block_width_range: tuple[float, float]
    block_height_range: tuple[float, float]
    default_connectivity_radius: float
    speed_range: tuple[float, float] = (0.5, 2.0)
    num_ramps_range: tuple[int, int] = (1, 4)
    ramp_length_range: tuple[float, float] = (0.1, 0.6)
    ramp_max_angle: float = 0.3
    vertical_ramp_probability: float = 0.15
    rest_fraction: float = 0.0
    dam_fraction: float = 0.0
    pool_depth_range: tuple[float, float] = (0.03, 0.25)
    rest_block_probability: float = 0.5
    ramp_spacing: float = 0.01
    wall_margin: float = 0.02
    jitter: float = 0.35
    collider_band: float = 1.0
    # Issue 13 (validated by gnsx.mpm.validate; docs/mpm-validation.md): stiffer water (worst impact J 0.55 ->
    # ~0.8-0.95, at 2.5x the substeps), a volume correction (a collapsed pool 15% low at frame 6000 -> <1%)
    # and a little viscosity (a pool at rest settles below 1 mm/s).
    stiffness: float = 2500.0
    density_relaxation: float = 0.2
    viscosity: float = 1e-3
    frame_dt: float = 0.0025
    gravity: float = 9.8
    bounds: tuple[float, float] = (0.1, 0.9)
    dtype: str = "float32"

    def __post_init__(self):
        unknown = set(self.trajectories) - set(SPLITS)
        if unknown:
            raise ValueError(f"preset {self.name!r}: trajectories has unknown split(s) {sorted(unknown)}")
        if any(int(n) < 0 for n in self.trajectories.values()):
            raise ValueError(f"preset {self.name!r}: trajectory counts must be >= 0, got {self.trajectories}")
        if self.num_frames < 3:
            raise ValueError(f"preset {self.name!r}: num_frames must be >= 3 (acceleration needs 3 frames)")
        for key in (
            "block_width_range",
            "block_height_range",
            "speed_range",
            "num_ramps_range",
            "ramp_length_range",
            "pool_depth_range",
        ):
            lo, hi = getattr(self, key)
            if not 0 <= lo <= hi:
                raise ValueError(f"preset {self.name!r}: {key} must be (min, max) with 0 <= min <= max")
        for key in ("rest_fraction", "dam_fraction", "rest_block_probability"):
            if not 0.0 <= getattr(self, key) <= 1.0:
                raise ValueError(f"preset {self.name!r}: {key} must be a probability in [0, 1]")
        if self.rest_fraction + self.dam_fraction > 1.0:
            raise ValueError(f"preset {self.name!r}: rest_fraction + dam_fraction must not exceed 1")
        self.solver_settings()  # validates the solver fields

    def solver_settings(self) -> SolverSettings:
        """The solver settings this preset implies."""
        return SolverSettings(
            grid=self.grid,
            substeps=self.substeps,
            frame_dt=self.frame_dt,
            stiffness=self.stiffness,
            density_relaxation=self.density_relaxation,
            viscosity=self.viscosity,
            gravity=self.gravity,
            wall_lo=self.bounds[0],
            wall_hi=self.bounds[1],
            collider_band=self.collider_band,
            dtype=self.dtype,
        )

    @property
    def ramp_clearance(self) -> float:
        """Closest a water particle may start to a ramp, m: the collider band plus half a particle spacing."""
        return self.collider_band * self.solver_settings().dx + 0.5 * self.particle_spacing

    @property
    def num_trajectories(self) -> int:
        return sum(self.trajectories.values())

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready values (tuples as lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Preset:
        """The preset a dataset's metadata recorded (``metadata["gnsx"]["preset_settings"]``).

        Fields the record lacks predate them: the solver fields added by issue 13 then take the values that
        reproduce the data as it was generated (:data:`SOLVER_BEFORE_ISSUE_13`: no volume correction, no
        viscosity), not today's defaults; any other missing field takes its default. Unknown keys are an
        error (a record from a newer gnsx).
        """
        fields = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - fields)
        if unknown:
            raise ValueError(f"preset record: unknown field(s) {unknown}")
        values = {**SOLVER_BEFORE_ISSUE_13, **d}
        for key, value in values.items():
            if isinstance(value, list):
                values[key] = tuple(value)
        return cls(**values)


#: Solver fields of a preset recorded before issue 13 added them (they reproduce that data bit for bit).
SOLVER_BEFORE_ISSUE_13: dict[str, Any] = {"density_relaxation": 0.0, "viscosity": 0.0}


PRESETS: dict[str, Preset] = {
    "waterramps": Preset(
        name="waterramps",
        grid=64,
        substeps=25,  # Courant number c dt / dx = 50 m/s x 0.1 ms / 12.5 mm = 0.4
        particle_spacing=0.009,  # WaterRamps' ~1.5k water particles in a 0.42 x 0.32 block
        num_frames=601,
        trajectories={"train": 1000, "valid": 100, "test": 100},
        block_width_range=(0.32, 0.48),
        block_height_range=(0.26, 0.36),
        default_connectivity_radius=0.015,
    ),
    "small": Preset(
        name="small",
        grid=32,
        substeps=13,  # Courant number 50 m/s x 0.19 ms / 31 mm = 0.31
        # No volume correction: at this coarse grid the legacy solver did not drift (a settled pool -0.1%
        # at frame 6000), and the correction, which needs water two cells deep, stood a deep pool 2.6% high
        # against 1.6% without it (docs/mpm-validation.md).
        density_relaxation=0.0,
        particle_spacing=0.015625,  # 0.5 dx: 4 particles per cell, as mpm88
        num_frames=250,
        trajectories={"train": 100, "valid": 8, "test": 16},
        block_width_range=(0.15, 0.45),
        block_height_range=(0.15, 0.35),
        default_connectivity_radius=0.035,
    ),
}


def get_preset(name: str, **overrides: Any) -> Preset:
    """The preset called ``name``, with any fields replaced by ``overrides``.

    Raises:
        KeyError: unknown preset name (the message lists the known ones).
        ValueError: an override names no field of :class:`Preset`, or makes the preset invalid.
    """
    if name not in PRESETS:
        raise KeyError(f"unknown preset {name!r}; known presets: {', '.join(sorted(PRESETS))}")
    fields = {f.name for f in dataclasses.fields(Preset)}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise ValueError(f"preset {name!r}: unknown field(s) {unknown}; fields are {sorted(fields)}")
    # A fresh trajectories dict, so a caller editing it cannot change the registry.
    overrides.setdefault("trajectories", dict(PRESETS[name].trajectories))
    return dataclasses.replace(PRESETS[name], **overrides)
