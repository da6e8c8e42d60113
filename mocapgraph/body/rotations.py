"""SO(3) helpers on batched numpy arrays: skew, exponential map and its right Jacobian.

Axis-angle vectors are ``(..., 3)`` in radians; rotation matrices ``(..., 3, 3)``.
Near zero angle the closed forms switch to Taylor series so that values and first
derivatives stay accurate to float64 round-off; nothing is singular up to and including π.
"""

from __future__ import annotations

import numpy as np

# Below this angle the Taylor expansions are used; their truncation error (θ⁴ terms)
# is then under 1e-16 relative.
_SMALL_ANGLE = 1e-4


def skew(v: np.ndarray) -> np.ndarray:
    """``(..., 3)`` → ``(..., 3, 3)`` cross-product matrices, ``skew(a) @ b == cross(a, b)``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape + (3,))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def _angle_coefficients(rotvec: np.ndarray):
    """θ and the three coefficients sin θ/θ, (1-cos θ)/θ², (θ - sin θ)/θ³ with series near 0."""
    theta2 = np.sum(rotvec * rotvec, axis=-1)
    theta = np.sqrt(theta2)
    small = theta < _SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(safe) / safe)
    # 2 sin²(θ/2) rather than 1 - cos θ: no cancellation just above the series threshold.
    b = np.where(small, 0.5 - theta2 / 24.0, 2.0 * np.sin(0.5 * safe) ** 2 / safe**2)
    c = np.where(small, 1.0 / 6.0 - theta2 / 120.0, (safe - np.sin(safe)) / safe**3)
    return a, b, c


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Exponential map: ``(..., 3)`` axis-angle → ``(..., 3, 3)`` rotation (Rodrigues)."""
    rotvec = np.asarray(rotvec, dtype=float)
    a, b, _ = _angle_coefficients(rotvec)
    K = skew(rotvec)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def right_jacobian(rotvec: np.ndarray) -> np.ndarray:
    """Right Jacobian ``Jr(θ)`` of SO(3): ``Exp(θ + δ) ≈ Exp(θ) Exp(Jr(θ) δ)``. ``(..., 3, 3)``."""
    rotvec = np.asarray(rotvec, dtype=float)
    _, b, c = _angle_coefficients(rotvec)
    K = skew(rotvec)
    return np.eye(3) - b[..., None, None] * K + c[..., None, None] * (K @ K)


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Logarithm map: ``(..., 3, 3)`` rotation → ``(..., 3)`` axis-angle with angle in [0, π]."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=float)
    flat = R.reshape(-1, 3, 3)
    return Rotation.from_matrix(flat).as_rotvec().reshape(R.shape[:-2] + (3,))


def relative_angle(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """``(...)`` radians in [0, π] between rotation matrices ``(..., 3, 3)`` (broadcast):
    ``arccos((trace(R_aᵀ R_b) − 1) / 2)``, with ``trace(R_aᵀ R_b)`` the sum of elementwise products."""
    trace = np.einsum("...ab,...ab->...", Ra, Rb)
    return np.arccos(np.clip(0.5 * (trace - 1.0), -1.0, 1.0))


def axis_rotation(axis: str, angle) -> np.ndarray:
    """``(..., 3, 3)`` rotations by ``angle (...)`` radians (a scalar gives ``(3, 3)``) about
    the named coordinate axis ``"x"``, ``"y"`` or ``"z"``."""
    unit = np.eye(3)["xyz".index(axis)]
    return rotvec_to_matrix(np.asarray(angle, dtype=float)[..., None] * unit)


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)``: the proper rotation nearest to each ``M (..., 3, 3)`` in the Frobenius
    norm (``U diag(1, 1, det(U Vᵀ)) Vᵀ`` of its SVD; a weighted sum of rotations gives their
    chordal mean)."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    U = U.copy()
    U[..., :, 2] *= np.sign(np.linalg.det(U @ Vt))[..., None]
    return U @ Vt


def minimal_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation ``(3, 3)`` turning direction ``a`` onto direction ``b`` (not antiparallel)."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    axis = np.cross(a, b)
    angle = np.arctan2(np.linalg.norm(axis), a @ b)
    return rotvec_to_matrix(axis / max(np.linalg.norm(axis), 1e-300) * angle)
