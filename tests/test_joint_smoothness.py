"""3D joint smoothness factor: residual against independent forward kinematics, Jacobians against
central differences."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from test_factors import assert_jacobians, random_shape, standing_root  # shared helpers (tests/ is on sys.path)

from mocapgraph.body import load_body_model
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.keys import pose_key, root_key, shape_key
from mocapgraph.factors.reprojection import ShapeTableCache
from mocapgraph.factors.smoothness import joint_smoothness_factor


@pytest.fixture(scope="module")
def body():
    return load_body_model()


def two_states(body, seed: int) -> gtsam.Values:
    rng = np.random.default_rng(seed)
    values = gtsam.Values()
    for i in range(2):
        values.insert(root_key(i), gtsam.Pose3(standing_root(rng)))
        values.insert(pose_key(i), rng.normal(scale=0.3, size=63))
    values.insert(shape_key(), random_shape(body, rng))
    return values


def test_residual_is_the_joint_velocity_over_sigma(body):
    values = two_states(body, 0)
    factor = joint_smoothness_factor(ShapeTableCache(body), (root_key(0), pose_key(0)), (root_key(1), pose_key(1)), shape_key(), 0.04, 2.0)
    shape = values.atVector(shape_key())
    joints = [
        body.forward(shape, values.atPose3(root_key(i)).matrix()[None], values.atVector(pose_key(i)).reshape(1, 21, 3)).joints[0]
        for i in range(2)
    ]
    want = (joints[1] - joints[0]).ravel() / (0.04 * 2.0)
    np.testing.assert_allclose(factor.whitenedError(values), want, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("seed", [1, 2])
def test_jacobians(body, seed):
    values = two_states(body, seed)
    cache = ShapeTableCache(body)
    a, b = (root_key(0), pose_key(0)), (root_key(1), pose_key(1))
    assert_jacobians(joint_smoothness_factor(cache, a, b, shape_key(), 1 / 30, 1.5), values)
    fixed = joint_smoothness_factor(cache, a, b, None, 1 / 30, 1.5, fixed_shape=values.atVector(shape_key()))
    assert len(fixed.keys()) == 4
    assert_jacobians(fixed, values)


def test_bad_arguments(body):
    cache = ShapeTableCache(body)
    with pytest.raises(MocapgraphError, match="dt and sigma"):
        joint_smoothness_factor(cache, (1, 2), (3, 4), shape_key(), 0.0, 1.0)
    with pytest.raises(MocapgraphError, match="format 'body'"):
        joint_smoothness_factor(ShapeTableCache(body, "coco17"), (1, 2), (3, 4), shape_key(), 0.1, 1.0)
