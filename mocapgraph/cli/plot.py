"""``mocapgraph plot RESULT``: a picture of a result (cameras and body in 3D)."""

from __future__ import annotations

from pathlib import Path

from mocapgraph.cli.common import command
from mocapgraph.data_tools.io.files import refuse_existing


def cmd_plot(args) -> None:
    from mocapgraph.data_tools.evaluation.report import plot_result
    from mocapgraph.data_tools.io.result import load_result

    result = load_result(args.result)
    out = args.out or Path(args.result) / "result.png"
    refuse_existing(out, args.overwrite)
    print(f"wrote {plot_result(result, out, poses=args.poses).resolve()}")


def add_parsers(subparsers) -> None:
    parser = command(subparsers, "plot", "draw a result: every camera's track and the body at a few instants, in 3D")
    parser.add_argument("result", type=Path, help="result directory")
    parser.add_argument("--out", type=Path, help="PNG to write (default: RESULT/result.png)")
    parser.add_argument("--poses", type=int, default=5, help="body poses drawn, spread over the capture")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing picture")
    parser.set_defaults(func=cmd_plot)
