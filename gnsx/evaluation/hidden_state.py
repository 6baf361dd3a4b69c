"""How much of the next frame is not determined by what a one-velocity model sees? The MPM's hidden state.

``python -m gnsx.evaluation.hidden_state --preset small --split test --scenes 4 --every 20 --out <dir>``

A learned simulator with one velocity frame sees the positions ``x_{k-1}, x_k`` and predicts ``x_{k+1}``. The MPM
particle carries more: its own velocity ``v`` (the end of frame ``k``'s, not the frame's finite difference: a
frame is ``substeps`` solver steps), the APIC affine field ``C`` and the volume ratio ``J`` (pressure
``E (1 - J)``). This module rebuilds scenes exactly as the dataset generator does
(:func:`~gnsx.mpm.generate.split_scene`, :func:`~gnsx.mpm.generate.scene_solver`), snapshots the whole solver
state every ``--every`` frames, and steps ONE frame from it with parts of the state replaced by estimates from
``(x_{k-1}, x_k)``:

* ``true``: the true state (must reproduce the next frame to float rounding; asserted);
* ``v=fd``: ``v = (x_k - x_{k-1}) / dt``; ``v=fd+g``: the same plus the lag of free fall,
  ``-g dt (S - 1) / (2 S)`` along y (S substeps), exact for a ballistic particle, wrong by that much at rest;
* ``C=lsq``: least-squares velocity gradient of the neighbours' ``fd`` velocities within the connectivity
  radius (:func:`velocity_gradient`); ``C=0``;
* ``J=1``; ``J=density``: the volume the particles' packing implies, from the grid mass the solver itself
  scatters (:func:`density_volume_ratio`);
* ``all (...)``: all three replaced: the state a model seeing ``(x_{k-1}, x_k)`` could reconstruct with these
  particular estimators.

Each variant's one-frame position MSE against the truth (per coordinate, m^2 = data units^2, water only) is
reported per regime of the true motion (:func:`gnsx.evaluation.regimes.classify`, the regime of frame k) beside
the physics-free baseline's (``2 x_k - x_{k-1} + g``) on the same particle-frames. Read ``all`` as an estimate
of how much the hidden state matters with these estimators, not as a proven floor: a cleverer estimator (a
hydrostatic J from the depth, a velocity lag from the neighbourhood) could do better, and so could a network.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from gnsx.core.atomic import write_json
from gnsx.core.cli import run_main
from gnsx.core.constants import WATER_PARTICLE_ID
from gnsx.data.store import load_metadata, open_split
from gnsx.evaluation.regimes import REGIMES, classify
from gnsx.evaluation.sensitivity import dataset_recipe
from gnsx.mpm.generate import one_thread, scene_solver, split_scene
from gnsx.mpm.presets import Preset, get_preset
from gnsx.mpm.solver import SURFACE_NODE_FRACTION, MLSMPMSolver, SolverSettings

#: Variant name -> which estimate replaces v, C and J (None: the true one).
VARIANTS = {
    "true": (None, None, None),
    "v=fd": ("fd", None, None),
    "v=fd+g": ("fd+g", None, None),
    "C=lsq": (None, "lsq", None),
    "C=0": (None, "zero", None),
    "J=density": (None, None, "density"),
    "J=1": (None, None, "one"),
    "all (fd+g, lsq, 1)": ("fd+g", "lsq", "one"),
    "all (fd, lsq, 1)": ("fd", "lsq", "one"),
    "all (fd, 0, 1)": ("fd", "zero", "one"),
}
BASELINE = "physics-free baseline"
#: The true state must give the true next frame to this (m): float32 positions near 1 m are 6e-8 apart.
TRUE_STATE_TOLERANCE = 1e-6


def fd_velocity(x_prev: np.ndarray, x: np.ndarray, preset: Preset, gravity_lag: bool) -> np.ndarray:
    """``[N, 2]`` m/s: the frame's finite-difference velocity from ``[N, 2]`` positions (m) of frames k-1, k.

    With ``gravity_lag`` it adds ``-g dt (S - 1) / (2 S)`` along y: with S symplectic substeps a ballistic
    particle moves ``dt v_k - g dt^2 (S - 1) / (2 S)`` in the frame that ends with velocity ``v_k``.
    """
    v = (np.asarray(x, np.float64) - x_prev) / preset.frame_dt
    if gravity_lag:
        v[:, 1] -= preset.gravity * preset.frame_dt * (preset.substeps - 1) / (2 * preset.substeps)
    return v


def velocity_gradient(x: np.ndarray, v: np.ndarray, radius: float) -> np.ndarray:
    """``[N, 2, 2]`` 1/s: per particle, the least-squares ``G`` (``G[a, b] = dv_a / dx_b``, the layout of the
    solver's ``C``) fitting ``v_j - v_i = G (x_j - x_i)`` over its neighbours within ``radius`` (m).

    ``x``: ``[N, 2]`` m; ``v``: ``[N, 2]`` m/s. Where the neighbours do not span 2D (a jet, a lone droplet),
    the minimum-norm fit: the gradient along the directions they span, 0 across.
    """
    x, v = np.asarray(x, np.float64), np.asarray(v, np.float64)
    pairs = cKDTree(x).query_pairs(radius, output_type="ndarray")  # [P, 2], i < j
    i, j = np.concatenate([pairs[:, 0], pairs[:, 1]]), np.concatenate([pairs[:, 1], pairs[:, 0]])
    dx, dv = x[j] - x[i], v[j] - v[i]
    moment = np.zeros((len(x), 2, 2))  # sum dx dx^T
    cross = np.zeros((len(x), 2, 2))  # sum dv dx^T
    np.add.at(moment, i, dx[:, :, None] * dx[:, None, :])
    np.add.at(cross, i, dv[:, :, None] * dx[:, None, :])
    # Pseudo-inverse: along a line of particles (a jet) only the gradient along it is fitted, 0 across it.
    return cross @ np.linalg.pinv(moment, rcond=1e-3)


def density_volume_ratio(x: np.ndarray, settings: SolverSettings, spacing: float) -> np.ndarray:
    """``[N]``: the volume ratio the packing of ``[N, 2]`` positions (m) implies, the solver's way.

    The particles' mass is scattered to the grid with the solver's quadratic B-splines and gathered back:
    a particle inside water at rest gathers ``rho dx^2``, so ``J = rho dx^2 / gathered``. Near a free surface
    the gathered mass reads low for want of neighbours, not for expansion: a particle any of whose nine nodes
    is not covered by water (mass below the solver's ``SURFACE_NODE_FRACTION`` of the rest mass) gets 1.
    """
    s, g = settings, settings.grid_nodes
    xg = (np.asarray(x, np.float64) - s.grid_origin) / s.dx
    base = np.floor(xg - 0.5).astype(np.int64)
    fx = xg - base
    w = np.stack([0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2])  # [3, N, 2]
    nodes = np.stack([(base[:, 0] + a) * g + base[:, 1] + b for a in range(3) for b in range(3)])  # [9, N]
    weights = np.stack([w[a, :, 0] * w[b, :, 1] for a in range(3) for b in range(3)])  # [9, N]
    mass = np.zeros(g * g)
    np.add.at(mass, nodes.ravel(), (weights * spacing**2 * s.density).ravel())
    rest = s.density * s.dx**2
    gathered = (weights * mass[nodes]).sum(0)
    covered = (mass[nodes] >= SURFACE_NODE_FRACTION * rest).all(0)
    return np.where(covered, rest / gathered, 1.0)


def step_frame(ramps: np.ndarray, preset: Preset, x, v, C, J) -> np.ndarray:
    """``[N, 2]`` m: positions one frame after the state ``x [N, 2]`` m, ``v [N, 2]`` m/s, ``C [N, 2, 2]``
    1/s, ``J [N]`` (the step reads nothing else: the ramp sides follow from x, the grid is rebuilt)."""
    solver = MLSMPMSolver(x, v, ramps, preset.particle_spacing, preset.solver_settings(), affine=C,
                          volume_ratio=J)  # fmt: skip
    solver.step_frame()
    return solver.x.numpy().astype(np.float64)


def simulate(preset: Preset, seed: int, split: str, index: int, every: int):
    """Trajectory ``index`` of ``split`` as the generator makes it, with the solver state every ``every``
    frames. Returns ``position [T, N, 2]`` float32 m (water, then ramp particles), ``particle_type [N]``,
    the ramps ``[R, 2, 2]`` m, and ``{k: (x, v, C, J)}`` numpy states of the water at frames k."""
    scene, placement_seed = split_scene(preset, seed, split, index)
    solver, initial, types = scene_solver(scene, preset, placement_seed)
    water = types == WATER_PARTICLE_ID
    frames = np.empty((preset.num_frames, *initial.shape), np.float32)
    frames[:, ~water] = initial[~water]
    states = {}
    for k in range(preset.num_frames):
        if k:
            solver.step_frame()
        frames[k, water] = solver.x.numpy()
        if k >= 1 and k % every == 0 and k + 1 < preset.num_frames:
            states[k] = tuple(t.numpy().copy() for t in (solver.x, solver.v, solver.C, solver.J))
    return frames, types, scene.ramp_array(), states


def snapshot_errors(
    preset: Preset, ramps: np.ndarray, true: np.ndarray, k: int, state
) -> dict[str, np.ndarray]:
    """Squared errors ``[N]`` (m^2 per coordinate; for an estimator, its own units^2 per component) at frame
    ``k`` of ``true [T, N, 2]`` (water, float64 m), with ``state = (x, v, C, J)`` the solver's at frame k.

    Keys: the baseline, every variant of :data:`VARIANTS`, and ``est:<estimator>`` for each estimate itself.
    """
    x, v, C, J = state
    g = np.array([0.0, -preset.gravity * preset.frame_dt**2])  # per-frame gravity increment, m
    out = {BASELINE: ((2 * true[k] - true[k - 1] + g - true[k + 1]) ** 2).mean(1)}
    vs = {key: fd_velocity(true[k - 1], true[k], preset, key == "fd+g") for key in ("fd", "fd+g")}
    Cs = {"lsq": velocity_gradient(true[k], vs["fd"], preset.default_connectivity_radius), "zero": 0 * C}
    Js = {
        "density": density_volume_ratio(x, preset.solver_settings(), preset.particle_spacing),
        "one": 0 * J + 1,
    }
    for name, (kv, kc, kj) in VARIANTS.items():
        state = (v if kv is None else vs[kv], C if kc is None else Cs[kc], J if kj is None else Js[kj])
        out[name] = ((step_frame(ramps, preset, x, *state) - true[k + 1]) ** 2).mean(1)
    out |= {f"est:v={key}": ((value - v) ** 2).mean(1) for key, value in vs.items()}
    out |= {f"est:C={key}": ((value - C) ** 2).reshape(len(C), 4).mean(1) for key, value in Cs.items()}
    out |= {f"est:J={key}": (value - J) ** 2 for key, value in Js.items()}
    return out


def measure(preset: Preset, seed: int, split: str, scenes: int, every: int, data: Path | None = None) -> dict:
    """Squared errors of every variant, the baseline and the estimators, pooled per regime over the
    particle-frames of the first ``scenes`` scenes of ``split``; ``data``: a stored dataset of the same
    recipe the rebuilt frames are compared with.

    Returns ``{"mse": {variant: {regime: m^2}}, "estimators": {name: {regime: units^2}}, "count": {regime:
    particle-frames}, "checks": {"true_state_max_abs_m", "dataset_max_abs_m"}}``.

    Raises:
        AssertionError: the true state does not give the true next frame (within TRUE_STATE_TOLERANCE).
    """
    gravity = np.array([0.0, -preset.gravity * preset.frame_dt**2])
    sums: dict[str, np.ndarray] = {}
    count = np.zeros(len(REGIMES))
    checks = {"true_state_max_abs_m": 0.0, "dataset_max_abs_m": None}
    stored = None
    if data is not None:
        metadata = load_metadata(data)
        recorded, recorded_seed = dataset_recipe(data, metadata)
        same = lambda p: {k: v for k, v in p.to_dict().items() if k != "trajectories"}
        if same(recorded) != same(preset) or recorded_seed != seed:
            raise ValueError(f"{data}: generated with another preset or seed ({recorded_seed})")
        stored = open_split(data, split, metadata, check_values=False)
        if len(stored) < scenes:
            raise ValueError(f"{data}: the {split} split holds {len(stored)} trajectories, not {scenes}")
    for index in range(scenes):
        frames, types, ramps, states = simulate(preset, seed, split, index, every)
        if stored is not None:
            diff = float(np.abs(stored[index].position - frames).max())
            checks["dataset_max_abs_m"] = max(checks["dataset_max_abs_m"] or 0.0, diff)
        water = types == WATER_PARTICLE_ID
        labels = classify(frames, types, gravity)[:, water]  # [T, N_water], the regime of frame k
        true = frames[:, water].astype(np.float64)
        for k, state in states.items():
            onehot = (labels[k][:, None] == np.arange(len(REGIMES))).astype(np.float64)  # [N, regimes]
            count += onehot.sum(0)
            errors = snapshot_errors(preset, ramps, true, k, state)
            worst = float(errors["true"].max() ** 0.5 * 2**0.5)  # max |error| over both coordinates, bound
            assert worst <= TRUE_STATE_TOLERANCE, f"scene {index} frame {k}: true state off by {worst} m"
            checks["true_state_max_abs_m"] = max(checks["true_state_max_abs_m"], worst)
            for key, squared in errors.items():
                sums[key] = sums.get(key, 0.0) + squared @ onehot
    per = lambda keys: {k.removeprefix("est:"): dict(zip(REGIMES, (sums[k] / np.maximum(count, 1)).tolist()))
                        for k in keys}  # fmt: skip
    return {"mse": per([k for k in sums if not k.startswith("est:")]),
            "estimators": per([k for k in sums if k.startswith("est:")]),
            "count": dict(zip(REGIMES, count.tolist())), "checks": checks}  # fmt: skip


def table(result: dict) -> list[str]:
    """Markdown: each variant's one-frame MSE and its ratio to the baseline's, per regime; the estimators'
    RMS errors."""
    mse, base = result["mse"], result["mse"][BASELINE]
    lines = [
        "| state stepped one frame | "
        + " | ".join(f"{r}: MSE (m^2) | {r}: / baseline" for r in REGIMES)
        + " |",
        "|---|" + "---|---|" * len(REGIMES),  # fmt: skip
        "| particle-frames | " + " | ".join(f"{int(result['count'][r])} | " for r in REGIMES) + " |",
    ]
    for name, row in mse.items():
        cells = [
            f"{row[r]:.3g} | {row[r] / base[r]:.3g}" if base[r] > 0 else f"{row[r]:.3g} | –" for r in REGIMES
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    units = {"v": "m/s", "C": "1/s", "J": "1"}
    lines += ["", "| estimator | " + " | ".join(f"{r}: RMS error" for r in REGIMES) + " |",
              "|---|" + "---|" * len(REGIMES)]  # fmt: skip
    for name, row in result["estimators"].items():
        lines.append(
            f"| {name} ({units[name[0]]}) | " + " | ".join(f"{row[r] ** 0.5:.3g}" for r in REGIMES) + " |"
        )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m gnsx.evaluation.hidden_state", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--preset", default="small", help="dataset preset (default small)")
    parser.add_argument("--seed", type=int, default=0, help="the dataset's generation seed (default 0)")
    parser.add_argument("--split", default="test", help="split whose scenes are rebuilt (default test)")
    parser.add_argument("--scenes", type=int, default=4, help="the split's first N scenes (default 4)")
    parser.add_argument("--every", type=int, default=20, help="snapshot every N-th frame (default 20)")
    parser.add_argument(
        "--data", type=Path, default=None, help="a dataset of this recipe to check frames against"
    )
    parser.add_argument("--out", type=Path, default=None, help="folder for hidden_state.md and .json")
    args = parser.parse_args(argv)
    if args.scenes < 1 or args.every < 1:
        parser.error("--scenes and --every must be >= 1")
    preset = get_preset(args.preset)
    start = time.perf_counter()
    with one_thread():  # the generator's thread count: float results identical to the dataset's
        result = measure(preset, args.seed, args.split, args.scenes, args.every, args.data)
    result["wall_s"] = time.perf_counter() - start
    result["args"] = {k: str(v) for k, v in vars(args).items()}
    checks = result["checks"]
    command = f"python -m gnsx.evaluation.hidden_state --preset {args.preset} --split {args.split} " + (
        f"--scenes {args.scenes} --every {args.every}" + (f" --data {args.data}" if args.data else "")
    )
    dataset = ("not checked" if checks["dataset_max_abs_m"] is None
               else f"max |rebuilt - {args.data}| = {checks['dataset_max_abs_m']:.3g} m")  # fmt: skip
    lines = [
        f"# How much of the next frame the MPM's hidden state decides: {args.preset}, {args.split} split",
        "",
        f"Command: `{command}` ({result['wall_s']:.0f} s, one thread). Scenes {args.split} 0-{args.scenes - 1}"
        f" (seed {args.seed}), rebuilt as the generator does ({dataset}); a snapshot every {args.every} frames,"
        f" stepped one frame ({preset.substeps} substeps). True state: max |error| "
        f"{checks['true_state_max_abs_m']:.3g} m (asserted <= {TRUE_STATE_TOLERANCE:g}).",
        "",
        "MSE: one-frame position error per coordinate, water particles, pooled over the particle-frames of each"
        " regime of the true motion at frame k (`gnsx.evaluation.regimes.classify`); the baseline is"
        " `2 x_k - x_{k-1} + g` on the same particle-frames. `fd`: the frame's finite-difference velocity;"
        " `fd+g`: plus free fall's lag `-g dt (S-1)/(2S)`; `lsq`: least-squares gradient of the neighbours' `fd`"
        f" velocities within {preset.default_connectivity_radius} m; `density`: J from the particles' packing"
        " on the solver's grid (1 where the stencil is not covered by water).",
        "",
        *table(result),
        "",
        "The `all` rows are the state a model seeing (x_{k-1}, x_k) could reconstruct with these particular"
        " estimators: an estimate of how much the hidden state matters, not a proven floor (a cleverer estimator,"
        " e.g. a hydrostatic J from the depth or a velocity lag read from the neighbourhood, could do better).",
        "",
        "In flight the baseline is exact (~1e-12 m^2, float rounding), so any departure shows as a large ratio;"
        " compare the absolute MSE there with the other regimes' baselines instead. `J=density` is a poor"
        " estimator when the preset does not relax J (density_relaxation"
        f" {preset.density_relaxation}): J then integrates the velocity divergence from 1 on a jittered packing"
        " and does not follow the packing, whose few-percent ripple the estimate turns into pressure.",
        "",
    ]
    text = "\n".join(lines)
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "hidden_state.md").write_text(text)
        write_json(args.out / "hidden_state.json", result)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, user_errors=(ValueError, KeyError)))
