"""The public posing call: validation at the boundary, and native == numpy on the real bodies."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import random_root

from mocapgraph.body import load_body_model
from mocapgraph.body.kinematics import forward_kinematics_numpy
from mocapgraph.errors import MocapgraphError


@pytest.fixture(scope="module")
def body():
    return load_body_model()


def test_forward_equals_numpy_reference_for_every_format(body):
    rng = np.random.default_rng(0)
    root, pose = random_root(rng, 4), rng.normal(size=(4, 21, 3))
    shape = body.default_shape + 0.1
    for fmt in ("body", "coco17", "openpose25", "blazepose33"):
        native = body.forward(shape, root, pose, keypoints=fmt, jacobians=True)
        ref = forward_kinematics_numpy(body.table(shape, fmt), root, pose, jacobians=True)
        for name in ("joints", "keypoints", "d_joints", "d_keypoints"):
            assert np.abs(getattr(native, name) - getattr(ref, name)).max() < 1e-9, (fmt, name)


def test_single_frame_without_batch_axis(body):
    res = body.forward(body.default_shape, np.eye(4), np.zeros((21, 3)))
    assert res.joints.shape == (1, 22, 3) and res.keypoints.shape == (1, 23, 3)


@pytest.mark.parametrize(
    ("root", "pose", "message"),
    [
        (np.eye(4), np.full((21, 3), np.nan), r"joint rotations \(axis-angle\): contains NaN"),
        (np.eye(4), np.zeros((22, 3)), r"joint rotations \(axis-angle\): expected shape \(1, 21, 3\)"),
        (np.eye(3), np.zeros((21, 3)), r"root pose world_T_root: expected shape \(N, 4, 4\)"),
        (2 * np.eye(4), np.zeros((21, 3)), "rotation block is not a rotation"),
        ("abc", np.zeros((21, 3)), "root pose world_T_root: not a numeric array"),
    ],
)
def test_bad_poses_are_one_clear_error(body, root, pose, message):
    with pytest.raises(MocapgraphError, match=message):
        body.forward(body.default_shape, root, pose)


def test_unknown_backend_and_format(body):
    with pytest.raises(MocapgraphError, match="unknown body backend 'star'"):
        load_body_model("star")
    with pytest.raises(MocapgraphError, match="unknown keypoint format 'posenet9'"):
        body.table(body.default_shape, "posenet9")
