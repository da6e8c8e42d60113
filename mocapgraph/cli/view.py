"""``mocapgraph overlay`` (a result drawn over a camera's video) and ``mocapgraph view`` (the
result in the rerun viewer, or saved as a recording)."""

from __future__ import annotations

from pathlib import Path

from mocapgraph.cli.common import command, result_body, result_capture


def cmd_overlay(args) -> None:
    from mocapgraph.data_tools.evaluation.overlay import write_overlay
    from mocapgraph.data_tools.io.result import load_result

    result = load_result(args.result)
    capture = result_capture(result, args.capture, required=True)
    path = write_overlay(
        result, capture, args.camera, args.out, body=result_body(result, args.model_path), overwrite=args.overwrite, max_frames=args.max_frames,
    )  # fmt: skip
    print(f"wrote {path.resolve()}")


def add_parsers(subparsers) -> None:
    overlay = command(subparsers, "overlay", "draw a result (mesh, skeleton) and the detections over one camera's video (or a plain background)")
    overlay.add_argument("result", type=Path, help="result directory")
    overlay.add_argument("--camera", required=True, help="camera name (as in the capture)")
    overlay.add_argument("--out", type=Path, required=True, help="MP4 video to write")
    overlay.add_argument("--capture", type=Path, help="capture directory (default: the one the result names)")
    overlay.add_argument("--model-path", type=Path, help="SMPL/SMPL-X results: your own model file (without it: skeleton only)")
    overlay.add_argument("--max-frames", type=int, help="only the first frames (default: all)")
    overlay.add_argument("--overwrite", action="store_true", help="replace an existing video")
    overlay.set_defaults(func=cmd_overlay)
