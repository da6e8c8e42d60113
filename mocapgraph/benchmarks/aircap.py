"""``mocapgraph bench aircap``: the thesis' comparison on one synthetic ``aircap`` capture, one run.

Variants: ``per_frame`` (each state alone, cameras refined near their GPS/IMU prior), ``sequence``
(the whole sequence, cameras refined), ``cameras_fixed_gps`` (the sequence with cameras held at
the offline GPS/IMU fusion) and ``triangulation`` (the DLT + RANSAC baseline with the GPS/IMU
camera poses as its calibration; it estimates keypoints, so its ``mpjpe_m`` is on keypoints).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.data_tools.evaluation.evaluate import evaluate, matched_truth
from mocapgraph.data_tools.evaluation.metrics import covariance_coverage
from mocapgraph.data_tools.io.result import Result
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.pipelines.aircap import AircapOptions, camera_tracks, run_aircap
from mocapgraph.pipelines.baseline import triangulate_capture

REPORTED = ("mpjpe_m", "pa_mpjpe_m", "ra_mpjpe_m", "mpe_m", "moe_rad", "mcpe_m", "mcoe_rad")


def _metrics(result: Result, capture) -> dict:
    ev = evaluate(result, capture)
    return {k: round(ev.metrics[k], 4) for k in REPORTED if k in ev.metrics}


def bench_aircap(duration_s: float = 60.0, seed: int = 0) -> dict:
    """All variants on one capture; frames/s count every camera frame of the capture."""
    capture = synthesize("aircap", seed=seed, duration_s=duration_s)
    frames = sum(cam.num_frames for cam in capture.cameras)
    out: dict = {"duration_s": duration_s, "seed": seed, "camera_frames": frames}
    variants = {
        "per_frame": AircapOptions(mode="per-frame", cameras="refine", covariances=False),
        "sequence": AircapOptions(mode="sequence", cameras="refine", covariances=False),
        "cameras_fixed_gps": AircapOptions(mode="sequence", cameras="prior", covariances=False),
    }
    for name, options in variants.items():
        start = time.perf_counter()
        result = run_aircap(capture, options)
        seconds = time.perf_counter() - start
        out[name] = _metrics(result, capture)
        out[f"{name}_frames_per_s"] = round(frames / seconds, 1)
        if name == "sequence":
            # Uncertainty is measured on its own: the joint marginals cost more than the solve.
            start = time.perf_counter()
            with_cov = run_aircap(capture, replace(options, covariances=True))
            out["covariance_seconds"] = round(time.perf_counter() - start - with_cov.parameters["seconds"], 1)
            have, idx = matched_truth(with_cov, capture.ground_truth)
            covered = covariance_coverage(with_cov.joints[have], capture.ground_truth.joints[idx], with_cov.covariances["joints"][have])
            out["coverage_95"] = round(covered.value, 3)

    priors, _ = camera_tracks(capture, "prior")
    calibrated = replace(capture, cameras=[replace(cam, extrinsics=priors[c][0]) for c, cam in enumerate(capture.cameras) if c in priors])
    start = time.perf_counter()
    tri = triangulate_capture(calibrated)
    seconds = time.perf_counter() - start
    baseline = Result(
        "baseline", capture.name, "capture", tri.timestamps, np.full((len(tri.timestamps), NUM_JOINTS, 3), np.nan),
        keypoints=tri.points, keypoint_format=tri.format,
    )  # fmt: skip
    ev = evaluate(baseline, capture)
    out["triangulation"] = {"mpjpe_m": round(ev.metrics["mpjpe_keypoints_m"], 4), "on": "keypoints"}
    out["triangulation_frames_per_s"] = round(frames / seconds, 1)
    out["sequence_frames_per_s"] = out.pop("sequence_frames_per_s")
    out["per_frame_frames_per_s"] = out.pop("per_frame_frames_per_s")
    return out
