"""The ``mocapgraph`` command: one entry point, a module per command group, ``--help`` on each."""

from __future__ import annotations

import argparse
import sys

from mocapgraph import __version__
from mocapgraph.errors import MocapgraphError
from mocapgraph.progress import configure_logging


def build_parser() -> argparse.ArgumentParser:
    from mocapgraph.cli import batch, bench, body, capture, colmap, demo, detect, evaluate, export, plot, priors, run, synth, view

    parser = argparse.ArgumentParser(prog="mocapgraph", description="Markerless multi-camera human motion capture as factor graphs.")
    parser.add_argument("--version", action="version", version=f"mocapgraph {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in (body, bench, capture, detect, synth, colmap, run, evaluate, plot, export, view, batch, priors, demo):
        module.add_parsers(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args.verbosity)
    from mocapgraph.data_tools.io.files import release_outputs

    try:
        args.func(args)
    except MocapgraphError as exc:
        print(f"mocapgraph: error: {exc}", file=sys.stderr)
        return 2
    finally:
        release_outputs()  # outputs reserved by a command that stopped before writing them
    return 0


if __name__ == "__main__":
    sys.exit(main())
