"""The ``mocapgraph`` command: one entry point, a subcommand per job, ``--help`` on each."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from mocapgraph import __version__
from mocapgraph.errors import MocapgraphError


def _add_body_args(parser: argparse.ArgumentParser) -> None:
    from mocapgraph.body import BACKENDS

    parser.add_argument("--backend", choices=BACKENDS, default="anny", help="body model (default: anny)")
    parser.add_argument(
        "--model-path",
        type=Path,
        help="smpl/smplx: your own licensed model file (.npz or .pkl); anny: an exported table (default: the cache)",
    )


def _body(args):
    from mocapgraph.body import load_body_model

    return load_body_model(args.backend, args.model_path)


def cmd_body_info(args) -> None:
    info = _body(args).describe()
    if args.json:
        print(json.dumps(info, indent=2))
        return
    print(f"backend: {info['backend']}")
    print(f"joints ({len(info['joints'])}, SMPL order; parent in brackets):")
    for i, (name, parent) in enumerate(zip(info["joints"], info["parents"])):
        print(f"  {i:2d} {name:15s} [{info['joints'][parent] if parent >= 0 else '-'}]")
    print(f"keypoints ({len(info['keypoints'])}): {', '.join(info['keypoints'])}")
    print(f"shape parameters ({len(info['shape'])}):")
    for s in info["shape"]:
        print(f"  {s['name']:12s} range [{s['min']:g}, {s['max']:g}]  default {s['default']:g}")


def cmd_body_prepare(args) -> None:
    from mocapgraph.body.anny_backend import ensure_anny_table

    print(ensure_anny_table(rebuild=args.rebuild))


def cmd_bench_body(args) -> None:
    from mocapgraph.body.benchmark import bench_body

    result = bench_body(_body(args), frames=args.frames, min_seconds=args.seconds)
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:22s} {value}")


def cmd_demo(args) -> None:
    from mocapgraph.pipelines.demo import run_demo

    path = run_demo(args.out, args.motion_dir)
    print(f"wrote {path.resolve()}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mocapgraph", description="Markerless multi-camera human motion capture as factor graphs."
    )
    parser.add_argument("--version", action="version", version=f"mocapgraph {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    body = sub.add_parser("body", help="inspect and prepare body models").add_subparsers(
        dest="body_command", required=True, metavar="SUBCOMMAND"
    )
    info = body.add_parser("info", help="joints, keypoints and shape parameters of a body model")
    _add_body_args(info)
    info.add_argument("--json", action="store_true", help="print one JSON object")
    info.set_defaults(func=cmd_body_info)
    prepare = body.add_parser("prepare", help="export the Anny model into the cache (done on first use)")
    prepare.add_argument("--rebuild", action="store_true", help="export again even if the cache is fresh")
    prepare.set_defaults(func=cmd_body_prepare)

    bench = sub.add_parser("bench", help="speed and accuracy benchmarks").add_subparsers(
        dest="bench_command", required=True, metavar="SUBCOMMAND"
    )
    bench_body = bench.add_parser("body", help="native vs numpy posing with Jacobians, one run")
    _add_body_args(bench_body)
    bench_body.add_argument("--frames", type=int, default=256, help="frames per batch (default 256)")
    bench_body.add_argument("--seconds", type=float, default=1.0, help="time spent per variant (default 1)")
    bench_body.add_argument("--json", action="store_true", help="print one JSON object")
    bench_body.set_defaults(func=cmd_bench_body)

    demo = sub.add_parser("demo", help="pose the default body and draw it (grows with the pipelines)")
    demo.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory (default out/demo)")
    demo.add_argument("--motion-dir", type=Path, help="CMU motion directory (default ../shared/motion/cmu_train)")
    demo.set_defaults(func=cmd_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except MocapgraphError as exc:
        print(f"mocapgraph: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
