"""The OpenCV camera model: projecting world points to pixels, undoing the lens distortion, and what
a camera can see.

Cameras are OpenCV pinholes (x right, y down, z forward) posed by ``world_T_camera``, with
OpenCV's ``k1, k2, p1, p2, k3`` distortion: the model of ``cv2.projectPoints``, in numpy and
batched over frames; its inverse on pixels is ``cv2.undistortPoints``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from mocapgraph.errors import MocapgraphError

MIN_DEPTH_M = 0.05
"""Points closer to the camera than this (or behind it) are not seen."""


def _camera_for(points: np.ndarray, world_T_camera) -> np.ndarray:
    """``world_T_camera`` shaped to broadcast against ``points (..., 3)`` (its leading dims are a
    prefix of the points' leading dims)."""
    cam = np.asarray(world_T_camera, dtype=float)
    if cam.shape[-2:] != (4, 4):
        raise MocapgraphError(f"world_T_camera must have shape (..., 4, 4), got {cam.shape}")
    lead_c, lead_p = cam.shape[:-2], points.shape[:-1]
    if lead_p[: len(lead_c)] != lead_c:
        raise MocapgraphError(
            f"world_T_camera leading shape {lead_c} is not a prefix of the points' leading shape {lead_p}"
        )
    return cam.reshape(lead_c + (1,) * (len(lead_p) - len(lead_c)) + (4, 4))


def _distortion5(distortion) -> np.ndarray:
    d = np.zeros(5) if distortion is None else np.asarray(distortion, dtype=float).ravel()
    if d.size not in (4, 5):
        raise MocapgraphError(f"distortion must be OpenCV (k1, k2, p1, p2[, k3]), got {d.size} values")
    return np.concatenate([d, np.zeros(5 - d.size)])


def _camera_points(points: np.ndarray, world_T_camera) -> np.ndarray:
    """``points (..., 3)`` world → camera coordinates (OpenCV: x right, y down, z forward)."""
    cam = _camera_for(points, world_T_camera)
    return np.einsum("...ji,...j->...i", cam[..., :3, :3], points - cam[..., :3, 3])


def _pixels(p: np.ndarray, K, distortion) -> np.ndarray:
    """Camera points ``(..., 3)`` → pixels ``(..., 2)`` by OpenCV's model; NaN where z <= 0."""
    K = np.asarray(K, dtype=float)
    k1, k2, p1, p2, k3 = _distortion5(distortion)
    depth = p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = p[..., 0] / depth, p[..., 1] / depth
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    pixels = np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=-1)
    pixels[depth <= 0] = np.nan
    return pixels


def project_points(points, world_T_camera, K, distortion=None) -> tuple[np.ndarray, np.ndarray]:
    """Project world points through an OpenCV camera (the model of ``cv2.projectPoints``).

    Args:
        points: ``(..., 3)`` world, metres.
        world_T_camera: ``(4, 4)``, or ``(*B, 4, 4)`` with ``B`` a prefix of the points' leading
            shape (e.g. ``(T, 4, 4)`` for points ``(T, K, 3)``). OpenCV camera: x right, y down,
            z forward.
        K: ``(3, 3)`` intrinsics (fx, fy, cx, cy; skew ``K[0, 1]`` is honoured).
        distortion: OpenCV ``k1, k2, p1, p2[, k3]``, or None for none.

    Returns:
        ``pixels (..., 2)`` (NaN where the depth is <= 0) and ``depth (...)``, the camera z in metres.
    """
    p = _camera_points(np.asarray(points, dtype=float), world_T_camera)
    return _pixels(p, K, distortion), p[..., 2]


def undistort_pixels(points, K, distortion) -> np.ndarray:
    """Pixels of a distorted image → pixels of the ideal pinhole camera with the same ``K``.

    Args:
        points: ``(..., 2)`` pixels; NaN rows stay NaN.
        K: ``(3, 3)`` intrinsics.
        distortion: OpenCV coefficients ``k1, k2, p1, p2[, k3, …]``.

    Returns:
        ``(..., 2)`` undistorted pixels (a copy; unchanged when the distortion is all zero).
    """
    pts = np.array(points, dtype=float, copy=True)
    dist = np.asarray(distortion, dtype=float).ravel()
    if not np.any(dist):
        return pts
    flat = pts.reshape(-1, 2)
    ok = np.all(np.isfinite(flat), axis=1)
    if np.any(ok):
        # OpenCV's default stops after 5 fixed-point iterations: with k1 = -0.3 that leaves ~0.2 px
        # of error half-way to the image edge and more beyond; iterate to convergence instead.
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        Kf = np.asarray(K, dtype=float)
        und = cv2.undistortPoints(flat[ok].reshape(-1, 1, 2), Kf, dist, P=Kf, criteria=criteria)
        flat[ok] = und.reshape(-1, 2)
    return flat.reshape(pts.shape)


def distortion_max_radius2(distortion) -> float:
    """Squared normalised radius ``(x/z)² + (y/z)²`` up to which OpenCV's radial distortion is
    monotonic (``inf`` if everywhere); beyond it far points fold back into the image."""
    k1, k2, _, _, k3 = _distortion5(distortion)
    # d/dr [r (1 + k1 r² + k2 r⁴ + k3 r⁶)] = 1 + 3 k1 s + 5 k2 s² + 7 k3 s³ with s = r²
    coeffs = np.trim_zeros(np.array([7 * k3, 5 * k2, 3 * k1, 1.0]), "f")
    roots = np.roots(coeffs) if coeffs.size > 1 else np.array([])
    real = roots[np.abs(roots.imag) <= 1e-12 * np.maximum(1, np.abs(roots.real))].real
    positive = real[real > 0]
    return float(positive.min()) if positive.size else math.inf


def in_frame_mask(points, world_T_camera, K, distortion, image_size) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``pixels (..., 2)``, ``depth (...)`` and whether each point is seen by the camera: in front
    (depth > ``MIN_DEPTH_M``), within the monotonic range of the distortion, inside the image."""
    p = _camera_points(np.asarray(points, dtype=float), world_T_camera)
    pixels, depth = _pixels(p, K, distortion), p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        r2 = (p[..., 0] ** 2 + p[..., 1] ** 2) / depth**2
    inside = (depth > MIN_DEPTH_M) & (r2 < distortion_max_radius2(distortion))
    return pixels, depth, inside & in_image(pixels, image_size)


def in_image(pixels, image_size) -> np.ndarray:
    """``(...)`` bool: finite and inside ``0 <= u < w, 0 <= v < h``."""
    w, h = image_size
    u, v = pixels[..., 0], pixels[..., 1]
    with np.errstate(invalid="ignore"):
        return (u >= 0) & (u < w) & (v >= 0) & (v < h)
