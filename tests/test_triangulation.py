"""The calibrated-camera baseline: DLT, RANSAC over views, undistortion, and whole captures.

Cameras stand on a circle looking at the subject (OpenCV convention: +z forward, y down), and
observations come from a projection written here, independent of the module under test.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from mocapgraph.data_tools.geometry.camera_model import undistort_pixels
from mocapgraph.data_tools.geometry.triangulation import projection_matrix, triangulate_points, triangulate_ransac
from mocapgraph.data_tools.io.capture import Camera, Capture, Detector
from mocapgraph.errors import MocapgraphError
from mocapgraph.pipelines.baseline import Triangulation, triangulate_capture

FOCAL = 1000.0
SIZE = (1920, 1080)
TARGET = np.array([0.0, 0.0, 1.0])


def intrinsics(f: float = FOCAL) -> np.ndarray:
    return np.array([[f, 0.0, SIZE[0] / 2], [0.0, f, SIZE[1] / 2], [0.0, 0.0, 1.0]])


def look_at(position, target=TARGET) -> np.ndarray:
    """world_T_camera of a camera at ``position`` whose +z points at ``target`` and y points down."""
    position = np.asarray(position, dtype=float)
    z = np.asarray(target, dtype=float) - position
    z /= np.linalg.norm(z)
    down = np.array([0.0, 0.0, -1.0])
    y = down - (down @ z) * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = position
    return T


def ring(n: int, radius: float = 4.0, height: float = 1.5, phase: float = 0.3) -> list[np.ndarray]:
    angles = phase + 2 * np.pi * np.arange(n) / n
    return [look_at([radius * np.cos(a), radius * np.sin(a), height]) for a in angles]


def project(K: np.ndarray, world_T_camera: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) and depths (N,) of world points X (N, 3)."""
    R, c = world_T_camera[:3, :3], world_T_camera[:3, 3]
    Xc = (X - c) @ R  # rows: R^T (X - c)
    u = K[0, 0] * Xc[:, 0] / Xc[:, 2] + K[0, 2]
    v = K[1, 1] * Xc[:, 1] / Xc[:, 2] + K[1, 2]
    return np.column_stack([u, v]), Xc[:, 2]


def P_of(K: np.ndarray, world_T_camera: np.ndarray) -> np.ndarray:
    camera_T_world = np.linalg.inv(world_T_camera)
    return K @ camera_T_world[:3]


def random_points(rng, n: int) -> np.ndarray:
    return rng.uniform([-0.5, -0.5, 0.2], [0.5, 0.5, 1.8], size=(n, 3))


def scene(n_cams: int, n_points: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    K = intrinsics()
    poses = ring(n_cams)
    X = random_points(rng, n_points)
    obs = np.stack([project(K, T, X)[0] for T in poses])
    P = np.stack([P_of(K, T) for T in poses])
    return rng, K, poses, P, X, obs


def errors_m(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.linalg.norm(estimate - truth, axis=-1)


# ---------------------------------------------------------------------------------------------
# Points


def test_projection_matrix_matches_the_independent_projection():
    _, K, poses, P, X, obs = scene(4, 10)
    for c, T in enumerate(poses):
        assert np.allclose(projection_matrix(K, T), P[c])
        assert np.all(project(K, T, X)[1] > 0)
        assert np.all((obs[c] > 0) & (obs[c] < SIZE)), "synthetic points must be inside the images"


def test_noise_free_dlt_is_exact():
    _, _, _, P, X, obs = scene(5, 50)
    est = triangulate_points(P, obs, np.ones(obs.shape[:2]))
    assert errors_m(est, X).max() < 1e-8
    # Any scale or sign of a projection matrix describes the same camera.
    scaled = P * np.array([1.0, -3.0, 1e-3, 7.0, 0.5])[:, None, None]
    assert errors_m(triangulate_points(scaled, obs), X).max() < 1e-8
    pts, inl, err = triangulate_ransac(scaled, obs)
    assert errors_m(pts, X).max() < 1e-8 and inl.all() and err.max() < 1e-6


def predicted_rms(K, poses, X, sigma_px: float) -> float:
    """First-order RMS 3D error of the least-squares estimate under isotropic pixel noise."""
    traces = []
    for x in X:
        H = np.zeros((3, 3))
        for T in poses:
            J = np.zeros((2, 3))
            for i in range(3):
                d = np.zeros(3)
                d[i] = 1e-6
                J[:, i] = (project(K, T, (x + d)[None])[0][0] - project(K, T, (x - d)[None])[0][0]) / 2e-6
            H += J.T @ J
        traces.append(np.trace(np.linalg.inv(H)) * sigma_px**2)
    return float(np.sqrt(np.mean(traces)))


def test_one_pixel_noise_error_matches_the_first_order_bound():
    rng, K, poses, P, X, obs = scene(5, 300, seed=1)
    noisy = obs + rng.normal(scale=1.0, size=obs.shape)
    bound = predicted_rms(K, poses, X, 1.0)
    # 1 px at 4 m with f = 1000 px is 4 mm per view; five views shrink it to a few mm.
    assert 0.5e-3 < bound < 5e-3
    dlt = errors_m(triangulate_points(P, noisy), X)
    pts, inl, err = triangulate_ransac(P, noisy, threshold_px=10.0)
    rs = errors_m(pts, X)
    assert inl.all()
    for e in (dlt, rs):
        assert np.sqrt(np.mean(e**2)) < 1.25 * bound
        assert np.mean(e) < bound and e.max() < 4 * bound  # 4σ: the tail of 300 draws, not a fluke
    # Gauss-Newton reaches the least-squares optimum, which the linear solution only approaches.
    assert np.sqrt(np.mean(rs**2)) <= np.sqrt(np.mean(dlt**2)) * 1.01
    assert 0.5 < np.mean(err) < 1.5  # mean residual of 1 px noise, less the 3 fitted dof


@pytest.mark.parametrize("noise_px", [0.0, 0.5])
def test_ransac_rejects_a_gross_outlier_view(noise_px):
    rng, K, poses, P, X, obs = scene(5, 200, seed=2)
    obs = obs + rng.normal(scale=noise_px, size=obs.shape)
    bad = rng.integers(0, 5, size=len(X))
    obs[bad, np.arange(len(X)), 0] += 200.0
    dlt = errors_m(triangulate_points(P, obs), X)
    pts, inl, err = triangulate_ransac(P, obs, threshold_px=10.0, seed=0)
    rs = errors_m(pts, X)
    assert np.mean(dlt) > 0.02, "plain DLT should be pulled away by a 200 px outlier"
    if noise_px == 0:
        assert rs.max() < 1e-6
    else:
        # 0.5 px on the four good views: about 1.5 mm RMS (see the first-order bound above).
        assert np.mean(rs) < 3e-3 and rs.max() < 8e-3
    expected = np.ones_like(inl)
    expected[bad, np.arange(len(X))] = False
    assert np.array_equal(inl, expected)
    assert np.all(err < 3 * noise_px + 1e-6)


def test_views_behind_the_camera_never_count_as_inliers():
    _, K, poses, P, X, obs = scene(4, 30, seed=3)
    # A camera facing away from the subject: the algebra still gives consistent "pixels".
    away = look_at([6.0, 0.0, 1.0], target=[12.0, 0.0, 1.0])
    px, depth = project(K, away, X)
    assert np.all(depth < 0)
    P5 = np.concatenate([P, P_of(K, away)[None]])
    obs5 = np.concatenate([obs, px[None]])
    pts, inl, _ = triangulate_ransac(P5, obs5)
    assert errors_m(pts, X).max() < 1e-8
    assert not inl[4].any() and inl[:4].all()


def test_missing_views_and_too_few_views():
    rng, K, poses, P, X, obs = scene(5, 40, seed=4)
    obs = obs + rng.normal(scale=0.3, size=obs.shape)
    conf = rng.uniform(0.5, 1.0, size=obs.shape[:2])
    obs[:3, 0] = np.nan  # point 0: two views
    obs[:4, 1] = np.nan  # point 1: one view
    obs[:, 2] = np.nan  # point 2: none
    conf[0, 3] = np.nan  # point 3: a NaN confidence is missing too
    conf[1, 4] = 0.0  # point 4: and so is a zero one
    obs[2, 4] = np.nan
    obs[3, 4] = np.nan  # ... leaving views 0 and 4
    for est in (triangulate_points(P, obs, conf), triangulate_ransac(P, obs, conf)[0]):
        assert np.all(np.isnan(est[1])) and np.all(np.isnan(est[2]))
        ok = np.ones(len(X), dtype=bool)
        ok[[1, 2]] = False
        assert np.all(np.isfinite(est[ok]))
        assert errors_m(est[ok], X[ok]).max() < 5e-3
    _, inl, err = triangulate_ransac(P, obs, conf)
    assert not inl[:, 1].any() and not inl[:, 2].any() and np.isnan(err[[1, 2]]).all()
    assert np.array_equal(inl[:, 0], [False, False, False, True, True])
    assert np.array_equal(inl[:, 3], [False, True, True, True, True])
    assert np.array_equal(inl[:, 4], [True, False, False, False, True])
    # min_views counts agreeing views: point 0 has only two.
    pts3, inl3, _ = triangulate_ransac(P, obs, conf, min_views=3)
    assert np.all(np.isnan(pts3[0])) and not inl3[:, 0].any() and np.all(np.isfinite(pts3[3]))


def test_confidence_weights_the_views():
    rng, K, poses, P, X, obs = scene(5, 50, seed=5)
    obs[0, :, 0] += 30.0  # a biased view ...
    conf = np.ones(obs.shape[:2])
    conf[0] = 0.05  # ... that says it is unsure
    weighted = errors_m(triangulate_points(P, obs, conf), X)
    plain = errors_m(triangulate_points(P, obs), X)
    assert np.mean(weighted) < 0.1 * np.mean(plain)


def test_sampled_pairs_are_deterministic_and_robust():
    rng, K, poses, P, X, obs = scene(8, 60, seed=6)
    obs = obs + rng.normal(scale=0.5, size=obs.shape)
    bad = rng.integers(0, 8, size=len(X))
    obs[bad, np.arange(len(X))] += [150.0, -80.0]
    a = triangulate_ransac(P, obs, max_pairs=6, seed=3)
    b = triangulate_ransac(P, obs, max_pairs=6, seed=3)
    for u, v in zip(a, b):
        assert np.array_equal(u, v, equal_nan=True)
    # One view in eight is wrong, so most sampled pairs are clean and six tries suffice.
    assert errors_m(a[0], X).max() < 5e-3
    assert not a[1][bad, np.arange(len(X))].any()


def round_off(expected: np.ndarray) -> float:
    """A few float64 ulps of the largest finite magnitude in ``expected``."""
    return 64 * np.finfo(float).eps * np.nanmax(np.abs(expected))


def assert_same_triangulation(got, expected):
    (pts, inl, err), (pts_e, inl_e, err_e) = got, expected
    assert np.array_equal(inl, inl_e)
    assert np.array_equal(np.isnan(pts), np.isnan(pts_e)) and np.array_equal(np.isnan(err), np.isnan(err_e))
    np.testing.assert_allclose(pts, pts_e, rtol=0, atol=round_off(pts_e))
    np.testing.assert_allclose(err, err_e, rtol=0, atol=round_off(err_e))


def test_per_point_projections_equal_the_per_view_form_and_per_frame_calls():
    # One matrix per view repeated over the points is the per-view form, sampled pairs included.
    rng, K, poses, P, X, obs = scene(8, 40, seed=10)
    obs = obs + rng.normal(scale=0.5, size=obs.shape)
    obs[rng.integers(0, 8, size=len(X)), np.arange(len(X))] += 120.0
    obs[2, :5] = np.nan
    repeated = np.repeat(P[:, None], len(X), axis=1)
    for options in ({}, {"max_pairs": 6, "seed": 2}):
        assert_same_triangulation(triangulate_ransac(repeated, obs, **options), triangulate_ransac(P, obs, **options))
    dlt = triangulate_points(P, obs)
    np.testing.assert_allclose(triangulate_points(repeated, obs), dlt, rtol=0, atol=round_off(dlt))

    # Frames of moving cameras batched as one call equal one call per frame.
    n_frames, n_cams, n_points = 6, 5, 17
    K = intrinsics()
    frames = []
    for f in range(n_frames):
        poses = ring(n_cams, radius=4.0 + 0.2 * f, phase=0.3 + 0.15 * f)
        X = random_points(rng, n_points)
        P = np.stack([P_of(K, T) for T in poses])
        obs = np.stack([project(K, T, X)[0] for T in poses]) + rng.normal(scale=0.5, size=(n_cams, n_points, 2))
        obs[f % n_cams, : 2 + f] += [90.0, -40.0]  # a wrong person in one view
        conf = rng.uniform(0.5, 1.0, size=(n_cams, n_points))
        frames.append((P, obs, conf))
    frames[3][1][1] = np.nan  # camera 1 has no frame then: the batch gives it a zero matrix
    per_frame = [triangulate_ransac(P, obs, conf, threshold_px=10.0) for P, obs, conf in frames]
    P_batch = np.concatenate([np.repeat(P[:, None], n_points, axis=1) for P, _, _ in frames], axis=1)
    P_batch[1, 3 * n_points : 4 * n_points] = 0.0
    batched = triangulate_ransac(
        P_batch, np.concatenate([o for _, o, _ in frames], axis=1), np.concatenate([c for _, _, c in frames], axis=1),
        threshold_px=10.0,
    )  # fmt: skip
    pts, inl, err = zip(*per_frame)
    assert_same_triangulation(batched, (np.concatenate(pts), np.concatenate(inl, axis=1), np.concatenate(err)))
    assert not batched[1][1, 3 * n_points : 4 * n_points].any() and np.all(np.isfinite(batched[0]))


def test_distorted_observations_are_undistorted_before_triangulation():
    rng = np.random.default_rng(7)
    # Close cameras with a short focal length, so the points reach where the lens bends most.
    K = intrinsics(600.0)
    dist = np.array([-0.3, 0.09, 0.0008, -0.0006, -0.012])
    poses = ring(4, radius=2.2)
    X = rng.uniform([-0.8, -0.8, 0.1], [0.8, 0.8, 1.9], size=(80, 3))
    obs = []
    for T in poses:
        R = T[:3, :3].T
        t = -R @ T[:3, 3]
        px, _ = cv2.projectPoints(X, cv2.Rodrigues(R)[0], t, K, dist)
        obs.append(px.reshape(-1, 2))
    obs = np.stack(obs)
    P = np.stack([P_of(K, T) for T in poses])
    ideal = np.stack([project(K, T, X)[0] for T in poses])
    und = undistort_pixels(obs, K, dist)
    assert np.abs(und - ideal).max() < 1e-6
    assert np.abs(obs - ideal).max() > 20.0, "the lens must distort noticeably for this test to mean anything"
    assert errors_m(triangulate_points(P, und), X).max() < 1e-6
    assert np.mean(errors_m(triangulate_points(P, obs), X)) > 0.01
    # NaN rows pass through, and zero distortion is the identity.
    obs[0, 0] = np.nan
    assert np.all(np.isnan(undistort_pixels(obs, K, dist)[0, 0]))
    assert np.array_equal(undistort_pixels(obs, K, np.zeros(5)), obs, equal_nan=True)


# ---------------------------------------------------------------------------------------------
# Captures

RATE = 30.0
VELOCITY = np.array([0.2, -0.1, 0.05])  # m/s: slow, so a few ms of clock offset cost < 1 mm


def keypoints_at(base: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(T, K, 3) world keypoints moving at constant velocity."""
    return base[None] + t[:, None, None] * VELOCITY


def make_camera(name, K, dist, poses, timestamps, base, rng, fmt="coco17", rate=RATE, noise_px=0.0):
    """A camera whose detections are the (distorted) projections of the moving keypoints."""
    X = keypoints_at(base, timestamps)
    kp = np.zeros(X.shape[:2] + (3,))
    for f, t in enumerate(timestamps):
        T = poses[0] if len(poses) == 1 else poses[f]
        R = T[:3, :3].T
        px, _ = cv2.projectPoints(X[f], cv2.Rodrigues(R)[0], -R @ T[:3, 3], K, dist)
        kp[f, :, :2] = px.reshape(-1, 2) + rng.normal(scale=noise_px, size=(len(base), 2))
    kp[..., 2] = rng.uniform(0.6, 1.0, size=kp.shape[:2])
    return Camera(
        name=name, K=K, distortion=dist, image_size=SIZE, moving=len(poses) > 1,
        timestamps=np.asarray(timestamps, dtype=float), frame_rate=rate,
        detectors={"det": Detector("det", fmt, kp)}, extrinsics=np.asarray(poses),
    )  # fmt: skip


def small_capture(noise_px: float = 0.0, seed: int = 8) -> tuple[Capture, np.ndarray]:
    rng = np.random.default_rng(seed)
    base = random_points(rng, 17)
    K = intrinsics()
    static = ring(4)
    n = 12
    cams = [
        # The reference camera starts three frames late: the others' first frames still count.
        make_camera("cam0", K, np.zeros(5), [static[0]], (3 + np.arange(n)) / RATE, base, rng, noise_px=noise_px),
        make_camera(
            "cam1", K, np.array([-0.2, 0.05, 0, 0, 0]), [static[1]], np.arange(n + 3) / RATE + 0.004, base, rng,
            noise_px=noise_px,
        ),
        make_camera("cam2", K, np.zeros(5), [static[2]], np.arange(n + 3) / RATE - 0.003, base, rng, noise_px=noise_px),
    ]  # fmt: skip
    # A moving camera at twice the frame rate, sliding along its circle.
    t3 = np.arange(2 * (n + 3)) / (2 * RATE) + 0.001
    moving = [look_at([4.0 * np.cos(4.0 + 0.05 * t), 4.0 * np.sin(4.0 + 0.05 * t), 1.5 + 0.1 * t]) for t in t3]
    cams.append(make_camera("cam3", K, np.zeros(5), moving, t3, base, rng, rate=2 * RATE, noise_px=noise_px))
    return Capture(name="tiny", cameras=cams, world_frame="test"), base


def test_capture_recovers_the_moving_points():
    capture, base = small_capture()
    # A detection a camera lost, and one wrong person in one view.
    capture.cameras[2].detectors["det"].keypoints[5, 3] = np.nan
    capture.cameras[1].detectors["det"].keypoints[6, 4, :2] += 250.0
    tri = triangulate_capture(capture, threshold_px=10.0)
    assert isinstance(tri, Triangulation)
    assert tri.format == "coco17" and tri.detector == "det"
    assert tri.cameras == ("cam0", "cam1", "cam2", "cam3")
    # Reference clock: cam0's 12 frames plus the 3 earlier frames the others saw.
    assert np.allclose(tri.timestamps, np.arange(15) / RATE)
    assert tri.points.shape == (15, 17, 3)
    assert tri.inliers.shape == (15, 4, 17) and tri.reprojection_error_px.shape == (15, 17)
    truth = keypoints_at(base, tri.timestamps)
    err = errors_m(tri.points, truth)
    assert np.all(np.isfinite(err))
    # Offsets of ≤ 4 ms at ~0.23 m/s move the points < 1 mm between views.
    assert err.max() < 2e-3
    assert not tri.inliers[:3, 0].any() and tri.inliers[3:, 0].all()  # cam0 has no early frames
    assert not tri.inliers[6, 1, 4]
    assert tri.inliers[:, 3].all() and tri.inliers[3:, 2, 3].sum() == 11  # cam2 lost one detection
    assert np.nanmax(tri.reprojection_error_px) < 1.0


def test_capture_with_pixel_noise_and_named_detector():
    capture, base = small_capture(noise_px=1.0, seed=9)
    tri = triangulate_capture(capture, "det", seed=1)
    err = errors_m(tri.points, keypoints_at(base, tri.timestamps))
    assert np.mean(err) < 5e-3 and err.max() < 0.015
    again = triangulate_capture(capture, "det", seed=1)
    assert np.array_equal(tri.points, again.points, equal_nan=True)


def test_capture_max_time_offset_drops_late_frames():
    capture, base = small_capture()
    # cam1 runs 4 ms late on every frame: too far for 3.5 ms, and then it can never take part.
    with pytest.raises(MocapgraphError, match="cam1.*no frame within 0.0035 s"):
        triangulate_capture(capture, max_time_offset_s=0.0035)
    # Spread cam1's clock so only its first frames are within 3.5 ms of the reference.
    cam1 = capture.cameras[1]
    cam1.timestamps = cam1.timestamps + 0.0007 * np.arange(len(cam1.timestamps)) - 0.0058
    cam1.detectors["det"].keypoints[...] = make_camera(
        "x", cam1.K, cam1.distortion, cam1.extrinsics, cam1.timestamps, base, np.random.default_rng(0)
    ).detectors["det"].keypoints
    tri = triangulate_capture(capture, max_time_offset_s=0.0035)
    offset = np.abs(cam1.timestamps - np.arange(len(cam1.timestamps)) / RATE)
    assert np.array_equal(tri.inliers[:, 1].all(axis=1), offset <= 0.0035)
    assert 0 < np.count_nonzero(offset <= 0.0035) < len(offset)
    assert errors_m(tri.points, keypoints_at(base, tri.timestamps)).max() < 2e-3


def test_capture_errors_name_the_camera():
    capture, _ = small_capture()
    capture.cameras[2].extrinsics = None
    with pytest.raises(MocapgraphError, match="cam2.*extrinsics"):
        triangulate_capture(capture)

    capture, _ = small_capture()
    with pytest.raises(MocapgraphError, match="cam0.*no detector 'openpose'"):
        triangulate_capture(capture, "openpose")
    capture.cameras[1].detectors = {"other": capture.cameras[1].detectors["det"]}
    with pytest.raises(MocapgraphError, match="cam1.*no detector 'det'"):
        triangulate_capture(capture, "det")
    with pytest.raises(MocapgraphError, match="no detector is present on every camera"):
        triangulate_capture(capture)

    capture, _ = small_capture()
    det = capture.cameras[3].detectors["det"]
    det.format = "openpose25"
    with pytest.raises(MocapgraphError, match="cam3.*'openpose25'.*'coco17'"):
        triangulate_capture(capture)

    capture, _ = small_capture()
    capture.cameras[2].timestamps = capture.cameras[2].timestamps + 100.0
    with pytest.raises(MocapgraphError, match="cam2.*no frame within"):
        triangulate_capture(capture)

    capture, _ = small_capture()
    capture.cameras[1].extrinsics = np.tile(np.eye(4), (3, 1, 1))
    with pytest.raises(MocapgraphError, match=r"cam1.*extrinsics must have shape"):
        triangulate_capture(capture)

    capture, _ = small_capture()
    with pytest.raises(MocapgraphError, match="threshold_px"):
        triangulate_capture(capture, threshold_px=0.0)
    with pytest.raises(MocapgraphError, match="max_time_offset_s"):
        triangulate_capture(capture, max_time_offset_s=-1.0)


def test_bad_point_inputs_name_the_argument():
    _, _, _, P, X, obs = scene(3, 5)
    with pytest.raises(MocapgraphError, match="projections"):
        triangulate_points(P[:, :, :3], obs)
    with pytest.raises(MocapgraphError, match="projections"):
        triangulate_points(np.where(np.eye(3, 4) > 0, np.nan, P), obs)
    with pytest.raises(MocapgraphError, match=r"projections\[1\].*singular"):
        triangulate_points(np.stack([P[0], np.zeros((3, 4)), P[2]]), obs)
    # A matrix no observation goes through is never used: a view without a frame may be zeros.
    unseen = obs.copy()
    unseen[1] = np.nan
    assert np.all(np.isfinite(triangulate_points(np.stack([P[0], np.zeros((3, 4)), P[2]]), unseen)))
    per_point = np.repeat(P[:, None], obs.shape[1], axis=1)
    per_point[2, 4] = 0.0
    with pytest.raises(MocapgraphError, match=r"projections\[2, 4\].*singular"):
        triangulate_ransac(per_point, obs)
    with pytest.raises(MocapgraphError, match="points"):
        triangulate_ransac(per_point[:, 1:], obs)
    with pytest.raises(MocapgraphError, match="points"):
        triangulate_points(P, obs[:2])
    with pytest.raises(MocapgraphError, match="confidences"):
        triangulate_points(P, obs, -np.ones(obs.shape[:2]))
    with pytest.raises(MocapgraphError, match="confidences"):
        triangulate_points(P, obs, np.ones((3, 4)))
    with pytest.raises(MocapgraphError, match="threshold_px"):
        triangulate_ransac(P, obs, threshold_px=-1.0)
    with pytest.raises(MocapgraphError, match="min_views"):
        triangulate_ransac(P, obs, min_views=1)
    with pytest.raises(MocapgraphError, match="max_pairs"):
        triangulate_ransac(P, obs, max_pairs=0)
