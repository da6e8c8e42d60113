"""The ``mocapgraph`` command: one entry point, a subcommand per job, ``--help`` on each."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

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
    from mocapgraph.benchmarks.body import bench_body

    result = bench_body(_body(args), frames=args.frames, min_seconds=args.seconds)
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:22s} {value}")


def cmd_run_baseline(args) -> None:
    from mocapgraph.pipelines.baseline import run_baseline

    run_baseline(args.capture, args.out, args.detector, args.threshold_px, args.seed, args.overwrite)
    print(f"wrote {args.out}")


def cmd_run_aircap(args) -> None:
    from mocapgraph.pipelines.aircap import AircapOptions, run_aircap_command

    options = AircapOptions(
        mode=args.mode, cameras=args.cameras, sync=args.sync, grid_hz=args.grid_hz, gm_sigma_px=args.gm_sigma_px, workers=args.workers,
        detectors=tuple(args.detectors.split(",")) if args.detectors else None,
        covariances=not args.no_covariances, progress=not args.quiet, pose_prior=args.pose_prior,
        motion_prior=args.motion_prior,
    )  # fmt: skip
    run_aircap_command(args.capture, args.out, options, overwrite=args.overwrite)
    print(f"wrote {args.out}")


def _graph_options(args):
    from mocapgraph.pipelines.uncalibrated import GraphOptions

    return GraphOptions(gm_sigma_px=args.gm_sigma_px, shape=args.shape, pose_prior=args.pose_prior)


def cmd_run_airpose(args) -> None:
    from mocapgraph.pipelines.airpose import AirposeOptions, run_airpose_command

    options = AirposeOptions(
        initialiser=args.initialiser, refine=not args.initialiser_only, min_confidence=args.min_confidence,
        detectors=tuple(args.detectors.split(",")) if args.detectors else None,
        covariances=not args.no_covariances, progress=not args.quiet, graph=_graph_options(args),
    )  # fmt: skip
    run_airpose_command(args.capture, args.out, options, overwrite=args.overwrite)
    print(f"wrote {args.out}")


def cmd_run_smartmocap(args) -> None:
    from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap_command

    options = SmartmocapOptions(
        initialiser=args.initialiser, motion_prior=args.motion_prior, executor=args.executor, workers=args.workers,
        address=args.address, detectors=tuple(args.detectors.split(",")) if args.detectors else None,
        covariances=not args.no_covariances, progress=not args.quiet, graph=_graph_options(args),
    )  # fmt: skip
    run_smartmocap_command(args.capture, args.out, options, overwrite=args.overwrite)
    print(f"wrote {args.out}")


def _add_uncalibrated_args(parser: argparse.ArgumentParser, shape: str) -> None:
    parser.add_argument("capture", type=Path, help="capture directory")
    parser.add_argument("--out", type=Path, required=True, help="result directory to write")
    parser.add_argument(
        "--initialiser", choices=("pnp", "regressor"), default="pnp",
        help="body relative to each camera: PnP of the mean body (default), or the fusion regressor (PnP for a view where they disagree)",
    )  # fmt: skip
    parser.add_argument(
        "--shape", choices=("hold", "estimate"), default=shape,
        help=f"hold the initial body shape during the solve (the body's size is the only scale) or estimate it (default {shape})",
    )  # fmt: skip
    parser.add_argument("--pose-prior", choices=("gmm", "none"), default="gmm", help="learned pose prior on every state (default gmm)")
    parser.add_argument("--detectors", help="comma-separated detector names (default: all)")
    parser.add_argument("--gm-sigma-px", type=float, default=40.0, help="Geman-McClure scale in pixels (default 40)")
    parser.add_argument("--no-covariances", action="store_true", help="skip the marginal covariances")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing result")


def cmd_eval(args) -> None:
    from mocapgraph.data_tools.io.capture import load_capture
    from mocapgraph.data_tools.evaluation.evaluate import evaluate
    from mocapgraph.data_tools.io.result import load_result

    result = load_result(args.result)
    capture_path = args.capture or Path(result.capture)
    evaluation = evaluate(result, load_capture(capture_path))
    if args.json:
        print(json.dumps({"pipeline": result.pipeline, "alignment": evaluation.alignment, **evaluation.metrics}))
        return
    print(f"{result.pipeline} on {capture_path}: {evaluation.frames_compared} frames compared "
          f"({evaluation.frames_without_truth} without ground truth)")
    print(f"alignment: {evaluation.alignment}")
    for key, value in evaluation.metrics.items():
        print(f"  {key:28s} {value:.4f}")


def cmd_synth(args) -> None:
    from mocapgraph.data_tools.io.capture import write_capture
    from mocapgraph.data_tools.sim.synthetic import synthesize

    detectors = tuple(args.detectors.split(",")) if args.detectors else None
    capture = synthesize(args.preset, seed=args.seed, duration_s=args.duration, motion=args.motion, detectors=detectors)
    path = write_capture(capture, args.out, overwrite=args.overwrite)
    frames = sum(cam.num_frames for cam in capture.cameras)
    print(f"synthesised {capture.name}: {len(capture.cameras)} cameras, {frames} frames, motion: {capture.metadata['motion']}")
    print(f"wrote {path}")


def cmd_capture_info(args) -> None:
    from mocapgraph.data_tools.io.capture import load_capture

    capture = load_capture(args.capture)
    print(f"capture {capture.name}: {len(capture.cameras)} cameras, world frame: {capture.world_frame}")
    for cam in capture.cameras:
        span = cam.timestamps[-1] - cam.timestamps[0]
        dets = ", ".join(
            f"{d.name} ({d.format}, {np.isfinite(d.keypoints[..., 0]).mean():.0%} points)" for d in cam.detectors.values()
        )
        print(
            f"  {cam.name:10s} {'moving' if cam.moving else 'static':6s} {cam.num_frames:5d} frames over {span:.1f} s "
            f"at {cam.frame_rate:g} fps; {cam.image_size[0]}x{cam.image_size[1]}; "
            f"calibrated: {'yes' if cam.extrinsics is not None else 'no'}; sensors: {', '.join(cam.sensors) or 'none'}"
        )
        print(f"  {'':10s} detectors: {dets or 'none'}")
    gt = capture.ground_truth
    print(f"ground truth: {'none' if gt is None else f'{len(gt.timestamps)} body states ({gt.body_model}), cameras: {len(gt.cameras)}'}")
    if capture.notes:
        print("repaired while loading:")
        for note in capture.notes:
            print(f"  {note}")


def cmd_bench_aircap(args) -> None:
    from mocapgraph.benchmarks.aircap import bench_aircap

    print(json.dumps(bench_aircap(duration_s=args.duration, seed=args.seed)))


def cmd_bench_smartmocap(args) -> None:
    from mocapgraph.benchmarks.smartmocap import bench_smartmocap

    print(json.dumps(bench_smartmocap(duration_s=args.duration, seed=args.seed, workers=args.workers)))


def cmd_bench_airpose(args) -> None:
    from mocapgraph.benchmarks.airpose import bench_airpose

    print(json.dumps(bench_airpose(duration_s=args.duration, seed=args.seed)))


def cmd_bench_priors(args) -> None:
    from mocapgraph.benchmarks.priors import bench_priors

    print(json.dumps(bench_priors(args.motion, duration_s=args.duration, seed=args.seed, noise_scale=args.noise_scale)))


def cmd_demo(args) -> None:
    from mocapgraph.cli.demo import run_demo

    path = run_demo(args.out, args.motion_dir, duration_s=args.duration, phones_duration_s=args.phones_duration)
    print(f"wrote {path.resolve()}")


def _progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def cmd_priors_train_pose(args) -> None:
    from mocapgraph.data_tools.sim.cmu_motion import motion_dir

    directory = args.motion or motion_dir()
    if args.model == "gmm":
        from mocapgraph.priors.training import train_pose_prior

        gmm = train_pose_prior(directory, _body(args), components=args.components, seed=args.seed, progress=_progress)
        path = gmm.save(args.out)
        info = gmm.info
        print(f"held-out subjects {', '.join(map(str, info['val_subjects']))}: {info['val_poses']} poses")
        print(f"  mean log-likelihood       {info['val_mean_log_likelihood']:.2f} nats (training poses: {info['train_mean_log_likelihood']:.2f})")
        print(f"  nearest-mean geodesic     {info['val_nearest_mean_geodesic_rad']:.3f} rad per joint")
        print(f"  time                      {info['load_seconds']:.1f} s loading, {info['fit_seconds']:.1f} s EM")
    else:
        from mocapgraph.priors.pose_vae import train_pose_vae

        vae = train_pose_vae(directory, _body(args), latent=args.latent, width=args.width, epochs=args.epochs, seed=args.seed, progress=_progress)
        path = vae.save(args.out, float16=True)
        info = vae.info
        print(f"held-out subjects {', '.join(map(str, info['val_subjects']))}: {info['val_poses']} poses")
        print(f"  reconstruction geodesic   {info['val_geodesic_err_rad']:.3f} rad per modelled joint")
        print(f"  ELBO                      {info['val_elbo']:.2f} nats per pose")
        print(f"  time                      {info['load_seconds']:.1f} s loading, {info['fit_seconds']:.1f} s training")
    print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KB)")


def cmd_priors_train_motion(args) -> None:
    from mocapgraph.data_tools.sim.cmu_motion import motion_dir
    from mocapgraph.priors.motion_vae import train_motion_vae

    vae = train_motion_vae(
        args.motion or motion_dir(), _body(args), width=args.width, latent=args.latent, epochs=args.epochs,
        seed=args.seed, stride=args.stride, progress=_progress,
    )  # fmt: skip
    path = vae.save(args.out)
    info = vae.info
    print(f"held-out subjects {', '.join(map(str, info['val_subjects']))}: {info['val_windows']} windows")
    print(f"  position error            {1000 * info['val_mpjpe_m']:.1f} mm per joint (decode(encode(window)))")
    print(f"  model                     width {info['width']}, latent {info['latent']}, {info['parameters']} parameters")
    print(f"  time                      {info['load_seconds']:.1f} s loading, {info['fit_seconds']:.1f} s training")
    print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KB)")


def build_parser() -> argparse.ArgumentParser:
    from mocapgraph.cli.capture import add_detect_parser, add_import_parser

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
    bench_aircap = bench.add_parser("aircap", help="the AirCap variants on a synthetic capture, one run, one JSON object")
    bench_aircap.add_argument("--duration", type=float, default=60.0, help="seconds of capture (default 60)")
    bench_aircap.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    bench_aircap.add_argument("--json", action="store_true", help="print one JSON object (always on)")
    bench_aircap.set_defaults(func=cmd_bench_aircap)
    bench_smartmocap = bench.add_parser("smartmocap", help="SmartMocap on a rich capture: camera configurations, with and without the motion prior")
    bench_smartmocap.add_argument("--duration", type=float, default=10.0, help="seconds of capture (default 10)")
    bench_smartmocap.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    bench_smartmocap.add_argument("--workers", type=int, default=2, help="parallel chunks (default 2)")
    bench_smartmocap.add_argument("--json", action="store_true", help="print one JSON object (always on)")
    bench_smartmocap.set_defaults(func=cmd_bench_smartmocap)
    bench_airpose = bench.add_parser("airpose", help="AirPose vs AirPose+ on an airpose capture, for every initialiser (regressor ablation, PnP)")
    bench_airpose.add_argument("--duration", type=float, default=10.0, help="seconds of capture (default 10)")
    bench_airpose.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    bench_airpose.add_argument("--json", action="store_true", help="print one JSON object (always on)")
    bench_airpose.set_defaults(func=cmd_bench_airpose)
    bench_priors = bench.add_parser("priors", help="the shipped learned priors on held-out CMU subjects and on aircap, one JSON object")
    bench_priors.add_argument("--motion", type=Path, metavar="DIR", help="CMU motion directory (default ../shared/motion/cmu_train)")
    bench_priors.add_argument("--duration", type=float, default=10.0, help="seconds of the aircap capture (default 10)")
    bench_priors.add_argument("--seed", type=int, default=0, help="aircap scenario seed (default 0)")
    bench_priors.add_argument("--noise-scale", type=float, default=3.0, help="keypoint noise multiplier of the aircap capture (default 3)")
    bench_priors.add_argument("--json", action="store_true", help="print one JSON object (always on)")
    bench_priors.set_defaults(func=cmd_bench_priors)

    capture = sub.add_parser("capture", help="inspect, import and assemble captures").add_subparsers(
        dest="capture_command", required=True, metavar="SUBCOMMAND"
    )
    info_capture = capture.add_parser("info", help="cameras, detectors, sensors and ground truth of a capture")
    info_capture.add_argument("capture", type=Path, help="capture directory")
    info_capture.set_defaults(func=cmd_capture_info)
    add_import_parser(capture)

    synth = sub.add_parser("synth", help="synthesise a capture with ground truth from a scenario preset")
    synth.add_argument("preset", choices=("aircap", "airpose", "rich", "phones"), help="scenario (docs/scenarios.md)")
    synth.add_argument("--out", type=Path, required=True, help="capture directory to write")
    synth.add_argument("--seed", type=int, default=0, help="seed of everything random (default 0)")
    synth.add_argument("--duration", type=float, default=10.0, help="seconds (default 10)")
    synth.add_argument(
        "--motion", help="walk, turn, arms, zigzag_then_act, stand, or a CMU take (cmu:cmu_02_01.npz); default per preset"
    )
    synth.add_argument("--detectors", help="comma-separated detector presets (default per preset)")
    synth.add_argument("--overwrite", action="store_true", help="replace an existing capture")
    synth.set_defaults(func=cmd_synth)

    run = sub.add_parser("run", help="run a pipeline on a capture").add_subparsers(
        dest="pipeline", required=True, metavar="PIPELINE"
    )
    baseline = run.add_parser("baseline", help="calibrated-camera triangulation (DLT + RANSAC), the reference")
    baseline.add_argument("capture", type=Path, help="capture directory (all cameras calibrated)")
    baseline.add_argument("--out", type=Path, required=True, help="result directory to write")
    baseline.add_argument("--detector", help="detector name (default: the first one every camera has)")
    baseline.add_argument("--threshold-px", type=float, default=15.0, help="RANSAC inlier threshold (default 15 px)")
    baseline.add_argument("--seed", type=int, default=0, help="seed for RANSAC's pair sampling")
    baseline.add_argument("--overwrite", action="store_true", help="replace an existing result")
    baseline.set_defaults(func=cmd_run_baseline)

    aircap = run.add_parser("aircap", help="UAV cameras with GPS/IMU: body and cameras from keypoints (AirCap)")
    aircap.add_argument("capture", type=Path, help="capture directory")
    aircap.add_argument("--out", type=Path, required=True, help="result directory to write")
    aircap.add_argument("--mode", choices=("sequence", "per-frame"), default="sequence", help="joint sequence fit (default) or per frame")
    aircap.add_argument(
        "--cameras", choices=("refine", "prior", "fixed"), default="refine",
        help="refine: jointly, near the offline GPS/IMU fusion (default); prior: held at that fusion; fixed: held at the onboard online estimate",
    )  # fmt: skip
    aircap.add_argument(
        "--sync", choices=("grid", "states", "closest"),
        help="grid: states on a regular grid, each frame interpolated at its own time (sequence default); "
        "states: a state per frame time; closest: the thesis' closest-frame pairing (per-frame default)",
    )  # fmt: skip
    aircap.add_argument("--grid-hz", type=float, default=30.0, help="body states per second with --sync grid (default 30)")
    aircap.add_argument("--workers", type=int, default=2, help="processes for the per-frame pass (default 2)")
    aircap.add_argument(
        "--pose-prior", choices=("none", "gmm", "vae"), default="none",
        help="learned pose prior on every state (docs/priors.md); default none",
    )  # fmt: skip
    aircap.add_argument(
        "--motion-prior", choices=("none", "vae"), default="none",
        help="SmartMocap's motion prior on 25-state windows of the sequence fit (docs/priors.md); default none",
    )  # fmt: skip
    aircap.add_argument("--detectors", help="comma-separated detector names (default: all)")
    aircap.add_argument("--gm-sigma-px", type=float, default=40.0, help="Geman-McClure scale in pixels (default 40)")
    aircap.add_argument("--no-covariances", action="store_true", help="skip the marginal covariances")
    aircap.add_argument("--quiet", action="store_true", help="no progress on stderr")
    aircap.add_argument("--overwrite", action="store_true", help="replace an existing result")
    aircap.set_defaults(func=cmd_run_aircap)
    airpose = run.add_parser("airpose", help="uncalibrated moving cameras: body and cameras relative to camera 1 (AirPose+)")
    _add_uncalibrated_args(airpose, shape="hold")
    airpose.add_argument("--initialiser-only", action="store_true", help="AirPose: the initialiser's estimate, no bundle adjustment")
    airpose.add_argument("--min-confidence", type=float, default=3.0, help="summed keypoint confidence a frame needs (default 3)")
    airpose.set_defaults(func=cmd_run_airpose)
    smartmocap = run.add_parser("smartmocap", help="static and moving uncalibrated cameras in the ground plane's frame (SmartMocap)")
    _add_uncalibrated_args(smartmocap, shape="estimate")
    smartmocap.add_argument("--motion-prior", choices=("vae", "none"), default="vae", help="SmartMocap's motion prior (default vae)")
    smartmocap.add_argument("--executor", choices=("local", "ray"), default="local", help="where chunks run: local processes (default) or Ray")
    smartmocap.add_argument("--address", help="Ray cluster address (default: start a local Ray instance)")
    smartmocap.add_argument("--workers", type=int, default=2, help="parallel chunks (default 2)")
    smartmocap.set_defaults(func=cmd_run_smartmocap)

    evaluate = sub.add_parser("eval", help="score a result against its capture's ground truth")
    evaluate.add_argument("result", type=Path, help="result directory")
    evaluate.add_argument("--capture", type=Path, help="capture directory (default: the one the result names)")
    evaluate.add_argument("--json", action="store_true", help="print one JSON object")
    evaluate.set_defaults(func=cmd_eval)

    add_detect_parser(sub)

    from mocapgraph.pipelines.batch import add_batch_parser

    add_batch_parser(sub)

    priors = sub.add_parser("priors", help="learned priors: training").add_subparsers(
        dest="priors_command", required=True, metavar="SUBCOMMAND"
    )
    train = priors.add_parser("train", help="train a prior on CMU motion").add_subparsers(
        dest="prior", required=True, metavar="PRIOR"
    )
    train_pose = train.add_parser("pose", help="pose prior: Gaussian mixture or VAE (docs/priors.md)")
    train_pose.add_argument("--model", choices=("gmm", "vae"), default="gmm", help="which pose prior (default gmm)")
    train_pose.add_argument("--motion", type=Path, metavar="DIR", help="CMU motion directory (default ../shared/motion/cmu_train)")
    train_pose.add_argument("--out", type=Path, required=True, metavar="FILE", help=".npz file to write")
    train_pose.add_argument("--components", type=int, default=8, help="gmm: mixture components (default 8)")
    train_pose.add_argument("--latent", type=int, default=32, help="vae: latent size (default 32)")
    train_pose.add_argument("--width", type=int, default=512, help="vae: hidden width (default 512)")
    train_pose.add_argument("--epochs", type=int, default=40, help="vae: training epochs (default 40)")
    train_pose.add_argument("--seed", type=int, default=0, help="seed of the initialisation and the subject split (default 0)")
    _add_body_args(train_pose)
    train_pose.set_defaults(func=cmd_priors_train_pose)
    train_motion = train.add_parser("motion", help="SmartMocap motion VAE over 25-frame windows (docs/priors.md)")
    train_motion.add_argument("--motion", type=Path, metavar="DIR", help="CMU motion directory (default ../shared/motion/cmu_train)")
    train_motion.add_argument("--out", type=Path, required=True, metavar="FILE", help=".npz file to write")
    train_motion.add_argument("--width", type=int, default=128, help="convolution channels (default 128)")
    train_motion.add_argument("--latent", type=int, default=64, help="latent size (default 64)")
    train_motion.add_argument("--epochs", type=int, default=40, help="training epochs, two 20-epoch KL cycles (default 40)")
    train_motion.add_argument("--stride", type=int, default=5, help="frames between training windows (default 5)")
    train_motion.add_argument("--seed", type=int, default=0, help="seed of the weights, the batches and the subject split (default 0)")
    _add_body_args(train_motion)
    train_motion.set_defaults(func=cmd_priors_train_motion)

    def cmd_priors_train_fusion(args) -> None:
        from mocapgraph.data_tools.sim.cmu_motion import motion_dir
        from mocapgraph.priors.fusion_training import train_fusion_regressor

        regressor = train_fusion_regressor(
            args.motion or motion_dir(), _body(args), variant=args.variant, epochs=args.epochs, samples=args.samples,
            seed=args.seed, progress=_progress,
        )  # fmt: skip
        path = regressor.save(args.out)
        info, val = regressor.info, regressor.info["val"]
        print(f"held-out subjects {', '.join(map(str, info['val_subjects']))}: {val['frames']} bodies, 2 views each")
        print(f"  root-relative MPJPE       {1000 * val['mpjpe_m']:.0f} mm (camera frame)")
        print(f"  root position             {val['root_position_m']:.2f} m (depth {val['root_depth_m']:.2f} m, rotation {val['root_rotation_deg']:.1f}°)")
        print(f"  camera 2 in camera 1      {val['relative_camera_m']:.2f} m, {val['relative_camera_deg']:.1f}°")
        print(f"  time                      {info['load_seconds']:.1f} s loading, {info['fit_seconds']:.1f} s training")
        print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KB)")

    train_fusion = train.add_parser("fusion", help="multi-view fusion regressor: body and camera-relative root from 2D keypoints (docs/fusion-regressor.md)")
    train_fusion.add_argument("--motion", type=Path, metavar="DIR", help="CMU motion directory (default ../shared/motion/cmu_train)")
    train_fusion.add_argument("--out", type=Path, required=True, metavar="FILE", help=".npz file to write")
    train_fusion.add_argument("--variant", choices=("full", "no_exchange", "no_crop"), default="full", help="ablation variant (default full)")
    train_fusion.add_argument("--epochs", type=int, default=28, help="training epochs (default 28)")
    train_fusion.add_argument("--samples", type=int, default=32768, help="synthetic samples per epoch, fresh cameras each (default 32768)")
    train_fusion.add_argument("--seed", type=int, default=0, help="seed of the weights, the synthetic views and the subject split (default 0)")
    _add_body_args(train_fusion)
    train_fusion.set_defaults(func=cmd_priors_train_fusion)

    demo = sub.add_parser("demo", help="AirCap and SmartMocap on embedded synthetic captures, reports, and the body model drawn")
    demo.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory (default out/demo)")
    demo.add_argument("--motion-dir", type=Path, help="CMU motion directory (default ../shared/motion/cmu_train)")
    demo.add_argument("--duration", type=float, default=8.0, help="seconds of the synthetic aircap capture (default 8)")
    demo.add_argument("--phones-duration", type=float, default=6.0, help="seconds of the uncalibrated phones capture (default 6)")
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
