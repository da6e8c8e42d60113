"""Ground-penetration factors (E_HGP, E_CGP): residuals against independent forward kinematics,
Jacobians against central differences on both sides of the plane."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from test_factors import assert_jacobians, random_shape, standing_root  # shared helpers (tests/ is on sys.path)

from mocapgraph.body import load_body_model
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.ground import camera_ground_factor, joint_ground_factor
from mocapgraph.factors.keys import camera_key, pose_key, root_key, shape_key
from mocapgraph.factors.reprojection import ShapeTableCache


@pytest.fixture(scope="module")
def body():
    return load_body_model()


def sunk_state(body, seed: int, height: float):
    """An upright body with its pelvis ``height`` metres above the plane, random pose and shape."""
    rng = np.random.default_rng(seed)
    root = standing_root(rng)
    root[2, 3] = height
    values = gtsam.Values()
    values.insert(root_key(0), gtsam.Pose3(root))
    values.insert(pose_key(0), rng.normal(scale=0.3, size=63))
    values.insert(shape_key(), random_shape(body, rng))
    return values


@pytest.mark.parametrize("height", [0.3, 0.6, 2.0])
def test_joint_penetration_matches_forward_kinematics(body, height):
    """r_j = max(0, ground − z_j) / σ with z_j from body.forward; 0.3 m sinks the legs, 2 m nothing."""
    values = sunk_state(body, seed=int(height * 10), height=height)
    factor = joint_ground_factor(ShapeTableCache(body), root_key(0), pose_key(0), shape_key(), sigma_m=0.02, ground_z=0.1)
    joints = body.forward(
        values.atVector(shape_key()), values.atPose3(root_key(0)).matrix()[None], values.atVector(pose_key(0)).reshape(1, 21, 3)
    ).joints[0]
    want = np.maximum(0.1 - joints[:, 2], 0.0) / 0.02
    np.testing.assert_allclose(factor.whitenedError(values), want, rtol=1e-12, atol=1e-12)
    assert (want > 0).any() == (height < 1.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_joint_penetration_jacobian(body, seed):
    values = sunk_state(body, seed, height=0.45)
    cache = ShapeTableCache(body)
    assert_jacobians(joint_ground_factor(cache, root_key(0), pose_key(0), shape_key(), sigma_m=0.05), values)
    fixed = joint_ground_factor(cache, root_key(0), pose_key(0), None, fixed_shape=values.atVector(shape_key()))
    assert list(fixed.keys()) == [root_key(0), pose_key(0)]
    assert_jacobians(fixed, values)


def test_a_fit_lifts_a_sunk_body_out_of_the_ground(body):
    """Gauss-Newton on the penetration factor plus a weak prior to the start: no joint ends below."""
    values = sunk_state(body, seed=5, height=0.35)
    cache = ShapeTableCache(body)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(joint_ground_factor(cache, root_key(0), pose_key(0), None, sigma_m=0.001, fixed_shape=values.atVector(shape_key())))
    graph.add(gtsam.PriorFactorPose3(root_key(0), values.atPose3(root_key(0)), gtsam.noiseModel.Isotropic.Sigma(6, 1.0)))
    graph.add(gtsam.PriorFactorVector(pose_key(0), values.atVector(pose_key(0)), gtsam.noiseModel.Isotropic.Sigma(63, 1.0)))
    start = gtsam.Values()
    start.insert(root_key(0), values.atPose3(root_key(0)))
    start.insert(pose_key(0), values.atVector(pose_key(0)))
    before = graph.at(0).whitenedError(start).max() * 0.001
    from mocapgraph.graphs.solver import levenberg_marquardt

    out = levenberg_marquardt(graph, start).values
    after = graph.at(0).whitenedError(out).max() * 0.001
    assert before > 0.05 and after < 0.005


def test_camera_penetration_residual_and_jacobian():
    rng = np.random.default_rng(3)
    for z, want in [(-0.4, 0.4 + 0.5), (0.2, 0.3), (3.0, 0.0)]:
        values = gtsam.Values()
        values.insert(camera_key(0, 1), gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), np.array([1.0, 2.0, z])))
        factor = camera_ground_factor(camera_key(0, 1), sigma_m=0.1, clearance_m=0.5)
        assert factor.whitenedError(values)[0] == pytest.approx(want / 0.1)
        assert_jacobians(factor, values)


def test_bad_arguments(body):
    cache = ShapeTableCache(body)
    with pytest.raises(MocapgraphError, match="sigma_m"):
        joint_ground_factor(cache, root_key(0), pose_key(0), shape_key(), sigma_m=0.0)
    with pytest.raises(MocapgraphError, match="exactly one of shape_key and fixed_shape"):
        joint_ground_factor(cache, root_key(0), pose_key(0), None)
    with pytest.raises(MocapgraphError, match="format 'body'"):
        joint_ground_factor(ShapeTableCache(body, "coco17"), root_key(0), pose_key(0), shape_key())
    with pytest.raises(MocapgraphError, match="sigma_m"):
        camera_ground_factor(camera_key(0, 0), sigma_m=float("nan"))
