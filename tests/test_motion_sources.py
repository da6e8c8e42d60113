"""Motion sources: procedural motions walk, stand on the floor and face forward; sampling is
geodesic; shapes fitted to bone lengths; CMU takes (synthetic here, real ones when present)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_cmu_motion import write_take

from mocapgraph.body import load_body_model
from mocapgraph.body.rotations import matrix_to_rotvec, rotvec_to_matrix
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES, JOINT_NAMES
from mocapgraph.data_tools.sim.cmu_motion import motion_dir
from mocapgraph.data_tools.sim.motion_sources import (
    CMU_BONES,
    FOOT_KEYPOINTS,
    PROCEDURAL_KINDS,
    STRIDE_HZ,
    WALK_SPEED,
    Motion,
    bone_length_residuals,
    cmu_motion,
    fit_shape_to_bone_lengths,
    list_cmu_takes,
    procedural_motion,
)
from mocapgraph.errors import MocapgraphError

NOSE = BODY_KEYPOINT_NAMES.index("nose")


@pytest.fixture(scope="module")
def body():
    return load_body_model()


@pytest.fixture(scope="module")
def motions(body):
    durations = {"walk": 6.0, "turn": 8.0, "arms": 8.0, "zigzag_then_act": 12.0, "stand": 3.0}
    return {kind: procedural_motion(kind, durations[kind], seed=3, body=body) for kind in PROCEDURAL_KINDS}


def geodesic_angle(Ra, Rb):
    return np.linalg.norm(matrix_to_rotvec(np.swapaxes(Ra, -1, -2) @ Rb), axis=-1)


def rest_bone_lengths(body, shape):
    rest = body.rest_joints(shape)
    return {
        pair: float(np.linalg.norm(rest[JOINT_NAMES.index(pair[1])] - rest[JOINT_NAMES.index(pair[0])]))
        for pair in CMU_BONES
    }


# ---------------------------------------------------------------------------- procedural


def test_walk_speed_is_nominal(motions):
    m = motions["walk"]
    path = m.root[:, :2, 3]
    speed = np.linalg.norm(path[-1] - path[0]) / m.duration
    assert abs(speed - WALK_SPEED) < 0.1 * WALK_SPEED
    direction = (path[-1] - path[0]) / np.linalg.norm(path[-1] - path[0])
    assert direction @ [1.0, 0.0] > np.cos(np.deg2rad(5))  # straight along +X


@pytest.mark.parametrize("kind", PROCEDURAL_KINDS)
def test_feet_on_the_ground(motions, body, kind):
    m = motions[kind]
    feet = m.keypoints(body)[:, FOOT_KEYPOINTS, 2]
    lowest = feet.min(axis=1)
    assert np.all(np.abs(lowest) < 0.02), kind  # touching in every frame
    assert lowest.min() < 0.02 and feet.min() > -0.02
    assert m.root.shape == (m.num_frames, 4, 4) and m.pose.shape == (m.num_frames, 21, 3)
    # Upright: body +Y (up) is world +Z within the gait's small tilts.
    assert np.all(m.root[:, 2, 1] > np.cos(np.deg2rad(10)))


def test_standing_foot_does_not_slide(motions, body):
    m = motions["walk"]
    feet = m.keypoints(body)[:, FOOT_KEYPOINTS]
    lowest = np.argmin(feet[..., 2], axis=1)
    rows = np.arange(m.num_frames - 1)
    slide = np.linalg.norm(feet[rows + 1, lowest[:-1], :2] - feet[rows, lowest[:-1], :2], axis=-1) * m.fps
    assert np.median(slide) < 0.02  # m/s, against a walking speed of 1.3 m/s
    # The pelvis bobs a few centimetres.
    assert 0.01 < np.ptp(m.root[:, 2, 3]) < 0.08


@pytest.mark.parametrize("kind", ["walk", "turn", "zigzag_then_act"])
def test_body_faces_where_it_walks(motions, body, kind):
    m = motions[kind]
    k = int(round(0.5 * m.fps))  # velocity over a second: the gait's side sway averages out
    pelvis = m.root[:, :3, 3]
    velocity = (pelvis[2 * k :] - pelvis[: -2 * k]) / (2 * k / m.fps)
    moving = np.linalg.norm(velocity[:, :2], axis=1) > 0.5
    assert moving.sum() > 30
    nose = m.keypoints(body)[k:-k, NOSE] - pelvis[k:-k]
    ahead = np.sum(nose[:, :2] * velocity[:, :2], -1) / np.linalg.norm(velocity[:, :2], axis=-1)
    assert np.all(ahead[moving] > 0.05)
    forward = m.root[k:-k, :2, 2]  # body +Z in the world
    cos = np.sum(forward * velocity[:, :2], -1) / np.linalg.norm(velocity[:, :2], axis=-1)
    assert np.all(cos[moving] > np.cos(np.deg2rad(30)))


def test_gait_is_periodic(motions):
    m = motions["walk"]
    knee = np.linalg.norm(m.pose[:, JOINT_NAMES.index("left_knee") - 1], axis=-1)
    x = knee - knee.mean()
    ac = np.correlate(x, x, "full")[len(x) - 1 :] / (x @ x)
    period = m.fps / STRIDE_HZ
    lags = np.arange(int(0.8 * period), int(1.2 * period))
    best = lags[np.argmax(ac[lags])]
    assert ac[best] > 0.8 and abs(best - period) < 0.06 * period
    assert ac[int(round(period / 2))] < 0.0
    # Legs in antiphase: the right knee is the left one half a stride later.
    right = np.linalg.norm(m.pose[:, JOINT_NAMES.index("right_knee") - 1], axis=-1)
    half = int(round(period / 2))
    assert np.corrcoef(knee[half:], right[:-half])[0, 1] > 0.9
    assert np.corrcoef(knee, right)[0, 1] < 0.0


def test_arms_swing_against_the_legs(motions):
    m = motions["walk"]
    left_hip = m.pose[:, JOINT_NAMES.index("left_hip") - 1, 0]  # flexion is negative about x
    left_shoulder = m.pose[:, JOINT_NAMES.index("left_shoulder") - 1]
    arm_forward = np.einsum("tij,j->ti", rotvec_to_matrix(left_shoulder), [1.0, 0.0, 0.0])[:, 2]
    assert np.corrcoef(-left_hip, arm_forward)[0, 1] < -0.8


def test_same_seed_same_motion(body):
    a = procedural_motion("zigzag_then_act", 4.0, seed=7, body=body)
    b = procedural_motion("zigzag_then_act", 4.0, seed=7, body=body)
    c = procedural_motion("zigzag_then_act", 4.0, seed=8, body=body)
    for name in ("timestamps", "root", "pose", "shape"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert not np.allclose(a.root, c.root)
    assert not np.allclose(a.pose, c.pose)


def test_zigzag_then_act(motions, body):
    m = motions["zigzag_then_act"]
    t, path = m.timestamps, m.root[:, :2, 3]
    walk_end = 0.6 * m.duration
    # Direction of travel over each stride of the walking part: it swings from side to side.
    stride = int(round(m.fps / STRIDE_HZ))
    idx = np.arange(0, int(walk_end * m.fps) - stride, stride // 2)
    step = path[idx + stride] - path[idx]
    heading = np.unwrap(np.arctan2(step[:, 1], step[:, 0]))
    turns = np.diff(np.sign(heading - heading.mean()))
    assert np.count_nonzero(turns) >= 2
    assert np.ptp(heading) > np.deg2rad(40)
    assert np.linalg.norm(path[t <= walk_end][-1] - path[0]) > 3.0
    # Then it acts on the spot: arms raised above the shoulders, a turn, and the root stays put.
    act = t >= walk_end
    assert np.linalg.norm(path[act] - path[act][0], axis=1).max() < 0.5
    facing = m.root[act, :2, 2]
    turn = np.abs(np.unwrap(np.arctan2(facing[:, 1], facing[:, 0])))
    assert np.ptp(turn) > np.deg2rad(60)
    joints = m.joints(body)[act]
    wrists = joints[:, [JOINT_NAMES.index("left_wrist"), JOINT_NAMES.index("right_wrist")], 2].max(axis=1)
    assert np.any(wrists > joints[:, JOINT_NAMES.index("neck"), 2])
    assert m.info["actions"] and all(start >= walk_end for _, start, _ in m.info["actions"])


def test_turn_and_stand(motions):
    facing = motions["turn"].root[:, :2, 2]
    assert np.ptp(np.unwrap(np.arctan2(facing[:, 1], facing[:, 0]))) > np.pi
    stand = motions["stand"]
    assert np.linalg.norm(stand.root[:, :2, 3] - stand.root[0, :2, 3], axis=1).max() < 0.03
    assert np.abs(stand.pose).max() < 0.5 or np.ptp(stand.pose, axis=0).max() < 0.1


def test_procedural_needs_a_known_kind_and_positive_duration(body):
    with pytest.raises(MocapgraphError, match="unknown procedural motion 'jog'.*walk"):
        procedural_motion("jog", 2.0, body=body)
    with pytest.raises(MocapgraphError, match="duration must be positive"):
        procedural_motion("walk", 0.0, body=body)


def test_other_shapes_and_frame_rates(body):
    shape = body.default_shape.copy()
    shape[4] = 1.0  # tallest
    m = procedural_motion("walk", 2.0, fps=25.0, seed=1, body=body, shape=shape)
    assert m.num_frames == 51 and m.fps == 25.0 and np.allclose(np.diff(m.timestamps), 0.04)
    feet = m.keypoints(body)[:, FOOT_KEYPOINTS, 2].min(axis=1)
    assert np.abs(feet).max() < 0.02
    assert m.root[:, 2, 3].mean() > procedural_motion("walk", 2.0, seed=1, body=body).root[:, 2, 3].mean()


# ---------------------------------------------------------------------------- Motion


def test_sample_at_frames_and_midpoints(motions):
    m = motions["walk"]
    root, pose = m.sample(m.timestamps)
    assert np.array_equal(root, m.root) and np.array_equal(pose, m.pose)

    mid = 0.5 * (m.timestamps[:-1] + m.timestamps[1:])
    root, pose = m.sample(mid)
    assert np.allclose(root[:, :3, 3], 0.5 * (m.root[:-1, :3, 3] + m.root[1:, :3, 3]))
    full = geodesic_angle(m.root[:-1, :3, :3], m.root[1:, :3, :3])
    assert np.allclose(geodesic_angle(m.root[:-1, :3, :3], root[:, :3, :3]), full / 2, atol=1e-9)
    assert np.allclose(geodesic_angle(root[:, :3, :3], m.root[1:, :3, :3]), full / 2, atol=1e-9)
    R0, R1, Rm = rotvec_to_matrix(m.pose[:-1]), rotvec_to_matrix(m.pose[1:]), rotvec_to_matrix(pose)
    full = geodesic_angle(R0, R1)
    assert full.max() > 0.01  # the joints do move between frames
    assert np.allclose(geodesic_angle(R0, Rm), full / 2, atol=1e-9)
    assert np.allclose(geodesic_angle(Rm, R1), full / 2, atol=1e-9)

    # A quarter of the way: a quarter of the angle.
    quarter = 0.75 * m.timestamps[:-1] + 0.25 * m.timestamps[1:]
    _, pose = m.sample(quarter)
    assert np.allclose(geodesic_angle(R0, rotvec_to_matrix(pose)), full / 4, atol=1e-9)


def test_sample_outside_the_range_is_an_error(motions):
    m = motions["stand"]
    end = m.timestamps[-1]
    root, _ = m.sample([end + 1e-9, -1e-9])  # within the tolerance: clamped
    assert np.array_equal(root, m.root[[-1, 0]])
    with pytest.raises(MocapgraphError, match="outside the motion's range"):
        m.sample([0.0, end + 0.01])
    with pytest.raises(MocapgraphError, match="outside the motion's range"):
        m.sample(-0.5)


def test_motion_checks_its_arrays(motions, body):
    m = motions["stand"]
    assert m.joints(body).shape == (m.num_frames, 22, 3)
    with pytest.raises(MocapgraphError, match="motion joint rotations: expected shape"):
        Motion("anny", 30.0, m.timestamps, m.root, m.pose[:-1], m.shape, "bad")
    with pytest.raises(MocapgraphError, match="strictly increasing"):
        Motion("anny", 30.0, m.timestamps[::-1], m.root, m.pose, m.shape, "bad")
    other = Motion("smpl", 30.0, m.timestamps, m.root, m.pose, m.shape, "other body")
    with pytest.raises(MocapgraphError, match="for the 'smpl' body model"):
        other.joints(body)


# ---------------------------------------------------------------------------- shape fitting


def test_fit_recovers_a_known_shape(body):
    true = np.array([0.3, 0.25, 0.1, 0.15, 0.65, 0.65])
    lengths = rest_bone_lengths(body, true)
    shape = fit_shape_to_bone_lengths(body, lengths)
    residuals = np.array(list(bone_length_residuals(body, shape, lengths).values()))
    assert np.abs(residuals).max() < 1e-3
    assert np.abs(shape - true).max() < 0.05
    assert np.abs(body.rest_joints(shape) - body.rest_joints(true)).max() < 0.005

    # Any shape: the bone lengths are met, though Anny's muscle / weight / proportions hardly
    # move the skeleton, so they are not always recovered.
    rng = np.random.default_rng(1)
    lo, hi = body.shape_bounds.T
    for _ in range(2):
        true = lo + (hi - lo) * rng.uniform(0.1, 0.9, len(lo))
        lengths = rest_bone_lengths(body, true)
        shape = fit_shape_to_bone_lengths(body, lengths)
        assert np.abs(list(bone_length_residuals(body, shape, lengths).values())).max() < 1e-3
        assert abs(shape[4] - true[4]) < 0.05  # height


def test_fit_stays_in_bounds_for_impossible_lengths(body):
    lo, hi = body.shape_bounds.T
    for scale in (3.0, 0.05):
        lengths = {pair: scale * v for pair, v in rest_bone_lengths(body, body.default_shape).items()}
        shape = fit_shape_to_bone_lengths(body, lengths)
        assert np.all(shape >= lo) and np.all(shape <= hi)
        body.check_shape(shape)
        residuals = np.array(list(bone_length_residuals(body, shape, lengths).values()))
        assert np.all(np.sign(residuals) == (-1 if scale > 1 else 1))  # as close as the body gets
        assert shape[4] > 0.9 if scale > 1 else shape[4] < 0.1  # the tallest / shortest body
    with pytest.raises(MocapgraphError, match="expected a pair of joint names"):
        fit_shape_to_bone_lengths(body, {("left_hip", "left_toe"): 0.4})


# ---------------------------------------------------------------------------- CMU


def write_motion_dir(tmp_path):
    write_take(tmp_path / "cmu_01_01.npz", frames=12, seed=1)
    write_take(tmp_path / "cmu_01_02.npz", frames=12, seed=2)
    index = [
        {"file": "cmu_01_01.npz", "tags": ["walk"], "description": "walk"},
        {"file": "cmu_01_02.npz", "tags": ["dance", "jump"], "description": "dance"},
    ]
    (tmp_path / "index.json").write_text(json.dumps(index))
    return tmp_path


def test_list_cmu_takes(tmp_path):
    directory = write_motion_dir(tmp_path)
    assert [p.name for p in list_cmu_takes(directory)] == ["cmu_01_01.npz", "cmu_01_02.npz"]
    assert [p.name for p in list_cmu_takes(directory, tags="walk")] == ["cmu_01_01.npz"]
    assert [p.name for p in list_cmu_takes(directory, tags=["jump", "run"])] == ["cmu_01_02.npz"]
    with pytest.raises(MocapgraphError, match="index.json: CMU motion index not found"):
        list_cmu_takes(tmp_path / "nowhere")


def test_cmu_motion_on_a_synthetic_take(tmp_path, body):
    path = write_motion_dir(tmp_path) / "cmu_01_01.npz"
    m = cmu_motion(path, body=body)
    assert m.num_frames == 12 and m.fps == 30.0 and m.body_model == body.name
    body.check_shape(m.shape)
    feet = m.keypoints(body)[:, FOOT_KEYPOINTS, 2]
    assert feet.min() == pytest.approx(0.0, abs=1e-6)
    residuals = m.info["bone_residuals"]
    assert set(residuals) == set(CMU_BONES)
    # The synthetic skeleton has realistic limbs: the fit meets them to a few centimetres.
    limbs = [v for pair, v in residuals.items() if pair != ("left_shoulder", "right_shoulder")]
    assert np.abs(limbs).max() < 0.05

    part = cmu_motion(path, body=body, fit_shape=False, start_s=0.1, duration_s=0.2)
    assert part.num_frames == 7 and np.array_equal(part.shape, body.default_shape)
    assert part.timestamps[0] == 0.0
    with pytest.raises(MocapgraphError, match="start 5 s is outside the take"):
        cmu_motion(path, body=body, start_s=5.0)


@pytest.mark.skipif(not (motion_dir() / "index.json").exists(), reason="CMU motion directory not present")
def test_real_cmu_walk_take(body):
    path = list_cmu_takes(tags="walk")[0]
    m = cmu_motion(path, body=body)
    residuals = m.info["bone_residuals"]
    limbs = {pair: v for pair, v in residuals.items() if pair != ("left_shoulder", "right_shoulder")}
    assert np.abs(list(limbs.values())).max() < 0.03
    lowest = m.keypoints(body)[:, FOOT_KEYPOINTS, 2].min(axis=1)
    assert lowest.min() == pytest.approx(0.0, abs=1e-6)
    assert np.median(lowest) < 0.10  # the take's own floor drifts by a few centimetres
    speed = np.linalg.norm(m.root[-1, :2, 3] - m.root[0, :2, 3]) / m.duration
    assert 0.5 < speed < 2.5
    assert np.all(m.root[:, 2, 3] > 0.6)  # standing height pelvis
