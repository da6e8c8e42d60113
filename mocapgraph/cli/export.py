"""``mocapgraph export RESULT --format F --out FILE``: a result for Blender, OpenSim, glTF viewers
or SMPL tools (see :mod:`mocapgraph.data_tools.io.exporters`)."""

from __future__ import annotations

import logging
from pathlib import Path

from mocapgraph.cli.common import command
from mocapgraph.errors import MocapgraphError

log = logging.getLogger(__name__)


def result_capture(result, given: Path | None):
    """The capture a result came from: ``given``, else the one the result names if it can be
    read there (None, with a note, when it cannot: what needs it is then left out)."""
    from mocapgraph.data_tools.io.capture import load_capture

    if given is not None:
        return load_capture(given)
    try:
        return load_capture(result.capture)
    except MocapgraphError as exc:
        log.warning("the result's capture is not readable (%s); pass --capture for the cameras' lenses", exc)
        return None


def cmd_export(args) -> None:
    from mocapgraph.body import load_body_model
    from mocapgraph.data_tools.io.exporters import export_result
    from mocapgraph.data_tools.io.result import load_result

    result = load_result(args.result)
    body = load_body_model(result.body_model, args.model_path) if args.model_path is not None and result.has_body_parameters else None
    capture = result_capture(result, args.capture) if args.format == "gltf" else None
    path = export_result(result, args.format, args.out, body=body, capture=capture, overwrite=args.overwrite)
    print(f"wrote {path.resolve()}")


def add_parsers(subparsers) -> None:
    from mocapgraph.data_tools.io.exporters import FORMATS

    parser = command(
        subparsers, "export", "write a result as BVH (Blender), glTF binary (skinned mesh and cameras), TRC (OpenSim, Pose2Sim), CSV or SMPL .npz",
    )  # fmt: skip
    parser.add_argument("result", type=Path, help="result directory")
    parser.add_argument("--format", required=True, choices=tuple(FORMATS), help="bvh, gltf (.glb), trc, csv, or smpl (.npz; SMPL/SMPL-X results only)")
    parser.add_argument("--out", type=Path, required=True, help="file to write, with the format's suffix (" + ", ".join(FORMATS.values()) + ")")
    parser.add_argument("--capture", type=Path, help="the result's capture, for the cameras' lenses in glTF (default: the one the result names)")
    parser.add_argument("--model-path", type=Path, help="SMPL/SMPL-X results: your own model file the result was solved with")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing file")
    parser.set_defaults(func=cmd_export)
