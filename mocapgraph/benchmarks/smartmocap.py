"""``mocapgraph bench smartmocap``: SmartMocap on synthetic captures, one run each.

``rich``: one capture in the camera configurations of the thesis' Table 4.1, with and without
the motion prior. The subject moves as a CMU take of a subject the motion prior never trained on
(subject 15, "walk/wander"; the prior's validation subjects are 2, 5, 8, 15, 18, 20, 27, 32 and
49), so the prior is measured on real motion it has not seen. Camera 1 is the first static
camera, 2 the second, "moving" the hand-held one.

``phones``: short ``phones`` captures (two static phones, two carried ones with IMUs) of five
takes of those held-out subjects (walks, a turning dance, a dance, an everyday motion), each with
its own seed, solved with and without the carried phones' IMUs (the default, and the
accelerometer at its datasheet noise) and with and without the moving cameras' constant-velocity
model (``camera_sigma_m_s2`` None); the medians over the takes. The default variant is solved
with its covariances too, and each take reports how many of its joint and camera-centre errors lie
inside their 95 % ellipsoids (goal 0.85-0.99 on every take).
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace

import numpy as np

from mocapgraph.data_tools.evaluation.evaluate import evaluate
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.errors import MocapgraphError
from mocapgraph.graphs.camera_imu import PHONE_GYRO_NOISE, PHONE_IMU_NOISE
from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap

log = logging.getLogger(__name__)

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


PHONES_TAKES = ("cmu_15_01_s1.npz", "cmu_15_09_s1.npz", "cmu_05_07_s0.npz", "cmu_05_12_s0.npz", "cmu_02_06.npz")
"""walk/wander twice; dance with a pirouette (turn); dance with upper-body rotation; bend over,
scoop up, rise (everyday): held-out subjects 15, 5 and 2."""
PHONES_VARIANTS = {
    # name: (the carried phones' IMU noise in the graph or None, the moving cameras' constant-velocity model σ m/s²);
    # "imu_gyro" is SmartMocap's default, "imu" the accelerometer at its datasheet noise
    "imu": (PHONE_IMU_NOISE, "default"),
    "imu_gyro": (PHONE_GYRO_NOISE, "default"),
    "imu_no_motion_model": (PHONE_IMU_NOISE, None),
    "no_imu": (None, "default"),
    "no_imu_no_motion_model": (None, None),
}
PHONES_REPORTED = (
    "static_mcpe_m", "static_mcoe_rad", "static_mcpe_procrustes_m", "static_mcoe_procrustes_rad", "moving_mcpe_procrustes_m", "moving_mcoe_procrustes_rad",
    "moving_mcpe_m", "moving_mcoe_rad", "mpe_m", "ra_mpjpe_m",
    "static_mcpe_cameras_m", "static_mcpe_scene_m", "static_mcpe_ground_m", "static_alignment_noise_m", "static_rig_turn_rad", "static_rig_scale",
    "static_view_bearing_rad", "static_view_distance_ratio", "static_pair_turn_rad",
)  # fmt: skip
"""``static_mcpe_procrustes_m``: the static phones as a rig after its own Procrustes, how far
their geometry is from the truth apart from the joints' alignment (on which the goal stays);
``static_mcpe_cameras_m`` / ``_scene_m`` / ``_ground_m``: after the other alignments
``eval`` reports, and ``static_alignment_noise_m`` the error the joints' alignment alone may put
on the static phones (docs/metrics.md, "Which alignment for the static cameras");
``static_rig_turn_rad`` / ``static_rig_scale``: the static pair's own Procrustes after the
joints' alignment, how far that alignment turns and scales the body's frame against the
cameras' (docs/phone-imu.md, "What sets the 8 s static error"); ``static_view_bearing_rad`` /
``static_view_distance_ratio`` / ``static_pair_turn_rad``: with no alignment, the direction in
which each static phone sees the body, its distance in body sizes and the pair's relative
rotation (docs/metrics.md, "The static cameras' views")."""
PHONES_GOALS = {"moving_mcpe_procrustes_m": 0.05, "moving_mcoe_procrustes_rad": 0.03, "static_mcpe_m": 0.02}
COVERAGE = ("coverage95_joints", "coverage95_cameras")
"""Of the default variant (``imu_gyro``, with covariances), per take: the share of joint and of
camera-centre errors inside their 95 % ellipsoids (``evaluate.coverage``)."""
COVERAGE_GOAL = (0.85, 0.99)
"""Per take. A take's camera errors share most of their error (a static phone has one pose, a
carried phone's frames turn with the body's frame), so even exactly calibrated covariances put a
third or more of the takes at 1.0 and a few under the goal (docs/uncertainty.md, "Per take, the
cameras' coverage is nearly one draw"): ``coverage_over_takes``, the mean of the takes' shares,
is the one to hold near 0.95."""
STATIC_GOAL_ON = "imu_gyro_long"
"""The static phones' goal is judged on the long takes (the issue's 8 s): on 3 s the joints'
alignment, the world a user gets, rotates by about a degree from one half of a take to the other
(``static_alignment_noise_m`` 4-9 cm at the far static phone), more than the goal's 2 cm."""


def bench_smartmocap(
    duration_s: float = 10.0, seed: int = 0, motion: str = BENCH_MOTION, workers: int = 2, sections: str = "rich,phones", phones_duration_s: float = 3.0,
    phones_long_s: float = 8.0,
) -> dict:  # fmt: skip
    """The ``sections`` asked for (comma-separated ``rich``, ``phones``): :func:`bench_rich`
    with ``duration_s``, ``seed`` and ``motion``; :func:`bench_phones` with ``phones_duration_s``,
    ``phones_long_s`` and seeds from ``seed``."""
    wanted = [name.strip() for name in sections.split(",") if name.strip()]
    unknown = [name for name in wanted if name not in ("rich", "phones")]
    if unknown or not wanted:
        raise MocapgraphError(f"sections {sections!r}: choose among rich, phones")
    out: dict = {}
    if "rich" in wanted:
        out.update(bench_rich(duration_s, seed, motion, workers))
    if "phones" in wanted:
        out["phones"] = bench_phones(phones_duration_s, seed, workers, long_duration_s=phones_long_s)
    return out


def bench_phones(duration_s: float = 3.0, seed: int = 0, workers: int = 2, takes: tuple[str, ...] = PHONES_TAKES, long_duration_s: float = 8.0) -> dict:
    """Per take (seed ``seed + k`` for the k-th), every :data:`PHONES_VARIANTS`, and the default
    one (``imu_gyro``) again on ``long_duration_s`` of the same take and seed (``imu_gyro_long``;
    0: not); metrics after the ground-plane frame's similarity alignment, the moving cameras also
    after their own Procrustes alignment; seconds per chunk; the medians over the takes and
    which goals they meet (with IMU; the static phones' on the long takes, :data:`STATIC_GOAL_ON`)."""
    default = SmartmocapOptions().graph.camera_sigma_m_s2
    rows: dict[str, dict] = {}
    runs = [(duration_s, name, variant) for name, variant in PHONES_VARIANTS.items()]
    if long_duration_s > 0:
        runs.append((long_duration_s, "imu_gyro_long", PHONES_VARIANTS["imu_gyro"]))
    for k, take in enumerate(takes):
        captures = {d: synthesize("phones", seed=seed + k, duration_s=d, motion=f"cmu:{take}") for d in {d for d, _, _ in runs}}
        for seconds, name, (noise, sigma) in runs:
            # without the keypoint-offset passes: five takes in six variants on a shared machine
            options = SmartmocapOptions(imu=noise is not None, workers=workers, covariances=name.startswith("imu_gyro"), keypoint_offsets=False)
            options.graph = replace(options.graph, camera_sigma_m_s2=default if sigma == "default" else sigma, imu_noise=noise or PHONE_IMU_NOISE)
            result = run_smartmocap(captures[seconds], options)
            metrics = evaluate(result, captures[seconds]).metrics
            row = {key: round(metrics[key], 4) for key in PHONES_REPORTED + COVERAGE if key in metrics}
            row["seconds_per_chunk"] = result.parameters["seconds_per_chunk"]
            row["seconds"] = result.parameters["seconds"]
            rows.setdefault(name, {})[f"{take.removesuffix('.npz')}_seed{seed + k}"] = row
            log.info("bench phones: %s seed %d %s: %s", take, seed + k, name, row)  # a long run's rows survive an interruption
    medians = {
        name: {key: round(float(np.median([r[key] for r in per_take.values() if key in r])), 4) for key in PHONES_REPORTED + ("seconds_per_chunk", "seconds")}
        for name, per_take in rows.items()
    }
    judged = {key: STATIC_GOAL_ON if key.startswith("static") and STATIC_GOAL_ON in medians else "imu_gyro" for key in PHONES_GOALS}
    return {
        "preset": "phones", "duration_s": duration_s, "long_duration_s": long_duration_s, "takes": list(takes), "seeds": [seed + k for k in range(len(takes))],
        "camera_sigma_m_s2_default": default, "goals": PHONES_GOALS, "median": medians, "per_take": rows,
        "goals_judged_on": judged,
        "goals_met_with_imu": {key: bool(medians[judged[key]][key] <= goal) for key, goal in PHONES_GOALS.items()},
        "coverage_goal": COVERAGE_GOAL,
        "coverage_met_every_take": {
            f"{name}.{key}": all(COVERAGE_GOAL[0] <= row[key] <= COVERAGE_GOAL[1] for row in rows[name].values())
            for name in ("imu_gyro", "imu_gyro_long") if name in rows for key in COVERAGE
        },
        "coverage_over_takes": {
            f"{name}.{key}": round(float(np.mean([row[key] for row in rows[name].values() if key in row])), 4)
            for name in ("imu_gyro", "imu_gyro_long") if name in rows for key in COVERAGE if any(key in row for row in rows[name].values())
        },
    }  # fmt: skip


def bench_rich(duration_s: float = 10.0, seed: int = 0, motion: str = BENCH_MOTION, workers: int = 2) -> dict:
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
