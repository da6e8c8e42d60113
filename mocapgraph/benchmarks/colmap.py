"""``mocapgraph bench colmap``: COLMAP as pseudo-ground truth on rendered synthetic captures.

Per preset (``phones``: two tripods and two walking phones; ``rich``: seven static cameras and a
hand-held one), one capture with fixed seeds is synthesised at ``image_scale`` (960×540 at 0.5),
rendered (frames/s per camera), reconstructed by COLMAP (registration rate per camera, s/frame of
extraction + matching + mapping), and solved by SmartMocap; then, camera by camera
(:mod:`~mocapgraph.data_tools.evaluation.reference_eval`): COLMAP against the truth, SmartMocap
against COLMAP and SmartMocap against the truth, side by side, after the same alignments
(per-camera Procrustes for moving cameras, one similarity over all cameras for static ones) and
on the same frames (those COLMAP registered).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from mocapgraph.data_tools.evaluation.colmap_reference import ColmapOptions, reconstruct
from mocapgraph.data_tools.evaluation.reference_eval import compare_tracks, tracks_at_frames
from mocapgraph.data_tools.io.capture import load_capture, write_capture
from mocapgraph.data_tools.sim.render import render_capture_videos
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap

PRESETS = ("phones", "rich")


def _scores(scores: dict) -> dict:
    return {n: {"moving": s.moving, "cm": round(100 * s.mcpe_m, 2), "deg": round(s.mcoe_deg, 2), "frames": s.frames} for n, s in scores.items()}


def _moving_mean(scores: dict) -> dict:
    picked = [s for s in scores.values() if s.moving and np.isfinite(s.mcpe_m)]
    if not picked:
        return {"cm": None, "deg": None}
    w = np.array([s.frames for s in picked], float)
    return {"cm": round(100 * float(np.average([s.mcpe_m for s in picked], weights=w)), 2),
            "deg": round(float(np.average([s.mcoe_deg for s in picked], weights=w)), 2)}  # fmt: skip


def bench_colmap(duration_s: float = 2.0, seed: int = 1, image_scale: float = 0.5, frame_step: int = 3, workers: int = 2) -> dict:
    """One run per preset; see the module docstring."""
    out: dict = {"duration_s": duration_s, "seed": seed, "image_scale": image_scale, "frame_step": frame_step}
    with tempfile.TemporaryDirectory(prefix="mocapgraph-bench-colmap-") as tmp:
        for preset in PRESETS:
            capture = synthesize(preset, seed=seed, duration_s=duration_s, image_scale=image_scale)
            speeds = {}
            path = write_capture(capture, Path(tmp) / preset, extra_files=lambda root: speeds.update(render_capture_videos(capture, root)))
            capture = load_capture(path)
            start = time.perf_counter()
            reference = reconstruct(capture, options=ColmapOptions(frame_step=frame_step, seed=seed))
            colmap_s = time.perf_counter() - start
            moving = {c.name: c.moving for c in capture.cameras}
            truth = capture.ground_truth.cameras
            groups = reference.groups()
            colmap_vs_truth = compare_tracks(reference.cameras, truth, moving, groups)

            start = time.perf_counter()
            result = run_smartmocap(capture, SmartmocapOptions(workers=workers, covariances=False))
            smartmocap_s = time.perf_counter() - start
            est = tracks_at_frames(result, capture)
            common = {n: reference.cameras[n] for n in est if n in reference.cameras}
            vs_colmap = compare_tracks(common, {n: est[n] for n in common}, moving, groups)
            on_reference = {n: np.where(np.all(np.isfinite(common[n]), axis=(1, 2))[:, None, None], est[n], np.nan) for n in common}
            vs_truth = compare_tracks(on_reference, truth, moving)
            stats = reference.stats
            out[preset] = {
                "image_size": list(capture.cameras[0].image_size),
                "render_fps_per_camera": {n: round(v, 2) for n, v in speeds.items()},
                "registration_rate": round(stats["registration_rate"], 3),
                "registration_rate_per_camera": {n: round(c["registration_rate"], 3) for n, c in stats["cameras"].items()},
                "reprojection_error_px": round(stats["mean_reprojection_error_px"], 3),
                "mean_track_length": round(stats["mean_track_length"], 2),
                "colmap_seconds_per_frame": round(stats["seconds_per_frame"], 2),
                "colmap_seconds": {k: round(v, 1) for k, v in stats["seconds"].items()} | {"total": round(colmap_s, 1)},
                "failures": reference.failures,
                "colmap_vs_truth": _scores(colmap_vs_truth),
                "smartmocap_vs_colmap": _scores(vs_colmap),
                "smartmocap_vs_truth": _scores(vs_truth),
                "moving_mean": {"colmap_vs_truth": _moving_mean(colmap_vs_truth), "smartmocap_vs_colmap": _moving_mean(vs_colmap),
                                "smartmocap_vs_truth": _moving_mean(vs_truth)},  # fmt: skip
                "smartmocap_seconds": round(smartmocap_s, 1),
            }
    return out
