"""A 2D MLS-MPM water solver in torch (Taichi's mpm88 scheme) with box walls and static ramp colliders.

The scheme (Hu et al. 2018, "A moving least squares material point method", as in Taichi's ``mpm88.py``):
quadratic B-spline weights, APIC affine momentum ``C``, and a weakly compressible equation of state on the
volume ratio ``J`` (pressure ``E (1 - J)``, so the sound speed is ``sqrt(E / rho)``: 20 m/s for E = 400).

Units: metres, seconds, kilograms per square metre (2D). The walls of the box sit at ``wall_lo`` and
``wall_hi`` on both axes (WaterRamps: 0.1 and 0.9); gravity points to -y.

Boundaries:
  * Walls: the grid is fitted to the wall box so that node lines lie on the walls; nodes on or beyond a wall
    get separating slip (the outward velocity component is zeroed, tangential and inward ones kept), so
    water slides along a wall and can leave it.
  * Ramps: static segments. Grid nodes within ``collider_band * dx`` of a segment lose the velocity
    component that points into the segment. A segment is thin, so the side a node is on is decided by where
    its mass comes from (the mass-weighted side of the particles that scattered to it), not by the node's
    own position: a node just below a ramp that only water above reaches must stop that water too. Nodes
    fed from both sides lose their whole normal component. Past the segment ends the normal is radial.
  * Safety nets, documented because they move particles by hand: a particle whose step would cross a
    ramp segment is put back on its side (a twentieth of a cell off the line) and loses its normal velocity;
    positions are clamped into the wall box, because the grid walls act on node velocities and a particle
    can overshoot a wall by float round-off or a sliver of a cell (measured: at most 7e-5 m, half a percent
    of a cell). The grid conditions make both rare; they are counted in
    :attr:`MLSMPMSolver.ramp_corrections` and :attr:`MLSMPMSolver.wall_clamps`.

Accuracy: float32 suffices (float64 agrees to the float32 output resolution for the first tens of frames,
then the splash's chaos takes over; J extremes are identical). J stays within a few percent of 1 in flowing
water; impacts at 3-4 m/s compress a few particles by 10-20 % for a few frames (sound speed 20 m/s).

Implementation: particle quantities are stored structure-of-arrays (``[2, N]``, particles last) so every
op runs over contiguous memory; the particle-to-grid transfer is one matmul plus one ``index_add_``, the
grid-to-particle transfer one gather plus one matmul (see :meth:`MLSMPMSolver._setup_transfers`). About
60 torch ops per substep, on CPU or CUDA, wherever the tensors live. One CPU thread: ~0.4 ms per substep
at 300 particles (op overhead), ~0.6 ms at 1.6k.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
import torch

#: Grid cells outside each wall: a particle on a wall reaches 1.5 cells beyond it with its stencil.
_GRID_PAD = 2
#: A collider node is one-sided when at least this fraction of its (signed) mass comes from one side.
_ONE_SIDED_FRACTION = 0.5
#: A node with less mass than this fraction of water at rest's is not covered by water.
SURFACE_NODE_FRACTION = 0.5
#: Nodes within this many cells of an uncovered node do not count as covered (see _volume_correction).
_SURFACE_EROSION = 2
#: Distance (in cells) from the ramp's line at which a particle pushed back across a ramp is placed.
_RAMP_PUSHBACK_CELLS = 0.05


@dataclass(frozen=True)
class SolverSettings:
    """Numerical and physical settings of :class:`MLSMPMSolver` (plain values, so they serialise).

    Attributes:
        grid: nominal grid resolution, nodes per metre (``dx ~ 1 / grid``). The grid is fitted to the wall
            box: ``cells = round((wall_hi - wall_lo) * grid)`` cells span it exactly, so nodes lie on the
            walls and the separating-slip condition acts at the wall itself, not up to a cell away.
        substeps: solver steps per output frame (substep = ``frame_dt / substeps``).
        frame_dt: seconds between output frames (WaterRamps: 0.0025).
        stiffness: bulk modulus E of the equation of state, Pa (mpm88: 400).
        density: rest density, kg/m^2.
        gravity: gravitational acceleration along -y, m/s^2.
        wall_lo: position of the left and bottom walls, m.
        wall_hi: position of the right and top walls, m.
        collider_band: grid nodes within ``collider_band * dx`` of a ramp segment are collider nodes. The
            band acts like a ramp thickness; measured at 64^2, resting water sits 0.3-0.5 dx off the line
            with 1.0 and 0.9-1.1 dx with 1.5. 1.0 keeps water within a particle spacing of the ramp
            particles (so a model sees them at WaterRamps' radius 0.015), and the grid colliders alone
            still stop every particle in the tests.
        density_relaxation: relaxation time, s, of the volume ratio ``J`` towards the one the particles'
            density implies (0: off, mpm88's plain ``J``). See :meth:`MLSMPMSolver._volume_correction`.
        viscosity: dynamic viscosity mu, Pa s (kg/s in 2D), of the stress ``mu (grad v + grad v^T)``
            (0: inviscid, as mpm88).
        dtype: ``"float32"`` or ``"float64"``.
    """

    grid: int = 64
    substeps: int = 10
    frame_dt: float = 0.0025
    stiffness: float = 400.0
    density: float = 1.0
    gravity: float = 9.8
    wall_lo: float = 0.1
    wall_hi: float = 0.9
    collider_band: float = 1.0
    density_relaxation: float = 0.0
    viscosity: float = 0.0
    dtype: str = "float32"

    def __post_init__(self):
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"SolverSettings.dtype: expected 'float32' or 'float64', got {self.dtype!r}")
        if not self.wall_lo < self.wall_hi:
            raise ValueError(
                f"SolverSettings: wall_lo ({self.wall_lo}) must be below wall_hi ({self.wall_hi})"
            )
        if self.grid < 2 or self.substeps < 1 or self.frame_dt <= 0:
            raise ValueError("SolverSettings: grid >= 2, substeps >= 1 and frame_dt > 0 are required")
        if self.density_relaxation < 0 or self.viscosity < 0:
            raise ValueError("SolverSettings: density_relaxation and viscosity must be >= 0")

    @property
    def cells(self) -> int:
        """Grid cells between the walls."""
        return max(1, round((self.wall_hi - self.wall_lo) * self.grid))

    @property
    def dx(self) -> float:
        """Grid spacing, m."""
        return (self.wall_hi - self.wall_lo) / self.cells

    @property
    def grid_origin(self) -> float:
        """Coordinate of node 0 on both axes, m: ``_GRID_PAD`` cells outside the low wall."""
        return self.wall_lo - _GRID_PAD * self.dx

    @property
    def grid_nodes(self) -> int:
        """Nodes per axis: the cells between the walls plus ``_GRID_PAD`` cells of padding on each side."""
        return self.cells + 2 * _GRID_PAD + 1

    def node_positions(self) -> np.ndarray:
        """``[grid_nodes]`` float64 node coordinates along one axis, m."""
        return self.grid_origin + np.arange(self.grid_nodes) * self.dx

    @property
    def dt(self) -> float:
        """Substep, s."""
        return self.frame_dt / self.substeps

    def to_dict(self) -> dict:
        return asdict(self)


def _float64(a: np.ndarray | torch.Tensor | Sequence) -> np.ndarray:
    """A float64 numpy copy of an array, a (possibly CUDA) tensor or nested lists."""
    if isinstance(a, torch.Tensor):
        a = a.detach().cpu().numpy()
    return np.array(a, dtype=np.float64)


class MLSMPMSolver:
    """Weakly compressible water in a box with static ramps; the state lives on ``device``.

    Args:
        position: ``[N, 2]`` initial water particle positions, m (inside the wall box).
        velocity: ``[N, 2]`` initial velocities, m/s.
        ramps: ``[R, 2, 2]`` ramp segments ``(p0, p1)``, m; ``R`` may be 0.
        spacing: initial particle spacing, m; a particle's volume is ``spacing^2`` (2D).
        settings: numerical and physical settings.
        device: torch device of the state (``"cpu"``, ``"cuda"``...).
        affine: optional ``[N, 2, 2]`` initial APIC field C, 1/s (default 0), e.g. to resume a simulation.
        volume_ratio: optional ``[N]`` initial J (default 1).

    State (read-only properties, ``[N, ...]`` views or copies): :attr:`x` positions (m), :attr:`v`
    velocities (m/s), :attr:`C` ``[N, 2, 2]`` APIC affine velocity field (1/s), :attr:`J` ``[N]`` volume
    ratio (1 at rest; the pressure is ``E (1 - J)``).
    """

    def __init__(
        self,
        position: np.ndarray | torch.Tensor,
        velocity: np.ndarray | torch.Tensor,
        ramps: np.ndarray | torch.Tensor,
        spacing: float,
        settings: SolverSettings,
        device: str | torch.device = "cpu",
        *,
        affine: np.ndarray | torch.Tensor | None = None,
        volume_ratio: np.ndarray | torch.Tensor | None = None,
    ):
        self.settings = s = settings
        self.device = torch.device(device)
        self.dtype = getattr(torch, s.dtype)
        as_t = lambda a: torch.as_tensor(a, dtype=self.dtype, device=self.device)
        position = _float64(position)
        if position.ndim != 2 or position.shape[1] != 2 or len(position) == 0:
            raise ValueError(f"MLSMPMSolver: position must be [N > 0, 2], got shape {position.shape}")
        velocity = _float64(velocity)
        if velocity.shape != position.shape:
            raise ValueError(
                f"MLSMPMSolver: velocity shape {velocity.shape} != position shape {position.shape}"
            )
        if not (np.isfinite(position).all() and np.isfinite(velocity).all()):
            raise ValueError("MLSMPMSolver: initial position or velocity is not finite")
        if (position < s.wall_lo).any() or (position > s.wall_hi).any():
            raise ValueError(f"MLSMPMSolver: initial positions must lie inside [{s.wall_lo}, {s.wall_hi}]^2")
        if spacing <= 0:
            raise ValueError(f"MLSMPMSolver: spacing must be positive, got {spacing}")

        n = len(position)
        # Structure of arrays: components first, particles last (contiguous rows for every op).
        self._x = as_t(position.T).contiguous()  # [2, N], m
        self._v = as_t(velocity.T).contiguous()  # [2, N], m/s
        # [4, N] rows C00, C01, C10, C11 (row-major 2 x 2 per particle), and [N] volume ratios.
        if affine is None:
            self._C = torch.zeros(4, n, dtype=self.dtype, device=self.device)
        else:
            self._C = as_t(_float64(affine).reshape(n, 4).T).contiguous()
        if volume_ratio is None:
            self._J = torch.ones(n, dtype=self.dtype, device=self.device)
        else:
            self._J = as_t(_float64(volume_ratio).reshape(n)).contiguous()

        self._g = s.grid_nodes
        self._inv_dx = 1.0 / s.dx
        self._dt = s.dt
        self._p_mass = spacing**2 * s.density
        #: Scales (J - 1) into the stress term of the affine momentum (mpm88: ``-dt * 4 * E * vol / dx^2``).
        self._stress_scale = -self._dt * 4.0 * s.stiffness * spacing**2 * self._inv_dx**2
        # Viscous stress mu (C + C^T) joins the affine term as m C_eff = m C + k (C + C^T) (see substep).
        self._viscous_scale = -self._dt * 4.0 * s.viscosity * spacing**2 * self._inv_dx**2 / self._p_mass
        # Fraction of the gap to the density's J closed per substep: 1 - exp(-dt / tau).
        self._relax = 0.0 if s.density_relaxation <= 0 else -math.expm1(-self._dt / s.density_relaxation)
        #: Rest density times dx^2: the grid mass of a node inside water at rest (see _volume_correction).
        self._rest_node_mass = s.density * s.dx**2
        self._p_volume = spacing**2  # V_0, m^2
        self._gravity = torch.tensor([[0.0], [-s.gravity * self._dt]], dtype=self.dtype, device=self.device)
        self.ramp_corrections = 0
        self.wall_clamps = 0
        self._wall_min, self._wall_max = self._wall_limits()
        self._setup_ramps(_float64(ramps).reshape(-1, 2, 2))
        self._setup_transfers()
        #: ``[R, N]`` signed distances of the current positions to the ramp lines, m (reused next substep).
        self._side = self._ramp_side(self._x)

    # ------------------------------------------------------------------ state

    @property
    def num_particles(self) -> int:
        return int(self._x.shape[1])

    @property
    def x(self) -> torch.Tensor:
        """``[N, 2]`` positions, m."""
        return self._x.T

    @property
    def v(self) -> torch.Tensor:
        """``[N, 2]`` velocities, m/s."""
        return self._v.T

    @property
    def C(self) -> torch.Tensor:
        """``[N, 2, 2]`` APIC affine velocity field (velocity gradient estimate), 1/s."""
        return self._C.T.reshape(-1, 2, 2)

    @property
    def J(self) -> torch.Tensor:
        """``[N]`` volume ratio (current / initial particle volume)."""
        return self._J

    # ------------------------------------------------------------------ set-up

    def _wall_limits(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-node bounds ``[2, G*G]`` on the grid velocity: 0 where a wall forbids that direction.

        A node on or beyond a wall may not move outwards. Clamping the grid velocity between these bounds is
        the whole separating-slip condition, in two ops.
        """
        s = self.settings
        node = torch.as_tensor(s.node_positions())
        tol = 1e-6 * s.dx
        lo_1d = torch.where(node <= s.wall_lo + tol, 0.0, -math.inf)  # [G]
        hi_1d = torch.where(node >= s.wall_hi - tol, 0.0, math.inf)
        g = self._g
        # Flat node index = i * G + j with i along x, j along y.
        lo = torch.stack([lo_1d[:, None].expand(g, g), lo_1d[None, :].expand(g, g)]).reshape(2, -1)
        hi = torch.stack([hi_1d[:, None].expand(g, g), hi_1d[None, :].expand(g, g)]).reshape(2, -1)
        return lo.to(self.device, self.dtype), hi.to(self.device, self.dtype)

    def _setup_ramps(self, ramps: np.ndarray) -> None:
        """Precompute each ramp's line and its static collider nodes.

        Args:
            ramps: ``[R, 2, 2]`` segments, m.

        Collider entries (node, ramp) are split into layers in which every node occurs once, so a node near
        two ramps is projected by one and then the other (order matters for a node in a corner).
        """
        s = self.settings
        dev, dt = self.device, self.dtype
        self.num_ramps = len(ramps)
        p0, seg = ramps[:, 0], ramps[:, 1] - ramps[:, 0]  # [R, 2]
        length = np.linalg.norm(seg, axis=1)
        if (length <= 0).any():
            raise ValueError(f"MLSMPMSolver: ramp {int(np.argmin(length))} has zero length")
        tangent = seg / np.maximum(length, 1e-300)[:, None]
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], -1).reshape(-1, 2)
        self._ramp_p0 = torch.as_tensor(p0.T.copy(), dtype=dt, device=dev)  # [2, R]
        self._ramp_tangent = torch.as_tensor(tangent.T.copy(), dtype=dt, device=dev)  # [2, R]
        self._ramp_len = torch.as_tensor(length, dtype=dt, device=dev)  # [R]
        self._ramp_normal = torch.as_tensor(normal, dtype=dt, device=dev)  # [R, 2]
        self._ramp_offset = torch.as_tensor((normal * p0).sum(1), dtype=dt, device=dev)  # [R], n . p0

        coord = s.node_positions()
        xx, yy = np.meshgrid(coord, coord, indexing="ij")
        nodes = np.stack([xx.reshape(-1), yy.reshape(-1)], -1)  # [G*G, 2], flat index = i * G + j
        entries = []  # (node, ramp, line normal [2], radial normal [2], is_end)
        for r in range(len(ramps)):
            t_raw = ((nodes - p0[r]) @ seg[r]) / length[r] ** 2
            closest = p0[r] + np.clip(t_raw, 0.0, 1.0)[:, None] * seg[r]
            rel = nodes - closest
            dist = np.linalg.norm(rel, axis=1)
            (idx,) = np.nonzero(dist < s.collider_band * s.dx)
            # Past an end the obstacle is the end point: push radially. A node (almost) on the end point has
            # no radial direction and is treated like an interior node.
            is_end = ((t_raw[idx] < 0) | (t_raw[idx] > 1)) & (dist[idx] > 1e-3 * s.dx)
            radial = rel[idx] / np.maximum(dist[idx], 1e-300)[:, None]
            entries += [(int(k), r, normal[r], radial[j], bool(is_end[j])) for j, k in enumerate(idx)]
        seen: dict[int, int] = {}
        layers: list[list] = []
        for e in entries:
            j = seen.get(e[0], 0)
            seen[e[0]] = j + 1
            if j == len(layers):
                layers.append([])
            layers[j].append(e)
        self._collider_layers = []
        for layer in layers:
            node = torch.tensor([e[0] for e in layer], device=dev)
            ramp = torch.tensor([e[1] for e in layer], device=dev)
            line_n = torch.as_tensor(np.array([e[2] for e in layer]).T.copy(), dtype=dt, device=dev)  # [2, K]
            radial_n = torch.as_tensor(np.array([e[3] for e in layer]).T.copy(), dtype=dt, device=dev)
            is_end = torch.tensor([e[4] for e in layer], device=dev)  # [K]
            self._collider_layers.append((node, ramp, line_n, radial_n, is_end))
        self.num_collider_nodes = len(entries)

    def _setup_transfers(self) -> None:
        """Constant matrices that turn each transfer into one dense matmul.

        Stencil node k = 3 i + j sits at offset ``o_k = (i, j)`` cells from the particle's base node. P2G:
        node k receives ``w_k (m v + A (o_k - fx) dx)`` momentum and ``w_k m`` mass, where
        ``A = m C + stress I``. Split into ``q = m v - dx A fx`` (the same for every k) and ``dx A o_k``
        (linear in C and the stress), all nine nodes' channels before weighting are
        ``U = bias + M @ P`` with ``P = [q (2), ramp sides (R), C (4), stress (1)]``. G2P: the weighted node
        velocities ``[9 * 2, N]`` times ``M_g`` give the new velocity and ``sum_k w_k v_k o_k^T`` at once.
        """
        R, dx, m = self.num_ramps, self.settings.dx, self._p_mass
        ch = 3 + R  # scattered channels: momentum x, y, mass, mass times the side (+-1) of each ramp
        ii, jj = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
        offsets = np.stack([ii.reshape(-1), jj.reshape(-1)], -1).astype(np.float64)  # [9, 2], cells
        M = np.zeros((ch, 9, R + 7))
        bias = np.zeros((ch, 9))
        bias[2] = m
        for k in range(9):
            for i in range(2):
                M[i, k, i] = 1.0
                for j in range(2):
                    M[i, k, 2 + R + 2 * i + j] = m * dx * offsets[k, j]
                M[i, k, R + 6] = dx * offsets[k, i]
            for r in range(R):
                M[3 + r, k, 2 + r] = m
        M_g = np.zeros((6, 2, 9))  # rows: v (2), sum_k w_k v_k o_k^T row-major (4); columns: (component, k)
        for k in range(9):
            for i in range(2):
                M_g[i, i, k] = 1.0
                for j in range(2):
                    M_g[2 + 2 * i + j, i, k] = offsets[k, j]
        as_t = lambda a: torch.as_tensor(a, dtype=self.dtype, device=self.device)
        self._p2g_matrix = as_t(M.reshape(ch * 9, R + 7))
        self._p2g_bias = as_t(bias.reshape(ch * 9, 1))
        self._g2p_matrix = as_t(M_g.reshape(6, 18))
        self._offset_flat = torch.as_tensor((ii * self._g + jj).reshape(9, 1), device=self.device)

    # ------------------------------------------------------------------ stepping

    def _ramp_side(self, x: torch.Tensor) -> torch.Tensor:
        """Signed distances ``[R, N]`` of positions ``x`` ``[2, N]`` to the ramp lines, m (+: normal side)."""
        return self._ramp_normal @ x - self._ramp_offset[:, None]

    def substep(self) -> None:
        """Advance the state by one substep ``dt = frame_dt / substeps``."""
        n, g, inv_dx, dt, R = self.num_particles, self._g, self._inv_dx, self._dt, self.num_ramps
        x, v, C, ch = self._x, self._v, self._C, 3 + self.num_ramps

        # Quadratic B-spline weights. fx: position in cells from the stencil's base node, in [0.5, 1.5).
        xg = (x - self.settings.grid_origin) * inv_dx
        base = (xg - 0.5).floor()
        fx = xg - base  # [2, N]
        w = torch.stack([0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2])  # [3, 2, N]
        wts = (w[:, None, 0] * w[None, :, 1]).reshape(9, n)  # [9, N], k = 3 i + j
        base_i = base.long()
        idx = (base_i[0] * g + base_i[1] + self._offset_flat).reshape(-1)  # [9 N], flat node of (k, particle)

        # P2G (see _setup_transfers): momentum, mass and per-ramp side mass of all nine nodes, one matmul.
        stress = self._stress_scale * (self._J - 1.0)  # [N]
        if self._viscous_scale:
            # Rows C00, C01, C10, C11; C^T has rows C00, C10, C01, C11.
            C = C + self._viscous_scale * (C + C[[0, 2, 1, 3]])
        a_fx = self._p_mass * (C.view(2, 2, n) * fx).sum(1) + stress * fx  # [2, N], A fx
        q = self._p_mass * v - self.settings.dx * a_fx
        P = torch.cat([q, torch.sign(self._side), C, stress[None]])  # [R + 7, N]
        vals = torch.addmm(self._p2g_bias, self._p2g_matrix, P).view(ch, 9, n) * wts
        grid = torch.zeros(ch, g * g, dtype=self.dtype, device=self.device)
        grid.index_add_(1, idx, vals.view(ch, 9 * n))

        # Grid update: momentum -> velocity, gravity, separating-slip walls, ramps.
        mass = grid[2]
        gv = torch.where(mass > 0, grid[:2] / mass.clamp(min=1e-30) + self._gravity, 0.0)  # [2, G*G], m/s
        gv = torch.maximum(torch.minimum(gv, self._wall_max), self._wall_min)
        if R:
            self._project_colliders(gv, mass, grid[3:])

        # G2P: velocity and C = 4 / dx^2 sum_k w_k v_k (o_k - fx)^T dx, then advection and J.
        wgv = (
            torch.stack([gv[0].index_select(0, idx), gv[1].index_select(0, idx)]).view(2, 9, n) * wts
        ).view(18, n)
        out = self._g2p_matrix @ wgv  # [6, N]: v (2), sum_k w_k v_k o_k^T (4)
        new_v = out[:2]
        new_C = (out[2:] - (new_v[:, None] * fx[None]).view(4, n)) * (4.0 * inv_dx)  # [4, N], 1/s
        self._J = self._J * (1.0 + dt * (new_C[0] + new_C[3]))
        if self._relax:
            self._J = self._J * self._volume_correction(mass, idx, wts)
        x_new = x + dt * new_v
        if R:
            side_new = self._ramp_side(x_new)
            x_new, new_v, self._side = self._stop_ramp_crossings(x, x_new, new_v, self._side, side_new)
        self._x, self._v, self._C = self._clamp_to_walls(x_new), new_v, new_C

    def _volume_correction(self, mass: torch.Tensor, idx: torch.Tensor, wts: torch.Tensor) -> torch.Tensor:
        """The factor (0-d tensor) that moves every ``J`` a step ``1 - exp(-dt / tau)`` towards the volume
        the particles actually fill.

        Why: ``J`` integrates the velocity divergence, which drifts away from the particles' actual packing
        (measured, waterramps spacing: +18% density at frame 6000 while ``J`` stays ~1, so pressure never
        pushes back and a pool stands 15% low).

        How: inside the water every grid node's cell is full, so the particle volumes ``J V_0`` the node
        gathers (the same B-spline weights as the mass) should add up to its area ``dx^2``. Over those nodes,
        area / gathered volume is the factor that makes the particles' volumes tile the water again. Nodes
        count only if water covers everything within two cells of them (a node gathers particles 1.5 cells
        away; free surfaces, walls, jets and water on ramps are partial).

        Measured alternatives, all worse (docs/mpm-validation.md): relaxing each particle's ``J`` to its own
        density (the density's few-percent ripple, against hydrostatic ``rho g h / E ~ 0.3%``, became the
        dominant force: 9 mm/s of jitter in a pool at rest, 3 mm/s without); one global factor from the
        density at the particles (clustered particles sample their own crowding, so it read dense and
        stood a settled pool 2.7-4.7% too high).

        Args:
            mass: ``[G*G]`` grid mass; idx ``[9 N]`` stencil nodes; wts ``[9, N]`` stencil weights.
        """
        g, reach = self._g, _SURFACE_EROSION
        claimed = torch.zeros_like(mass).index_add_(0, idx, (wts * (self._p_volume * self._J)).view(-1))
        covered = (mass >= SURFACE_NODE_FRACTION * self._rest_node_mass).to(mass.dtype).view(1, 1, g, g)
        interior = -torch.nn.functional.max_pool2d(-covered, 2 * reach + 1, stride=1, padding=reach)
        interior = interior.view(-1) > 0.5  # [G*G] bool
        count = interior.sum()
        if not bool(count):
            return torch.ones((), dtype=self.dtype, device=self.device)
        area = count * self.settings.dx**2
        return (area / claimed[interior].sum()) ** self._relax

    def _project_colliders(self, gv: torch.Tensor, mass: torch.Tensor, side_mass: torch.Tensor) -> None:
        """Remove the grid velocity that points into a ramp, in place, on collider nodes.

        Args:
            gv: ``[2, G*G]`` grid velocities, m/s (modified).
            mass: ``[G*G]`` grid mass.
            side_mass: ``[R, G*G]`` mass times the side (+1 / -1) of the particles that scattered to a node.
        """
        for node, ramp, line_n, radial_n, is_end in self._collider_layers:
            m = mass[node]  # [K]
            sigma = side_mass[ramp, node] / m.clamp(min=1e-30)  # [K], in [-1, 1]
            # Interior nodes face the side their mass comes from; end nodes face away from the end point.
            n = torch.where(is_end, radial_n, line_n * torch.sign(sigma))  # [2, K]
            v = gv[:, node]
            vn = (v * n).sum(0)
            vn_line = (v * line_n).sum(0)
            # One-sided and end nodes: drop the inward part only; two-sided nodes: drop all normal motion.
            inward_only = (sigma.abs() >= _ONE_SIDED_FRACTION) | is_end
            v_new = torch.where(inward_only, v - vn.clamp(max=0.0) * n, v - vn_line * line_n)
            gv[:, node] = torch.where(m > 0, v_new, v)

    def _stop_ramp_crossings(
        self,
        x_old: torch.Tensor,
        x_new: torch.Tensor,
        v: torch.Tensor,
        d_old: torch.Tensor,
        d_new: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Safety net: a particle whose step ``x_old -> x_new`` crosses a ramp segment goes back to its side.

        Args:
            x_old, x_new: ``[2, N]`` positions before and after the step, m.
            v: ``[2, N]`` velocities, m/s.
            d_old, d_new: ``[R, N]`` signed distances of ``x_old`` and ``x_new`` to the ramp lines, m.

        Returns:
            The corrected ``[2, N]`` positions, ``[2, N]`` velocities (normal component removed for the
            particles put back) and ``[R, N]`` signed distances of the corrected positions.
        """
        crossed_line = (d_old >= 0) != (d_new >= 0)  # [R, N]
        if not bool(crossed_line.any()):  # the usual case: nobody crossed even a ramp's infinite line
            return x_new, v, d_new
        # Where the step meets the line, as a fraction of the step, then as a fraction along the segment.
        frac = d_old / (d_old - d_new).where(crossed_line, torch.ones_like(d_new))  # [R, N]
        hit = x_old[:, None] + frac[None] * (x_new - x_old)[:, None]  # [2, R, N]
        t = ((hit - self._ramp_p0[:, :, None]) * self._ramp_tangent[:, :, None]).sum(0) / self._ramp_len[
            :, None
        ]
        crossed = crossed_line & (t >= 0) & (t <= 1)
        if not bool(crossed.any()):
            return x_new, v, d_new
        self.ramp_corrections += int(crossed.sum())
        eps = _RAMP_PUSHBACK_CELLS * self.settings.dx
        for r in torch.nonzero(crossed.any(1)).reshape(-1).tolist():
            mask = crossed[r]
            nrm = self._ramp_normal[r][:, None]  # [2, 1]
            target = torch.where(d_old[r] >= 0, eps, -eps)
            x_new = torch.where(mask, x_new + (target - d_new[r]) * nrm, x_new)
            v = torch.where(mask, v - (v * nrm).sum(0) * nrm, v)
            d_new = self._ramp_side(x_new)
        return x_new, v, d_new

    def _clamp_to_walls(self, x: torch.Tensor) -> torch.Tensor:
        """Safety net: clamp ``[2, N]`` positions into the wall box, counting the particles it moves."""
        s = self.settings
        outside = (x < s.wall_lo) | (x > s.wall_hi)
        if bool(outside.any()):
            self.wall_clamps += int(outside.any(0).sum())
            x = x.clamp(s.wall_lo, s.wall_hi)
        return x

    def step_frame(self) -> None:
        """Advance by one output frame (``substeps`` substeps)."""
        for _ in range(self.settings.substeps):
            self.substep()

    def run(self, num_frames: int) -> np.ndarray:
        """Record ``num_frames`` frames, the first being the current state, stepping a frame in between.

        Returns:
            ``[num_frames, N, 2]`` float32 positions, m.
        """
        out = torch.empty(num_frames, 2, self.num_particles, dtype=torch.float32, device=self.device)
        for f in range(num_frames):
            if f > 0:
                self.step_frame()
            out[f] = self._x
        return out.transpose(1, 2).cpu().numpy()
