"""The shared rotation helpers against scipy's Rotation (an independent implementation)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.body.rotations import axis_rotation, nearest_rotation


@pytest.mark.parametrize("axis", ["x", "y", "z"])
def test_axis_rotation_batches_like_scipy(axis):
    angles = np.random.default_rng(0).uniform(-np.pi, np.pi, size=(4, 5))
    expected = Rotation.from_euler(axis, angles.reshape(-1, 1)).as_matrix().reshape(4, 5, 3, 3)
    np.testing.assert_allclose(axis_rotation(axis, angles), expected, rtol=0, atol=1e-14)
    np.testing.assert_allclose(axis_rotation(axis, 0.3), Rotation.from_euler(axis, 0.3).as_matrix(), rtol=0, atol=1e-15)


def test_nearest_rotation_is_a_proper_rotation_and_fixes_rotations():
    rng = np.random.default_rng(1)
    R = Rotation.random(50, random_state=2).as_matrix()
    np.testing.assert_allclose(nearest_rotation(R), R, rtol=0, atol=1e-14)
    noisy = nearest_rotation(R + 0.05 * rng.normal(size=R.shape))
    np.testing.assert_allclose(noisy @ np.swapaxes(noisy, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-13)
    np.testing.assert_allclose(np.linalg.det(noisy), 1.0, atol=1e-13)
    assert np.all(np.linalg.norm(noisy - R, axis=(1, 2)) < 0.2)
    reflection = np.diag([1.0, 1.0, -1.0])  # det -1: the nearest proper rotation, not itself
    assert np.linalg.det(nearest_rotation(reflection)) == pytest.approx(1.0)


def test_nearest_rotation_of_a_weighted_sum_is_the_chordal_mean():
    rotations = Rotation.random(7, random_state=3)
    weights = np.random.default_rng(4).uniform(0.5, 2.0, 7)
    mean = nearest_rotation(np.einsum("n,nij->ij", weights, rotations.as_matrix()))
    np.testing.assert_allclose(mean, rotations.mean(weights).as_matrix(), rtol=0, atol=1e-12)
