"""Self-calibration on the real clip (``tests/data/real``: four static cameras, two people) against
the lab's Qualisys calibration, for SmartMocap and the generic uncalibrated baseline, with the
measures of ``mocapgraph bench real`` (:mod:`mocapgraph.benchmarks.real`).

The bounds sit above the numbers measured (given in each test) with room for the solvers'
run-to-run changes, and below what a wrong answer gives (a camera placed on the wrong side of
the room is metres off; a mixed-up person hundreds of pixels).
"""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from real_clip import BODY25B_CLIP, clip_capture

from mocapgraph.benchmarks import real
from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import SWAP_KINDS, swap_permutation
from mocapgraph.cli.main import main
from mocapgraph.data_tools.geometry.camera_model import project_points, undistort_pixels
from mocapgraph.data_tools.geometry.triangulation import projection_matrix, triangulate_points, triangulate_ransac
from mocapgraph.data_tools.io.capture import load_capture
from mocapgraph.data_tools.tracking.track_files import load_track_set, save_track_set
from mocapgraph.errors import MocapgraphError


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """The default person's capture and choice, with the lab's intrinsics and with guessed ones."""
    out = {}
    for intrinsics in real.INTRINSICS:
        path, choice = clip_capture(tmp_path_factory.mktemp(intrinsics) / "capture", "largest", intrinsics)
        out[intrinsics] = (load_capture(path), choice)
    return out


@pytest.fixture(scope="module")
def measured(captures, lab):
    """``measured(pipeline, intrinsics)``: the bench's numbers of one run, each run made once."""
    done = {}

    def run(pipeline: str, intrinsics: str) -> dict:
        if (pipeline, intrinsics) not in done:
            capture = captures[intrinsics][0]
            result, seconds = real.run_pipeline(pipeline, capture)
            done[pipeline, intrinsics] = real.measure(result, seconds, capture, lab) | {"result": result}
        return done[pipeline, intrinsics]

    return run


def test_the_lab_world_stands_on_its_floor(clip, lab):
    """The ground tilt is measured against the lab's Z: its floor is z = 0. The cameras hang
    1.69-2.09 m up, looking down, and the heels of the person standing beside the treadmill
    (rank 1) triangulate 1-3 cm above z = 0 (measured: median 1.7 cm)."""
    heights = np.array([lab[c].world_T_camera[2, 3] for c in clip.cameras])
    assert np.all((heights > 1.6) & (heights < 2.2)), heights
    assert all(lab[c].world_T_camera[2, 2] < -0.2 for c in clip.cameras)  # optical axes point down
    standing = {"cam01": 0, "cam02": 0, "cam03": 1, "cam04": 0}  # rank 1's tracks (test_the_fitted_person_...)
    names = get_format(clip.keypoint_format).names
    heels = [names.index("left_heel"), names.index("right_heel")]
    P = np.stack([projection_matrix(lab[c].K, lab[c].world_T_camera) for c in clip.cameras])
    x, w = [], []
    for c in clip.cameras:
        kp = clip.tracks[c].keypoints[standing[c]][:, heels]
        x.append(undistort_pixels(kp[..., :2], lab[c].K, lab[c].distortion))
        w.append(np.where(kp[..., 2] >= 0.5, kp[..., 2], 0.0))
    x, w = np.stack(x), np.nan_to_num(np.stack(w))
    z = np.concatenate([triangulate_ransac(P, x[:, t], w[:, t], threshold_px=20.0)[0][:, 2] for t in range(x.shape[1])])
    assert np.isfinite(z).sum() > 100
    assert 0.0 < np.nanmedian(z) < 0.04 and np.nanpercentile(z, 10) > -0.03


def test_the_fitted_person_is_the_same_in_every_camera(clip, lab, captures):
    """With guessed intrinsics (37 % off) the default rule fits the same tracks as with the lab's,
    and the lab's calibration says they are one person: the other cameras' triangulation of
    their left/right midpoints lands 18-41 px from the chosen track in each camera, 242-472 px
    from the other person's (measured). Putting the other person's track into one camera is caught."""
    guessed, calibrated = captures["guessed"][1], captures["calibrated"][1]
    assert guessed.person.tracks == calibrated.person.tracks
    check = real.same_person_check(clip, lab, guessed)
    assert check["same_person"], check
    for cam, v in check["cameras"].items():
        assert v["chosen_px"] < 60.0 and v["nearest_other_px"] > 150.0, (cam, v)

    cam = "cam03"
    (own,) = guessed.person.tracks[cam]
    other = 1 - own
    mixed = replace(
        guessed,
        people=[replace(p, tracks={**p.tracks, cam: (other,)}) if k == guessed.chosen else p for k, p in enumerate(guessed.people)],
        keypoints={**guessed.keypoints, cam: clip.tracks[cam].keypoints[other]},
    )
    wrong = real.same_person_check(clip, lab, mixed)
    assert not wrong["same_person"]
    assert wrong["cameras"][cam]["chosen_px"] > wrong["cameras"][cam]["nearest_other_px"]


def test_baseline_on_the_real_clip(measured, captures):
    """The generic baseline with the lab's intrinsics: cameras 4.9 cm and 2.2 deg off after a
    similarity (measured); its size from an assumed 1.75 m height 18 % too large for this person,
    so 58 cm off without the scale. The reprojection medians computed from its result by the
    bench agree with the ones it reports (3.9/4.7/13.6/3.7 px)."""
    row = measured("baseline", "calibrated")
    assert row["cameras_estimated"] == 4
    assert row["camera_cm"] < 8.0 and row["camera_deg"] < 3.5, row
    assert 8.0 < row["scale_error_pct"] < 30.0 and row["rigid_cm"] > 30.0, row
    assert row["ground_tilt_deg"] < 10.0
    computed = real.reprojection_px(row["result"], captures["calibrated"][0])
    assert computed["all"] == pytest.approx(row["reprojection_px"], abs=0.1)
    for cam, px in row["reprojection_px_per_camera"].items():
        assert computed["camera"][cam] == pytest.approx(px, abs=0.1), cam


@pytest.mark.slow  # 45-65 s on two shared cores
def test_smartmocap_on_the_real_clip(measured):
    """SmartMocap (defaults) with the lab's intrinsics: cameras 3.9 cm and 1.5 deg off after a
    similarity, 18 cm with rigid alignment alone, its size 5 % small, the ground 4.9 deg tilted
    (measured; the baseline's 4.9 cm, 2.2 deg, 58 cm, 18 % too large, 6.2 deg): at or below the
    generic baseline on every camera measure (the issue's goal). Metric without being told the
    person's height: nearer the lab's scale, and with the rigid alignment, than the baseline with
    its assumed height. Reprojection 7.1 px as the pipeline reports it (with its keypoint offsets
    and their drift per state, refined in the images, over every view, the ones left out of the
    last pass too; 7.2 px with the drift of the samples alone, 8.7 px without the drift), the same from the result's keypoints (they carry both), against the
    baseline's 4.8 px on the same points (measured)."""
    sm, bl = measured("smartmocap", "calibrated"), measured("baseline", "calibrated")
    assert sm["cameras_estimated"] == 4
    assert sm["camera_cm"] < 10.0 and sm["camera_deg"] < 3.5, sm
    assert abs(sm["scale_error_pct"]) < 12.0 and sm["ground_tilt_deg"] < 8.0, sm
    assert abs(sm["scale_error_pct"]) < abs(bl["scale_error_pct"]) and sm["rigid_cm"] < bl["rigid_cm"]
    assert sm["camera_cm"] <= bl["camera_cm"] and sm["camera_deg"] <= bl["camera_deg"], (sm["camera_cm"], bl["camera_cm"])  # 3.85 / 4.87 cm
    assert sm["ground_tilt_deg"] <= bl["ground_tilt_deg"]
    assert any("static cameras adjusted on" in note for note in sm["notes"])
    assert sm["reprojection_from"] == "pipeline" and sm["reprojection_px"] < 8.0 and sm["reprojection_px_of_result"] < 8.0
    assert set(sm["reprojection_px_per_keypoint"]) >= {"left_hip", "right_foot_index"}
    assert sm["reprojection_px_body_points"] == pytest.approx(sm["reprojection_px_of_result"], abs=0.01)  # a body result: only its points anyway


@pytest.mark.slow  # 55-60 s on the idle machine: a SmartMocap run on the clip with every pass
def test_guessed_intrinsics_on_the_real_clip(measured, lab):
    """With guessed intrinsics (f = 2304 px for all four; the lab's 1674-1682 px), SmartMocap
    frees one focal length shared by the four cameras guessed alike: 1631 px (2.6-3.0 % off,
    measured), the cameras 3.6 cm off after a similarity (the calibrated run's 3.9 cm; goal 2x),
    far within the baseline's 32 cm, which keeps the guess."""
    sm, bl = measured("smartmocap", "guessed"), measured("baseline", "guessed")
    assert sorted(sm["focal_estimated"]) == sorted(lab)
    for cam, f in sm["focal_px"].items():
        assert abs(f - lab[cam].K[0, 0]) < abs(2304.0 - lab[cam].K[0, 0]), (cam, f)
    assert len(set(sm["focal_px"].values())) == 1 and np.max(np.abs(list(sm["focal_error_pct"].values()))) < 5.0, sm["focal_px"]
    assert sm["camera_cm"] < 2.0 * measured("smartmocap", "calibrated")["camera_cm"] and sm["camera_cm"] < bl["camera_cm"], sm["camera_cm"]


def _elbow_angles_deg(points: np.ndarray, names) -> np.ndarray:
    """``(T, K, 3)`` keypoints → ``(T, 2)`` left and right elbow angles (180 = straight arm)."""
    out = []
    for side in ("left", "right"):
        s, e, w = (points[:, names.index(f"{side}_{p}")] for p in ("shoulder", "elbow", "wrist"))
        u, v = s - e, w - e
        cos = np.sum(u * v, axis=-1) / (np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1))
        out.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.stack(out, axis=-1)


@pytest.fixture(scope="module")
def second_person(tmp_path_factory):
    """The clip's second person (rank 1, beside the treadmill) with the lab's intrinsics: the
    capture, the choice and SmartMocap's result with its defaults (45-90 s)."""
    path, choice = clip_capture(tmp_path_factory.mktemp("second") / "capture", 1, "calibrated")
    capture = load_capture(path)
    result, _ = real.run_pipeline("smartmocap", capture)
    return capture, choice, result


@pytest.mark.slow  # 45-90 s: a SmartMocap run on the clip's second person
def test_bent_arms_are_fitted_on_the_real_clip(clip, lab, second_person):
    """The person beside the treadmill (rank 1, no swaps) bends the elbows to 90-120 deg (the
    lab's triangulation). A fit that frees the pose from the mean body's straight arms under the
    robust kernel alone left them at 170-176 deg, the wrists 34 and 67 px off (measured); the
    chunks now anneal from L2 when the pose is freed: wrists 5 and 11 px, elbows within a few
    degrees where they bend most (measured)."""
    _, choice, result = second_person
    names = get_format(clip.keypoint_format).names
    P = np.stack([projection_matrix(lab[c].K, lab[c].world_T_camera) for c in clip.cameras])
    x, w = [], []
    for c in clip.cameras:
        (track,) = choice.person.tracks[c]
        kp = clip.tracks[c].keypoints[track]
        x.append(undistort_pixels(kp[..., :2], lab[c].K, lab[c].distortion))
        w.append(np.where(kp[..., 2] >= 0.5, kp[..., 2], 0.0))
    x, w = np.stack(x), np.nan_to_num(np.stack(w))
    frames = np.rint(result.timestamps * clip.fps[clip.cameras[0]]).astype(int)  # the video's frame times
    assert frames.min() >= 0 and frames.max() < x.shape[1]
    triangulated = np.stack([triangulate_ransac(P, x[:, t], w[:, t], threshold_px=20.0)[0] for t in frames])
    truth, fitted = _elbow_angles_deg(triangulated, names), _elbow_angles_deg(result.keypoints, names)
    bent = np.isfinite(truth) & (truth < 120.0)
    assert bent.sum() >= 10, bent.sum()
    assert np.median(np.abs(fitted - truth)[bent]) < 25.0, (np.round(truth[bent]), np.round(fitted[bent]))
    wrists = result.parameters["reprojection_px"]["keypoint"][clip.keypoint_format]
    assert wrists["left_wrist"] < 15.0 and wrists["right_wrist"] < 20.0, wrists


def _labellings_the_lab_shows(clip, lab, choice) -> np.ndarray:
    """Which labelling of each camera's detections the lab's calibration shows: ``(C, H, T)`` per
    camera, swap kind (``SWAP_KINDS``) and frame, how much farther (px, median over the points the
    kind moves) the detections so relabelled lie than as detected from where the other three
    cameras' triangulation (as detected, the lab's poses) projects: positive where the labels as
    detected are the lab's, NaN where the camera does not see those points (``H = 0``: zeros)."""
    names = get_format(clip.keypoint_format).names
    perms = np.stack([swap_permutation(names, kind) for kind in SWAP_KINDS])
    x, w = {}, {}
    for c in clip.cameras:
        kp = choice.keypoints[c]
        x[c] = undistort_pixels(kp[..., :2], lab[c].K, lab[c].distortion)
        w[c] = np.where(np.nan_to_num(kp[..., 2]) >= 0.5, kp[..., 2], 0.0)
    T = min(len(v) for v in x.values())
    out = np.zeros((len(clip.cameras), len(perms), T))
    for i, c in enumerate(clip.cameras):
        others = [o for o in clip.cameras if o != c]
        P = np.stack([projection_matrix(lab[o].K, lab[o].world_T_camera) for o in others])
        X = triangulate_points(P, np.stack([x[o][:T] for o in others]).reshape(len(others), -1, 2), np.stack([w[o][:T] for o in others]).reshape(len(others), -1))
        predicted, _ = project_points(X.reshape(T, -1, 3), lab[c].world_T_camera, lab[c].K)

        def distance(perm: np.ndarray, moved: np.ndarray) -> np.ndarray:
            d = np.linalg.norm(x[c][:T, perm][:, moved] - predicted[:, moved], axis=-1)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # frames the camera does not see
                return np.nanmedian(np.where(w[c][:T, perm][:, moved] > 0, d, np.nan), axis=1)

        for h in range(1, len(perms)):
            moved = np.flatnonzero(perms[h] != perms[0])
            out[i, h] = distance(perms[h], moved) - distance(perms[0], moved)
    return out


@pytest.mark.slow  # the SmartMocap run of the second person's fixture
def test_the_second_persons_labels_are_the_ones_the_lab_shows(clip, lab, second_person):
    """Which labelling of the second person's detections is right, the lab's calibration shows:
    each camera's detections against the other three cameras' triangulation. On frames 3-24 the
    legs as detected sit nearer it than the legs swapped in every camera, by 64-97 px in cam01,
    cam02 and cam04 and 37-46 px in cam03, whose lab pose disagrees with its detections (README;
    measured; the person stands with the feet 20 cm apart). With the definition prior
    fitted on the clip, the last pass (cameras held after their adjustment on free points)
    re-decided the labels from the body as it stood against the cameras before they moved, took
    the legs swapped in all four cameras on those frames and crossed the body's legs to follow
    (21-22 frames per camera, measured); it now keeps the labels the cameras were adjusted on.
    Every camera-frame the result relabels must be one the lab shows swapped of that kind."""
    _, choice, result = second_person
    margin = _labellings_the_lab_shows(clip, lab, choice)
    frames = np.arange(3, 25)
    legs = margin[:, SWAP_KINDS.index("legs"), frames]
    assert np.all(legs > 25.0), np.round(legs)
    relabelled = np.stack([result.cameras[c].swaps[: margin.shape[-1]] for c in clip.cameras])
    assert not np.any(relabelled[:, frames] > 0), relabelled[:, frames]
    for i, t in zip(*np.nonzero(relabelled > 0)):
        assert margin[i, relabelled[i, t], t] < 0.0, (clip.cameras[i], t, SWAP_KINDS[relabelled[i, t]], margin[i, :, t])


def test_the_clip_folder_must_hold_the_clip(tmp_path, monkeypatch, capsys):
    assert main(["bench", "real", "--clip", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err == f"mocapgraph: error: {tmp_path}: tracks.npz and Calib.qca.txt missing (a real clip is a folder with tracks.npz and Calib.qca.txt)\n"
    monkeypatch.setattr(real, "DEFAULT_CLIP", tmp_path / "tests" / "data" / "real")  # as in an installed wheel
    with pytest.raises(MocapgraphError, match="ships with the source repository .* pass --clip DIR"):
        real.bench_real()
    (tmp_path / real.TRACKS_FILE).write_bytes(b"not a zip")
    (tmp_path / real.CALIBRATION_FILE).write_text("<calibration/>")
    with pytest.raises(MocapgraphError, match="tracks.npz: not a readable .npz file"):
        real.bench_real(tmp_path)


def test_track_files_round_trip_and_errors(clip, tmp_path):
    path = save_track_set(clip, tmp_path / "tracks.npz")
    back = load_track_set(path)
    assert back.cameras == clip.cameras and back.sizes == clip.sizes and back.fps == clip.fps and back.keypoint_format == "blazepose33"
    for cam in clip.cameras:
        np.testing.assert_array_equal(back.tracks[cam].keypoints, clip.tracks[cam].keypoints)  # stored values are already compact
    arrays = dict(np.load(path))
    del arrays["tracks_cam02"]
    np.savez(tmp_path / "missing.npz", **arrays)
    with pytest.raises(MocapgraphError, match="missing.npz: tracks_cam02: missing"):
        load_track_set(tmp_path / "missing.npz")
    arrays = dict(np.load(path), tracks_cam02=clip.tracks["cam02"].keypoints[..., :17, :])
    np.savez(tmp_path / "coco.npz", **arrays)
    with pytest.raises(MocapgraphError, match=r"coco.npz: tracks_cam02: expected shape \(N, N, 33, 3\)"):
        load_track_set(tmp_path / "coco.npz")


@pytest.mark.slow  # one SmartMocap run on the clip, four offset rounds: 1.5-3 min on two shared cores
@pytest.mark.parametrize(
    "clip, fmt, points, absent",
    [(real.DEFAULT_CLIP, "blazepose33", {"left_hip", "right_hip", "left_heel", "right_foot_index", "nose"}, "left_pinky"),
     (BODY25B_CLIP, "openpose25b", {"left_hip", "right_hip", "left_heel", "right_big_toe", "nose"}, "head_top")],
)  # fmt: skip
def test_the_definitions_table_reproduces_from_the_clip(clip, fmt, points, absent):
    """``mocapgraph bench definitions`` (the cameras held at the lab's calibration, the offsets
    measured from zero) gives the committed table of the clip's format back to within 3 mm per
    component (the solvers' run-to-run change; the tables' largest entries are 1-3 cm), reports
    the reprojection of every body point, and says where the table came from."""
    from mocapgraph.body.definition_priors import FITTED_OFFSETS_M, PROVENANCE

    fit = real.fit_clip_offsets(clip)
    assert fit["format"] == fmt and fit["committed_m"] == FITTED_OFFSETS_M[fmt]
    assert set(fit["offsets_m"]) == set(FITTED_OFFSETS_M[fmt])
    for name, value in fit["offsets_m"].items():
        np.testing.assert_allclose(value, FITTED_OFFSETS_M[fmt][name], atol=0.003, err_msg=name)
    reprojected = fit["reprojection_px"]["keypoint"][fmt]
    assert points <= set(reprojected) and absent not in reprojected
    assert set(fit["reprojection_px"]["camera"]) == {"cam01", "cam02", "cam03", "cam04"}
    assert Path(clip).name in PROVENANCE[fmt]["clip"] and "bench definitions" in PROVENANCE[fmt]["command"]
