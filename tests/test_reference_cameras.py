"""A reference reconstruction's camera tracks as SmartMocap's input (``run smartmocap --cameras-from colmap``)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.data_tools.evaluation.alignment import Similarity
from mocapgraph.data_tools.evaluation.colmap_reference import ColmapReference, ReferenceError, write_reference
from mocapgraph.data_tools.io.capture import load_capture, write_capture
from mocapgraph.data_tools.sim.scenarios import look_at
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.graphs.state_model import Estimate
from mocapgraph.pipelines.observations import capture_state_model
from mocapgraph.pipelines.reference_cameras import load_camera_reference, reference_similarities, reference_tracks

# COLMAP-like worlds: rotated, shifted, scaled; the reference is the truth seen from one of them.
WORLD_A = Similarity(0.37, rotvec_to_matrix(np.array([0.3, -1.1, 0.5])), np.array([2.0, -1.0, 0.4]))
WORLD_B = Similarity(2.6, rotvec_to_matrix(np.array([-2.0, 0.4, 0.9])), np.array([-3.0, 0.5, 7.0]))


def _inverse(S: Similarity) -> Similarity:
    return Similarity(1 / S.scale, S.R.T, -S.R.T @ S.t / S.scale)


def _walk(frames: int, start, step, target) -> np.ndarray:
    """``(frames, 4, 4)`` a camera walking by ``step`` per frame while looking at ``target``."""
    return np.stack([look_at(np.asarray(start) + k * np.asarray(step), target) for k in range(frames)])


def test_reference_similarities_undo_hand_made_ones_per_colmap_model():
    frames = 12
    truth = {
        "tripod": np.repeat(look_at([6.0, 1.0, 1.4], [0.0, 0.0, 1.0])[None], frames, axis=0),
        "walk1": _walk(frames, [-4.0, -3.0, 1.5], [0.03, 0.01, 0.002], [0.0, 0.0, 1.0]),
        "walk2": _walk(frames, [3.0, -4.0, 1.3], [-0.05, 0.07, -0.004], [0.0, 0.0, 1.0]),
    }
    groups = {"tripod": 0, "walk1": 0, "walk2": 1}
    reference = {n: (WORLD_A if groups[n] == 0 else WORLD_B).apply_pose(p) for n, p in truth.items()}
    reference["walk1"][[2, 5]] = np.nan  # not registered
    solved = {n: p.copy() for n, p in truth.items()}
    solved["walk2"][:3] = np.nan  # not estimated
    found = reference_similarities(reference, solved, groups)
    assert set(found) == {0, 1}
    for g, world in ((0, WORLD_A), (1, WORLD_B)):
        want = _inverse(world)
        assert found[g].scale == pytest.approx(want.scale, rel=1e-12)
        np.testing.assert_allclose(found[g].R, want.R, atol=1e-12)
        np.testing.assert_allclose(found[g].t, want.t, atol=1e-9)
    # a model of one static camera has no spread to scale by, a short track too little: left out, not guessed
    assert reference_similarities({"tripod": reference["tripod"]}, solved, {"tripod": 0}) == {}
    assert reference_similarities({"walk2": reference["walk2"][:4]}, {"walk2": solved["walk2"][:4]}, {"walk2": 1}) == {}


def _capture_and_model(tmp_path):
    capture = synthesize("phones", seed=0, duration_s=0.6)
    path = write_capture(capture, tmp_path / "cap")
    capture = load_capture(path)
    return capture, capture_state_model(capture, "closest")


def test_reference_tracks_scale_the_motion_into_metres_and_start_the_solve_there(tmp_path):
    capture, model = _capture_and_model(tmp_path)
    truth = capture.ground_truth.cameras
    names = model.names
    reference_cameras = {n: WORLD_A.apply_pose(truth[n]) for n in names}
    walk = next(c for c, cam in enumerate(model.cameras) if cam.moving)
    frames = model.camera_frames(walk)
    unregistered = frames[[1, 4]]
    reference_cameras[names[walk]][unregistered] = np.nan
    stats = {"cameras": {n: {"model": 0} for n in names}}
    reference = ColmapReference("colmap", reference_cameras, {n: np.ones(len(p), bool) for n, p in reference_cameras.items()},
                                np.zeros((0, 3)), np.zeros(0), np.zeros(0), stats)  # fmt: skip
    # A first solution in the truth's world, the walking camera's track bent 5 cm off somewhere.
    body = Estimate(np.repeat(np.eye(4)[None], model.num_states, 0), np.zeros((model.num_states, 21, 3)), np.zeros(6), [truth[n].copy() for n in names])
    bent = body.cameras[walk]
    bent[frames[len(frames) // 2 :], 0, 3] += 0.05
    tracks, notes = reference_tracks(reference, model, body, (0.01, 0.01))
    registered = np.setdiff1d(frames, unregistered)
    np.testing.assert_array_equal(tracks.frames[walk], registered)
    assert any(f"camera {names[walk]}: {len(registered)} of its {len(frames)} frames from the reference 'colmap'" in n for n in notes)
    # The similarity is fitted on the bent solution, so the poses are near the truth, not on it;
    # the motion between registered frames, what the priors hold, is the truth's in metres
    # whatever that similarity's rotation and translation (its scale is within a per cent).
    mapped = tracks.poses[walk]
    moved = np.linalg.norm(mapped[:, :3, 3] - truth[names[walk]][registered, :3, 3], axis=1)
    assert moved.max() < 0.1
    for a in range(len(registered) - 1):
        want = np.linalg.inv(truth[names[walk]][registered[a]]) @ truth[names[walk]][registered[a + 1]]
        got = np.linalg.inv(mapped[a]) @ mapped[a + 1]
        np.testing.assert_allclose(got[:3, :3], want[:3, :3], atol=1e-9)
        np.testing.assert_allclose(got[:3, 3], want[:3, 3], rtol=0.01, atol=1e-6)
    # The priors (both carried phones): zero error at the started tracks, one per consecutive pair.
    graph = gtsam.NonlinearFactorGraph()
    moving = [c for c, cam in enumerate(model.cameras) if cam.moving]
    assert sorted(tracks.frames) == moving and len(moving) == 2
    assert tracks.add_to(graph, model) == sum(len(f) - 1 for f in tracks.frames.values())
    started = tracks.started(body, model)
    values = gtsam.Values()
    for c in moving:
        for j in model.camera_frames(c):
            values.insert(model.camera_var(c, j), gtsam.Pose3(started.cameras[c][j]))
    assert graph.error(values) < 1e-12
    # An unregistered frame moved with its nearest registered neighbour (rigidly).
    j, n = unregistered[0], registered[np.argmin(np.abs(registered - unregistered[0]))]
    np.testing.assert_allclose(started.cameras[walk][j], started.cameras[walk][n] @ np.linalg.inv(body.cameras[walk][n]) @ body.cameras[walk][j], atol=1e-12)


def test_reference_clock_offsets_find_each_phone_log_clock_on_the_reference_turns(tmp_path):
    """The carried phones' logs are 10-30 ms off their cameras' clocks (the simulator's truth);
    the reference is the truth in a COLMAP-like world, every third frame registered and each
    turned by up to 0.03° (COLMAP's error on bench colmap's walk)."""
    from mocapgraph.pipelines.observations import camera_imus
    from mocapgraph.pipelines.reference_cameras import reference_clock_offsets, reference_rotation_cost

    capture = load_capture(write_capture(synthesize("phones", seed=0, duration_s=1.5), tmp_path / "cap"))
    model = capture_state_model(capture, "closest")
    imus, _ = camera_imus(capture)
    truth = capture.metadata["imu_time_offsets_s"]
    assert sorted(model.names[c] for c in imus) == sorted(truth) and min(abs(o) for o in truth.values()) > 0.005
    rng = np.random.default_rng(4)
    cameras = {}
    for c, name in enumerate(model.names):
        poses = WORLD_A.apply_pose(capture.ground_truth.cameras[name])
        poses[:, :3, :3] = poses[:, :3, :3] @ rotvec_to_matrix(rng.normal(0.0, np.radians(0.03) / np.sqrt(3), (len(poses), 3)))
        poses[np.arange(len(poses)) % 3 != 0] = np.nan
        cameras[name] = poses
    reference = ColmapReference("colmap", cameras, {n: np.ones(len(p), bool) for n, p in cameras.items()}, np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    found = reference_clock_offsets(reference, model, imus, 0.05, 0.001)
    assert sorted(found) == sorted(imus)
    for c, offset in found.items():
        assert offset == pytest.approx(truth[model.names[c]], abs=0.001), (model.names[c], offset, truth)
    # the cost it minimises is the gyroscope against the reference: least at the truth, not at zero
    c = next(iter(imus))
    name = model.names[c]
    frames = model.camera_frames(c)[np.isfinite(cameras[name][model.camera_frames(c), 0, 0])][4:14]
    times, poses = model.cameras[c].timestamps[frames], cameras[name][frames]
    assert reference_rotation_cost(imus[c], truth[name], times, poses, 0.001) < 0.1 * reference_rotation_cost(imus[c], 0.0, times, poses, 0.001)
    # a camera the reference registered on one frame only, or not at all, is left out
    cameras[name][3:] = np.nan
    del cameras[model.names[next(k for k in imus if k != c)]]
    assert reference_clock_offsets(reference, model, imus, 0.05, 0.001) == {}


def test_a_missing_or_foreign_reference_gives_one_clear_error(tmp_path, capsys):
    from mocapgraph.cli.main import main

    capture, _ = _capture_and_model(tmp_path)
    assert main(["run", "smartmocap", str(capture.path), "--out", str(tmp_path / "res"), "--cameras-from", "colmap"]) == 2
    assert "has no reference 'colmap' (it has: none; make one with `mocapgraph colmap" in capsys.readouterr().err
    foreign = {"cam_elsewhere": np.repeat(np.eye(4)[None], 3, 0)}
    write_reference(ColmapReference("other", foreign, {"cam_elsewhere": np.ones(3, bool)}, np.zeros((0, 3)), np.zeros(0), np.zeros(0)), capture.path)
    with pytest.raises(ReferenceError, match="cameras cam_elsewhere are not in the capture"):
        load_camera_reference(capture, "colmap", "other")
    assert main(["run", "smartmocap", str(capture.path), "--out", str(tmp_path / "res"), "--cameras-from", "colmap", "--reference", "other"]) == 2
    assert "cameras cam_elsewhere are not in the capture" in capsys.readouterr().err
    assert not (tmp_path / "res").exists()


@pytest.mark.slow  # 2-3 min: rendering, COLMAP and two SmartMocap runs; the alignment, the priors and the errors have fast tests above
def test_cameras_from_colmap_end_to_end_on_a_rendered_capture(tmp_path):
    """2 s of phones at 960x540 with the tripod and the walking phone that register together
    (``bench colmap``'s capture; in 1 s the phone's track spreads too little for a scale): COLMAP,
    then SmartMocap with and without its tracks; the walking phone's track against the truth."""
    pytest.importorskip("pycolmap")
    from test_colmap import _rendered

    from mocapgraph.cli.main import main
    from mocapgraph.data_tools.evaluation.colmap_reference import ColmapOptions, reconstruct
    from mocapgraph.data_tools.evaluation.reference_eval import compare_tracks, tracks_at_frames
    from mocapgraph.data_tools.io.result import load_result

    capture = _rendered(tmp_path, "phones", 1, 2.0, 0.5, ("phone_static2", "phone_walk1"))
    reference = reconstruct(capture, options=ColmapOptions(frame_step=3))
    write_reference(reference, capture.path)
    registered = int(reference.registered("phone_walk1").sum())
    assert registered >= 19 and reference.groups()["phone_static2"] == 0, reference.failures
    # the tripod's own frames give COLMAP no baseline, the walking phone's do (what `colmap` says of a camera registered nowhere)
    cams = reference.stats["cameras"]
    assert cams["phone_static2"]["own_parallax"] == 0 < cams["phone_walk1"]["own_parallax"] and cams["phone_walk1"]["cross_inliers"] >= 50, cams
    moving = {c.name: c.moving for c in capture.cameras}
    errors = {}
    for label, extra in (("own", []), ("colmap", ["--cameras-from", "colmap"])):
        assert main(["run", "smartmocap", str(capture.path), "--out", str(tmp_path / label), "--no-covariances", *extra]) == 0
        result = load_result(tmp_path / label)
        errors[label] = compare_tracks(tracks_at_frames(result, capture), capture.ground_truth.cameras, moving)["phone_walk1"]
    notes = result.parameters["notes"]
    assert any(n.startswith(f"camera phone_walk1: {registered} of its 61 frames from the reference 'colmap'") for n in notes), "\n".join(notes)
    # The phone's IMU log is 18.5 ms off its camera's clock: found on COLMAP's turns (the body's
    # views of this capture found -0.7 ms, and the gyroscope, so shifted, turned the track 0.4°
    # per 0.1 s away from COLMAP's: 0.97° after Procrustes with the reference as without it).
    assert result.parameters["imu_clock_offsets_s"]["phone_walk1"] == pytest.approx(capture.metadata["imu_time_offsets_s"]["phone_walk1"], abs=0.002)
    # COLMAP's track of this walk is within 0.5 cm of the truth after Procrustes (bench colmap:
    # 0.2 cm): held by it, SmartMocap's is within 1.5 cm and 2° on all 61 frames, the two in
    # between each registered pair held by the IMU and smoothness alone (measured 0.30 cm, 0.33°,
    # against 12.5 cm, 0.97° on its own with these two cameras: its gyroscope alone already
    # keeps its turns within about 1° after the track's own Procrustes).
    assert errors["colmap"].mcpe_m < 0.015 and errors["colmap"].mcoe_deg < 2.0, errors
    assert errors["colmap"].mcpe_m < 0.5 * errors["own"].mcpe_m and errors["colmap"].mcoe_deg < 0.5 * errors["own"].mcoe_deg, errors
