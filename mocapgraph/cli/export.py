"""``mocapgraph export RESULT --format F --out FILE``: a result for Blender, OpenSim, glTF viewers
or SMPL tools (see :mod:`mocapgraph.data_tools.io.exporters`)."""

from __future__ import annotations

from pathlib import Path

from mocapgraph.cli.common import command, result_body, result_capture


def cmd_export(args) -> None:
    from mocapgraph.data_tools.io.exporters import export_result
    from mocapgraph.data_tools.io.result import load_result

    result = load_result(args.result)
    body = result_body(result, args.model_path)
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
