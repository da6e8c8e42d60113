"""CMU takes retargeted onto the body: every mapped bone points where the take's bone points."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.body import load_body_model
from mocapgraph.body.skeleton import JOINT_NAMES
from mocapgraph.data_tools.sim.cmu_motion import RETARGET_MAP, Y_UP_TO_Z_UP, load_cmu_take, retarget
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
    assert np.allclose(root[:, :3, 3], theirs["hip"])


def test_bad_takes_name_the_file_and_key(tmp_path):
    with pytest.raises(MocapgraphError, match="nothere.npz: motion file not found"):
        load_cmu_take(tmp_path / "nothere.npz")
    np.savez(tmp_path / "partial.npz", joint_names=np.array(NAMES))
    with pytest.raises(MocapgraphError, match="partial.npz: missing key 'parents'"):
        load_cmu_take(tmp_path / "partial.npz")
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(MocapgraphError, match="junk.npz: not a readable motion"):
        load_cmu_take(tmp_path / "junk.npz")
