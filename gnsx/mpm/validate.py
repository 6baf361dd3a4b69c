"""Validation of the MPM ground truth against experiment and hydrostatics (``make validate-mpm``).

    python -m gnsx.mpm.validate --out outputs/validate-mpm        # both presets, before and after; ~20 min

Every learned model is trained on and scored against this solver, so its errors become the models' errors.
The cases, each a function returning plain numbers:

* :func:`dam_break`: Martin & Moyce (1952), a square water column of width ``a`` (``n^2 = height / width
  = 1``) collapsing along the floor from the left wall. The surge front ``Z = x / a`` (x from the wall)
  against ``T = n t sqrt(g / a)``, next to the measured points :data:`MARTIN_MOYCE`
  (Martin & Moyce 1952, Phil. Trans. A 244),
  also under grid refinement (:data:`REFINEMENT`). An inviscid solver without the experiment's gate (lifted
  in a finite time) and wall friction runs ahead of them; the shallow-water (Ritter) front speed
  ``2 sqrt(g a)``, i.e. ``Z <= 1 + 2 T``, bounds it above.
* :func:`settled_pool`: a column collapses, sloshes and settles; after ``frames`` frames its height
  ``2 (mean y - floor)`` (exact for a uniform layer; hydrostatic compression ``g h / c^2`` is < 1e-3 here)
  against the height its volume (``N spacing^2``) fills wall to wall.
* :func:`still_pool`: a layer placed at rest; its particles' mean speed at the end (target < 1 mm/s).
* :func:`free_fall`: a block in free fall; the acceleration of its centre of mass against ``g``.
* :func:`sampled_scenes`: scenes drawn as the preset draws them; the most compressed particle (``min J``),
  the fastest one, and the safety nets' counts (ramp put-backs, wall clamps).

``--no-before`` skips the pre-issue-13 solver (:data:`LEGACY`) that the report compares against.
Units: metres, seconds; the solver's water density is 1 kg/m^2 (2D).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence

import numpy as np
import torch

from gnsx.core.constants import WATER_PARTICLE_ID
from gnsx.core.errors import DataError
from gnsx.data.metadata import compute_statistics
from gnsx.data.trajectory import Trajectory
from gnsx.mpm.generate import scene_solver
from gnsx.mpm.presets import SOLVER_BEFORE_ISSUE_13, Preset
from gnsx.mpm.scenes import Scene, WaterBlock, sample_scene, water_particles
from gnsx.mpm.solver import MLSMPMSolver, SolverSettings

#: Martin & Moyce (1952), n^2 = 1: surge-front points (T, Z), read off their figure for the square column.
MARTIN_MOYCE = np.array(
    [
        (0.43, 1.11), (0.62, 1.22), (0.80, 1.44), (0.97, 1.67), (1.14, 1.89), (1.29, 2.11),
        (1.45, 2.33), (1.62, 2.56), (1.76, 2.78), (1.93, 3.00), (2.07, 3.22), (2.24, 3.44),
        (2.40, 3.67), (2.54, 3.89), (2.71, 4.11), (2.87, 4.33), (3.04, 4.56), (3.21, 4.78),
    ]
)  # fmt: skip


def _lattice(
    lower: Sequence[float], upper: Sequence[float], spacing: float, rng, jitter: float
) -> np.ndarray:
    """``[N, 2]`` water positions filling the rectangle, as the dataset generator places them."""
    scene = Scene([WaterBlock(tuple(lower), tuple(upper))], [])
    position, _ = water_particles(scene, spacing, rng, jitter=jitter)
    return position


def _solver(position: np.ndarray, spacing: float, settings: SolverSettings, ramps=()) -> MLSMPMSolver:
    return MLSMPMSolver(
        position, np.zeros_like(position), np.asarray(ramps, float).reshape(-1, 2, 2), spacing, settings
    )


def dam_break(
    settings: SolverSettings,
    spacing: float,
    width: float = 0.12,
    t_max: float = 3.3,
    jitter: float = 0.35,
    seed: int = 0,
) -> dict:
    """Collapse of a ``width`` x ``width`` column against the left wall; the surge front against time.

    ``width`` 0.12 m keeps the front clear of the far wall up to T = 3.3 (the box is 6.7 widths wide; with
    0.15 m the front reached the wall at T ~ 2.9 and the error at T = 3 was cut short). The front is the
    largest x of any particle within ``3 * spacing`` of the floor (the experiment read the
    front at the floor), minus the wall; Z = front / width. One point per frame up to ``T = t_max``.

    Returns:
        ``{"T": [...], "Z": [...], "error_at": {T: relative error vs the interpolated measurement},
        "max_abs_error": ..., "particles": N}``.
    """
    lo = settings.wall_lo
    rng = np.random.default_rng(seed)
    position = _lattice((lo, lo), (lo + width, lo + width), spacing, rng, jitter)
    solver = _solver(position, spacing, settings)
    time_scale = math.sqrt(width / settings.gravity)  # seconds per unit of T
    frames = int(math.ceil(t_max * time_scale / settings.frame_dt)) + 1
    T, Z = [], []
    for f in range(frames):
        if f:
            solver.step_frame()
        x = solver.x.numpy().astype(np.float64)
        near_floor = x[:, 1] < lo + 3 * spacing
        front = x[near_floor, 0].max() if near_floor.any() else lo
        T.append(f * settings.frame_dt / time_scale)
        Z.append((front - lo) / width)
    T, Z = np.array(T), np.array(Z)
    measured = MARTIN_MOYCE
    inside = measured[:, 0] <= T[-1]
    sim_at = np.interp(measured[inside, 0], T, Z)
    rel = sim_at / measured[inside, 1] - 1.0
    error_at = {}
    for t_check in (1.0, 2.0, 3.0):
        if t_check <= T[-1]:
            ref = np.interp(t_check, measured[:, 0], measured[:, 1])
            error_at[f"{t_check:g}"] = float(np.interp(t_check, T, Z) / ref - 1.0)
    return {
        "T": T.tolist(),
        "Z": Z.tolist(),
        "error_at": error_at,
        "max_abs_error": float(np.abs(rel).max()),
        "particles": int(len(position)),
        "min_J": float(solver.J.min()),
    }


def settled_pool(
    settings: SolverSettings,
    spacing: float,
    column: tuple[float, float] = (0.45, 0.45),
    frames: int = 6000,
    report_every: int = 500,
    last: int = 100,
    jitter: float = 0.35,
    seed: int = 0,
    progress=None,
) -> dict:
    """A ``column`` (width, height) of water against the left wall collapses and settles, ``frames`` frames.

    The volume the particles stand for is ``N spacing^2``; spread wall to wall it fills a height of
    ``N spacing^2 / (wall_hi - wall_lo)``. A solver that loses volume packs the particles closer than that.

    Returns:
        ``{"expected_height", "height": {frame: height}, "height_error" (final, relative), "mean_speed" (m/s,
        mean over particles and the last ``last`` frames), "max_speed", "J_mean", "density_ratio"}``.
        Height is ``2 (mean y - floor)``; ``density_ratio`` is expected / final height (> 1: volume lost).
    """
    lo, hi = settings.wall_lo, settings.wall_hi
    rng = np.random.default_rng(seed)
    position = _lattice((lo, lo), (lo + column[0], lo + column[1]), spacing, rng, jitter)
    expected = len(position) * spacing**2 / (hi - lo)
    solver = _solver(position, spacing, settings)
    heights, speeds = {}, []
    for f in range(1, frames + 1):
        solver.step_frame()
        if f % report_every == 0 or f == frames:
            heights[f] = float(2.0 * (solver.x[:, 1].double().mean() - lo))
            if progress:
                progress(f, heights[f] / expected - 1.0)
        if f > frames - last:
            speeds.append(solver.v.double().norm(dim=1).numpy())
    speeds = np.stack(speeds)
    final = heights[frames]
    return {
        "particles": int(len(position)),
        "expected_height": float(expected),
        "height": heights,
        "height_error": float(final / expected - 1.0),
        "mean_speed": float(speeds.mean()),
        "max_speed": float(speeds.max()),
        "J_mean": float(solver.J.double().mean()),
        "density_ratio": float(expected / final),
    }


def free_fall(settings: SolverSettings, spacing: float, frames: int = 40) -> dict:
    """A small block released in mid-air: its centre of mass' acceleration against ``g`` (m/s^2)."""
    mid = 0.5 * (settings.wall_lo + settings.wall_hi)
    position = _lattice(
        (mid - 0.05, mid + 0.2), (mid + 0.05, mid + 0.3), spacing, np.random.default_rng(0), 0.35
    )
    solver = _solver(position, spacing, settings)
    y = [float(solver.x[:, 1].double().mean())]
    for _ in range(frames):
        solver.step_frame()
        y.append(float(solver.x[:, 1].double().mean()))
    y = np.array(y)
    acc = np.diff(y, 2) / settings.frame_dt**2
    return {"acceleration": float(-acc[5:].mean()), "gravity": settings.gravity}


def sampled_scenes(preset: Preset, count: int, seed: int = 1234, progress=None) -> dict:
    """``count`` scenes as ``preset`` draws them, simulated in full: compression and leakage.

    Returns:
        per-scene rows (``min_J``, ``max_speed``, ``ramp_corrections``, ``wall_clamps``, ``seconds``) and
        their extremes; ``ms_per_substep`` is the median wall time of a substep (one thread).
    """
    rng = np.random.default_rng(seed)
    rows, trajectories = [], []
    for i in range(count):
        scene = sample_scene(rng, preset)
        solver = scene_solver(scene, preset, seed=seed + i)[0]
        n = solver.num_particles
        min_J, max_speed, below = 1.0, 0.0, 0
        frames = [solver.x.numpy().copy()]
        start = time.perf_counter()
        for _ in range(preset.num_frames - 1):
            solver.step_frame()
            min_J = min(min_J, float(solver.J.min()))
            below += int((solver.J < 0.9).sum())
            max_speed = max(max_speed, float(solver.v.norm(dim=1).max()))
            frames.append(solver.x.numpy().copy())
        seconds = time.perf_counter() - start
        water_types = np.full(n, WATER_PARTICLE_ID)
        trajectories.append(Trajectory(position=np.stack(frames), particle_type=water_types, key=i))
        rows.append(
            {
                "particles": n,
                "min_J": min_J,
                "compressed_fraction": below / ((preset.num_frames - 1) * n),
                "max_speed": max_speed,
                "ramp_corrections": solver.ramp_corrections,
                "wall_clamps": solver.wall_clamps,
                "seconds": seconds,
                "ms_per_substep": 1e3 * seconds / ((preset.num_frames - 1) * preset.substeps),
            }
        )
        if progress:
            progress(i, rows[-1])
    return {
        "scenes": rows,
        "min_J": min(r["min_J"] for r in rows),
        "max_speed": max(r["max_speed"] for r in rows),
        "ramp_corrections": sum(r["ramp_corrections"] for r in rows),
        "wall_clamps": sum(r["wall_clamps"] for r in rows),
        "seconds_per_trajectory": float(np.median([r["seconds"] for r in rows])),
        "ms_per_substep": float(np.median([r["ms_per_substep"] for r in rows])),
        "compressed_fraction": float(np.mean([r["compressed_fraction"] for r in rows])),
        "statistics": _statistics(trajectories, preset.name),
    }


def _statistics(trajectories: list[Trajectory], name: str) -> dict | None:
    """The normalisation statistics, or None when the scenes are too short to have them (nothing moved)."""
    try:
        return compute_statistics(trajectories, where=f"{name} sampled scenes")
    except DataError:
        return None


def one_thread() -> None:
    """Validation figures are single-threaded, like dataset generation's workers."""
    torch.set_num_threads(1)


def still_pool(
    settings: SolverSettings,
    spacing: float,
    depth: float = 0.1,
    frames: int = 4000,
    last: int = 100,
    seed: int = 0,
) -> dict:
    """A wall-to-wall slab of ``depth`` placed at rest: does it stay at rest, and at its height?

    Returns:
        ``mean_speed`` (m/s, over particles and the last ``last`` frames), ``max_speed``, ``height_error``
        (final height against ``N spacing^2 / width``), ``J_min``/``J_max`` at the end.
    """
    lo, hi = settings.wall_lo, settings.wall_hi
    position = _lattice((lo, lo), (hi, lo + depth), spacing, np.random.default_rng(seed), 0.35)
    expected = len(position) * spacing**2 / (hi - lo)
    solver = _solver(position, spacing, settings)
    speeds = []
    for f in range(1, frames + 1):
        solver.step_frame()
        if f > frames - last:
            speeds.append(solver.v.double().norm(dim=1).numpy())
    speeds = np.stack(speeds)
    height = float(2.0 * (solver.x[:, 1].double().mean() - lo))
    return {
        "particles": int(len(position)),
        "mean_speed": float(speeds.mean()),
        "max_speed": float(speeds.max()),
        "height_error": height / expected - 1.0,
        "J_min": float(solver.J.min()),
        "J_max": float(solver.J.max()),
    }


#: The solver before issue 13 (mpm88's water): soft, inviscid, J integrated without a density correction.
LEGACY = {"stiffness": 400.0, "substeps": 10, **SOLVER_BEFORE_ISSUE_13}
#: Dam-break grid refinement: grids (nodes per metre) at the preset's particles-per-cell.
REFINEMENT = (64, 128, 256)


def _variant(preset: Preset, legacy: bool, grid: int | None = None) -> tuple[SolverSettings, float]:
    """The preset's settings (or the legacy solver's), optionally refined to ``grid`` at the same
    particles per cell and the same Courant number."""
    settings = preset.solver_settings()
    if legacy:
        settings = dataclasses.replace(settings, **LEGACY)
    spacing = preset.particle_spacing
    if grid is not None and grid != settings.grid:
        ratio = grid / settings.grid
        settings = dataclasses.replace(
            settings, grid=grid, substeps=int(math.ceil(settings.substeps * ratio))
        )
        spacing = spacing / ratio
    return settings, spacing


def validate(
    presets: Sequence[Preset],
    *,
    legacy: bool = False,
    pool_frames: int = 6000,
    still_frames: int = 4000,
    scenes: int = 10,
    refinement: Sequence[int] = REFINEMENT,
    log=print,
) -> dict:
    """Every validation case for each preset (``legacy``: the pre-issue-13 solver). Plain JSON-ready dict."""
    out = {}
    for preset in presets:
        settings, spacing = _variant(preset, legacy)
        row: dict = {"settings": dataclasses.asdict(settings), "spacing": spacing}
        log(f"[{preset.name}{' legacy' if legacy else ''}] free fall, dam break")
        row["free_fall"] = free_fall(settings, spacing)
        row["dam_break"] = dam_break(settings, spacing)
        refined = {settings.grid: row["dam_break"]}  # the preset's own grid first
        for grid in refinement:
            if grid == settings.grid:
                continue
            log(f"[{preset.name}] dam break, grid {grid}")
            refined[grid] = dam_break(*_variant(preset, legacy, grid))
        row["dam_break_refinement"] = {str(g): r for g, r in refined.items()}
        log(f"[{preset.name}] settling pool, {pool_frames} frames")
        row["settled_pool"] = settled_pool(settings, spacing, frames=pool_frames)
        log(f"[{preset.name}] still pool, {still_frames} frames")
        row["still_pool"] = still_pool(settings, spacing, frames=still_frames)
        if scenes:
            log(f"[{preset.name}] {scenes} sampled scenes")
            run_preset = dataclasses.replace(preset, **LEGACY) if legacy else preset
            row["scenes"] = sampled_scenes(run_preset, scenes)
        out[preset.name] = row
    return out


def summary_rows(report: dict) -> list[dict]:
    """One row per (preset, solver) with the headline figures of the issue's table."""
    rows = []
    for which, by_preset in report.items():
        for name, r in by_preset.items():
            row = {
                "preset": name,
                "solver": which,
                "g": r["free_fall"]["acceleration"],
                "front_T1": r["dam_break"]["error_at"].get("1"),
                "front_T2": r["dam_break"]["error_at"].get("2"),
                "front_T3": r["dam_break"]["error_at"].get("3"),
                "pool_height_6000": r["settled_pool"]["height_error"],
                "still_speed_mm_s": 1e3 * r["still_pool"]["mean_speed"],
            }
            if "scenes" in r:
                sc = r["scenes"]
                row.update(
                    min_J=sc["min_J"],
                    max_speed=sc["max_speed"],
                    crossings=sc["ramp_corrections"],
                    ms_per_substep=sc["ms_per_substep"],
                    s_per_trajectory=sc["seconds_per_trajectory"],
                )
            rows.append(row)
    return rows


def format_markdown(report: dict) -> str:
    """The before/after table and the dam-break refinement table, as markdown."""
    cols = [
        ("preset", "preset", "{}"), ("solver", "solver", "{}"), ("g", "g (m/s^2)", "{:.4f}"),
        ("front_T1", "front T=1", "{:+.1%}"), ("front_T2", "T=2", "{:+.1%}"), ("front_T3", "T=3", "{:+.1%}"),
        ("pool_height_6000", "pool height @6000", "{:+.1%}"),
        ("still_speed_mm_s", "still pool mm/s", "{:.2f}"),
        ("min_J", "min J", "{:.3f}"), ("max_speed", "max speed m/s", "{:.1f}"),
        ("crossings", "ramp put-backs", "{}"), ("ms_per_substep", "ms/substep", "{:.2f}"),
        ("s_per_trajectory", "s/trajectory", "{:.1f}"),
    ]  # fmt: skip
    lines = ["| " + " | ".join(c[1] for c in cols) + " |", "|" + "---|" * len(cols)]
    for row in summary_rows(report):
        cells = [fmt.format(row[k]) if row.get(k) is not None else "-" for k, _, fmt in cols]
        lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        "Dam-break front against Martin & Moyce (relative error at T = 1, 2, 3) under grid refinement:",
        "",
    ]
    lines += ["| preset | solver | grid | particles | T=1 | T=2 | T=3 |", "|---|---|---|---|---|---|---|"]
    for which, by_preset in report.items():
        for name, r in by_preset.items():
            for grid, d in r["dam_break_refinement"].items():
                e = d["error_at"]
                lines.append(
                    f"| {name} | {which} | {grid} | {d['particles']} | "
                    + " | ".join(f"{e[k]:+.1%}" if k in e else "-" for k in ("1", "2", "3"))
                    + " |"
                )
    from gnsx.data.waterramps import WATERRAMPS

    lines += ["", "Normalisation statistics of the sampled scenes (per frame; x, y) next to WaterRamps':", ""]
    lines += ["| preset | solver | vel_std | acc_std |", "|---|---|---|---|"]
    fmt = lambda v: ", ".join(f"{x:.3g}" for x in v)  # noqa: E731
    lines.append(
        f"| WaterRamps (DeepMind) | - | {fmt(WATERRAMPS['vel_std'])} | {fmt(WATERRAMPS['acc_std'])} |"
    )
    for which, by_preset in report.items():
        for name, r in by_preset.items():
            if r.get("scenes", {}).get("statistics"):
                st = r["scenes"]["statistics"]
                lines.append(f"| {name} | {which} | {fmt(st['vel_std'])} | {fmt(st['acc_std'])} |")
    return "\n".join(lines) + "\n"


def plot_dam_break(report: dict, path) -> None:
    """Front position Z against T: Martin & Moyce's points, the Ritter bound, every solver and grid."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    ax.plot(MARTIN_MOYCE[:, 0], MARTIN_MOYCE[:, 1], "ko", label="Martin & Moyce 1952")
    t = np.linspace(0, 3.3, 50)
    ax.plot(t, 1 + 2 * t, "k:", lw=1, label="Ritter bound 1 + 2T")
    styles = {"after": "-", "before": "--"}
    for which, by_preset in report.items():
        for name, r in by_preset.items():
            for grid, d in r["dam_break_refinement"].items():
                ax.plot(
                    d["T"],
                    d["Z"],
                    styles.get(which, "-"),
                    lw=1.2,
                    label=f"{which}: {name} spacing, grid {grid}",
                )
    ax.set_xlabel("T = t sqrt(g / a)")
    ax.set_ylabel("Z = front / a")
    ax.set_xlim(0, 3.3)
    ax.set_ylim(0.9, 6)
    ax.legend(fontsize=6, loc="upper left")
    ax.set_title("Dam break (square column): surge front")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    import argparse
    from pathlib import Path

    from gnsx.core.atomic import write_json
    from gnsx.mpm.presets import get_preset

    parser = argparse.ArgumentParser(prog="python -m gnsx.mpm.validate", description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="outputs/validate-mpm", help="report folder (created)")
    parser.add_argument("--presets", nargs="+", default=["waterramps", "small"])
    parser.add_argument("--no-before", action="store_true", help="skip the legacy (pre-issue-13) solver")
    parser.add_argument("--pool-frames", type=int, default=6000)
    parser.add_argument("--still-frames", type=int, default=4000)
    parser.add_argument("--scenes", type=int, default=10, help="sampled scenes per preset (0: none)")
    parser.add_argument("--refinement", type=int, nargs="*", default=list(REFINEMENT))
    args = parser.parse_args(argv)
    for key in ("pool_frames", "still_frames"):
        if getattr(args, key) < 10:
            parser.exit(2, f"error: --{key.replace('_', '-')} must be >= 10\n")
    try:
        presets = [get_preset(n) for n in args.presets]
    except KeyError as e:
        parser.exit(2, f"error: --presets: {e.args[0]}\n")
    one_thread()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    kw = dict(
        pool_frames=args.pool_frames,
        still_frames=args.still_frames,
        scenes=args.scenes,
        refinement=args.refinement,
    )
    report = {"after": validate(presets, **kw)}
    if not args.no_before:
        report["before"] = validate(presets, legacy=True, **kw)
    write_json(out / "report.json", report)
    text = format_markdown(report)
    (out / "report.md").write_text(text)
    plot_dam_break(report, out / "dam_break.png")
    print(text)
    print(f"report: {out / 'report.md'}, figure: {out / 'dam_break.png'}", flush=True)
    return 0


if __name__ == "__main__":
    import sys

    from gnsx.core.cli import run_main

    sys.exit(run_main(main))
