"""``mocapgraph synth PRESET --out CAPTURE``: a synthetic capture with ground truth."""

from __future__ import annotations

from mocapgraph.cli.common import command, detector_list, function_flags, out_args


def cmd_synth(args) -> None:
    from mocapgraph.data_tools.io.capture import MANIFEST, write_capture
    from mocapgraph.data_tools.io.files import reserve_output
    from mocapgraph.data_tools.sim.synthetic import synthesize

    reserve_output(args.out, args.overwrite, MANIFEST)
    capture = synthesize(
        args.preset, seed=args.seed, duration_s=args.duration_s, motion=args.motion, detectors=args.detectors,
        detector_faults=args.detector_faults, image_scale=args.image_scale, imu=args.imu,
    )  # fmt: skip
    speeds = {}
    render = None
    if args.render:
        from mocapgraph.data_tools.sim.render import render_capture_videos

        def render(tmp):
            speeds.update(render_capture_videos(capture, tmp))

    path = write_capture(capture, args.out, overwrite=args.overwrite, extra_files=render)
    frames = sum(cam.num_frames for cam in capture.cameras)
    swapped = sum(int((codes != 0).sum()) for by_det in capture.ground_truth.swaps.values() for codes in by_det.values())
    detections = sum(cam.num_frames * len(cam.detectors) for cam in capture.cameras)
    print(f"synthesised {capture.name}: {len(capture.cameras)} cameras, {frames} frames, motion: {capture.metadata['motion']}")
    print(f"detector faults: {args.detector_faults}; left/right swapped in {swapped} of {detections} camera-detector frames")
    if speeds:
        size = "; ".join(f"{name} {capture.camera(name).image_size[0]}x{capture.camera(name).image_size[1]} {fps:.2f}" for name, fps in speeds.items())
        print(f"rendered video (frames/s per camera): {size}")
    print(f"wrote {path}")


def add_parsers(subparsers) -> None:
    from mocapgraph.data_tools.sim.detectors import FAULT_LEVELS
    from mocapgraph.data_tools.sim.scenarios import PRESETS
    from mocapgraph.data_tools.sim.synthetic import synthesize

    synth = command(subparsers, "synth", "synthesise a capture with ground truth from a scenario preset")
    synth.add_argument("preset", choices=PRESETS, help="scenario (docs/scenarios.md)")
    out_args(synth, "capture")
    function_flags(
        synth, synthesize,
        {"seed": "seed of everything random", "duration_s": ("seconds", {"flag": "--duration"}),
         "motion": "walk, turn, arms, zigzag_then_act, stand, or a CMU take (cmu:cmu_02_01.npz); default per preset",
         "detectors": ("comma-separated detector presets; default per preset", {"type": detector_list}),
         "detector_faults": ("sustained left/right swaps, far-side guesses, keypoint offsets, size bias "
                             "(docs/detector_faults.md)", {"choices": FAULT_LEVELS}),
         "image_scale": "resize every camera's images and intrinsics (0.5: 960x540 for the 1920x1080 presets)"},
    )  # fmt: skip
    synth.add_argument("--render", action="store_true",
                       help="also render each camera's video (MP4: textured ground, walls, crates, poles and the body's mesh; docs/capture-format.md)")
    synth.add_argument("--no-imu", dest="imu", action="store_false", help="no IMU logs on the carried phones of phones (docs/phone-imu.md)")
    synth.set_defaults(func=cmd_synth)
