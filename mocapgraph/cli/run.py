"""``mocapgraph run PIPELINE CAPTURE --out RESULT``: one pipeline on one capture.

Each pipeline's flags are fields of its options dataclass (defaults read from it); the run goes
through :func:`~mocapgraph.pipelines.runner.run_capture` (load, run, write).
"""

from __future__ import annotations

from pathlib import Path

from mocapgraph.cli.common import OptionFlags, command, detector_list, group, out_args


def _capture_args(parser) -> None:
    parser.add_argument("capture", type=Path, help="capture directory")
    out_args(parser)


def cmd_run(args) -> None:
    import shutil

    from mocapgraph.data_tools.io.files import reserve_output
    from mocapgraph.data_tools.io.result import MANIFEST
    from mocapgraph.pipelines.runner import run_capture, summary

    options = args.options_from(args)
    checkpoint = None
    if args.pipeline == "smartmocap":
        # Solved chunks are kept beside OUT until it is written: --resume reads them back. OUT is
        # reserved first, so that another run's chunks are never touched.
        reserve_output(args.out, args.overwrite, MANIFEST, inputs=[args.capture])
        checkpoint = args.out.parent / f".{args.out.name}.chunks"
        if not args.resume:
            shutil.rmtree(checkpoint, ignore_errors=True)
        options.checkpoint = str(checkpoint)
    result = run_capture(args.pipeline, args.capture, args.out, options, overwrite=args.overwrite)
    if checkpoint is not None:
        shutil.rmtree(checkpoint, ignore_errors=True)
    print(summary(args.pipeline, result))
    print(f"wrote {args.out}")


def _graph_flags(flags: OptionFlags, pose_priors: tuple[str, ...]) -> None:
    from mocapgraph.graphs.body_graph import FOCAL_MODES

    flags.add("graph.pose_prior", "learned pose prior on every state (docs/priors.md)", choices=pose_priors)
    flags.add("graph.gm_sigma_px", "Geman-McClure scale in pixels")
    flags.add("graph.swaps", "keep the detectors' left/right labels as detected (no swap check, no relabelling in the solve)")
    flags.add("graph.focal", "which cameras' focal lengths are variables: those whose intrinsics were guessed, all, or none", choices=FOCAL_MODES)
    flags.add("graph.focal_shared", "give every guessed camera its own focal length (default: cameras guessed alike, i.e. of the same image size, share one)")


def _uncalibrated_flags(flags: OptionFlags) -> None:
    from mocapgraph.graphs.body_graph import SHAPE_MODES
    from mocapgraph.graphs.initialisation import INITIALISERS

    flags.add(
        "initialiser", "body relative to each camera: PnP of the mean body, or the fusion regressor (PnP for a view where they disagree)",
        choices=INITIALISERS,
    )  # fmt: skip
    flags.add("graph.shape", "hold the initial body shape during the solve (the body's size is the only scale) or estimate it", choices=SHAPE_MODES)
    _graph_flags(flags, ("gmm", "none"))


def add_parsers(subparsers) -> None:
    from mocapgraph.graphs.body_graph import POSE_PRIORS
    from mocapgraph.graphs.sync import SYNC_POLICIES
    from mocapgraph.pipelines.aircap import CAMERA_MODES, MODES, AircapOptions
    from mocapgraph.pipelines.airpose import AirposeOptions
    from mocapgraph.pipelines.baseline import BaselineOptions
    from mocapgraph.pipelines.executors import EXECUTORS
    from mocapgraph.pipelines.reference_cameras import SOURCES as CAMERA_SOURCES
    from mocapgraph.pipelines.smartmocap import MOTION_PRIORS, OFFSET_PRIORS, STATIC_CAMERAS, SmartmocapOptions

    run = group(subparsers, "run", "run a pipeline on a capture", "pipeline")

    baseline = command(
        run, "baseline", "calibrated-camera triangulation (DLT + RANSAC), the reference; with --uncalibrated, static cameras "
        "self-calibrated from the keypoints (essential matrices, swap check, bundle adjustment)",
    )  # fmt: skip
    _capture_args(baseline)
    flags = OptionFlags(baseline, BaselineOptions())
    flags.add("detector", "detector name", unset="the first one every camera has")
    flags.add("threshold_px", "RANSAC inlier threshold in pixels (with --uncalibrated also of the essential matrices and PnP)")
    flags.add("seed", "seed of RANSAC's sampling")
    flags.add("uncalibrated", "estimate the static cameras' poses from the keypoints (the capture's intrinsics are used, its extrinsics not)")
    flags.add("self_calibration.height_m", "--uncalibrated: the person's standing height assumed for the metric scale, metres")
    flags.add("swap_check", "keep the detectors' left/right labels as they are (no swap check; calibrated: of the static cameras)")
    flags.add("self_calibration.gm_sigma_px", "--uncalibrated: Geman-McClure scale of the bundle adjustment in pixels")
    flags.add("self_calibration.min_confidence", "--uncalibrated: keypoints below this confidence are not used")

    aircap = command(run, "aircap", "UAV cameras with GPS/IMU: body and cameras from keypoints (AirCap)")
    _capture_args(aircap)
    flags = OptionFlags(aircap, AircapOptions())
    flags.add("mode", "joint sequence fit or per frame", choices=MODES)
    flags.add(
        "cameras", "refine: jointly, near the offline GPS/IMU fusion; prior: held at that fusion; fixed: held at the onboard online estimate",
        choices=CAMERA_MODES,
    )  # fmt: skip
    flags.add(
        "sync", "grid: states on a regular grid, each frame interpolated at its own time (the sequence's default); "
        "states: a state per frame time; closest: the thesis' closest-frame pairing (the per-frame default)", choices=SYNC_POLICIES,
        unset="per mode",
    )  # fmt: skip
    flags.add("grid_hz", "body states per second with --sync grid")
    flags.add("workers", "processes for the per-frame pass")
    flags.add("motion_prior", "SmartMocap's motion prior on 25-state windows of the sequence fit (docs/priors.md)", choices=("none", "vae"))
    flags.add("detectors", "comma-separated detector names", type=detector_list, unset="all")
    flags.add("covariances", "skip the marginal covariances")
    _graph_flags(flags, POSE_PRIORS)

    airpose = command(run, "airpose", "uncalibrated moving cameras: body and cameras relative to camera 1 (AirPose+)")
    _capture_args(airpose)
    flags = OptionFlags(airpose, AirposeOptions())
    _uncalibrated_flags(flags)
    flags.add("refine", "AirPose: the initialiser's estimate, no bundle adjustment", flag="--initialiser-only")
    flags.add("min_confidence", "summed keypoint confidence a frame needs")
    flags.add("detectors", "comma-separated detector names", type=detector_list, unset="all")
    flags.add("imu", "leave the moving cameras' gyroscopes unused (docs/phone-imu.md)")
    flags.add("covariances", "skip the marginal covariances")

    smartmocap = command(run, "smartmocap", "static and moving uncalibrated cameras in the ground plane's frame (SmartMocap)")
    _capture_args(smartmocap)
    flags = OptionFlags(smartmocap, SmartmocapOptions())
    _uncalibrated_flags(flags)
    flags.add("motion_prior", "SmartMocap's motion prior", choices=MOTION_PRIORS)
    flags.add("executor", "where chunks run: local processes or Ray", choices=EXECUTORS)
    flags.add("address", "Ray cluster address", unset="start a local Ray instance")
    flags.add("workers", "parallel chunks")
    flags.add("detectors", "comma-separated detector names", type=detector_list, unset="all")
    flags.add("keypoint_offsets", "no last pass with the detector's keypoint-definition offsets (nor its outlier views left out)")
    flags.add("offset_prior", "the offsets' prior: the table fitted on real footage where the format has one (fitted) or zero; docs/smartmocap.md", choices=OFFSET_PRIORS)
    flags.add("imu", "leave the moving cameras' IMU logs unused (docs/phone-imu.md)")
    flags.add("static_cameras", "three or more static cameras: adjusted last on free points (points) or left as the body's solve puts them (body); docs/smartmocap.md", choices=STATIC_CAMERAS)
    flags.add("covariances", "skip the marginal covariances")
    flags.add(
        "cameras_from", "moving cameras' tracks (their motion between registered frames) from the capture's reference reconstruction "
        "(`mocapgraph colmap`), scaled onto a first solution", choices=CAMERA_SOURCES,
    )  # fmt: skip
    flags.add("camera_reference", "with --cameras-from: the reference's name (its folder under CAPTURE/references/)", flag="--reference")
    smartmocap.add_argument("--resume", action="store_true", help="after a run that was stopped: keep the chunks it solved, solve the rest")

    for parser in (baseline, aircap, airpose, smartmocap):
        parser.set_defaults(func=cmd_run)

    from mocapgraph.pipelines.online import BOOTSTRAP_CAMERAS, BOOTSTRAP_MOTION_PRIORS, PRIOR_SOURCES, RIGS, UAV_BODY_SWAPS, OnlineOptions
    from mocapgraph.pipelines.online import CAMERA_MODES as ONLINE_CAMERAS

    online = command(
        run, "online", "replay a capture as a stream through the fixed-lag fusion; writes the smoothed trajectory at --out and "
        "the filtered one (each state as first estimated) at OUT/filtered",
    )  # fmt: skip
    _capture_args(online)
    flags = OptionFlags(online, OnlineOptions())
    flags.add("lag_s", "smoother window, seconds", flag="--lag")
    flags.add("rig", "which pipeline the rig mirrors", choices=RIGS, unset="aircap when a camera has a mount, else smartmocap")
    flags.add("bootstrap_s", "seconds buffered and solved in batch before the loop starts", flag="--bootstrap")
    flags.add("rate_hz", "body states per second")
    flags.add("cameras", "aircap: per-frame camera variables near the onboard estimate, or held at it", choices=ONLINE_CAMERAS)
    flags.add(
        "camera_priors", "aircap: the UAV cameras' priors: the vehicle's GPS/IMU fusion run incrementally (fused), its onboard estimate "
        "(self_pose), or the onboard estimate where logged, else the fusion (auto)", choices=PRIOR_SOURCES,
    )  # fmt: skip
    flags.add("detector", "detector name", unset="each camera's first")
    flags.add(
        "uav_body_swaps", "aircap: a UAV detection may relabel its whole body (its detector's front/back flip) while fewer of its "
        "update's UAV cameras see the body flipped than not, or alone in the update on its onboard estimate (minority), or never (none)", choices=UAV_BODY_SWAPS,
    )  # fmt: skip
    flags.add(
        "unmodelled_sigma_rad", "regulariser width on the joints the pose GMM leaves out (spine3, collars, feet), radians; "
        "rig: 0.2 on aircap, off on uncalibrated rigs; none: off", flag="--unmodelled-sigma", type=_number_or_word, metavar="RAD|rig|none",
    )  # fmt: skip
    flags.add(
        "pose_sigma_rad_s2", "joint rotations' constant-velocity prior, rad/s^2; rig: 20 on uncalibrated rigs, off on aircap; none: off",
        flag="--pose-sigma", type=_number_or_word, metavar="RAD_S2|rig|none",
    )  # fmt: skip
    flags.add("hips_sigma_rad_s2", "the hips' rotations in that prior, rad/s^2 (none: as the other joints)", flag="--hips-sigma", type=_number_or_word, metavar="RAD_S2|none")
    flags.add("coast_s", "seconds without detections before the track counts as lost (the prediction held, the gate opened)", flag="--coast")
    flags.add("gate_margin", "the gate's region of interest: the predicted body's box widened by this fraction of its height")
    flags.add("prior_timeout_s", "aircap: a UAV frame with no onboard-estimate sample this near its time is not used, seconds", flag="--prior-timeout")
    flags.add("bootstrap_motion_prior", "the motion prior in the bootstrap's batch solve", choices=BOOTSTRAP_MOTION_PRIORS)
    flags.add(
        "bootstrap_cameras", "aircap: the bootstrap's batch with the UAV cameras held at their priors (prior), checked by a second "
        "with them refined and their whole-body relabelling, taken where the two headings end more than 90 deg apart (check)", choices=BOOTSTRAP_CAMERAS,
    )  # fmt: skip
    flags.add("static_cameras", "uncalibrated rigs: static cameras refined in the window under a prior, or held at the bootstrap's estimate", choices=("refine", "hold"))
    flags.add("static_refine_s", "seconds a static camera is refined before it is held at its estimate (none: all along)", flag="--static-refine", type=_number_or_word, metavar="S|none")
    flags.add("shape", "body shape after the bootstrap: held, or refined in the window", choices=("hold", "refine"))
    online.add_argument("--realtime", action="store_true", help="replay at the capture's own rate")
    online.set_defaults(func=cmd_run_online)


def _number_or_word(text: str):
    """A flag's value: a number, ``none`` (None), or another word left for the options' check to
    accept (``rig``) or refuse with its own message."""
    if text.lower() == "none":
        return None
    try:
        return float(text)
    except ValueError:
        return text


def cmd_run_online(args) -> None:
    from mocapgraph.data_tools.io.capture import load_capture
    from mocapgraph.data_tools.io.files import reserve_output
    from mocapgraph.data_tools.io.result import MANIFEST, write_result
    from mocapgraph.pipelines.online import run_online, summary
    from mocapgraph.progress import LiveLine

    options = args.options_from(args)
    options.check()  # before OUT is reserved: a bad flag is the options' one clear error
    reserve_output(args.out, args.overwrite, MANIFEST, inputs=[args.capture])
    capture = load_capture(args.capture)
    status = LiveLine()

    def live(fusion, state) -> None:
        if not status.due() or not fusion.stats.latencies:
            return
        s = fusion.stats.summary()
        lat = s["latency_ms"]
        status.show(f"t {state.time:7.2f} s  {s['updates_per_s']:6.1f} updates/s  latency p50 {lat['p50']:5.1f} ms p95 {lat['p95']:5.1f} ms  dropped {fusion.stats.dropped}")

    run = run_online(capture, options, capture_label=str(args.capture), realtime=args.realtime, on_update=live)
    status.close()
    write_result(run.smoothed, args.out, overwrite=args.overwrite)
    write_result(run.filtered, args.out / "filtered", overwrite=True)
    print(summary(run))
    print(f"wrote {args.out} (smoothed) and {args.out / 'filtered'} (filtered)")
