"""Synthetic captures with ground truth: a motion, a scenario's cameras and sensors, simulated
detectors, written in the capture format. ``mocapgraph synth PRESET --out DIR`` runs it.

Everything derives from one seed: the same preset, seed, duration and motion give the same
capture, array for array.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from mocapgraph.body import load_body_model
from mocapgraph.body.model import BodyModel
from mocapgraph.data_tools.io.capture import Camera, Capture, GroundTruth
from mocapgraph.data_tools.sim.detectors import DETECTOR_PRESETS, FAULT_LEVELS, simulate_detections_with_info
from mocapgraph.data_tools.sim.motion_sources import PROCEDURAL_KINDS, Motion, cmu_motion, procedural_motion
from mocapgraph.data_tools.sim.scenarios import PRESETS, scenario_cameras
from mocapgraph.data_tools.sim.sensors import PhoneImu
from mocapgraph.errors import MocapgraphError
from mocapgraph.progress import progress_bar

# The subject's default motion and the detectors every camera runs, per scenario.
PRESET_MOTION = {"aircap": "zigzag_then_act", "airpose": "turn", "rich": "turn", "phones": "walk"}
PRESET_DETECTORS = {
    "aircap": ("openpose", "alphapose"),  # the thesis fused several detectors per UAV image
    "airpose": ("openpose",),
    "rich": ("coco_hrnet",),
    "phones": ("mediapipe",),
}

WORLD_FRAMES = {
    "aircap": "ENU, metres, origin on the ground at the subject's start (GPS frame)",
    "airpose": "Z up, metres, origin on the ground at the subject's start",
    "rich": "Z up, metres, origin on the ground at the subject's start",
    "phones": "Z up, metres, origin on the ground at the subject's start",
}


def subject_motion(preset: str, motion: str | None, duration_s: float, seed: int, body: BodyModel) -> Motion:
    """The subject's motion: a procedural kind, ``cmu:<file.npz>`` / a take path, or the preset's default."""
    spec = motion or PRESET_MOTION[preset]
    if spec in PROCEDURAL_KINDS:
        # A little longer than the capture so that camera frames near the end can be sampled.
        return procedural_motion(spec, duration_s + 0.5, seed=seed, body=body)
    path = Path(spec.removeprefix("cmu:"))
    if not path.is_absolute() and not path.exists():
        from mocapgraph.data_tools.sim.cmu_motion import motion_dir

        path = motion_dir() / path
    if not path.exists():
        kinds = ", ".join(PROCEDURAL_KINDS)
        raise MocapgraphError(f"motion {spec!r}: neither a procedural kind ({kinds}) nor an existing take file")
    take = cmu_motion(path, body=body, duration_s=duration_s + 0.5)
    # Start at the origin so every scenario is laid out around the subject.
    start = take.root[0, :2, 3].copy()
    take.root[:, :2, 3] -= start
    return take


def scaled_camera(sim, scale: float):
    """``sim`` (a scenario camera) with images resized by ``scale``: image size rounded, and the
    intrinsics mapped so that a ray hits the same place in the resized image (pixel centres at
    integers: ``u' = scale · (u + ½) − ½``)."""
    size = (max(1, round(sim.image_size[0] * scale)), max(1, round(sim.image_size[1] * scale)))
    sx, sy = size[0] / sim.image_size[0], size[1] / sim.image_size[1]
    K = np.asarray(sim.K, dtype=float).copy()
    K[0] *= sx
    K[1] *= sy
    K[0, 2] += 0.5 * sx - 0.5
    K[1, 2] += 0.5 * sy - 0.5
    return replace(sim, K=K, image_size=size)


def synthesize(
    preset: str,
    seed: int = 0,
    duration_s: float = 10.0,
    motion: str | None = None,
    detectors: tuple[str, ...] | None = None,
    noise_scale: float = 1.0,
    detector_faults: str = "realistic",
    image_scale: float = 1.0,
    imu: bool = True,
) -> Capture:
    """A synthetic capture of ``preset`` (``aircap``, ``airpose``, ``rich``, ``phones``).

    ``motion``: a procedural kind or a CMU take (``cmu:cmu_02_01.npz`` or a path); default per
    preset (:data:`PRESET_MOTION`). ``detectors``: names in ``DETECTOR_PRESETS``; default per preset.
    ``noise_scale`` multiplies every detector's keypoint noise (its fraction of the person's
    height and its pixel floor), e.g. 3 for the heavy noise the learned priors are measured on.
    ``detector_faults``: ``none``, ``realistic`` or ``heavy`` (:data:`FAULT_LEVELS`): sustained
    and view-dependent left/right swaps, far-side guesses, keypoint-definition offsets and a size
    bias per detector (``docs/detector_faults.md``); the swaps applied are recorded per camera and
    detector in ``ground_truth.swaps``. ``imu``: the carried phones of ``phones`` log their IMU
    (:class:`~mocapgraph.data_tools.sim.sensors.PhoneImu`; each log's clock offset from its
    camera in ``metadata.imu_time_offsets_s``); False: no IMU logs.
    """
    if preset not in PRESETS:
        raise MocapgraphError(f"unknown scenario preset {preset!r}; presets: {', '.join(PRESETS)}")
    if not duration_s > 0:
        raise MocapgraphError(f"duration must be positive, got {duration_s}")
    if not (np.isfinite(noise_scale) and noise_scale >= 0):
        raise MocapgraphError(f"noise_scale must be a finite number >= 0, got {noise_scale}")
    if not (np.isfinite(image_scale) and 0.05 <= image_scale <= 4):
        raise MocapgraphError(f"image_scale must lie in [0.05, 4], got {image_scale}")
    if detector_faults not in FAULT_LEVELS:
        raise MocapgraphError(f"unknown detector fault level {detector_faults!r}; levels: {', '.join(FAULT_LEVELS)}")
    detectors = tuple(detectors or PRESET_DETECTORS[preset])
    unknown = [d for d in detectors if d not in DETECTOR_PRESETS]
    if unknown:
        raise MocapgraphError(f"unknown detector {unknown[0]!r}; detectors: {', '.join(DETECTOR_PRESETS)}")
    body = load_body_model()
    subject = subject_motion(preset, motion, duration_s, seed, body)
    sims = scenario_cameras(
        preset, subject.timestamps, subject.root[:, :3, 3], seed=seed, duration_s=duration_s, phone_imu=PhoneImu() if imu else None
    )
    if image_scale != 1.0:
        sims = [scaled_camera(sim, image_scale) for sim in sims]
    streams = np.random.SeedSequence([seed, 0x5EED]).spawn(len(sims) * len(detectors))

    cameras, truth_cameras, truth_swaps = [], {}, {}
    models = {
        name: replace(
            DETECTOR_PRESETS[name].at_fault_level(detector_faults),
            noise_frac_of_height=DETECTOR_PRESETS[name].noise_frac_of_height * noise_scale,
            noise_floor_px=DETECTOR_PRESETS[name].noise_floor_px * noise_scale,
        )
        for name in detectors
    }
    for c, sim in enumerate(progress_bar(sims, desc=f"synth {preset}", unit="camera")):
        root, pose = subject.sample(sim.timestamps)
        found, swaps = {}, {}
        for d, name in enumerate(detectors):
            rng = np.random.default_rng(streams[c * len(detectors) + d])
            det, info = simulate_detections_with_info(
                body, subject.shape, root, pose, sim.world_T_camera, sim.K, sim.distortion, sim.image_size,
                models[name], rng, timestamps=sim.timestamps,
            )  # fmt: skip
            det.name = name
            found[name], swaps[name] = det, info.swaps
        cameras.append(
            Camera(
                name=sim.name, K=sim.K, distortion=sim.distortion, image_size=sim.image_size, moving=sim.moving,
                timestamps=sim.timestamps, frame_rate=sim.frame_rate, detectors=found, extrinsics=sim.extrinsics,
                mount=sim.mount, sensors=sim.sensors,
            )  # fmt: skip
        )
        truth_cameras[sim.name] = sim.world_T_camera
        truth_swaps[sim.name] = swaps

    offsets = {sim.name: sim.imu_time_offset_s for sim in sims if sim.imu_time_offset_s is not None}
    # Ground truth at every camera frame time, so any pipeline's timestamps match exactly.
    times = np.unique(np.concatenate([cam.timestamps for cam in cameras]))
    root, pose = subject.sample(times)
    joints = body.forward(subject.shape, root, pose).joints
    truth = GroundTruth(body.name, times, root, pose, subject.shape.copy(), joints, truth_cameras, truth_swaps)
    return Capture(
        name=f"{preset}-seed{seed}",
        cameras=cameras,
        world_frame=WORLD_FRAMES[preset],
        ground_truth=truth,
        metadata={
            "generator": "mocapgraph synth",
            "scenario": preset,
            "seed": seed,
            "duration_s": float(duration_s),
            "motion": subject.source,
            "detectors": list(detectors),
            "noise_scale": float(noise_scale),
            "detector_faults": detector_faults,
            "image_scale": float(image_scale),
            **({"imu_time_offsets_s": offsets} if offsets else {}),
        },
    )
