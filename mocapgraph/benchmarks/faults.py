"""``mocapgraph bench faults``: SmartMocap on synthetic captures whose detectors fail as real ones
do (``--detector-faults realistic``: sustained left/right swaps, far-side guesses, keypoint-definition
offsets, a size bias) against the same captures without the faults, and with swap handling off.

One run per preset (``rich``: seven static cameras and a hand-held one; ``phones``: hand-held
phones), the same seed for every variant, so the differences are the faults' and the handling's.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from mocapgraph.data_tools.evaluation.evaluate import evaluate
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.errors import MocapgraphError
from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap

PRESETS = ("rich", "phones")
REPORTED = ("ra_mpjpe_m", "mpjpe_m", "mpe_m", "mcpe_m", "static_mcpe_m", "moving_mcpe_procrustes_m", "mcoe_rad")
GOAL_RATIO = 1.2
"""Goal: with realistic faults, RA-MPJPE, MPE and camera errors within this factor of the faultless capture's."""
COMPARED = ("ra_mpjpe_m", "mpe_m", "mcpe_m")


def _swap_scores(result, capture) -> dict:
    """Relabelled frames against the simulator's record: precision and recall over every camera frame solved."""
    tp = fp = fn = 0
    for cam in capture.cameras:
        if cam.name not in result.cameras or cam.name not in capture.ground_truth.swaps:
            continue
        track = result.cameras[cam.name]
        frames = np.searchsorted(cam.timestamps, track.timestamps)
        truth = np.max(np.stack(list(capture.ground_truth.swaps[cam.name].values())), axis=0)[frames]
        got = track.swaps if track.swaps is not None else np.zeros_like(truth)
        tp += int(np.sum((truth > 0) & (got == truth)))
        fp += int(np.sum((got > 0) & (got != truth)))
        fn += int(np.sum((truth > 0) & (got != truth)))
    return {"swapped_frames": tp + fn, "precision": round(tp / max(tp + fp, 1), 3), "recall": round(tp / max(tp + fn, 1), 3)}


def _run(capture, swaps: bool, workers: int) -> dict:
    options = SmartmocapOptions(workers=workers, covariances=False)
    options = replace(options, graph=replace(options.graph, swaps=swaps))
    start = time.perf_counter()
    result = run_smartmocap(capture, options)
    seconds = time.perf_counter() - start
    metrics = evaluate(result, capture).metrics
    row = {k: round(metrics[k], 4) for k in REPORTED if k in metrics}
    row.update(seconds=round(seconds, 1), reprojection_px=result.parameters["reprojection_px"]["all"], **_swap_scores(result, capture))
    return row


def bench_faults(duration_s: float = 10.0, seed: int = 0, workers: int = 2, presets: str = ",".join(PRESETS)) -> dict:
    """Per preset of ``presets`` (comma-separated among :data:`PRESETS`): faultless, realistic
    faults handled, realistic faults with labels as detected."""
    wanted = [name.strip() for name in presets.split(",") if name.strip()]
    if not wanted or any(name not in PRESETS for name in wanted):
        raise MocapgraphError(f"presets {presets!r}: choose among {', '.join(PRESETS)}")
    out: dict = {"duration_s": duration_s, "seed": seed, "goal": f"realistic within {GOAL_RATIO}x of none on {', '.join(COMPARED)}"}
    for preset in wanted:
        none = synthesize(preset, seed=seed, duration_s=duration_s, detector_faults="none")
        faulty = synthesize(preset, seed=seed, duration_s=duration_s, detector_faults="realistic")
        rows = {"none": _run(none, True, workers), "realistic": _run(faulty, True, workers), "realistic_swaps_off": _run(faulty, False, workers)}
        rows["ratio_realistic_to_none"] = {k: round(rows["realistic"][k] / rows["none"][k], 2) for k in COMPARED if k in rows["none"]}
        rows["goal_met"] = all(v <= GOAL_RATIO for v in rows["ratio_realistic_to_none"].values())
        out[preset] = rows
    return out
