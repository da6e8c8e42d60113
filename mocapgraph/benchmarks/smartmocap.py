"""``mocapgraph bench smartmocap``: SmartMocap on one synthetic ``rich`` capture, one run, in the
camera configurations of the thesis' Table 4.1, with and without the motion prior.

The subject moves as a CMU take of a subject the motion prior never trained on (subject 15,
"walk/wander"; the prior's validation subjects are 2, 5, 8, 15, 18, 20, 27, 32 and 49), so the
prior is measured on real motion it has not seen. Camera 1 is the first static camera, 2 the
second, "moving" the hand-held one.
"""

from __future__ import annotations

import time
from dataclasses import replace

from mocapgraph.data_tools.evaluation.evaluate import evaluate
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap

BENCH_MOTION = "cmu:cmu_15_01_s1.npz"
CONFIGURATIONS = {
    "cam1": ("cam1",),
    "cam1+moving": ("cam1", "handheld"),
    "cam1+cam2+moving": ("cam1", "cam2", "handheld"),
    "all": None,
}
REPORTED = (
    "static_mcpe_m", "static_mcoe_rad", "moving_mcpe_procrustes_m", "moving_mcoe_procrustes_rad",
    "mpe_m", "moe_rad", "ra_mpjpe_m", "mpjpe_m", "pa_mpjpe_m", "mpvpe_m",
)  # fmt: skip
GOALS = {"ra_mpjpe_m": 0.03, "mpe_m": 0.05, "static_mcpe_m": 0.10, "seconds_per_chunk": 2.0}


def bench_smartmocap(duration_s: float = 10.0, seed: int = 0, motion: str = BENCH_MOTION, workers: int = 2) -> dict:
    """Every configuration with the motion prior, and without it; metrics after the similarity
    alignment ``eval`` uses for the ground-plane frame; seconds per 25-state chunk (median)."""
    capture = synthesize("rich", seed=seed, duration_s=duration_s, motion=motion)
    out: dict = {"preset": "rich", "duration_s": duration_s, "seed": seed, "motion": motion, "goals": GOALS}
    for prior in ("vae", "none"):
        for name, cameras in CONFIGURATIONS.items():
            cap = capture if cameras is None else replace(capture, cameras=[c for c in capture.cameras if c.name in cameras])
            start = time.perf_counter()
            result = run_smartmocap(cap, SmartmocapOptions(motion_prior=prior, workers=workers, covariances=False))
            seconds = time.perf_counter() - start
            metrics = evaluate(result, cap).metrics
            row = {k: round(metrics[k], 4) for k in REPORTED if k in metrics}
            row.update(
                seconds=round(seconds, 1), seconds_per_chunk=result.parameters["seconds_per_chunk"],
                initialiser=result.parameters["initialiser_used"],
            )  # fmt: skip
            out[f"{name}{'' if prior == 'vae' else '_no_motion_prior'}"] = row
    full = out["all"]
    out["goals_met"] = {k: bool(full.get(k, float("inf")) <= v) for k, v in GOALS.items()}
    return out
