"""CMU takes retargeted onto the body: every mapped bone points where the take's bone points, the
pelvis is built from the take's hip line and spine, and the joints stay near where they were."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.body import load_body_model
from mocapgraph.body.rotations import matrix_to_rotvec, rotvec_to_matrix
from mocapgraph.body.skeleton import JOINT_NAMES
from mocapgraph.body.skeleton import PARENTS as BODY_PARENTS
from mocapgraph.data_tools.sim.cmu_motion import (
    RETARGET_MAP,
    Y_UP_TO_Z_UP,
    load_cmu_take,
    motion_dir,
    retarget,
)
from mocapgraph.errors import MocapgraphError

NAMES = ["hip", "abdomen", "chest", "neck", "head", "lCollar", "lShldr", "lForeArm", "lHand", "rCollar",
         "rShldr", "rForeArm", "rHand", "lButtock", "lThigh", "lShin", "lFoot", "rButtock", "rThigh", "rShin", "rFoot"]  # fmt: skip
PARENTS = [-1, 0, 1, 2, 3, 2, 5, 6, 7, 2, 9, 10, 11, 0, 13, 14, 15, 0, 17, 18, 19]


def write_take(path, frames=5, seed=0):
    """A take in the shared/motion layout with random rotations and a plausible T-pose skeleton."""
    rng = np.random.default_rng(seed)
    offsets = np.array([[0, 0, 0], [0, .2, 0], [0, .12, 0], [0, .22, -.02], [0, .07, .01], [.03, .19, -.05],
                        [.09, -.02, .01], [.28, -.02, 0], [.23, 0, .07], [-.03, .19, -.05], [-.09, -.02, .01],
                        [-.28, -.02, 0], [-.23, 0, .07], [.09, .04, .01], [0, -.02, -.02], [0, -.37, .01],
                        [-.01, -.45, -.05], [-.09, .04, .01], [0, -.02, -.02], [0, -.37, .01], [.01, -.45, -.05]])  # fmt: skip
    quats = Rotation.from_rotvec(rng.normal(scale=0.6, size=(frames * 21, 3))).as_quat(scalar_first=True)
    np.savez(
        path,
        joint_names=np.array(NAMES), parents=np.array(PARENTS, dtype=np.int32),
        offsets=offsets.astype(np.float32), rotations=quats.reshape(frames, 21, 4).astype(np.float16),
        root_translation=rng.normal(size=(frames, 3)).astype(np.float32), fps=np.int32(30), up_axis="y",
        end_site_names=np.array(["headEnd", "lToeEnd", "rToeEnd", "lHandEnd", "rHandEnd"]),
        end_site_parents=np.array([4, 16, 20, 8, 12]),
        end_site_offsets=np.array([[0, .08, .08], [.01, -.04, .12], [-.01, -.04, .12], [.07, 0, .03], [-.07, 0, .03]]),
    )  # fmt: skip
    return path


def take_positions(take):
    """World positions (T, 21 + end sites, 3) by the README's forward kinematics."""
    T = take.world_rotations.shape[0]
    pos = {}
    for j, (name, p) in enumerate(zip(take.joint_names, take.parents)):
        pos[name] = take.root_translation if p < 0 else pos[take.joint_names[p]] + take.world_rotations[:, p] @ take.offsets[j]
    for name, (p, off) in take.end_sites.items():
        pos[name] = pos[take.joint_names[p]] + take.world_rotations[:, p] @ off
    return {k: v @ Y_UP_TO_Z_UP.T for k, v in pos.items()}, T


def test_mapped_bones_follow_the_take(tmp_path):
    body = load_body_model()
    take = load_cmu_take(write_take(tmp_path / "take.npz"))
    root, pose = retarget(take, body)
    joints = body.forward(body.default_shape, root, pose).joints
    theirs, _ = take_positions(take)
    checked = 0
    for name, (source, child, source_child) in RETARGET_MAP.items():
        if child is None:
            continue
        ours = joints[:, JOINT_NAMES.index(child)] - joints[:, JOINT_NAMES.index(name)]
        ref = theirs[source_child] - theirs[source]
        cos = np.sum(ours * ref, -1) / np.linalg.norm(ours, axis=-1) / np.linalg.norm(ref, axis=-1)
        assert np.all(cos > 1 - 1e-9), name
        checked += 1
    assert checked == 16


def root_rotation_retarget(take, root, pose):
    """The same retargeting with the take's root rotation on the pelvis and the take's hip position
    as the root, as it was before the pelvis was made anatomical (the children's world rotations
    are the same, their local rotations re-expressed)."""
    W = take.world_rotations[:, 0]
    pelvis = Y_UP_TO_Z_UP.T @ root[:, :3, :3]
    old_root = root.copy()
    old_root[:, :3, :3] = Y_UP_TO_Z_UP @ W
    old_root[:, :3, 3] = take.root_translation @ Y_UP_TO_Z_UP.T
    old_pose = pose.copy()
    for c in np.flatnonzero(BODY_PARENTS == 0):
        old_pose[:, c - 1] = matrix_to_rotvec(np.swapaxes(W, -1, -2) @ pelvis @ rotvec_to_matrix(pose[:, c - 1]))
    return old_root, old_pose


def test_the_pelvis_follows_the_hip_line_and_the_spine(tmp_path):
    body = load_body_model()
    take = load_cmu_take(write_take(tmp_path / "take.npz", frames=20))
    root, pose = retarget(take, body)
    theirs, _ = take_positions(take)
    rest = body.rest_joints(body.default_shape)
    R = root[:, :3, :3]
    hip_line = theirs["lThigh"] - theirs["rThigh"]
    ours = R @ (rest[JOINT_NAMES.index("left_hip")] - rest[JOINT_NAMES.index("right_hip")])
    cos = np.sum(ours * hip_line, -1) / np.linalg.norm(ours, axis=-1) / np.linalg.norm(hip_line, axis=-1)
    assert np.all(cos > 1 - 1e-12)
    # Our pelvis → neck turns into the plane of the take's hip line and hip → neck, on the neck's side.
    spine = theirs["neck"] - theirs["hip"]
    normal = np.cross(hip_line, spine)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    ours_spine = R @ rest[JOINT_NAMES.index("neck")]
    assert np.abs(np.sum(ours_spine * normal, -1)).max() < 1e-12
    in_plane = spine - np.sum(spine * hip_line, -1, keepdims=True) * hip_line / np.sum(hip_line**2, -1, keepdims=True)
    assert np.all(np.sum(ours_spine * in_plane, -1) > 0)


def test_our_rest_pose_is_the_identity(tmp_path):
    """A take whose thighs and neck sit where our rest hips and neck are gives the identity at rest
    and, turned as a whole, exactly that turn."""
    body = load_body_model()
    rest = body.rest_joints(body.default_shape)
    path = write_take(tmp_path / "take.npz", frames=3)
    with np.load(path) as d:
        data = dict(d)
    offsets = data["offsets"].astype(float)
    # Buttock at our hip, thigh on it; abdomen and chest share the way to our neck.
    offsets[NAMES.index("lButtock")] = rest[JOINT_NAMES.index("left_hip")]
    offsets[NAMES.index("rButtock")] = rest[JOINT_NAMES.index("right_hip")]
    offsets[NAMES.index("lThigh")] = offsets[NAMES.index("rThigh")] = 0
    offsets[NAMES.index("abdomen")] = offsets[NAMES.index("chest")] = 0.25 * rest[JOINT_NAMES.index("neck")]
    offsets[NAMES.index("neck")] = 0.5 * rest[JOINT_NAMES.index("neck")]
    turn = Rotation.from_rotvec([[0, 0, 0], [0.3, -1.2, 0.5], [2.0, 0.1, -0.4]])
    quats = np.zeros((3, 21, 4))
    quats[..., 0] = 1
    quats[:, 0] = turn.as_quat(scalar_first=True)
    data.update(offsets=offsets.astype(np.float32), rotations=quats.astype(np.float16))
    np.savez(path, **data)
    take = load_cmu_take(path)
    root, _ = retarget(take, body)
    # The float16 quaternions are the turn to ~1e-3, so the take's own root rotation is the
    # reference. The offsets are float32 (relative rounding 6e-8 on a 0.1–0.5 m hip line and
    # spine): the frames agree to about 1e-9, and 1e-6 leaves room while catching any real turn.
    expected = Y_UP_TO_Z_UP @ take.world_rotations[:, 0]
    assert np.abs(root[:, :3, :3] - expected).max() < 1e-6
    assert np.abs(root[0, :3, :3] - Y_UP_TO_Z_UP).max() < 1e-6


def test_joints_stay_where_the_takes_root_rotation_put_them(tmp_path):
    """The root translation is the least-squares choice: the joints' displacements from the
    retargeting with the take's root rotation sum to zero, and each pelvis child's subtree moves
    rigidly with it (so its bones, hence every bone test above, are unchanged)."""
    body = load_body_model()
    take = load_cmu_take(write_take(tmp_path / "take.npz", frames=20))
    root, pose = retarget(take, body)
    old_root, old_pose = root_rotation_retarget(take, root, pose)
    new = body.forward(body.default_shape, root, pose).joints
    old = body.forward(body.default_shape, old_root, old_pose).joints
    moved = new - old
    # Positions are float64 of about a metre: 1e-9 m is far above rounding, far below any real move.
    assert np.abs(moved.sum(axis=1)).max() < 1e-9
    for c in np.flatnonzero(BODY_PARENTS == 0):
        subtree = [j for j in range(len(JOINT_NAMES)) if c in _ancestors(j)]
        assert np.abs(moved[:, subtree] - moved[:, [c]]).max() < 1e-9


def _ancestors(j):
    chain = [j]
    while BODY_PARENTS[chain[-1]] >= 0:
        chain.append(int(BODY_PARENTS[chain[-1]]))
    return chain


# A walking take: tagged "walk" with a description that names a walk in an ordinary posture.
# The styles below bend the trunk on purpose, and the pelvis follows the trunk (it is built from
# hip → neck); with these rules subjects 13 and 14 (tagged walk, "jump up to grab, reach for,
# tiptoe"), 74 (only "stiff walk": 12.4° from upright, the take's trunk leans forward 11°; 14.2°
# with the take's root rotation), 77 (creeping, careful and silent walks: 23°–39°, but 3.5° on
# its "careful walk" 77_28) and 78 ("WalkEvasiveLeft": 31.5°) have none, 30 subjects have one.
WALK = re.compile(r"\bwalk", re.IGNORECASE)
TRUNK_BENDING_STYLE = re.compile(r"creep|stealth|silent|careful|limp|hobble|stiff|evasive", re.IGNORECASE)


def walking_takes(directory):
    """The first walking take of each training subject in ``index.json`` (``{subject: file}``)."""
    takes = {}
    for entry in json.loads((directory / "index.json").read_text()):
        description = entry.get("description", "")
        if "walk" in entry["tags"] and WALK.search(description) and not TRUNK_BENDING_STYLE.search(description):
            takes.setdefault(entry["subject"], entry["file"])
    return takes


def test_walking_pelvis_is_upright_on_every_training_subject():
    """Median over a walking take's frames of the pelvis's up axis against world +Z, one take per
    subject: 1.9°–7.4° (median 4.3°) measured, 1.9°–15.2° with the take's root rotation.

    The joints moved from where the take's root rotation put them by a median of 2.1 mm and at
    most 11.9 mm over these takes: the pelvis pitches by up to 11° about the hip line, which
    swings spine1 (7.5 cm from the hip line) against the hips by about 14 mm and the least-squares
    root shares that out. The bounds below leave a quarter of margin over the measurement.
    """
    directory = motion_dir()
    if not directory.exists():
        pytest.skip(f"CMU motion directory {directory} not present (a clone outside the workspace)")
    body = load_body_model()
    takes = walking_takes(directory)
    assert len(takes) == 30
    tilts, moves = {}, []
    for subject, name in sorted(takes.items()):
        take = load_cmu_take(directory / name)
        root, pose = retarget(take, body)
        tilts[subject] = np.degrees(np.median(np.arccos(np.clip(root[:, 2, 1], -1.0, 1.0))))
        old_root, old_pose = root_rotation_retarget(take, root, pose)
        new = body.forward(body.default_shape, root, pose).joints
        old = body.forward(body.default_shape, old_root, old_pose).joints
        moves.append(np.linalg.norm(new - old, axis=-1).ravel())
    assert max(tilts.values()) < 10.0, {s: round(t, 1) for s, t in tilts.items() if t >= 10.0}
    moves = np.concatenate(moves)
    assert np.median(moves) < 0.003 and moves.max() < 0.015


def test_bad_takes_name_the_file_and_key(tmp_path):
    with pytest.raises(MocapgraphError, match="nothere.npz: motion file not found"):
        load_cmu_take(tmp_path / "nothere.npz")
    np.savez(tmp_path / "partial.npz", joint_names=np.array(NAMES))
    with pytest.raises(MocapgraphError, match="partial.npz: missing key 'parents'"):
        load_cmu_take(tmp_path / "partial.npz")
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(MocapgraphError, match="junk.npz: not a readable motion"):
        load_cmu_take(tmp_path / "junk.npz")
