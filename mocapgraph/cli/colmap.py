"""``mocapgraph colmap CAPTURE``: COLMAP's reconstruction of the capture's videos, written into it
as a named reference (pseudo-ground truth for ``eval --reference``)."""

from __future__ import annotations

from pathlib import Path

from mocapgraph.cli.common import OptionFlags, command


def cmd_colmap(args) -> None:
    from mocapgraph.data_tools.evaluation.colmap_reference import check_writable, reconstruct, write_reference
    from mocapgraph.data_tools.io.capture import load_capture

    check_writable(args.capture, args.name, args.overwrite)
    capture = load_capture(args.capture)
    cameras = [c.strip() for c in args.cameras.split(",") if c.strip()] if args.cameras else None
    reference = reconstruct(capture, cameras, args.options_from(args), name=args.name, work_dir=args.work_dir, video_dir=args.videos)
    path = write_reference(reference, args.capture, overwrite=args.overwrite)
    s = reference.stats
    print(f"COLMAP reference of {capture.name}: {s['registered_frames']} of {s['sampled_frames']} sampled frames registered ({100 * s['registration_rate']:.0f} %)")
    for name, c in s["cameras"].items():
        print(f"  {name:20s} {c['registered']:4d} / {c['sampled']:4d}  ({100 * c['registration_rate']:.0f} %)")
    print(f"mean reprojection error {s['mean_reprojection_error_px']:.2f} px, mean track length {s['mean_track_length']:.1f} images, "
          f"{s['points']} points, {s['models']} model(s)")
    t = s["seconds"]
    print(f"time: extraction {t['extraction']:.0f} s, matching {t['matching']:.0f} s, mapping {t['mapping']:.0f} s ({s['seconds_per_frame']:.2f} s/frame)")
    for line in reference.failures:
        print(f"not registered: {line}")
    print(f"wrote {path}")


def add_parsers(subparsers) -> None:
    from mocapgraph.data_tools.evaluation.colmap_reference import ColmapOptions

    parser = command(subparsers, "colmap", "reconstruct the cameras' tracks from the capture's videos with COLMAP (pseudo-ground truth)")
    parser.add_argument("capture", type=Path, help="capture directory whose cameras have videos")
    parser.add_argument("--cameras", help="comma-separated camera names (default: all)")
    parser.add_argument("--videos", type=Path, metavar="DIR", help="folder of the videos, each named like its camera (default: the videos the capture names)")
    parser.add_argument("--name", default="colmap", help="the reference's name, its folder under references/ (default: colmap)")
    parser.add_argument("--work-dir", type=Path, help="keep COLMAP's images, masks and database here (default: a temporary directory)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing reference of that name")
    flags = OptionFlags(parser, ColmapOptions())
    flags.add("frame_step", "reconstruct every N-th frame of each video")
    flags.add("overlap", "match each sampled frame with this many following ones of its video")
    flags.add("keyframe_every", "match across cameras every N sampled frames")
    flags.add("max_features", "SIFT features per image")
    flags.add("seed", "COLMAP's random seed")
    flags.add("threads", "CPU threads")
    flags.add("init_min_tri_angle_deg", "smallest triangulation angle of COLMAP's first image pair, degrees", flag="--init-angle")
    parser.set_defaults(func=cmd_colmap)
