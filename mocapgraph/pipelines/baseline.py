"""``mocapgraph run baseline``: triangulation of calibrated cameras, written as a result.

The reference every pipeline is compared with: per frame and keypoint, confidence-weighted DLT
with RANSAC over views (``data_tools.triangulation``). It estimates 3D keypoints of the detector's
format, not a body, so the result's joints are NaN and ``eval`` scores its keypoints.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.data_tools.io.capture import load_capture
from mocapgraph.data_tools.io.result import Result, write_result
from mocapgraph.data_tools.geometry.triangulation import DEFAULT_THRESHOLD_PX, triangulate_capture
from mocapgraph.errors import MocapgraphError


def run_baseline(
    capture_path: Path, out: Path, detector: str | None = None, threshold_px: float = DEFAULT_THRESHOLD_PX,
    seed: int = 0, overwrite: bool = False,
) -> Result:  # fmt: skip
    """Triangulate every frame from the capture's calibrated cameras and write the result at ``out``."""
    capture = load_capture(capture_path)
    calibrated = [cam for cam in capture.cameras if cam.extrinsics is not None]
    skipped = [cam.name for cam in capture.cameras if cam.extrinsics is None]
    if len(calibrated) < 2:
        raise MocapgraphError(
            f"capture {capture.name!r}: the baseline needs at least 2 calibrated cameras, found "
            f"{len(calibrated)} (uncalibrated: {', '.join(skipped) or 'none'})"
        )
    if skipped:
        print(f"baseline: skipping uncalibrated cameras {', '.join(skipped)}")
    tri = triangulate_capture(replace(capture, cameras=calibrated), detector=detector, threshold_px=threshold_px, seed=seed)
    T = len(tri.timestamps)
    result = Result(
        pipeline="baseline",
        capture=str(capture_path),
        world_frame="capture",
        timestamps=tri.timestamps,
        joints=np.full((T, NUM_JOINTS, 3), np.nan),
        keypoints=tri.points,
        keypoint_format=tri.format,
        flags={
            "num_views": tri.inliers.any(axis=2).sum(axis=1),
            "points_triangulated": np.isfinite(tri.points).all(axis=2).sum(axis=1),
        },
        parameters={"detector": tri.detector, "threshold_px": float(threshold_px), "seed": seed},
    )
    write_result(result, out, overwrite=overwrite)
    known = np.isfinite(tri.points).all(axis=2)
    print(
        f"baseline: {T} frames from {len(tri.cameras)} cameras ({tri.detector}, {tri.format}); "
        f"{known.mean():.0%} of keypoints triangulated, median reprojection error "
        f"{np.nanmedian(tri.reprojection_error_px):.1f} px"
    )
    return result
