"""``make demo`` / ``mocapgraph demo``: the main job end to end on an embedded synthetic capture.

It synthesises a short ``aircap`` capture (three UAVs with GPS/IMU following a walking person),
runs the AirCap pipeline in its three variants (sequence with cameras refined, per-frame, and
cameras held at the GPS/IMU fusion), evaluates them against the ground truth and writes a report
(metrics table, root trajectory per axis, error per frame over detections). A second capture,
``phones`` (two phones on tripods and two carried by walking people, none calibrated), goes
through SmartMocap with and without its motion prior, into a report whose 3D plot shows the
estimated and true camera trajectories after alignment. It also draws the default body in a few
poses (CMU takes when the motion directory is present, built-in otherwise).
"""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path

import numpy as np

from mocapgraph.body import load_body_model
from mocapgraph.body.model import BodyModel
from mocapgraph.body.skeleton import JOINT_NAMES, PARENTS
from mocapgraph.cli.common import command, function_flags
from mocapgraph.progress import log_level

# (take file, frame) pairs chosen for variety: walking, running, waving, dancing.
CMU_POSES = (("cmu_02_01.npz", 40), ("cmu_09_01.npz", 20), ("cmu_13_26.npz", 150), ("cmu_05_09.npz", 120))


def builtin_poses() -> tuple[list[str], np.ndarray, np.ndarray]:
    """A T-pose, a stride, a wave and a squat: names, ``root (4, 4, 4)``, ``pose (4, 21, 3)``."""
    j = JOINT_NAMES.index
    poses = np.zeros((4, 21, 3))
    # Local rotations are about the body's axes: +X left, +Y up, +Z forward.
    poses[1, j("left_hip") - 1] = [-0.5, 0, 0]
    poses[1, j("right_hip") - 1] = [0.4, 0, 0]
    poses[1, j("right_knee") - 1] = [0.6, 0, 0]
    poses[1, j("left_shoulder") - 1] = [0, 0, -1.2]
    poses[1, j("right_shoulder") - 1] = [0, 0, 1.2]
    poses[2, j("right_shoulder") - 1] = [0, 0, -0.9]
    poses[2, j("right_elbow") - 1] = [0, 0, -1.2]
    poses[2, j("left_shoulder") - 1] = [0, 0, -1.3]
    for side in ("left", "right"):
        poses[3, j(f"{side}_hip") - 1] = [-1.3, 0, 0]
        poses[3, j(f"{side}_knee") - 1] = [2.0, 0, 0]
        poses[3, j(f"{side}_ankle") - 1] = [-0.6, 0, 0]
    poses[3, j("left_shoulder") - 1] = [0, -1.4, 0]  # both arms reach forward
    poses[3, j("right_shoulder") - 1] = [0, 1.4, 0]
    root = np.tile(np.eye(4), (4, 1, 1))
    root[:, :3, :3] = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])  # body Y-up into world Z-up
    root[:, 2, 3] = [0.95, 0.9, 0.95, 0.55]
    return ["T-pose", "stride", "wave", "squat"], root, poses


def cmu_poses(body: BodyModel, motion_dir: Path) -> tuple[list[str], np.ndarray, np.ndarray] | None:
    """The frames of :data:`CMU_POSES` that exist under ``motion_dir``, or None if none do."""
    from mocapgraph.data_tools.sim.cmu_motion import load_cmu_take, retarget

    names, roots, poses = [], [], []
    for file, frame in CMU_POSES:
        path = motion_dir / file
        if not path.exists():
            continue
        take = load_cmu_take(path)
        root, pose = retarget(take, body)
        frame = min(frame, len(pose) - 1)
        names.append(f"{path.stem} frame {frame}")
        roots.append(root[frame])
        poses.append(pose[frame])
    if not names:
        return None
    return names, np.stack(roots), np.stack(poses)


def face_the_viewer(root: np.ndarray) -> np.ndarray:
    """Turn each ``world_T_root (T, 4, 4)`` about world Z so the body faces −Y, over the origin."""
    from mocapgraph.body.rotations import axis_rotation

    out = root.copy()
    for t, pose in enumerate(root):
        forward = pose[:3, :3] @ [0.0, 0.0, 1.0]  # the body's +Z in the world
        yaw = np.arctan2(forward[1], forward[0])
        out[t, :3, :3] = axis_rotation("z", -np.pi / 2 - yaw) @ pose[:3, :3]
        out[t, :2, 3] = 0.0
    return out


def draw(body: BodyModel, names: list[str], root: np.ndarray, pose: np.ndarray, out: Path) -> Path:
    """PNG of each pose's skeleton and keypoints: front (world X–Z, the body faces −Y) and side (Y–Z)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = body.forward(body.default_shape, root, pose)
    n = len(names)
    fig, axes = plt.subplots(2, n, figsize=(3.2 * n, 6.4), squeeze=False)
    views = (("front", 0, 2), ("side", 1, 2))
    for col, name in enumerate(names):
        for row, (view, u, v) in enumerate(views):
            ax = axes[row, col]
            joints, kps = res.joints[col], res.keypoints[col]
            for c, p in enumerate(PARENTS):
                if p >= 0:
                    ax.plot(joints[[p, c], u], joints[[p, c], v], "-", color="0.3", lw=2)
            ax.plot(joints[:, u], joints[:, v], "o", color="tab:blue", ms=4, label="joints (22)")
            ax.plot(kps[:, u], kps[:, v], "x", color="tab:red", ms=5, label="keypoints (23)")
            ax.set_aspect("equal")
            ax.set_xlim(joints[:, u].mean() - 1.0, joints[:, u].mean() + 1.0)
            ax.set_ylim(-0.05, 2.0)
            ax.set_title(f"{name}\n{view}", fontsize=9)
            ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper left", fontsize=7)
    fig.suptitle(f"mocapgraph body model: {body.name}", fontsize=11)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    tmp.replace(out)
    return out


def run_aircap_demo(out_dir: Path, duration_s: float = 8.0, seed: int = 0) -> Path:
    """Synthesise an ``aircap`` capture, run the pipeline's variants, evaluate, write the report."""
    from mocapgraph.data_tools.evaluation.evaluate import evaluate
    from mocapgraph.data_tools.evaluation.report import write_report
    from mocapgraph.data_tools.io.capture import write_capture
    from mocapgraph.data_tools.io.result import write_result
    from mocapgraph.data_tools.sim.synthetic import synthesize
    from mocapgraph.pipelines.aircap import AircapOptions, run_aircap

    capture = synthesize("aircap", seed=seed, duration_s=duration_s)
    write_capture(capture, out_dir / "capture", overwrite=True)
    print(f"synthesised {capture.name}: {len(capture.cameras)} UAVs, {duration_s:g} s, motion {capture.metadata['motion']}")
    variants = {
        "sequence, cameras refined": AircapOptions(mode="sequence", cameras="refine"),
        "per-frame, cameras refined": AircapOptions(mode="per-frame", cameras="refine", covariances=False),
        "sequence, cameras at GPS/IMU": AircapOptions(mode="sequence", cameras="prior", covariances=False),
    }
    results, evaluations, paths = {}, {}, {}
    for label, options in variants.items():
        result = run_aircap(capture, options, capture_label=str(out_dir / "capture"))
        paths[label] = write_result(result, out_dir / ("result_" + label.split(",")[0].replace("-", "_") + "_" + options.cameras), overwrite=True)
        results[label], evaluations[label] = result, evaluate(result, capture)
        m = evaluations[label].metrics
        print(f"  {label:30s} MPJPE {100 * m['mpjpe_m']:5.1f} cm  RA-MPJPE {100 * m['ra_mpjpe_m']:4.1f} cm  "
              f"camera error {100 * m.get('mcpe_m', float('nan')):5.1f} cm  ({result.parameters['seconds']:.1f} s)")
    label = next(iter(results))
    look = write_look_files(out_dir, paths[label], results[label], capture)
    return write_report(out_dir, "mocapgraph demo: AirCap on a synthetic capture", capture, results, evaluations, extra=look)


def write_look_files(out_dir: Path, result_dir: Path, result, capture) -> str:
    """One BVH and one glTF of ``result`` (in ``out_dir/exports``), its mesh from the front and the
    side (a still and a short GIF), and an overlay still per camera (its middle frame, on a plain background with the
    detections, cropped to the person); the report's HTML about them and the commands that show
    the result in the viewer and over a camera."""
    import cv2
    from PIL import Image

    from mocapgraph.data_tools.evaluation.overlay import BACKGROUND_GREY, mesh_views, overlay_frame, overlay_scene
    from mocapgraph.data_tools.evaluation.report import look_section
    from mocapgraph.data_tools.io.exporters import export_result
    from mocapgraph.data_tools.io.files import write_file_atomically

    body = load_body_model(result.body_model)
    files = {
        "BVH (Blender: File > Import > Motion Capture, default settings)": export_result(result, "bvh", out_dir / "exports" / "aircap.bvh", body=body, overwrite=True),
        "glTF binary: skinned mesh and the UAV cameras (Blender: File > Import > glTF 2.0; any glTF viewer)":
            export_result(result, "gltf", out_dir / "exports" / "aircap.glb", body=body, capture=capture, overwrite=True),
    }  # fmt: skip
    mesh = body.mesh(result.shape)

    def views(t: int, size: tuple[int, int]) -> np.ndarray:
        vertices = mesh.vertices(mesh.bone_poses(body.forward(result.shape, result.root[t : t + 1], result.pose[t : t + 1])))[0]
        return mesh_views(vertices, mesh.faces, result.joints[t], result.root[t, :3, :3] @ [0.0, 0.0, 1.0], size)

    middle = len(result.timestamps) // 2
    png = cv2.imencode(".png", views(middle, (360, 480)))[1].tobytes()
    stills = {f"the fitted mesh at {result.timestamps[middle]:.1f} s, front and left side": write_file_atomically(out_dir / "overlays" / "mesh.png", True, lambda tmp: tmp.write_bytes(png))}
    # A short animation: up to 2 s from the middle state at 10 frames per second.
    step = max(1, int(round(0.1 / np.median(np.diff(result.timestamps))))) if len(result.timestamps) > 1 else 1
    frames = [Image.fromarray(cv2.cvtColor(views(t, (180, 240)), cv2.COLOR_BGR2RGB)) for t in range(middle, min(len(result.timestamps), middle + 20 * step), step)]
    gif = write_file_atomically(
        out_dir / "overlays" / "mesh.gif", True,
        lambda tmp: frames[0].save(tmp, format="GIF", save_all=True, append_images=frames[1:], duration=100, loop=0),
    )  # fmt: skip
    stills[f"the fitted mesh from {result.timestamps[middle]:.1f} s, {len(frames)} states at 10 per second"] = gif
    for camera in capture.cameras:
        if camera.name not in result.cameras:
            continue
        scene = overlay_scene(result, camera, body)
        frames = np.flatnonzero(scene.state >= 0)
        frame = int(frames[len(frames) // 2])
        width, height = camera.image_size
        image = overlay_frame(np.full((height, width, 3), BACKGROUND_GREY, np.uint8), scene, frame, camera)
        rows, cols = np.nonzero(np.any(image != BACKGROUND_GREY, axis=2))
        if len(rows):  # the person is small in a UAV's view: crop to what was drawn, with a margin
            margin = max(40, (rows.max() - rows.min()) // 2)
            image = image[max(rows.min() - margin, 0) : rows.max() + margin, max(cols.min() - margin, 0) : cols.max() + margin]
        png = cv2.imencode(".png", image)[1].tobytes()
        stills[f"{camera.name}, frame {frame}"] = write_file_atomically(out_dir / "overlays" / f"{camera.name}.png", True, lambda tmp: tmp.write_bytes(png))
    first = next(iter(result.cameras))
    commands = [f"mocapgraph view {result_dir}", f"mocapgraph overlay {result_dir} --camera {first} --out {out_dir / 'overlay.mp4'}"]
    print(f"wrote {', '.join(str(p) for p in files.values())}")
    print(f"look at it: {commands[0]}")
    return look_section(out_dir, files, stills, commands)


def run_smartmocap_demo(out_dir: Path, duration_s: float = 6.0, seed: int = 0) -> Path:
    """Synthesise an uncalibrated ``phones`` capture, run SmartMocap with and without the motion
    prior, evaluate, and write the report with the camera trajectories."""
    from mocapgraph.data_tools.evaluation.evaluate import evaluate
    from mocapgraph.data_tools.evaluation.report import write_report
    from mocapgraph.data_tools.io.capture import write_capture
    from mocapgraph.data_tools.io.result import write_result
    from mocapgraph.data_tools.sim.synthetic import synthesize
    from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap

    capture = synthesize("phones", seed=seed, duration_s=duration_s)
    write_capture(capture, out_dir / "capture", overwrite=True)
    moving = sum(cam.moving for cam in capture.cameras)
    print(f"synthesised {capture.name}: {len(capture.cameras)} uncalibrated phones ({moving} carried), {duration_s:g} s")
    variants = {
        "SmartMocap, motion prior": SmartmocapOptions(),
        "SmartMocap, no motion prior": SmartmocapOptions(motion_prior="none", covariances=False),
    }
    results, evaluations = {}, {}
    for label, options in variants.items():
        result = run_smartmocap(capture, options, capture_label=str(out_dir / "capture"))
        write_result(result, out_dir / ("result_" + options.motion_prior), overwrite=True)
        results[label], evaluations[label] = result, evaluate(result, capture)
        m = evaluations[label].metrics
        print(f"  {label:30s} MPJPE {100 * m['mpjpe_m']:5.1f} cm  static cameras {100 * m['static_mcpe_m']:5.1f} cm  "
              f"moving cameras {100 * m['moving_mcpe_procrustes_m']:5.1f} cm  ({result.parameters['seconds']:.1f} s)")
    return write_report(out_dir, "mocapgraph demo: SmartMocap on uncalibrated phones", capture, results, evaluations)


def run_demo(out_dir: Path, motion_dir: Path | None = None, duration_s: float = 8.0, phones_duration_s: float = 6.0) -> Path:
    """The AirCap and SmartMocap demos and the body-model figure, into ``out_dir``; returns the
    AirCap report (the SmartMocap one is in ``out_dir / "smartmocap"``)."""
    report = run_aircap_demo(out_dir, duration_s=duration_s)
    smartmocap = run_smartmocap_demo(out_dir / "smartmocap", duration_s=phones_duration_s)
    print(f"wrote {smartmocap}")
    run_body_figure(out_dir, motion_dir)
    return report


def run_body_figure(out_dir: Path, motion_dir: Path | None = None) -> Path:
    """Pose the default body (CMU poses if available) and write ``body_poses.png`` into ``out_dir``."""
    from mocapgraph.data_tools.sim.cmu_motion import motion_dir as default_motion_dir

    body = load_body_model()
    chosen = cmu_poses(body, motion_dir or default_motion_dir())
    source = "CMU motion"
    if chosen is None:
        chosen, source = builtin_poses(), "built-in poses"
    names, root, pose = chosen
    root = face_the_viewer(root)
    # Stand the body on the floor: lowest keypoint at z = 0.
    lowest = body.forward(body.default_shape, root, pose).keypoints[..., 2].min(axis=1)
    root[:, 2, 3] -= lowest
    path = draw(body, names, root, pose, out_dir / "body_poses.png")
    print(f"posed the {body.name} body in {len(names)} {source}: {', '.join(names)}")
    return path


def cmd_demo(args) -> None:
    # The demo prints a line per run: the pipelines' own steps only with -v.
    with log_level(logging.WARNING) if args.verbosity <= 0 else contextlib.nullcontext():
        path = run_demo(args.out, args.motion_dir, duration_s=args.duration_s, phones_duration_s=args.phones_duration_s)
    print(f"wrote {path.resolve()}")


def add_parsers(subparsers) -> None:
    demo = command(subparsers, "demo", "AirCap and SmartMocap on embedded synthetic captures, reports, and the body model drawn")
    demo.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory (default out/demo)")
    function_flags(
        demo, run_demo,
        {"motion_dir": ("CMU motion directory (default ../shared/motion/cmu_train)", {"type": Path}),
         "duration_s": ("seconds of the synthetic aircap capture", {"flag": "--duration"}),
         "phones_duration_s": ("seconds of the uncalibrated phones capture", {"flag": "--phones-duration"})},
    )  # fmt: skip
    demo.set_defaults(func=cmd_demo)
