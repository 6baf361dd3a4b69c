"""The MPM rolled out with a two-frame memory: how far the true physics gets over a whole rollout when, like a
one-velocity GNS, it sees only the last two frames of its own rollout at every step.

``python -m gnsx.evaluation.hidden_state_rollout --preset small --split test --scenes 16 --data data/small_400``

:mod:`gnsx.evaluation.hidden_state` measures one step from a state rebuilt from two true frames. A rollout
compounds that loss at every frame, and the network's failures show there (the water loses area, the first
frames of free flight drift). This module rebuilds each scene exactly as the generator does, takes its first
two true frames, and steps the MPM one frame at a time, rebuilding the hidden state before every frame:

* ``two frames (fd, lsq, J=1)``: velocity the frame's finite difference of the rollout's own last two frames,
  ``C`` the least-squares gradient of the neighbours' velocities, ``J = 1`` (no memory of compression). A
  simulator with the same information a one-velocity GNS has, stepped by the solver's own physics;
* ``two frames (fd+g, lsq, J=1)``: the velocity corrected for free fall's lag within the frame
  (``-g dt (S - 1) / (2 S)``, exact for a ballistic particle): a function of the two frames, so learnable;
* ``two frames + J carried``: either velocity, with ``J`` carried from the rollout's own previous frame: one
  hidden scalar per particle that two frames do not give, the volume ratio the pressure ``E (1 - J)`` reads.

Each rollout's position MSE (per coordinate, water, every predicted frame) is scored against the truth beside
the physics-free baseline's (:func:`gnsx.evaluation.scoring.baseline_errors`, the same baseline every other
table uses), with the water's area at the last frame over the truth's
(:func:`gnsx.evaluation.metrics.area_ratio`). Read the figures as what these estimators reach with exact
physics, not as a bound: a network may infer J from the packing better than J = 1, or worse than the solver.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gnsx.core.atomic import write_json
from gnsx.core.cli import run_main
from gnsx.core.constants import WATER_PARTICLE_ID
from gnsx.data.store import load_metadata
from gnsx.evaluation.hidden_state import fd_velocity, velocity_gradient
from gnsx.evaluation.metrics import area_ratio
from gnsx.evaluation.regimes import HORIZONS
from gnsx.evaluation.scoring import baseline_errors, horizon_mse, particle_spacing
from gnsx.evaluation.spread import geometric_mean_interval, mean_se
from gnsx.mpm.generate import one_thread, scene_solver, split_scene
from gnsx.mpm.presets import Preset, get_preset
from gnsx.mpm.solver import MLSMPMSolver

#: Variant name -> (velocity estimator of hidden_state.fd_velocity: "fd" or "fd+g", carry J).
VARIANTS = {
    "two frames (fd, lsq, J=1)": ("fd", False),
    "two frames (fd+g, lsq, J=1)": ("fd+g", False),
    "two frames + J carried (fd, lsq)": ("fd", True),
    "two frames + J carried (fd+g, lsq)": ("fd+g", True),
}
BASELINE = "physics-free baseline"


def true_trajectory(preset: Preset, seed: int, split: str, index: int):
    """Trajectory ``index`` of ``split`` as the generator makes it: ``position [T, N, 2]`` float32 m (water,
    then ramp particles), ``particle_type [N]`` and the ramps ``[R, 2, 2]`` m."""
    scene, placement_seed = split_scene(preset, seed, split, index)
    solver, initial, types = scene_solver(scene, preset, placement_seed)
    water = types == WATER_PARTICLE_ID
    frames = np.empty((preset.num_frames, *initial.shape), np.float32)
    frames[:, ~water] = initial[~water]
    frames[0, water] = solver.x.numpy()
    for k in range(1, preset.num_frames):
        solver.step_frame()
        frames[k, water] = solver.x.numpy()
    return frames, types, scene.ramp_array()


def two_frame_rollout(
    preset: Preset, ramps: np.ndarray, start: np.ndarray, frames: int, velocity: str, carry_j: bool
) -> np.ndarray:
    """``[frames, N, 2]`` m: the MPM rolled out from the two true frames ``start [2, N, 2]`` m (water only),
    its hidden state rebuilt from its own last two frames before every frame (the module docstring).

    ``velocity``: ``"fd"`` or ``"fd+g"`` (:func:`~gnsx.evaluation.hidden_state.fd_velocity`); ``carry_j``: keep
    the solver's J from the previous frame instead of resetting it to 1.
    """
    out = np.empty((frames, *start.shape[1:]))
    out[:2] = start
    J = np.ones(start.shape[1])
    for k in range(1, frames - 1):
        v = fd_velocity(out[k - 1], out[k], preset, velocity == "fd+g")
        C = velocity_gradient(out[k], v, preset.default_connectivity_radius)
        solver = MLSMPMSolver(out[k], v, ramps, preset.particle_spacing, preset.solver_settings(), affine=C,
                              volume_ratio=J if carry_j else np.ones_like(J))  # fmt: skip
        solver.step_frame()
        out[k + 1] = solver.x.numpy()
        J = solver.J.numpy().astype(np.float64)
    return out


def trajectory_row(
    preset: Preset, frames: np.ndarray, types: np.ndarray, ramps: np.ndarray, metadata
) -> dict:
    """One trajectory's rollout MSE per variant and the baseline's, by horizon, and the final area ratios."""
    water = types == WATER_PARTICLE_ID
    true = frames[:, water].astype(np.float64)
    input_frames = 2
    baseline, _, _ = baseline_errors(frames, types, input_frames, metadata, emd_every=0)
    rollouts = {BASELINE: baseline[:, water].astype(np.float64)}
    for name, (velocity, carry_j) in VARIANTS.items():
        rollouts[name] = two_frame_rollout(preset, ramps, true[:input_frames], len(true), velocity, carry_j)
    spacing = particle_spacing(true[0])
    row = {}
    for name, rolled in rollouts.items():
        per_frame = np.full(len(true), np.nan)
        per_frame[input_frames:] = ((rolled[input_frames:] - true[input_frames:]) ** 2).mean(axis=(1, 2))
        row[name] = {
            **{
                str(h or "all"): horizon_mse(per_frame, input_frames, h or len(true) - input_frames)
                for h in HORIZONS
            },  # fmt: skip
            "area_ratio_final": area_ratio(rolled[-1], true[-1], spacing),
        }
    return row


def measure(preset: Preset, seed: int, split: str, scenes: int, data: Path) -> dict:
    """Every variant and the baseline over the first ``scenes`` scenes of ``split``, checked frame for frame
    against the stored dataset ``data`` (its metadata gives the baseline's gravity and walls).

    Returns ``{"rows": [per trajectory {name: {horizon: mse, "area_ratio_final"}}], "summary": {name: {key:
    (mean, se)}}, "x_baseline": {name: (geomean, low, high, n)}, "dataset_max_abs_m"}``.

    Raises:
        ValueError: a rebuilt trajectory differs from the stored one (another recipe or seed).
    """
    from gnsx.data.store import open_split

    metadata = load_metadata(data)
    stored = open_split(data, split, metadata, check_values=False)
    if len(stored) < scenes:
        raise ValueError(f"{data}: the {split} split holds {len(stored)} trajectories, not {scenes}")
    rows, worst = [], 0.0
    for index in range(scenes):
        frames, types, ramps = true_trajectory(preset, seed, split, index)
        worst = max(worst, float(np.abs(stored[index].position - frames).max()))
        if worst > 1e-6:
            raise ValueError(
                f"{data}: {split} trajectory {index} is not the rebuilt scene ({worst:.3g} m apart)"
            )
        rows.append(trajectory_row(preset, frames, types, ramps, metadata))
    names = list(rows[0])
    summary = {
        name: {key: mean_se([row[name][key] for row in rows]) for key in rows[0][name]} for name in names
    }
    ratios = {
        name: geometric_mean_interval([row[BASELINE]["all"] / row[name]["all"] for row in rows])
        for name in names
        if name != BASELINE
    }
    return {"rows": rows, "summary": summary, "x_baseline": ratios, "dataset_max_abs_m": worst}


def table(result: dict) -> list[str]:
    """Markdown: rollout MSE by horizon, x baseline [95%] and the final area per variant."""
    summary = result["summary"]
    horizons = [str(h or "all") for h in HORIZONS]
    lines = ["| rollout | " + " | ".join(f"MSE, first {h} frames" if h != "all" else "MSE, all frames"
                                         for h in horizons)
             + " | x baseline [95%] | final area / truth |",
             "|---|" + "---|" * (len(horizons) + 2)]  # fmt: skip
    for name, figures in summary.items():
        cells = [f"{figures[h][0]:.3g} ± {figures[h][1]:.2g}" for h in horizons]
        ratio = result["x_baseline"].get(name)
        cells.append("1" if ratio is None else f"{ratio[0]:.3g}x [{ratio[1]:.3g}, {ratio[2]:.3g}]")
        area = figures["area_ratio_final"]
        cells.append(f"{area[0]:.2f} ± {area[1]:.2f}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m gnsx.evaluation.hidden_state_rollout", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--preset", default="small", help="dataset preset (default small)")
    parser.add_argument("--seed", type=int, default=0, help="the dataset's generation seed (default 0)")
    parser.add_argument("--split", default="test", help="split whose scenes are rebuilt (default test)")
    parser.add_argument("--scenes", type=int, default=4, help="the split's first N scenes (default 4)")
    parser.add_argument("--data", type=Path, required=True, help="the stored dataset of this recipe")
    parser.add_argument("--out", type=Path, default=None, help="folder for hidden_state_rollout.md and .json")
    args = parser.parse_args(argv)
    if args.scenes < 1:
        parser.error("--scenes must be >= 1")
    preset = get_preset(args.preset)
    start = time.perf_counter()
    with one_thread():  # the generator's thread count: the rebuilt frames are the dataset's to the bit
        result = measure(preset, args.seed, args.split, args.scenes, args.data)
    result["wall_s"] = time.perf_counter() - start
    command = (f"python -m gnsx.evaluation.hidden_state_rollout --preset {args.preset} --split {args.split} "
               f"--scenes {args.scenes} --data {args.data}")  # fmt: skip
    lines = [
        f"# The MPM rolled out with a two-frame memory: {args.preset}, {args.split} split",
        "",
        f"Command: `{command}` ({result['wall_s']:.0f} s, one thread). Scenes {args.split} 0-{args.scenes - 1},"
        f" rebuilt as the generator does (max |rebuilt - stored| = {result['dataset_max_abs_m']:.3g} m), rolled"
        f" out from their first two true frames, the hidden state rebuilt from the rollout's own last two frames"
        f" before each of the {preset.num_frames - 2} frames (`gnsx.evaluation.hidden_state_rollout`).",
        "",
        "MSE: position error per coordinate, water particles, mean over trajectories ± SE. 'x baseline': the"
        " physics-free baseline's whole-rollout MSE over the variant's, geometric mean over trajectories with its"
        " 95% t interval. Final area: the water's area at the last frame over the truth's.",
        "",
        *table(result),
        "",
    ]
    text = "\n".join(lines)
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "hidden_state_rollout.md").write_text(text)
        write_json(args.out / "hidden_state_rollout.json", result)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, user_errors=(ValueError, FileNotFoundError)))
