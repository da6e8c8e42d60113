"""The numpy reference of forward kinematics: values against an independent 4×4 chain, and every
Jacobian column against central differences, including rotations near 0 and near π."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import LinearShapeTable, random_root
from scipy.spatial.transform import Rotation

from mocapgraph.body.kinematics import SHAPE_START, forward_kinematics_numpy
from mocapgraph.body.rotations import matrix_to_rotvec, right_jacobian, rotvec_to_matrix
from mocapgraph.body.skeleton import PARENTS


def rotvecs_with_angles(rng, angles):
    axes = rng.normal(size=(len(angles), 3))
    return axes / np.linalg.norm(axes, axis=1, keepdims=True) * np.asarray(angles)[:, None]


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-7, 1e-4, 0.3, 2.0, np.pi - 1e-6, np.pi])
def test_exp_and_right_jacobian(angle):
    rng = np.random.default_rng(0)
    v = rotvecs_with_angles(rng, [angle])[0]
    assert np.allclose(rotvec_to_matrix(v), Rotation.from_rotvec(v).as_matrix(), atol=1e-15)
    # Exp(v + hδ) = Exp(v) Exp(h Jr(v) δ) + O(h²)
    h = 1e-6
    for delta in np.eye(3):
        plus = matrix_to_rotvec(rotvec_to_matrix(v).T @ rotvec_to_matrix(v + h * delta))
        minus = matrix_to_rotvec(rotvec_to_matrix(v).T @ rotvec_to_matrix(v - h * delta))
        assert np.allclose((plus - minus) / (2 * h), right_jacobian(v) @ delta, atol=1e-8)


def chain_4x4(table, root, pose):
    """Joints by composing homogeneous transforms [R_c | o_c] down the tree (independent path)."""
    T = np.zeros((22, 4, 4))
    T[0] = root
    for c in range(1, 22):
        local = np.eye(4)
        local[:3, :3] = Rotation.from_rotvec(pose[c - 1]).as_matrix()
        local[:3, 3] = table.offsets[c]
        T[c] = T[PARENTS[c]] @ local
    joints = T[:, :3, 3]
    keypoints = table.weights @ joints + np.einsum("cxy,kcy->kx", T[:, :3, :3], table.markers)
    return joints, keypoints


def test_values_match_independent_chain(linear_table):
    rng = np.random.default_rng(1)
    table = linear_table(rng.normal(size=4))
    root = random_root(rng, 3)
    pose = rng.normal(size=(3, 21, 3))
    res = forward_kinematics_numpy(table, root, pose)
    for t in range(3):
        joints, keypoints = chain_4x4(table, root[t], pose[t])
        assert np.abs(res.joints[t] - joints).max() < 1e-12
        assert np.abs(res.keypoints[t] - keypoints).max() < 1e-12


def finite_difference_jacobian(table_fn, beta, root, pose, h=1e-6):
    """Central differences over [root ω, root v, θ, β] with GTSAM's Pose3 right perturbation."""

    def outputs(x):
        w, v, th, b = x[:3], x[3:6], x[6:SHAPE_START], x[SHAPE_START:]
        moved = root.copy()
        moved[:, :3, :3] = root[:, :3, :3] @ rotvec_to_matrix(w)
        moved[:, :3, 3] += root[:, :3, :3] @ v
        out = forward_kinematics_numpy(table_fn(beta + b), moved, pose + th.reshape(21, 3))
        return np.concatenate([out.joints.reshape(len(root), -1), out.keypoints.reshape(len(root), -1)], 1)

    n = SHAPE_START + len(beta)
    cols = [(outputs(h * e) - outputs(-h * e)) / (2 * h) for e in np.eye(n)]
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize(
    "angles",
    [
        pytest.param(None, id="random"),
        pytest.param(1e-9, id="near-zero"),
        pytest.param(0.0, id="zero"),
        pytest.param(np.pi - 1e-6, id="near-pi"),
    ],
)
def test_jacobians_match_central_differences(angles):
    rng = np.random.default_rng(2)
    table_fn = LinearShapeTable(seed=5, num_keypoints=11, shape_dim=3)
    beta = rng.normal(size=3)
    root = random_root(rng, 2)
    if angles is None:
        pose = rng.normal(size=(2, 21, 3))
    else:
        pose = rotvecs_with_angles(rng, np.full(42, angles)).reshape(2, 21, 3)
    res = forward_kinematics_numpy(table_fn(beta), root, pose, jacobians=True)
    analytic = np.concatenate([res.d_joints.reshape(2, -1, res.d_joints.shape[-1]), res.d_keypoints.reshape(2, -1, res.d_keypoints.shape[-1])], 1)
    numeric = finite_difference_jacobian(table_fn, beta, root, pose)
    assert np.abs(analytic - numeric).max() / np.abs(numeric).max() < 1e-6


def test_unnormalised_keypoint_weights_keep_translation_exact():
    """Root translation moves a keypoint by Σ_c a_kc, not by 1, when weights do not sum to one."""
    table_fn = LinearShapeTable(seed=7)
    table_fn.a = table_fn.a * 0.8
    rng = np.random.default_rng(3)
    beta = rng.normal(size=4)
    root = random_root(rng, 1)
    pose = rng.normal(size=(1, 21, 3))
    res = forward_kinematics_numpy(table_fn(beta), root, pose, jacobians=True)
    numeric = finite_difference_jacobian(table_fn, beta, root, pose)
    analytic = np.concatenate([res.d_joints.reshape(1, -1, res.d_joints.shape[-1]), res.d_keypoints.reshape(1, -1, res.d_keypoints.shape[-1])], 1)
    assert np.abs(analytic - numeric).max() / np.abs(numeric).max() < 1e-6
