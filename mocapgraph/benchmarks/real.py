"""``mocapgraph bench real``: self-calibration on a real four-camera clip, against the lab's calibration.

The clip (``tests/data/real`` of the source repository: Pose2Sim's ``Demo_MultiPerson``, four
static cameras around a treadmill, 60 fps, 100 frames, two people; see its README) is a folder
with every person track of every camera (``tracks.npz``,
:mod:`mocapgraph.data_tools.tracking.track_files`) and the lab's Qualisys calibration
(``Calib.qca.txt``). For the person the default rule picks (``largest``) and for every other
person all cameras see, with the lab's intrinsics and with guessed ones (``f = 1.2 × max(w, h)``),
SmartMocap (defaults) and the generic uncalibrated baseline self-calibrate the cameras; the
poses are then compared with the lab's:

- camera centres aligned to the lab's by a similarity (Umeyama, every camera weighing the same):
  the position error (median over cameras, cm), the orientation error after the similarity's
  rotation (median, degrees), the similarity's scale as the result's size error (%), and the
  ground tilt (the angle between the result's world Z, mapped by the alignment, and the lab's Z;
  the lab's floor is its z = 0: the standing person's heels triangulate 1-3 cm above it);
- aligned by a rotation and translation only (no scale): the position error (cm), which is small
  only when the result is metric;
- the reprojection median (px) the pipeline reports (SmartMocap's over every view it was
  given, with per keypoint medians), or computed here from the result's 3D keypoints, cameras
  and focal lengths against the detections as it relabelled them (both pipelines: the same
  points, so the same definition);
- frames relabelled (left/right swaps found) per camera, focal lengths estimated, run time;
- whether the person fitted is the same person in every camera (:func:`same_person_check`);
- how far SmartMocap's body moved (``joint_motion_cm``, :func:`~mocapgraph.pipelines.results.joint_motion_m`):
  a nearly still person places the cameras poorly, and its note says so;
- held-out reprojection (``heldout``, :mod:`mocapgraph.benchmarks.heldout`): both pipelines run
  again with lab intrinsics and a share of the camera-frames hidden from every step, once as
  single frames and once as one run per camera; each one's 3D predicts the hidden detections
  through its camera, next to its in-sample median on the views it kept. In-sample reprojection
  rewards a model's freedom; held-out measures what it predicts.

The ``goals`` say where SmartMocap should be: at or below the baseline on every camera error,
the reprojection, the ground tilt and the scale (calibrated intrinsics), its cameras with guessed
intrinsics within 2× of its calibrated run, the same person in every camera, and at or below the
baseline on the hidden detections (both splits). Swaps found are
reported without a goal: the clip has no truth for them.
"""

from __future__ import annotations

import logging
import tempfile
import time
from pathlib import Path

import numpy as np

import mocapgraph
from mocapgraph.benchmarks.heldout import HELDOUT_SEED, HELDOUT_SHARE, SPLITS, capture_detections, projected, run_heldout, split_run_frames, view_errors
from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import swap_permutation, swap_permutations
from mocapgraph.data_tools.evaluation.alignment import MIN_ALIGNMENT_CAMERAS, align_camera_centres
from mocapgraph.data_tools.evaluation.metrics import mcoe_rad, mcpe_m
from mocapgraph.data_tools.geometry.association import MIN_VISIBILITY
from mocapgraph.data_tools.geometry.camera_model import project_points, undistort_pixels
from mocapgraph.data_tools.geometry.triangulation import projection_matrix, triangulate_points, triangulate_ransac
from mocapgraph.data_tools.io.calibration import CameraCalibration, intrinsics_only, read_calibration
from mocapgraph.data_tools.io.capture import Capture, load_capture
from mocapgraph.data_tools.io.result import CameraTrack, Result
from mocapgraph.data_tools.tracking.people import PersonChoice
from mocapgraph.data_tools.tracking.track_files import TrackSet, load_track_set
from mocapgraph.errors import MocapgraphError
from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap
from mocapgraph.pipelines.uncalibrated_baseline import UncalibratedOptions, run_uncalibrated_baseline

log = logging.getLogger(__name__)

DEFAULT_CLIP = Path(mocapgraph.__file__).resolve().parents[1] / "tests" / "data" / "real"
"""The clip in the source repository (absent from an installed wheel)."""
TRACKS_FILE = "tracks.npz"
CALIBRATION_FILE = "Calib.qca.txt"
PIPELINES = ("smartmocap", "baseline")
INTRINSICS = ("calibrated", "guessed")
ERROR_KEYS = (
    "camera_cm", "camera_deg", "rigid_cm", "scale_error_pct", "ground_tilt_deg", "camera_cm_per_camera", "camera_deg_per_camera", "rigid_cm_per_camera",
)  # fmt: skip
COMPARED = ("camera_cm", "camera_deg", "rigid_cm", "reprojection_px_body_points", "ground_tilt_deg", "scale_error_pct")
"""The metrics where SmartMocap should be at or below the baseline (the scale's by its size); the
reprojection's computed here for both on the same detections (every frame, the points a body has)."""
GUESSED_FACTOR = 2.0
"""With guessed intrinsics, cameras within this factor of the calibrated run's error."""
MIN_CONFIDENCE = UncalibratedOptions().min_confidence
"""Detections below this confidence are left out of the reprojection medians computed here."""


# ---------------------------------------------------------------------------------------------
# The clip


def clip_directory(clip: str | Path | None = None) -> Path:
    """The clip's folder (default :data:`DEFAULT_CLIP`), checked to hold its two files."""
    directory = DEFAULT_CLIP if clip is None else Path(clip)
    missing = [name for name in (TRACKS_FILE, CALIBRATION_FILE) if not (directory / name).is_file()]
    if missing:
        what = f"{directory}: {' and '.join(missing)} missing (a real clip is a folder with {TRACKS_FILE} and {CALIBRATION_FILE})"
        if clip is None:
            what += "; the clip ships with the source repository (tests/data/real), not with an installed package: pass --clip DIR"
        raise MocapgraphError(what)
    return directory


def lab_calibration(clip: str | Path | None = None) -> list[CameraCalibration]:
    """The clip's reference calibration: intrinsics, distortion and poses of every camera."""
    return read_calibration(clip_directory(clip) / CALIBRATION_FILE)


def load_clip(clip: str | Path | None = None) -> TrackSet:
    """The clip's person tracks (:func:`~mocapgraph.data_tools.tracking.track_files.load_track_set`)."""
    return load_track_set(clip_directory(clip) / TRACKS_FILE)


def clip_capture(clip: str | Path | None, out: str | Path, person: str | int = "largest", intrinsics: str = "guessed") -> tuple[Path, PersonChoice]:
    """A capture of one person of the clip, as ``mocapgraph detect`` would write it, the cameras
    static and their poses withheld: ``intrinsics="calibrated"`` keeps the lab's intrinsics and
    distortion, ``"guessed"`` leaves the capture to guess them (as without a calibration)."""
    if intrinsics not in INTRINSICS:
        raise MocapgraphError(f"intrinsics must be {' or '.join(repr(i) for i in INTRINSICS)}, got {intrinsics!r}")
    known = intrinsics_only(lab_calibration(clip)) if intrinsics == "calibrated" else None
    return load_clip(clip).write_capture(out, calibration=known, person=person)


# ---------------------------------------------------------------------------------------------
# Measures


def _midpoints(keypoints: np.ndarray, names, K: np.ndarray, distortion) -> tuple[np.ndarray, np.ndarray]:
    """``(..., K, 3)`` detections → undistorted pixels ``(..., M, 2)`` and confidences ``(..., M)``
    of the midpoints of every left/right pair and of the midline points: the same whatever
    left/right labels the detector gave (NaN / 0 where either point is below
    :data:`~mocapgraph.data_tools.geometry.association.MIN_VISIBILITY`)."""
    perm = swap_permutation(names, "body")
    first = np.flatnonzero(np.arange(len(names)) <= perm)
    pixels = undistort_pixels(keypoints[..., :2], K, distortion)
    mid = 0.5 * (pixels[..., first, :] + pixels[..., perm[first], :])
    conf = np.nan_to_num(np.minimum(keypoints[..., first, 2], keypoints[..., perm[first], 2]))
    seen = conf >= MIN_VISIBILITY
    return np.where(seen[..., None], mid, np.nan), np.where(seen, conf, 0.0)


def same_person_check(tracks: TrackSet, lab: dict[str, CameraCalibration], choice: PersonChoice) -> dict:
    """Whether the chosen person's tracks are one person in every camera, checked with the lab's calibration.

    Per camera: the person's left/right midpoints (swap-proof) seen by the other cameras are
    triangulated with the lab's poses and projected into it; the median distance (pixels,
    undistorted) to the chosen track's midpoints, and to each other track's, says which of its
    tracks is that person.

    Returns:
        ``{"cameras": {name: {"chosen_px", "nearest_other_px" (None without another track)}},
        "same_person": the chosen track is the nearest in every camera, "tracks": {name: [...]}}``.
    """
    names = get_format(tracks.keypoint_format).names
    cams = tracks.cameras
    mids = {c: _midpoints(choice.keypoints[c], names, lab[c].K, lab[c].distortion) for c in cams}
    out: dict = {"cameras": {}, "tracks": {c: list(choice.person.tracks.get(c, ())) for c in cams}}
    for c in cams:
        others = [o for o in cams if o != c]
        P = np.stack([projection_matrix(lab[o].K, lab[o].world_T_camera) for o in others])
        x = np.stack([mids[o][0] for o in others])  # (C-1, T, M, 2)
        w = np.stack([mids[o][1] for o in others])
        shape = x.shape[1:3]
        X = triangulate_points(P, x.reshape(len(others), -1, 2), w.reshape(len(others), -1)).reshape(*shape, 3)
        predicted, _ = project_points(X, lab[c].world_T_camera, lab[c].K)

        def distance(keypoints: np.ndarray) -> float | None:
            seen, _ = _midpoints(keypoints, names, lab[c].K, lab[c].distortion)
            d = np.linalg.norm(seen - predicted, axis=-1)
            return round(float(np.nanmedian(d)), 2) if np.isfinite(d).any() else None

        chosen = distance(choice.keypoints[c])
        rest = [distance(kp) for p, kp in enumerate(tracks.tracks[c].keypoints) if p not in choice.person.tracks.get(c, ())]
        rest = [d for d in rest if d is not None]
        out["cameras"][c] = {"chosen_px": chosen, "nearest_other_px": min(rest) if rest else None}
    out["same_person"] = all(v["chosen_px"] is not None and (v["nearest_other_px"] is None or v["chosen_px"] < v["nearest_other_px"]) for v in out["cameras"].values())
    return out


def camera_errors(result: Result, lab: dict[str, CameraCalibration]) -> dict:
    """The result's cameras against the lab's (module docstring): similarity and rigid alignment
    of the camera centres, errors per camera (median over its frames) and their medians; None
    where fewer than three cameras were estimated."""
    names = [n for n in result.cameras if n in lab]
    if len(names) < MIN_ALIGNMENT_CAMERAS:
        return {"cameras_estimated": len(names)} | dict.fromkeys(ERROR_KEYS)
    est = [result.cameras[n].world_T_camera for n in names]
    ref = [np.repeat(lab[n].world_T_camera[None], len(e), axis=0) for n, e in zip(names, est)]
    similarity = align_camera_centres([e[:, :3, 3] for e in est], [r[:, :3, 3] for r in ref])
    rigid = align_camera_centres([e[:, :3, 3] for e in est], [r[:, :3, 3] for r in ref], with_scale=False)
    position = {n: 100 * float(np.median(mcpe_m(similarity.apply_pose(e), r).per_item)) for n, e, r in zip(names, est, ref)}
    rotation = {n: float(np.degrees(np.median(mcoe_rad(similarity.apply_pose(e), r).per_item))) for n, e, r in zip(names, est, ref)}
    rigid_position = {n: 100 * float(np.median(mcpe_m(rigid.apply_pose(e), r).per_item)) for n, e, r in zip(names, est, ref)}
    tilt = float(np.degrees(np.arccos(np.clip(similarity.R[2, 2], -1.0, 1.0)))) if result.world_frame == "ground_plane" else None
    return {
        "cameras_estimated": len(names),
        "camera_cm": round(float(np.median(list(position.values()))), 2),
        "camera_deg": round(float(np.median(list(rotation.values()))), 2),
        "rigid_cm": round(float(np.median(list(rigid_position.values()))), 2),
        "scale_error_pct": round(100 * (1 / similarity.scale - 1), 2),
        "ground_tilt_deg": None if tilt is None else round(tilt, 2),
        "camera_cm_per_camera": {n: round(v, 2) for n, v in position.items()},
        "camera_deg_per_camera": {n: round(v, 2) for n, v in rotation.items()},
        "rigid_cm_per_camera": {n: round(v, 2) for n, v in rigid_position.items()},
    }


def reprojection_px(result: Result, capture: Capture, body_points: bool = False) -> dict:
    """Median distance (pixels) between each detection (confidence ≥ :data:`MIN_CONFIDENCE`,
    relabelled as the result's ``swaps`` say) and the result's 3D keypoint projected through its
    camera, with the capture's intrinsics (focal lengths as the result estimated them) and
    distortion (:func:`~mocapgraph.benchmarks.heldout.view_errors`): ``{"all": px, "camera":
    {name: px}}``. Of a result with a body, and with ``body_points`` of any result, only the
    points the body model has a counterpart for (:func:`~mocapgraph.benchmarks.heldout.measured_points`)."""
    views = view_errors(result, capture, capture_detections(result, capture), "result", body_points, MIN_CONFIDENCE)
    every, per_camera = [], {}
    for name in result.cameras:
        errors = views[name]["errors"]
        error = errors[np.isfinite(errors)]
        per_camera[name] = round(float(np.median(error)), 2) if error.size else None
        every.append(error)
    every = np.concatenate(every) if every else np.zeros(0)
    return {"all": round(float(np.median(every)), 2) if every.size else None, "camera": per_camera}


def lab_points(capture: Capture, labelled_by: Result, lab: dict[str, CameraCalibration]) -> Result:
    """Free points of the capture's detections triangulated with the lab's cameras: per frame and
    keypoint, RANSAC over the views (15 px) and Gauss-Newton
    (:func:`~mocapgraph.data_tools.geometry.triangulation.triangulate_ransac`), each view relabelled
    as ``labelled_by`` relabelled it. A result in the lab's world with the lab's poses as its
    cameras: what free points predict when the cameras are the lab's (``bench real``'s held-out
    reference; the cameras share one time line, the first camera's frames)."""
    cams = [c for c in capture.cameras if c.name in labelled_by.cameras]
    names = get_format(labelled_by.keypoint_format).names
    detections = capture_detections(labelled_by, capture)
    times = cams[0].timestamps
    perms = swap_permutations(names)
    x, w, labelled = [], [], {}
    for cam in cams:
        frames, _, codes = projected(labelled_by, capture, cam.name)
        labels = np.zeros(cam.num_frames, dtype=int)
        labels[frames] = codes
        labelled[cam.name] = labels.astype(np.int8)
        observed = np.take_along_axis(detections[cam.name], perms[labels][..., None], axis=1)
        seen = np.nan_to_num(observed[..., 2]) >= MIN_CONFIDENCE
        x.append(np.where(seen[..., None], undistort_pixels(observed[..., :2], lab[cam.name].K, lab[cam.name].distortion), np.nan))
        w.append(np.where(seen, observed[..., 2], 0.0))
    P = np.stack([projection_matrix(lab[c.name].K, lab[c.name].world_T_camera) for c in cams])
    T, K = len(times), len(names)
    points, _, _ = triangulate_ransac(P, np.stack(x).reshape(len(cams), T * K, 2), np.stack(w).reshape(len(cams), T * K))
    return Result(
        pipeline="lab_points", capture=labelled_by.capture, world_frame="lab", timestamps=times, joints=np.full((T, 22, 3), np.nan),
        keypoints=points.reshape(T, K, 3), keypoint_format=labelled_by.keypoint_format,
        cameras={c.name: CameraTrack(c.timestamps, np.repeat(lab[c.name].world_T_camera[None], c.num_frames, axis=0), labelled[c.name]) for c in cams},
    )  # fmt: skip


def reported_reprojection(result: Result) -> dict | None:
    """The reprojection medians the pipeline reported (``{"all", "camera"}``), or None."""
    p = result.parameters
    if "reprojection_px" in p:  # SmartMocap's
        return {"all": p["reprojection_px"]["all"], "camera": dict(p["reprojection_px"]["camera"])}
    if "median_reprojection_error_px" in p:  # the uncalibrated baseline's
        return {"all": p["median_reprojection_error_px"], "camera": dict(p["reprojection_median_px"])}
    return None


def run_pipeline(pipeline: str, capture: Capture) -> tuple[Result, float]:
    """One pipeline on the capture, with its defaults (SmartMocap without covariances: they do not
    change the estimate), and its wall time in seconds."""
    start = time.perf_counter()
    if pipeline == "smartmocap":
        result = run_smartmocap(capture, SmartmocapOptions(covariances=False))
    elif pipeline == "baseline":
        result = run_uncalibrated_baseline(capture, UncalibratedOptions())
    else:
        raise MocapgraphError(f"pipeline must be one of {', '.join(PIPELINES)}, got {pipeline!r}")
    return result, time.perf_counter() - start


def measure(result: Result, seconds: float, capture: Capture, lab: dict[str, CameraCalibration]) -> dict:
    """Every number of one run (module docstring)."""
    row = camera_errors(result, lab)
    reported = reported_reprojection(result)
    computed = reprojection_px(result, capture)
    reprojection = reported if reported is not None else computed
    estimated = result.parameters.get("focal_px") or {}
    focal = {c.name: round(float(estimated.get(c.name, c.K[0, 0])), 1) for c in capture.cameras}
    row.update(
        reprojection_px=reprojection["all"], reprojection_px_per_camera=reprojection["camera"],
        reprojection_px_per_keypoint=result.parameters.get("reprojection_px", {}).get("keypoint", {}).get(result.keypoint_format),
        reprojection_from="pipeline" if reported is not None else "bench",
        # the result's own 3D keypoints (SmartMocap's with its definition offsets), both
        # pipelines' on the same detections: those of confidence >= MIN_CONFIDENCE, every frame
        reprojection_px_of_result=computed["all"],
        reprojection_px_body_points=reprojection_px(result, capture, body_points=True)["all"],
        swaps_per_camera={n: int(np.count_nonzero(t.swaps > 0)) if t.swaps is not None else 0 for n, t in result.cameras.items()},
        focal_px=focal, focal_estimated=sorted(estimated),
        focal_error_pct={n: round(100 * (f / lab[n].K[0, 0] - 1), 1) for n, f in focal.items()},
        seconds=round(seconds, 1), notes=list(result.parameters.get("notes", [])),
        # how far the body moved (SmartMocap's; pipelines.results.joint_motion_m): a still one places cameras poorly
        joint_motion_cm=None if "joint_motion_m" not in result.parameters else round(100 * result.parameters["joint_motion_m"], 1),
    )  # fmt: skip
    return row


def goals(runs: dict, association: dict, heldout: dict | None = None) -> dict:
    """Per metric: what SmartMocap should reach, the numbers compared and whether it does (the
    held-out reprojection's on the detections both pipelines predict, when measured)."""
    sm, bl = runs["smartmocap"]["calibrated"], runs["baseline"]["calibrated"]
    out = {}
    for key in COMPARED:
        a, b = sm.get(key), bl.get(key)
        if key == "scale_error_pct":
            a, b = (None if v is None else abs(v) for v in (a, b))
        out[key] = {"goal": "smartmocap <= baseline (calibrated intrinsics)", "smartmocap": a, "baseline": b,
                    "met": None if a is None or b is None else bool(a <= b)}  # fmt: skip
    guessed, calibrated = runs["smartmocap"]["guessed"].get("camera_cm"), sm.get("camera_cm")
    limit = None if calibrated is None else round(GUESSED_FACTOR * calibrated, 2)
    out["guessed_camera_cm"] = {
        "goal": f"smartmocap with guessed intrinsics <= {GUESSED_FACTOR:g} x with calibrated", "smartmocap": guessed,
        "limit": limit, "met": None if guessed is None or limit is None else bool(guessed <= limit),
    }  # fmt: skip
    out["same_person"] = {"goal": "the fitted person the same in every camera (guessed intrinsics)", "met": bool(association["guessed"]["same_person"])}
    for split, held in (heldout or {}).items():
        a, b = (held.get(p, {}).get("heldout_px") for p in PIPELINES)
        out[f"heldout_px_{split}"] = {"goal": f"smartmocap <= baseline on hidden camera-frames ({split}; calibrated intrinsics, the detections both predict)",
                                      "smartmocap": a, "baseline": b, "met": None if a is None or b is None else bool(a <= b)}  # fmt: skip
    return out


# ---------------------------------------------------------------------------------------------
# The benchmark


def _result_of(results: dict[str, Result], pipeline: str) -> Result:
    if pipeline not in results:
        raise MocapgraphError(f"no {pipeline} result to take the labels from")
    return results[pipeline]


def bench_real(clip: str | Path | None = None, heldout_share: float = HELDOUT_SHARE, heldout_seed: int = HELDOUT_SEED) -> dict:
    """Both pipelines × both intrinsics on the default person and on every other person all the
    clip's cameras see (module docstring); one run each. With ``heldout_share`` > 0, both
    pipelines twice more per person (lab intrinsics), each time with that share of the
    camera-frames hidden (seed ``heldout_seed``; single frames, then one run per camera:
    :data:`~mocapgraph.benchmarks.heldout.SPLITS`), and their reprojection on the hidden
    detections (:func:`~mocapgraph.benchmarks.heldout.run_heldout`)."""
    if not heldout_share >= 0:
        raise MocapgraphError(f"held-out share must be >= 0 (0: no held-out runs), got {heldout_share}")
    directory = clip_directory(clip)
    tracks = load_clip(directory)
    lab = {c.name: c for c in lab_calibration(directory)}
    missing = [c for c in tracks.cameras if c not in lab]
    if missing:
        raise MocapgraphError(f"{directory / CALIBRATION_FILE}: no camera {', '.join(missing)} (the tracks' cameras are {', '.join(tracks.cameras)})")
    out: dict = {
        "clip": str(directory), "cameras": tracks.cameras, "frames": max(t.num_frames for t in tracks.tracks.values()),
        "lab_focal_px": {c: round(float(lab[c].K[0, 0]), 1) for c in tracks.cameras}, "people": [],
    }  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="mocapgraph-bench-real-") as tmp:
        people: list[str | int] = ["largest"]
        k = 0
        while k < len(people):
            person = people[k]
            row: dict = {"person": person, "rank": {}, "association": {}, "runs": {p: {} for p in PIPELINES}}
            for intrinsics in INTRINSICS:
                path, choice = clip_capture(directory, Path(tmp) / f"{person}-{intrinsics}", person, intrinsics)
                if person == "largest" and intrinsics == "calibrated":
                    people += [r for r, p in enumerate(choice.people) if r != choice.chosen and len(p.tracks) == len(tracks.cameras)]
                    row["people_seen"] = len(choice.people)
                row["rank"][intrinsics] = choice.chosen
                row["association"][intrinsics] = same_person_check(tracks, lab, choice)
                capture = load_capture(path)
                for pipeline in PIPELINES:
                    log.info("bench real: %s on person %s, %s intrinsics", pipeline, person, intrinsics)
                    try:
                        result, seconds = run_pipeline(pipeline, capture)
                    except MocapgraphError as exc:  # a pipeline that cannot fit this person is a finding, not the bench's end
                        log.warning("bench real: %s on person %s, %s intrinsics: %s", pipeline, person, intrinsics, exc)
                        row["runs"][pipeline][intrinsics] = {"error": str(exc)}
                        continue
                    row["runs"][pipeline][intrinsics] = measure(result, seconds, capture, lab)
            if heldout_share > 0:
                row["heldout"] = {}
                runners = {p: (lambda capture, p=p: run_pipeline(p, capture)[0]) for p in PIPELINES}
                # free points with the lab's cameras, labelled as the baseline labelled them
                references = {"lab_points": lambda capture, results: lab_points(capture, _result_of(results, "baseline"), lab)}
                for split in SPLITS:
                    log.info("bench real: both pipelines on person %s with %g of the camera-frames hidden (%s)", person, heldout_share, split)
                    run_frames = split_run_frames(split, out["frames"], heldout_share)
                    held = run_heldout(tracks, intrinsics_only(list(lab.values())), Path(tmp) / f"{person}-{split}", runners, person, heldout_share, heldout_seed, run_frames, references)
                    held["same_tracks_as_full_run"] = held["person"]["tracks"] == row["association"]["calibrated"]["tracks"]
                    row["heldout"][split] = held
            row["goals"] = goals(row["runs"], row["association"], row.get("heldout"))
            out["people"].append(row)
            k += 1
    out["goals_met"] = {key: goal["met"] for key, goal in out["people"][0]["goals"].items()}
    return out


# ---------------------------------------------------------------------------------------------
# Keypoint definitions measured against the lab's calibration


FIT_ROUNDS = 4
"""Offset rounds of the definitions' fit: on the lab clip its offsets moved less than 1 mm in a fifth."""


FREE_CAMERAS = "cam03"
"""Cameras the definitions' fit leaves free: the lab's pose of cam03 disagrees with its detections
(free points triangulated from the lab's cameras reproject there at 37 px median, at 6-8 px in
the others; README, *Real footage*)."""


def fit_clip_offsets(clip: str | Path | None = None, person: str | int = "largest", rounds: int = FIT_ROUNDS, free: str = FREE_CAMERAS) -> dict:
    """The detector format's keypoint-definition offsets on the clip, the cameras held at the lab's
    calibration: SmartMocap with the lab's intrinsics, every camera but those of ``free``
    (comma-separated names) moved to its lab pose once the swaps are settled
    (``run_smartmocap(held_cameras=...)``, in the solve's world and scale) and held, the offsets
    measured in ``rounds`` from zero (``offset_prior="zero"``: the table this fit makes is never
    its own start).

    Returns:
        ``{"clip", "format", "person", "rounds", "offsets_m": {point: [x, y, z] metres, left and
        midline points}, "reprojection_px": the fit's ``{"all", "camera", "keypoint"}``,
        "committed_m": the table in :mod:`mocapgraph.body.definition_priors` for the format (or
        None), "simulator_m": the simulator's ``realistic`` offsets of the format by part (or None), "notes"}``.
    """
    from mocapgraph.body.definition_priors import FITTED_OFFSETS_M
    from mocapgraph.data_tools.sim.detectors import KEYPOINT_DEFINITION_OFFSETS_M

    directory = clip_directory(clip)
    left_free = {name.strip() for name in free.split(",") if name.strip()}
    lab = {c.name: c.world_T_camera for c in lab_calibration(directory) if c.name not in left_free}
    with tempfile.TemporaryDirectory(prefix="mocapgraph-fit-offsets-") as tmp:
        path, _ = clip_capture(directory, Path(tmp) / "capture", person, "calibrated")
        capture = load_capture(path)
        # every component measured, the hips' up and forward too: with three cameras held at the
        # lab's calibration the world is theirs, and the committed tables were made so
        options = SmartmocapOptions(covariances=False, offset_prior="zero", offset_rounds=rounds, hold_root_offsets=False)
        result = run_smartmocap(capture, options, held_cameras={name: T for name, T in lab.items() if any(c.name == name for c in capture.cameras)})
    fmt = result.keypoint_format
    fitted = result.parameters["keypoint_offsets_m"].get(fmt, {})
    return {
        "clip": str(directory), "format": fmt, "person": person, "rounds": rounds, "held": sorted(lab),
        "offsets_m": {name: value for name, value in fitted.items() if not name.startswith("right_")},
        "reprojection_px": result.parameters["reprojection_px"], "committed_m": FITTED_OFFSETS_M.get(fmt),
        "simulator_m": KEYPOINT_DEFINITION_OFFSETS_M.get(fmt), "notes": list(result.parameters["notes"]),
    }  # fmt: skip


# ---------------------------------------------------------------------------------------------
# What the command prints


_ROWS = (
    ("camera_cm", "cameras, similarity (cm)"),
    ("camera_deg", "cameras, similarity (deg)"),
    ("rigid_cm", "cameras, rigid only (cm)"),
    ("scale_error_pct", "size error (%)"),
    ("ground_tilt_deg", "ground tilt (deg)"),
    ("reprojection_px", "reprojection, reported (px)"),
    ("reprojection_px_of_result", "reprojection, result (px)"),
    ("reprojection_px_body_points", "reprojection, body's points"),
    ("joint_motion_cm", "body's joint motion (cm)"),
    ("swaps_per_camera", "frames relabelled"),
    ("focal_px", "focal length (px)"),
    ("seconds", "run time (s)"),
)


def _cell(value, digits: int = 1) -> str:
    if value is None:
        return "-"
    if isinstance(value, dict):
        return "/".join(_cell(v, 0) for v in value.values())
    return f"{value:.{digits}f}" if isinstance(value, float) else str(value)


def _met(goal: dict) -> str:
    return {True: "met", False: "not met", None: "not measured"}[goal["met"]]


def _person_lines(person: dict, columns: list[tuple[str, str]], width: int) -> list[str]:
    rank = person["rank"]["calibrated"]
    label = f"the default choice (largest) of {person['people_seen']} people seen" if person["person"] == "largest" else f"rank {person['person']}"
    lines = ["", f"person {rank}: {label}"]
    checks = person["association"]
    same = checks["guessed"]["tracks"] == checks["calibrated"]["tracks"]
    for intrinsics in ("calibrated",) if same else INTRINSICS:
        check = checks[intrinsics]
        used = "with calibrated and with guessed intrinsics" if same else f"with {intrinsics} intrinsics"
        tracks = ", ".join(f"{c} {'+'.join(map(str, t))}" for c, t in check["tracks"].items())
        distances = ", ".join(f"{c} {_cell(v['chosen_px'], 0)}/{_cell(v['nearest_other_px'], 0)}" for c, v in check["cameras"].items())
        lines.append(f"  tracks {tracks} {used}: the same person in every camera: {'yes' if check['same_person'] else 'NO'}")
        lines.append(f"    (px from the lab's triangulation by the other cameras to this track / the nearest other: {distances})")
    lines.append("  " + " " * 29 + "".join(f"{f'{p} {i}':>{width}}" for p, i in columns) + "   goal")
    for key, title in _ROWS:
        goal = person["goals"].get(key)
        note = "" if goal is None else f"   smartmocap <= baseline (calibrated): {_met(goal)}"
        lines.append(f"  {title:29s}" + "".join(f"{_cell(person['runs'][p][i].get(key, 'failed')):>{width}}" for p, i in columns) + note)
    g = person["goals"]["guessed_camera_cm"]
    lines.append(f"  goal: {g['goal']}: {_cell(g['smartmocap'])} cm against {_cell(g['limit'])} cm: {_met(g)}")
    lines += [f"  {p} {i} failed: {person['runs'][p][i]['error']}" for p, i in columns if "error" in person["runs"][p][i]]
    for split, held in person.get("heldout", {}).items():
        lines += _heldout_lines(split, held, person["goals"].get(f"heldout_px_{split}"))
    return lines


_HELDOUT_ROWS = (
    ("in_sample_px", "reprojection, kept views (px)"),
    ("heldout_px", "reprojection, hidden views (px)"),
    ("heldout_px_as_detected", "  the same, labels as detected"),
    ("heldout_px_own", "  every point it predicts"),
    ("unpredicted", "  detections not predicted"),
    ("heldout_px_per_camera", "  per camera (px)"),
)


def _heldout_lines(split: str, heldout: dict, goal: dict | None) -> list[str]:
    hidden = ", ".join(f"{c} {n}" for c, n in heldout["hidden_per_camera"].items())
    runs = "single frames" if heldout["run_frames"] == 1 else f"runs of {heldout['run_frames']} frames"
    lines = [
        f"  held out ({split}): {100 * heldout['share']:g} % of the camera-frames hidden from both pipelines, {runs} "
        f"(seed {heldout['seed']}: {hidden}), lab intrinsics;",
        f"    {heldout.get('views', 0)} hidden views, {heldout.get('detections', 0)} detections of the body's points (confidence >= {heldout.get('min_confidence', 0):g}), "
        f"{heldout.get('common', 0)} predicted by every pipeline that ran" + ("" if heldout.get("same_tracks_as_full_run", True) else "; NOT the full run's tracks"),
        "  " + " " * 31 + "".join(f"{p:>12}" for p in PIPELINES),
    ]
    for key, title in _HELDOUT_ROWS:
        note = f"   smartmocap <= baseline: {_met(goal)}" if key == "heldout_px" and goal is not None else ""
        lines.append(f"  {title:31s}" + "".join(f"{_cell(heldout.get(p, {}).get(key, 'failed')):>12}" for p in PIPELINES) + note)
    for name, ref in heldout.get("references", {}).items():
        lines.append(f"  reference {name} (free points, the lab's cameras; not compared): kept views {_cell(ref['in_sample_px'])} px, hidden {_cell(ref['heldout_px_own'])} px, {ref['unpredicted']} not predicted")
    if "difference_px" in heldout:
        d = heldout["difference_px"]
        lines.append(f"  {d['of']}: {d['median']:+.2f} px (95 % over resampled hidden views: {d['interval_95'][0]:+.2f} to {d['interval_95'][1]:+.2f})")
    lines += [f"  {p} failed on the kept views: {message}" for p, message in heldout["errors"].items()]
    return lines


def format_report(report: dict) -> str:
    """The benchmark as tables for a terminal: per person, metrics by pipeline and intrinsics."""
    cams = report["cameras"]
    columns = [(p, i) for p in PIPELINES for i in INTRINSICS]
    cells = [_cell(person["runs"][p][i].get(key, "failed")) for person in report["people"] for p, i in columns for key, _ in _ROWS]
    width = max(len(f"{p} {i}") for p, i in columns) + 2
    width = max(width, *(len(c) + 2 for c in cells))
    lines = [
        f"real clip {report['clip']}: {len(cams)} cameras ({', '.join(cams)}), {report['frames']} frames; "
        f"lab focal lengths {_cell(report['lab_focal_px'])} px; values per camera in that order"
    ]
    for person in report["people"]:
        lines += _person_lines(person, columns, width)
    return "\n".join(lines)
