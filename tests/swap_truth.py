"""The simulator's record of a detector's left/right swaps, scored: which swapped camera-frames a
solver could see at all, and how many of them it relabelled with the right kind."""

from __future__ import annotations

import warnings

import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import SWAP_KINDS, swap_permutation
from mocapgraph.data_tools.sim.detectors import DETECTOR_PRESETS

MIN_RUN_FRAMES = 3
"""A sustained swap: a run of at least this many frames of one kind (0.1 s at 30 fps, the
simulator's shortest run; shorter ones are the single-frame limb flickers or runs a missed frame cut)."""

MIN_SEPARATION_NOISE = 3.0
"""A detectable swap: the points it exchanges lie, at the farthest, more than this many times the
detector's keypoint noise from their partners. A swap that moves no point by more than the
noise is neither detectable nor harmful."""


def result_codes(result, capture) -> dict[str, np.ndarray]:
    """Per camera of the result, ``(T_c,)`` the swap codes it recorded on the capture's frames, -1
    where it has none."""
    out = {}
    for cam in capture.cameras:
        if cam.name not in result.cameras:
            continue
        track = result.cameras[cam.name]
        codes = np.full(len(cam.timestamps), -1, dtype=int)
        codes[np.searchsorted(cam.timestamps, track.timestamps)] = track.swaps if track.swaps is not None else 0
        out[cam.name] = codes
    return out


def detectable(capture) -> dict[str, np.ndarray]:
    """Per camera, ``(T_c,)`` bool: the frames of sustained runs (:data:`MIN_RUN_FRAMES`) whose
    exchanged points lie more than :data:`MIN_SEPARATION_NOISE` times the detector's noise from
    their partners (the noise of the simulator's model: its fraction of the person's height in
    the image, at least its pixel floor), in the median over the run. One detector per camera."""
    out = {}
    for cam in capture.cameras:
        ((name, det),) = cam.detectors.items()
        (truth,) = capture.ground_truth.swaps[cam.name].values()
        model = DETECTOR_PRESETS[name]
        kp = det.keypoints
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # frames without the person
            height = np.nanmax(kp[..., 1], axis=1) - np.nanmin(kp[..., 1], axis=1)
            noise = np.maximum(model.noise_frac_of_height * height, model.noise_floor_px)
            mask = np.zeros(len(truth), dtype=bool)
            edges = np.flatnonzero(np.diff(np.r_[0, truth, 0]))
            for a, b in zip(edges[:-1], edges[1:]):
                if truth[a] == 0 or b - a < MIN_RUN_FRAMES:
                    continue
                p = swap_permutation(get_format(det.format).names, SWAP_KINDS[truth[a]])
                moved = np.flatnonzero(p != np.arange(len(p)))
                seen = (kp[a:b, moved, 2] > 0) & (kp[a:b, p[moved], 2] > 0)
                apart = np.where(seen, np.linalg.norm(kp[a:b, moved, :2] - kp[a:b, p[moved], :2], axis=-1), np.nan)
                mask[a:b] = np.nanmedian(np.nanmax(apart, axis=1) / noise[a:b]) > MIN_SEPARATION_NOISE
        out[cam.name] = mask
    return out


def swap_confusion(capture, codes: dict[str, np.ndarray], counted: dict[str, np.ndarray] | None = None) -> tuple[int, int, int]:
    """``codes`` (per camera ``(T_c,)``, -1 where not observed) against the simulator's record, over
    each camera's observed frames: (swapped frames relabelled with the right kind, frames
    relabelled wrongly or when not swapped, swapped frames not found). With ``counted`` (per
    camera ``(T_c,)`` bool), the found and missed frames are counted there only; a wrong
    relabelling counts wherever it is."""
    tp = fp = fn = 0
    for name, got in codes.items():
        (truth,) = capture.ground_truth.swaps[name].values()
        seen = got >= 0
        where = seen & (counted[name] if counted is not None else True)
        tp += int(np.sum((truth > 0) & (got == truth) & where))
        fp += int(np.sum((got > 0) & (got != truth) & seen))
        fn += int(np.sum((truth > 0) & (got != truth) & where))
    return tp, fp, fn
