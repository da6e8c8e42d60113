"""Held-out reprojection: how well a method's 3D predicts detections it never saw.

In-sample reprojection rewards freedom: a free 3D point per keypoint and frame has three unknowns
against at most two measurements per camera, so it follows part of the detector's noise and its
definitions' error, which a body cannot and should not. A camera-frame hidden from the whole run
(detection choice, association, swaps, offsets, solve) and predicted afterwards from the method's
3D through its camera measures instead what the method learned about the person.

- :func:`heldout_split`: which camera-frames are hidden; deterministic for a seed, spread over
  every camera and the whole clip, at most one camera per frame (so every hidden view's frame
  keeps the other cameras).
- :func:`hide`: a :class:`~mocapgraph.data_tools.tracking.track_files.TrackSet` with those
  camera-frames emptied in every track, as if the camera had seen nobody then.
- :func:`heldout_detections`: the chosen person's detections in the hidden camera-frames, from
  the tracks the choice made on the rest.
- :func:`view_errors`: per camera, the pixel distance of each detection from the result's 3D
  keypoint projected through the result's camera (intrinsics as the capture has them, focal
  lengths as the result estimated them, distortion), the left/right labels either as the result
  relabelled the view or, for a view the result never saw, the labelling that fits best.
- :func:`compare_heldout`: every method's in-sample and held-out medians, the held-out compared
  on the detections every method predicts, with a paired bootstrap over the hidden views.
- :func:`run_heldout`: all of it for one person of a recording's tracks and several methods.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from mocapgraph.body import load_body_model
from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import swap_permutations
from mocapgraph.data_tools.geometry.camera_model import project_points
from mocapgraph.data_tools.geometry.timing import match_times
from mocapgraph.data_tools.io.calibration import CameraCalibration
from mocapgraph.data_tools.io.capture import Capture, load_capture
from mocapgraph.data_tools.io.result import Result
from mocapgraph.data_tools.tracking.people import PersonChoice, PersonTracks, merge_tracks
from mocapgraph.data_tools.tracking.track_files import TrackSet
from mocapgraph.errors import MocapgraphError
from mocapgraph.graphs.point_bundle import MIN_CONFIDENCE

HELDOUT_SHARE = 0.15
"""Share of all camera-frames hidden: on a 4-camera, 100-frame clip 60 views, 15 per camera (about
1000 detections of the body's points), while every frame keeps at least three cameras."""
HELDOUT_SEED = 0
SPLITS = ("frames", "runs")
"""How :func:`run_heldout` is run by ``bench real``: single camera-frames (``run_frames=1``), and
each camera's share as one run (:func:`split_run_frames`)."""
HELDOUT_MIN_CONFIDENCE = 0.3
"""Detections below this confidence count in neither the held-out nor the in-sample median of
:func:`compare_heldout` (the pipelines fit those of 0.2 and more)."""
BOOTSTRAP_SAMPLES = 2000
"""Resamples of the hidden views for the interval of the difference of the medians."""


def heldout_split(
    cameras: Sequence[str], num_frames: int, share: float = HELDOUT_SHARE, seed: int = HELDOUT_SEED, run_frames: int = 1
) -> dict[str, np.ndarray]:
    """Which camera-frames to hide: ``round(share · T)`` of the ``num_frames`` (``T``) per camera,
    in runs of about ``run_frames`` consecutive frames (as many runs per camera as fit,
    ``max(1, round(share · T / run_frames))``, their lengths differing by at most one), no two
    runs sharing a frame, so no frame loses more than one camera. The runs are taken in time
    order and given to the ``C`` cameras in turn (the cameras' order drawn), and placed uniformly
    at random among all non-overlapping placements (``numpy.random.default_rng(seed)``): spread
    over every camera and the whole clip. ``run_frames=1`` hides single camera-frames, which a
    method smoothing over time can predict from the same camera's next frames; one run per
    camera hides a stretch it cannot.

    Returns:
        camera → ``(T,)`` bool, True where hidden.
    """
    C = len(cameras)
    if C < 3:
        raise MocapgraphError(f"held-out reprojection needs at least 3 cameras (a hidden view's frame keeps two to place the point), got {C}")
    if not 0 < share * C <= 1:
        raise MocapgraphError(f"held-out share must lie in (0, 1/{C}] with {C} cameras (one hidden camera per frame at most), got {share}")
    if run_frames < 1:
        raise MocapgraphError(f"held-out runs must be at least 1 frame long, got {run_frames}")
    rng = np.random.default_rng(seed)
    per_camera = round(share * num_frames)
    runs = max(1, round(per_camera / run_frames))
    lengths = np.tile(np.diff(np.linspace(0, per_camera, runs + 1).round().astype(int)), C)  # (C · runs,) in time order
    free = num_frames - int(lengths.sum())
    # a placement of R runs among `free` visible frames is a choice of R of the free + R slots
    slots = np.sort(rng.choice(free + len(lengths), size=len(lengths), replace=False))
    starts = slots - np.arange(len(lengths)) + np.concatenate([[0], np.cumsum(lengths)[:-1]])
    order = rng.permutation(C)
    held = {c: np.zeros(num_frames, dtype=bool) for c in cameras}
    for k, (start, length) in enumerate(zip(starts, lengths)):
        held[cameras[order[k % C]]][start : start + length] = True
    return held


def split_run_frames(split: str, num_frames: int, share: float = HELDOUT_SHARE) -> int:
    """The ``run_frames`` of a split of :data:`SPLITS` on a clip of ``num_frames``."""
    if split not in SPLITS:
        raise MocapgraphError(f"held-out split must be one of {', '.join(SPLITS)}, got {split!r}")
    return 1 if split == "frames" else max(1, round(share * num_frames))


def hide(tracks: TrackSet, held: Mapping[str, np.ndarray]) -> TrackSet:
    """A copy of ``tracks`` with every track of each camera empty (NaN) in its ``held`` frames."""
    hidden = {}
    for c in tracks.cameras:
        keypoints = tracks.tracks[c].keypoints.copy()
        mask = np.asarray(held.get(c, np.zeros(keypoints.shape[1], dtype=bool)), dtype=bool)
        if mask.shape != (keypoints.shape[1],):
            raise MocapgraphError(f"camera {c}: the held-out mask has {mask.shape} entries for its {keypoints.shape[1]} frames")
        keypoints[:, mask] = np.nan
        hidden[c] = PersonTracks(keypoints)
    return replace(tracks, tracks=hidden)


def heldout_detections(tracks: TrackSet, choice: PersonChoice, held: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The chosen person's detections ``(T, K, 3)`` per camera in its ``held`` frames (NaN in the
    others): the tracks ``choice`` made of that person on the hidden tracks, merged as the capture
    merges them, read from the full ``tracks``."""
    out = {}
    for c in tracks.cameras:
        keypoints = tracks.tracks[c].keypoints
        merged = merge_tracks(keypoints[list(choice.person.tracks.get(c, ()))], keypoints.shape[1:])
        merged[~np.asarray(held[c], dtype=bool)] = np.nan
        out[c] = merged
    return out


def measured_points(result: Result, body_points: bool = False) -> np.ndarray:
    """``(K,)`` bool: the result's keypoints a reprojection median counts. Of a result with a body,
    and with ``body_points`` of any result, only the points the body model has a counterpart for
    (the others are stand-ins no solve fitted): the same points for every pipeline."""
    names = get_format(result.keypoint_format).names
    if not (result.has_body_parameters or body_points):
        return np.ones(len(names), dtype=bool)
    body = load_body_model(result.body_model) if result.has_body_parameters else load_body_model()
    return body.table(result.shape if result.has_body_parameters else body.default_shape, keypoints=result.keypoint_format).mapped


def projected(result: Result, capture: Capture, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The result's 3D keypoints seen by camera ``name`` at every frame of the capture's camera
    with a body state within half a frame and a pose of the camera: the result's at that frame,
    or, for a static camera, its one pose (a pipeline that saw nothing in a frame may give no
    pose there). Intrinsics and distortion as the capture has them, focal lengths as the result
    estimated them (``parameters["focal_px"]``).

    Returns:
        ``frames (n,)`` into the capture camera's frames, ``pixels (n, K, 2)`` and the label codes
        ``(n,)`` into :data:`~mocapgraph.body.labelling.SWAP_KINDS` as the result relabelled each
        view (0 where it did not).
    """
    cam, track = capture.camera(name), result.cameras[name]
    tolerance = 0.5 / cam.frame_rate
    state = match_times(result.timestamps, cam.timestamps, tolerance)
    entry = match_times(track.timestamps, cam.timestamps, tolerance) if len(track.timestamps) else np.full(cam.num_frames, -1)
    if not cam.moving and len(track.timestamps):
        poses = np.where((entry >= 0)[:, None, None], track.world_T_camera[np.maximum(entry, 0)], track.world_T_camera[0])
        ok = state >= 0
    else:
        poses = track.world_T_camera[np.maximum(entry, 0)] if len(track.timestamps) else np.zeros((cam.num_frames, 4, 4))
        ok = (state >= 0) & (entry >= 0)
    K = cam.K.copy()
    focal = result.parameters.get("focal_px") or {}
    if name in focal:
        K[:2, :2] *= focal[name] / cam.K[0, 0]
    frames = np.flatnonzero(ok)
    pixels, _ = project_points(result.keypoints[state[frames]], poses[frames], K, cam.distortion)
    codes = np.zeros(cam.num_frames, dtype=int)
    if track.swaps is not None:
        codes[entry >= 0] = track.swaps[entry[entry >= 0]]
    return frames, pixels, codes[frames]


def capture_detections(result: Result, capture: Capture) -> dict[str, np.ndarray]:
    """camera → ``(F_c, K, 3)`` the capture's detections of the result's keypoint format, for every camera of the result."""
    out = {}
    for name in result.cameras:
        found = next((d for d in capture.camera(name).detectors.values() if d.format == result.keypoint_format), None)
        if found is None:
            raise MocapgraphError(f"camera {name}: no detector of the result's keypoint format {result.keypoint_format}")
        out[name] = found.keypoints
    return out


def view_errors(
    result: Result, capture: Capture, detections: Mapping[str, np.ndarray], labels: str = "result", body_points: bool = False, min_confidence: float = MIN_CONFIDENCE
) -> dict[str, dict]:
    """Per camera of the result, the distance (pixels) of each detection from its predicted point.

    Args:
        result: a pipeline's result with ``keypoints``.
        capture: the capture it ran on (cameras' intrinsics, distortion, frame times).
        detections: camera → ``(F_c, K, 3)`` detections over the capture camera's frames (NaN
            where none), in the result's keypoint format.
        labels: ``"result"``: relabelled as the result relabelled each view; ``"best"``: each view
            under the labelling of :data:`~mocapgraph.body.labelling.SWAP_KINDS` with the lowest
            median error (for views the result never saw: a prediction does not say which label
            a detector will give); ``"detected"``: as detected.
        body_points: count only the points a body has (:func:`measured_points`).
        min_confidence: detections below this confidence are not counted.

    Returns:
        camera → ``{"frames": (n,) the views' frames, "errors": (n, K) pixels, NaN where the
        detection is missing, below ``min_confidence`` or of a point not counted; inf where a counted detection has no prediction}``, for the views with a
        counted detection.
    """
    if labels not in ("result", "best", "detected"):
        raise MocapgraphError(f"labels must be 'result', 'best' or 'detected', got {labels!r}")
    names = get_format(result.keypoint_format).names
    counted = measured_points(result, body_points)
    perms = swap_permutations(names)
    out = {}
    for name in result.cameras:
        if name not in detections:
            continue
        frames, pixels, codes = projected(result, capture, name)
        observed = np.asarray(detections[name], dtype=float)[frames]
        seen = (np.nan_to_num(observed[..., 2]) >= min_confidence) & counted  # (n, K), under any labels
        if labels == "result":
            observed = np.take_along_axis(observed, perms[codes][..., None], axis=1)
            candidates = [observed]
        else:
            candidates = [observed] if labels == "detected" else [observed[:, p] for p in perms]
        errors = []
        for obs in candidates:
            ok = (np.nan_to_num(obs[..., 2]) >= min_confidence) & counted
            e = np.linalg.norm(pixels - obs[..., :2], axis=-1)
            errors.append(np.where(ok, np.where(np.isfinite(e), e, np.inf), np.nan))
        errors = np.stack(errors)  # (L, n, K)
        finite = np.where(np.isfinite(errors), errors, np.inf)
        middle = np.maximum(np.isfinite(finite).sum(axis=2) - 1, 0) // 2
        score = np.take_along_axis(np.sort(finite, axis=2), middle[..., None], axis=2)[..., 0]  # (L, n) the lower median, inf without a prediction
        pick = np.argmin(score, axis=0)
        chosen = errors[pick, np.arange(len(frames))]
        keep = seen.any(axis=1)
        out[name] = {"frames": frames[keep], "errors": chosen[keep]}
    return out


def _median(values: np.ndarray) -> float | None:
    return round(float(np.median(values)), 2) if values.size else None


def compare_heldout(
    results: Mapping[str, Result],
    capture: Capture,
    heldout: Mapping[str, np.ndarray],
    *,
    seed: int = HELDOUT_SEED,
    samples: int = BOOTSTRAP_SAMPLES,
    min_confidence: float = HELDOUT_MIN_CONFIDENCE,
) -> dict:
    """Every method's reprojection on the views it was given and on the hidden ones.

    Args:
        results: method → its result on ``capture`` (which lacks the hidden views).
        capture: the capture the methods ran on.
        heldout: camera → ``(F_c, K, 3)`` the hidden detections (:func:`heldout_detections`), NaN
            in the frames the methods saw.
        seed, samples: the paired bootstrap over the hidden views (first two methods).
        min_confidence: detections below it are counted in neither median.

    The points counted are those a body has (:func:`measured_points` with ``body_points``), at
    confidence ≥ ``min_confidence``; a hidden view is taken
    under the labelling each method predicts best (:func:`view_errors`, ``"best"``), and as
    detected too. The methods are compared on the common set: the hidden views every method has
    a pose for, and in each the points every method predicts.

    Returns:
        ``{"min_confidence", "views": hidden views with a counted detection, "detections": their counted
        detections, "common": those in the common set, method: {"in_sample_px" (every view the
        method saw, labels as it relabelled them), "heldout_px" (the common set),
        "heldout_px_own" (all it predicts), "heldout_px_as_detected" (the common set, labels as
        detected), "unpredicted", "heldout_px_per_camera"}, "difference_px": {"of", "median",
        "interval_95"}: the first method's held-out median minus the second's, and its 2.5-97.5
        percentiles over hidden views resampled with replacement}``.
    """
    names = list(results)
    best = {m: view_errors(results[m], capture, heldout, "best", True, min_confidence) for m in names}
    detected = {m: view_errors(results[m], capture, heldout, "detected", True, min_confidence) for m in names}
    cameras = [c for c in heldout if all(c in best[m] for m in names)]
    frames = {c: sorted(set.intersection(*(set(best[m][c]["frames"].tolist()) for m in names))) for c in cameras}

    def rows(per_camera: dict, c: str) -> np.ndarray:
        index = {int(f): k for k, f in enumerate(per_camera[c]["frames"])}
        return per_camera[c]["errors"][[index[f] for f in frames[c]]]

    K = len(get_format(results[names[0]].keypoint_format).names)
    stack = {m: np.concatenate([rows(best[m], c) for c in cameras]) if cameras else np.zeros((0, K)) for m in names}
    stack_detected = {m: np.concatenate([rows(detected[m], c) for c in cameras]) if cameras else np.zeros((0, K)) for m in names}
    camera_of = np.concatenate([[c] * len(frames[c]) for c in cameras]) if cameras else np.zeros(0, dtype=str)
    counted = ~np.isnan(stack[names[0]])
    common = np.all([np.isfinite(stack[m]) for m in names], axis=0)
    out: dict = {"min_confidence": min_confidence, "views": int(len(camera_of)), "detections": int(counted.sum()), "common": int(common.sum())}
    for m in names:
        e, d = stack[m], stack_detected[m]
        inside = view_errors(results[m], capture, capture_detections(results[m], capture), "result", True, min_confidence)
        inside = np.concatenate([v["errors"][np.isfinite(v["errors"])] for v in inside.values()])
        out[m] = {
            "in_sample_px": _median(inside),
            "heldout_px": _median(e[common]),
            "heldout_px_own": _median(e[np.isfinite(e)]),
            "heldout_px_as_detected": _median(d[common & np.isfinite(d)]),
            "unpredicted": int(np.count_nonzero(np.isinf(e))),
            "heldout_px_per_camera": {c: _median(e[camera_of == c][common[camera_of == c]]) for c in cameras},
        }
    if len(names) >= 2 and common.any():
        a, b = stack[names[0]], stack[names[1]]
        rng = np.random.default_rng(seed)
        differences = []
        for _ in range(samples):
            pick = rng.integers(0, len(a), len(a))
            mask = common[pick]
            if mask.any():
                differences.append(np.median(a[pick][mask]) - np.median(b[pick][mask]))
        out["difference_px"] = {
            "of": f"{names[0]} - {names[1]}", "median": round(float(np.median(a[common]) - np.median(b[common])), 2),
            "interval_95": [round(float(q), 2) for q in np.percentile(differences, [2.5, 97.5])],
        }  # fmt: skip
    return out


def run_heldout(
    tracks: TrackSet,
    calibration: Sequence[CameraCalibration] | None,
    out: str | Path,
    runners: Mapping[str, Callable[[Capture], Result]],
    person: str | int = "largest",
    share: float = HELDOUT_SHARE,
    seed: int = HELDOUT_SEED,
    run_frames: int = 1,
    references: Mapping[str, Callable[[Capture, Mapping[str, Result]], Result]] | None = None,
) -> dict:
    """Hide a share of ``tracks``' camera-frames in runs of about ``run_frames`` (:func:`heldout_split`, :func:`hide`), write the
    capture of ``person`` from the rest (``calibration``'s intrinsics and poses where given, as
    :meth:`~mocapgraph.data_tools.tracking.track_files.TrackSet.write_capture`) into ``out``, run
    every method of ``runners`` (name → a function of the capture returning its result) on it, and
    compare them on the hidden detections (:func:`compare_heldout`). Each of ``references`` (name →
    a function of the capture and the methods' results returning a result, e.g. free points
    triangulated with known cameras) is measured the same way on its own, outside the comparison.

    Returns:
        :func:`compare_heldout`'s report, with ``share``, ``seed``, ``run_frames``, ``hidden_per_camera`` (views),
        ``person`` (the rank chosen on the rest and its tracks per camera), ``seconds`` per method,
        ``errors``: method → message for a method that failed (left out of the comparison), and
        ``references``: name → its :func:`compare_heldout` row.
    """
    num_frames = max(t.num_frames for t in tracks.tracks.values())
    held = {c: m[: tracks.tracks[c].num_frames] for c, m in heldout_split(tracks.cameras, num_frames, share, seed, run_frames).items()}
    path, choice = hide(tracks, held).write_capture(out, calibration=calibration, person=person)
    capture = load_capture(path)
    results, seconds, errors = {}, {}, {}
    for name, run in runners.items():
        started = time.perf_counter()
        try:
            results[name] = run(capture)
        except MocapgraphError as exc:  # a method that cannot fit the rest is a finding, not the comparison's end
            errors[name] = str(exc)
            continue
        seconds[name] = round(time.perf_counter() - started, 1)
    hidden = heldout_detections(tracks, choice, held)
    report = compare_heldout(results, capture, hidden, seed=seed) if results else {}
    report["references"] = {}
    for name, make in (references or {}).items():
        try:
            report["references"][name] = compare_heldout({name: make(capture, results)}, capture, hidden)[name]
        except MocapgraphError as exc:
            errors[name] = str(exc)
    return report | {
        "share": share, "seed": seed, "run_frames": run_frames, "hidden_per_camera": {c: int(m.sum()) for c, m in held.items()},
        "person": {"rank": choice.chosen, "tracks": {c: list(t) for c, t in choice.person.tracks.items()}}, "seconds": seconds, "errors": errors,
    }  # fmt: skip
