"""``mocapgraph bench colmap``: COLMAP as pseudo-ground truth on rendered synthetic captures.

Per preset (``phones``: two tripods and two walking phones; ``rich``: seven static cameras and a
hand-held one), one capture with fixed seeds is synthesised at ``image_scale`` (960×540 at 0.5),
rendered (frames/s per camera), reconstructed by COLMAP (registration rate per camera, s/frame of
extraction + matching + mapping), and solved by SmartMocap twice: on its own, and with
``cameras_from="colmap"`` (the moving cameras' motion between registered frames as priors,
:mod:`~mocapgraph.pipelines.reference_cameras`); then, camera by camera
(:mod:`~mocapgraph.data_tools.evaluation.reference_eval`): COLMAP against the truth, SmartMocap
against COLMAP and SmartMocap against the truth, side by side, after the same alignments
(per-camera Procrustes for moving cameras, one similarity over all cameras for static ones) and
on the same frames (those COLMAP registered).
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from mocapgraph.data_tools.evaluation.colmap_reference import ColmapOptions, reconstruct, write_reference
from mocapgraph.data_tools.evaluation.reference_eval import compare_tracks, tracks_at_frames
from mocapgraph.data_tools.io.capture import load_capture, write_capture
from mocapgraph.data_tools.sim.render import render_capture_videos
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.errors import MocapgraphError
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


def _smartmocap(capture, reference, options: SmartmocapOptions, moving: dict, groups: dict) -> dict:
    """SmartMocap's cameras against COLMAP and against the truth, on the frames COLMAP registered."""
    start = time.perf_counter()
    result = run_smartmocap(capture, options)
    seconds = time.perf_counter() - start
    est = tracks_at_frames(result, capture)
    common = {n: reference.cameras[n] for n in est if n in reference.cameras}
    vs_colmap = compare_tracks(common, {n: est[n] for n in common}, moving, groups)
    on_reference = {n: np.where(np.all(np.isfinite(common[n]), axis=(1, 2))[:, None, None], est[n], np.nan) for n in common}
    vs_truth = compare_tracks(on_reference, capture.ground_truth.cameras, moving)
    return {
        "vs_colmap": _scores(vs_colmap), "vs_truth": _scores(vs_truth),
        "moving_mean": {"vs_colmap": _moving_mean(vs_colmap), "vs_truth": _moving_mean(vs_truth)},
        "reference_notes": [n for n in result.parameters["notes"] if "reference" in n], "seconds": round(seconds, 1),
    }  # fmt: skip


def bench_colmap(
    duration_s: float = 2.0, seed: int = 1, image_scale: float = 0.5, frame_step: int = 3, workers: int = 2, presets: str = ",".join(PRESETS)
) -> dict:
    """One run per preset of ``presets`` (comma-separated); see the module docstring."""
    out: dict = {"duration_s": duration_s, "seed": seed, "image_scale": image_scale, "frame_step": frame_step}
    chosen = [p.strip() for p in presets.split(",") if p.strip()]
    unknown = [p for p in chosen if p not in PRESETS]
    if unknown or not chosen:
        raise MocapgraphError(f"presets {presets!r}: choose among {', '.join(PRESETS)}")
    with tempfile.TemporaryDirectory(prefix="mocapgraph-bench-colmap-") as tmp:
        for preset in chosen:
            capture = synthesize(preset, seed=seed, duration_s=duration_s, image_scale=image_scale)
            speeds = {}
            path = write_capture(capture, Path(tmp) / preset, extra_files=lambda root: speeds.update(render_capture_videos(capture, root)))
            capture = load_capture(path)
            start = time.perf_counter()
            reference = reconstruct(capture, options=ColmapOptions(frame_step=frame_step, seed=seed))
            colmap_s = time.perf_counter() - start
            write_reference(reference, path)
            moving = {c.name: c.moving for c in capture.cameras}
            groups = reference.groups()
            colmap_vs_truth = compare_tracks(reference.cameras, capture.ground_truth.cameras, moving, groups)
            options = SmartmocapOptions(workers=workers, covariances=False)
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
                "colmap_moving_mean_vs_truth": _moving_mean(colmap_vs_truth),
                "smartmocap": _smartmocap(capture, reference, options, moving, groups),
                "smartmocap_cameras_from_colmap": _smartmocap(capture, reference, replace(options, cameras_from="colmap"), moving, groups),
            }
    return out
