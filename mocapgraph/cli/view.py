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


def cmd_view(args) -> None:
    from mocapgraph.data_tools.evaluation.viewer import view_result
    from mocapgraph.data_tools.io.result import load_result

    result = load_result(args.result)
    capture = result_capture(result, args.capture)
    path = view_result(result, capture, result_body(result, args.model_path), save=args.save, video=not args.no_video, mesh_every=args.mesh_every, overwrite=args.overwrite)
    print(f"wrote {path.resolve()} (open it with: rerun {path})" if path is not None else "opened the rerun viewer")


def add_view_parser(subparsers) -> None:
    view = command(subparsers, "view", "look at a result in the rerun viewer (needs the [viz] extra): mesh, skeleton, cameras, detections, ground truth")
    view.add_argument("result", type=Path, help="result directory")
    view.add_argument("--capture", type=Path, help="capture directory (default: the one the result names, when readable)")
    view.add_argument("--save", type=Path, help="write a recording (.rrd) instead of opening the viewer")
    view.add_argument("--model-path", type=Path, help="SMPL/SMPL-X results: your own model file")
    view.add_argument("--no-video", action="store_true", help="leave the capture's video frames out")
    view.add_argument("--mesh-every", type=int, default=1, help="log the mesh at every N-th body state (about 330 kB a state in a recording)")
    view.add_argument("--overwrite", action="store_true", help="replace an existing recording")
    view.set_defaults(func=cmd_view)


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
    add_view_parser(subparsers)
