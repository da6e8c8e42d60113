"""``mocapgraph bench airpose``: AirPose (the initialiser alone) against AirPose+ (the sequence
bundle adjustment) on one synthetic ``airpose`` capture, one run, for every initialiser: the
fusion regressor and its ablations (thesis Table 3.1: without the views' exchange, without the
crop parameters P) and the PnP of the mean body.

Reported per row: ``mpe_m`` and ``mpjpe_m`` in camera 1's frame (each frame mapped by camera 1's
true pose), ``pa_mpjpe_m``, ``camera2_position_m`` (mean distance between the estimated and the
true position of camera 2 relative to camera 1) and frames per second of the whole run.
"""

from __future__ import annotations

import time

import numpy as np

from mocapgraph.data_tools.evaluation.evaluate import evaluate
from mocapgraph.data_tools.evaluation.metrics import mcpe_m
from mocapgraph.data_tools.geometry.timing import match_times
from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.data_tools.io.result import Result
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.errors import MocapgraphError
from mocapgraph.pipelines.airpose import AirposeOptions, run_airpose

INITIALISERS = {
    "regressor": ("regressor", "full"),
    "regressor_no_exchange": ("regressor", "no_exchange"),
    "regressor_no_crop": ("regressor", "no_crop"),
    "pnp": ("pnp", "full"),
}


def camera2_position_error_m(result: Result, capture: Capture) -> float:
    """Mean distance (m) between camera 2's estimated and true position in camera 1's frame."""
    gt = capture.ground_truth
    c1, c2 = capture.cameras[0].name, capture.cameras[1].name
    truth = np.linalg.inv(gt.cameras[c1]) @ gt.cameras[c2]
    track = result.cameras[c2]
    frames = match_times(capture.camera(c2).timestamps, track.timestamps, tolerance=0.0)
    return mcpe_m(track.world_T_camera, truth[frames]).value


def bench_airpose(duration_s: float = 10.0, seed: int = 0, motion: str | None = None) -> dict:
    """Every initialiser alone and refined by AirPose+; an initialiser whose weights are missing
    is reported as such rather than stopping the run."""
    capture = synthesize("airpose", seed=seed, duration_s=duration_s, motion=motion)
    out: dict = {"preset": "airpose", "duration_s": duration_s, "seed": seed, "motion": motion or "default"}
    for name, (initialiser, variant) in INITIALISERS.items():
        for refine in (False, True):
            options = AirposeOptions(initialiser=initialiser, regressor_variant=variant, refine=refine, covariances=False)
            start = time.perf_counter()
            try:
                result = run_airpose(capture, options)
            except MocapgraphError as exc:
                out[name] = {"error": str(exc)}
                break
            seconds = time.perf_counter() - start
            m = evaluate(result, capture).metrics
            frames = int((~result.flags["left_out"]).sum())
            out[f"{name}{'_airpose_plus' if refine else ''}"] = {
                "mpe_m": round(m["mpe_m"], 4), "mpjpe_m": round(m["mpjpe_m"], 4), "pa_mpjpe_m": round(m["pa_mpjpe_m"], 4),
                "camera2_position_m": round(camera2_position_error_m(result, capture), 4),
                "frames_per_s": round(frames / seconds, 1),
            }  # fmt: skip
    return out
