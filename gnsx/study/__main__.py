"""``python -m gnsx.study``: build a perceptual study, run it in a browser, analyse its answers.

Subcommands::

    python -m gnsx.study build --rollouts [NAME=]PATH [...] --out DIR [--pairs-per-group 8]
                               [--methods M [M ...]] [--frames N] [--frame-stride 2] [--fps 25] [--size 256]
                               [--format gif|mp4] [--seed 0] [--name NAME] [--force]
        Pairs of animations of the same initial state by two methods, grouped by method pair, from gnsx
        rollout files (evaluate.py writes <run dir>/<model>/rollouts/*.npz; a folder is searched for .npz).
        Methods: the MPM ground truth ("MPM") and each model, named by the label stored in its rollouts
        or by NAME=PATH. Every pair of methods is a group (or of those given with --methods, in that order).
        Writes DIR/media/ and the manifest DIR/study.json.

    python -m gnsx.study serve DIR [--db FILE] [--host 127.0.0.1] [--port 8000]
        The web app of the study in DIR, recording answers into DIR/answers.sqlite (or --db). It listens on
        this machine only unless --host says otherwise: --host 0.0.0.0 lets people on your local network
        take part, at http://<this machine's address>:PORT/.

    python -m gnsx.study analyse DB [--out DIR] [--alpha 0.05]
        Pick ratios per method pair with 95% Wilson intervals and a binomial test against 50/50, from an
        answers database (a study's answers.sqlite, or a copy of it): DIR/analysis.json, analysis.md and
        figure10.png (default DIR: analysis/ beside the database).

Example (the day-one study, `make study`):
    python evaluate.py checkpoint=pretrained/small/model.ckpt max_trajectories=8 render.enabled=false \\
        hydra.run.dir=studies/day-one/rollouts
    python -m gnsx.study build --rollouts studies/day-one/rollouts --out studies/day-one
    python -m gnsx.study serve studies/day-one
    python -m gnsx.study analyse studies/day-one/answers.sqlite

Bad input prints one line naming what was wrong on stderr and exits with status 2.
"""

from __future__ import annotations

import argparse
import ipaddress
import sys
from collections.abc import Sequence
from pathlib import Path

from gnsx.core.errors import DataError

EXIT_DATA_ERROR = 2


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; return the exit status (0 success, 2 bad input)."""
    args = _parser().parse_args(argv)
    try:
        return args.run(args)
    except DataError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_DATA_ERROR


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m gnsx.study",
        description="Build, run and analyse a perceptual believability study (the paper's figure 10).",
        epilog=__doc__.split("\n", 2)[2],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True)

    build = sub.add_parser("build", help="render pairs of animations and write the study manifest")
    build.add_argument(
        "--rollouts",
        nargs="+",
        required=True,
        metavar="[NAME=]PATH",
        help="rollout .npz files or folders of them; NAME= names the method",
    )
    build.add_argument("--out", required=True, type=Path, help="study folder to write")
    build.add_argument(
        "--pairs-per-group", type=_positive, default=8, help="pairs per method pair (paper: 8)"
    )
    build.add_argument(
        "--methods", nargs="+", help="methods to compare, in report order (default: all, MPM first)"
    )
    build.add_argument("--frames", type=_positive, help="show the first N frames (default: all)")
    build.add_argument("--frame-stride", type=_positive, default=2, help="keep every k-th frame")
    build.add_argument("--fps", type=_positive, default=25, help="animation frames per second")
    build.add_argument("--size", type=_positive, default=256, help="animation size in pixels")
    build.add_argument("--format", choices=("gif", "mp4"), default="gif", help="animation format")
    build.add_argument("--seed", type=int, default=0, help="seeds the scenes drawn and participants' orders")
    build.add_argument("--name", help="study name (default: the folder's name)")
    build.add_argument("--force", action="store_true", help="rebuild a study that already has answers")
    build.set_defaults(run=_build)

    serve = sub.add_parser("serve", help="run the study's web app")
    serve.add_argument("study", type=Path, help="study folder (with study.json)")
    serve.add_argument("--db", type=Path, help="answers database (default: <study>/answers.sqlite)")
    serve.add_argument(
        "--host", default="127.0.0.1", help="address to listen on (0.0.0.0: the local network)"
    )
    serve.add_argument("--port", type=int, default=8000, help="port (0: any free one)")
    serve.set_defaults(run=_serve)

    analyse = sub.add_parser("analyse", help="pick ratios, intervals, tests and figure 10 from answers")
    analyse.add_argument("db", type=Path, help="answers database (answers.sqlite)")
    analyse.add_argument("--out", type=Path, help="report folder (default: analysis/ beside the database)")
    analyse.add_argument("--alpha", type=float, default=0.05, help="significance level of the tests")
    analyse.set_defaults(run=_analyse)
    return parser


def _build(args: argparse.Namespace) -> int:
    from gnsx.study.build import RenderSettings, build_study
    from gnsx.study.manifest import load_study

    settings = RenderSettings(
        frames=args.frames, frame_stride=args.frame_stride, fps=args.fps, size=args.size, format=args.format
    )
    path = build_study(
        args.rollouts,
        args.out,
        pairs_per_group=args.pairs_per_group,
        methods=args.methods,
        settings=settings,
        seed=args.seed,
        name=args.name,
        force=args.force,
    )
    study = load_study(path.parent)
    print(f"Study {study.name!r}: {len(study.pairs)} pairs in {len(study.groups)} groups")
    for a, b in study.groups:
        count = sum(pair.methods == (a, b) for pair in study.pairs)
        print(f"  {a} vs {b}: {count} pairs")
    print(f"Manifest: {path}")
    print(f"Run it:   python -m gnsx.study serve {path.parent}")
    return 0


def _is_address(host: str) -> bool:
    """``localhost`` or an IPv4/IPv6 address."""
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return host == "localhost"
    return True


def _serve(args: argparse.Namespace) -> int:
    from gnsx.study.app import create_app, make_server

    if not 0 <= args.port <= 65535:
        raise DataError("--port", f"must be in [0, 65535], got {args.port}")
    if not _is_address(args.host):
        raise DataError("--host", f"an IP address to listen on (127.0.0.1, 0.0.0.0, ...), got {args.host!r}")
    app = create_app(args.study, args.db)
    try:
        server = make_server(app, args.host, args.port)
    except OSError as e:
        raise DataError(f"{args.host}:{args.port}", f"cannot listen ({e.strerror or e})") from None
    study, store = app.extensions["gnsx_study"]["study"], app.extensions["gnsx_study"]["store"]
    local = args.host in ("127.0.0.1", "::1", "localhost")
    url = f"http://{'localhost' if local else args.host}:{server.server_port}/"
    print(f"Study {study.name!r} ({len(study.pairs)} pairs): {url}  (Ctrl-C stops)")
    if local:
        print("Listening on this machine only; --host 0.0.0.0 lets others on your local network take part.")
    else:
        print(
            f"Listening on {args.host}: anyone who can reach this machine on port {server.server_port} can "
            "take part (give them http://<this machine's address>:PORT/)."
        )
    print(f"Answers: {store.path}")
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    return 0


def _analyse(args: argparse.Namespace) -> int:
    from gnsx.study.analysis import analyse, format_markdown, write_report
    from gnsx.study.store import read_answers

    if not 0 < args.alpha < 1:
        raise DataError("--alpha", f"must be in (0, 1), got {args.alpha}")
    result = analyse(read_answers(args.db), alpha=args.alpha)
    paths = write_report(result, args.out or args.db.parent / "analysis")
    print(format_markdown(result))
    print("Wrote " + ", ".join(str(p) for p in paths.values()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
