"""``python -m gnsx.data``: generate, convert, inspect and export datasets.

Subcommands::

    python -m gnsx.data generate --preset small|waterramps --out DIR [--seed N] [--workers 2]
                                 [--train N --valid N --test N] [--rest-fraction F]
                                 [--dam-fraction F] [--overwrite]
        Simulate WaterRamps-like scenes with gnsx's MPM solver and write a gnsx dataset to DIR.
        --train/--valid/--test override the preset's number of trajectories per split. A killed run resumes:
        finished trajectories are kept in DIR.partial/ until the dataset is written, and rerunning the same
        command (same preset and --seed) simulates only the missing ones; the progress bar says how many
        were resumed. A DIR.partial/ of another preset or seed is refused (delete it to start over).

    python -m gnsx.data convert SRC DST [--format tfrecord|npz|h5] [--bounds LO HI [LO HI ...]]
                                [--dt SECONDS] [--radius R] [--type-map SRC:DST,...] [--overwrite]
        Convert a DeepMind TFRecord, geoelements/gns .npz or LagrangeBench .h5 dataset (SRC/{split}.{ext},
        usually with SRC/metadata.json) into a gnsx dataset at DST. The format is detected unless given.
        Without a metadata.json (or one lacking them) pass --bounds, --dt and --radius; sequence_length and
        the statistics are computed from the data when missing. --type-map remaps particle type ids
        (LagrangeBench to DeepMind: --type-map 0:5,1:3,2:3,3:0). Example (WaterRamps as DeepMind ships it):
            python -m gnsx.data convert ~/datasets/WaterRamps data/waterramps

    python -m gnsx.data info DIR
        Summarise a gnsx dataset: metadata, and per split the trajectories, frames, and particle counts
        (min/mean/max per trajectory) by particle type.

    python -m gnsx.data export DIR DST --format tfrecord|npz|h5 [--overwrite]
        Write a gnsx dataset in another format (every split plus metadata.json).

Bad input (a missing file, a truncated record, NaN at some frame, a negative --seed, an --out under a
file, ...) prints one line naming the file, trajectory, field and frame (or the flag) on stderr and exits with
status 2; --debug shows the traceback.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gnsx.core.cli import ArgumentParser, check_int, check_output_path, run_main
from gnsx.core.constants import NUM_PARTICLE_TYPES, PARTICLE_TYPE_NAMES
from gnsx.core.errors import DataError
from gnsx.data.formats import FORMATS, convert, export_dataset
from gnsx.data.metadata import STATISTICS_KEYS
from gnsx.data.store import SplitReader, list_splits, load_metadata, open_split


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; return the exit status (0 success, 2 bad input: one line on stderr)."""
    return run_main(_run, argv)


def _run(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    return args.run(args)


def _parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog="python -m gnsx.data",
        description="Generate, convert, inspect and export gnsx datasets.",
        epilog=__doc__.split("\n", 2)[2],  # the subcommand reference above, examples included
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True)

    gen = sub.add_parser("generate", help="simulate a WaterRamps-like dataset with gnsx's MPM solver")
    gen.add_argument("--preset", required=True, help="generation preset: small or waterramps")
    gen.add_argument("--out", required=True, type=Path, help="dataset folder to write")
    gen.add_argument("--seed", type=int, default=0, help="random seed of the scene sampler (default 0)")
    gen.add_argument("--workers", type=int, default=2, help="simulation processes (default 2)")
    for split in ("train", "valid", "test"):
        gen.add_argument(
            f"--{split}", type=int, metavar="N", help=f"number of {split} trajectories (preset's)"
        )
    gen.add_argument(
        "--rest-fraction",
        type=float,
        metavar="F",
        help="share of training scenes that start as a pool at rest (preset's, 0 for both presets)",
    )
    gen.add_argument(
        "--dam-fraction",
        type=float,
        metavar="F",
        help="share of training scenes that start as a dam break, a block at rest on the floor (preset's, 0)",
    )
    gen.add_argument(
        "--pool-depth",
        type=float,
        nargs=2,
        metavar=("MIN", "MAX"),
        help="depth range (m) of those pools (preset's: 0.03 0.25 for small)",
    )
    gen.add_argument("--overwrite", action="store_true", help="replace an existing dataset at --out")
    gen.set_defaults(run=_generate)

    conv = sub.add_parser("convert", help="convert TFRecord / .npz / .h5 data into a gnsx dataset")
    conv.add_argument("src", type=Path, help="folder with {split}.tfrecord|.npz|.h5 (and metadata.json)")
    conv.add_argument("dst", type=Path, help="gnsx dataset folder to write")
    conv.add_argument("--format", choices=FORMATS, help="source format (detected when omitted)")
    conv.add_argument(
        "--bounds",
        type=float,
        nargs="+",
        metavar="X",
        help="domain bounds LO HI per dimension, e.g. 0.1 0.9 0.1 0.9",
    )
    conv.add_argument("--dt", type=float, help="seconds between frames")
    conv.add_argument("--radius", type=float, help="default connectivity radius (data units)")
    conv.add_argument(
        "--type-map",
        metavar="SRC:DST,...",
        help="remap particle type ids, e.g. 0:5,1:3,2:3,3:0 (LagrangeBench)",
    )
    conv.add_argument("--overwrite", action="store_true", help="replace an existing dataset at DST")
    conv.set_defaults(run=_convert)

    info = sub.add_parser("info", help="summarise a gnsx dataset")
    info.add_argument("dir", type=Path, help="gnsx dataset folder")
    info.set_defaults(run=_info)

    exp = sub.add_parser("export", help="write a gnsx dataset as TFRecord / .npz / .h5")
    exp.add_argument("dir", type=Path, help="gnsx dataset folder")
    exp.add_argument("dst", type=Path, help="folder to write {split}.{ext} and metadata.json into")
    exp.add_argument("--format", choices=FORMATS, required=True, help="target format")
    exp.add_argument("--overwrite", action="store_true", help="replace existing files in DST")
    exp.set_defaults(run=_export)
    return parser


def _generate(args: argparse.Namespace) -> int:
    # Imported here: the solver pulls in heavier dependencies that convert/info never need.
    from gnsx.mpm.generate import generate_dataset
    from gnsx.mpm.presets import get_preset

    try:
        preset = get_preset(args.preset)
    except (KeyError, ValueError) as e:
        raise DataError("--preset", str(e.args[0]) if e.args else str(e)) from None
    check_int(args.seed, "--seed", minimum=0)
    check_int(args.workers, "--workers", minimum=1)
    check_output_path(args.out, "--out")
    counts = {split: getattr(args, split) for split in ("train", "valid", "test")}
    counts = {split: n for split, n in counts.items() if n is not None}
    if any(n < 0 for n in counts.values()):
        raise DataError("--train/--valid/--test", f"trajectory counts must be >= 0, got {counts}")
    if counts:
        preset = dataclasses.replace(preset, trajectories={**preset.trajectories, **counts})
    if args.rest_fraction is not None:
        try:
            preset = dataclasses.replace(preset, rest_fraction=args.rest_fraction)
        except ValueError as e:
            raise DataError("--rest-fraction", str(e)) from None
    if args.dam_fraction is not None:
        try:
            preset = dataclasses.replace(preset, dam_fraction=args.dam_fraction)
        except ValueError as e:
            raise DataError("--dam-fraction", str(e)) from None
    if args.pool_depth is not None:
        try:
            preset = dataclasses.replace(preset, pool_depth_range=tuple(args.pool_depth))
        except ValueError as e:
            raise DataError("--pool-depth", str(e)) from None
    out = generate_dataset(
        args.out, preset, seed=args.seed, workers=args.workers, overwrite=args.overwrite, progress=True
    )
    print(f"wrote {out}")
    return 0


def _convert(args: argparse.Namespace) -> int:
    check_output_path(args.dst, "DST")
    bounds = None
    if args.bounds is not None:
        if len(args.bounds) % 2:
            raise DataError(
                "--bounds", f"expected LO HI pairs (an even count), got {len(args.bounds)} numbers"
            )
        bounds = [args.bounds[i : i + 2] for i in range(0, len(args.bounds), 2)]
    type_map = _parse_type_map(args.type_map) if args.type_map else None
    meta = convert(
        args.src,
        args.dst,
        fmt=args.format,
        overwrite=args.overwrite,
        bounds=bounds,
        dt=args.dt,
        radius=args.radius,
        type_map=type_map,
    )
    counts = ", ".join(f"{split} {len(SplitReader(args.dst, split))}" for split in list_splits(args.dst))
    print(f"wrote {args.dst}: {counts} trajectories, dim {meta.dim}, sequence_length {meta.sequence_length}")
    return 0


def _parse_type_map(text: str) -> dict[int, int]:
    """``"0:5,1:3"`` -> ``{0: 5, 1: 3}``."""
    try:
        pairs = [item.split(":") for item in text.split(",") if item.strip()]
        return {int(source): int(target) for source, target in pairs}
    except ValueError:
        raise DataError("--type-map", f"expected SRC:DST pairs separated by commas, got {text!r}") from None


def _export(args: argparse.Namespace) -> int:
    check_output_path(args.dst, "DST")
    counts = export_dataset(args.dir, args.dst, args.format, overwrite=args.overwrite)
    summary = ", ".join(f"{split} {n}" for split, n in counts.items())
    print(f"wrote {args.dst} ({args.format}): {summary} trajectories")
    return 0


def _info(args: argparse.Namespace) -> int:
    print(format_info(args.dir))
    return 0


def format_info(root: str | Path) -> str:
    """A human-readable summary of the gnsx dataset at ``root`` (what ``info`` prints)."""
    root = Path(root)
    meta = load_metadata(root)
    bounds = " x ".join(f"[{lo:g}, {hi:g}]" for lo, hi in meta.bounds)
    lines = [
        f"dataset {root}",
        f"  dim {meta.dim}, dt {meta.dt:g} s, bounds {bounds}, "
        f"connectivity radius {meta.default_connectivity_radius:g}",
        f"  sequence_length {meta.sequence_length} (transitions per trajectory)",
        "  statistics (per frame, non-static particles of train):",
    ]
    for key in STATISTICS_KEYS:
        lines.append(f"    {key:<8} [{', '.join(f'{v:.4g}' for v in getattr(meta, key))}]")
    if meta.extra:
        lines.append(f"  other metadata keys: {', '.join(sorted(meta.extra))}")
    for split in list_splits(root):
        reader = open_split(root, split, meta, check_values=False)
        lines.append(f"  {split}: {len(reader)} trajectories, {reader.total_frames} frames")
        if len(reader) == 0:
            continue
        lines.append(f"    frames per trajectory: {_min_mean_max(reader.frame_counts)}")
        lines.append(f"    particles per trajectory: {_min_mean_max(reader.particle_counts)}")
        by_type = np.stack(
            [np.bincount(reader.particle_type(i), minlength=NUM_PARTICLE_TYPES) for i in range(len(reader))]
        )  # [trajectories, types]
        for t in np.flatnonzero(by_type.sum(axis=0)):
            name = PARTICLE_TYPE_NAMES.get(int(t), "unnamed")
            lines.append(f"      type {t} ({name}): {_min_mean_max(by_type[:, t])}")
    return "\n".join(lines)


def _min_mean_max(values: np.ndarray) -> str:
    return f"min {int(values.min())}, mean {values.mean():.1f}, max {int(values.max())}"


if __name__ == "__main__":
    sys.exit(main())
