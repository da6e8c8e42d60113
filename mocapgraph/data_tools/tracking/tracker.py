"""AirCap's CDT person tracker: one 3D track of the person from every camera's person boxes.

An extended Kalman filter (``filterpy.kalman.ExtendedKalmanFilter``) follows the person's centre
(the pelvis) in the world frame. Its state is position and velocity ``[p, v]`` (metres, m/s); the
motion model is constant velocity driven by continuous white-noise acceleration. The cameras are
not synchronised: every camera frame is a measurement at its own timestamp, processed in time
order (predict to that time, then update). The measurement is the person box: its centre and,
optionally, its height (which carries the range); the filter predicts it by projecting a nominal
person — a vertical square prism around the state position, turned to face the camera — through
the camera's *prior* pose (GPS/IMU, not ground truth) with the one camera model
(:func:`~mocapgraph.data_tools.geometry.camera_model.project_points`). Boxes cut by the image border measure
only their uncut edges. Mahalanobis gating rejects outlier boxes; a backward Rauch–Tung–Striebel
pass (``KalmanFilter.rts_smoother``) lets the offline track use future frames. ``docs/tracker.md``
describes the model, its parameters and its measured accuracy.

Uses downstream: the track initialises the body's position, :meth:`Track.predicted_rois` gives
each camera frame a region of interest, and :meth:`Track.inlier_detections` rejects keypoints
far from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter, KalmanFilter
from scipy.stats import chi2

from mocapgraph.data_tools.geometry.camera_model import project_points, undistort_pixels
from mocapgraph.data_tools.io.capture import Camera, Capture
from mocapgraph.errors import MocapgraphError

UP = np.array([0.0, 0.0, 1.0])
"""World up (Z up, ``DESIGN.md``)."""

_JACOBIAN_STEP_M = 1e-3
_REFINE_ITERATIONS = 5
_MIN_RAY_ANGLE_RAD = math.radians(3.0)

# Measurement rows as combinations of the box edges [x0, y0, x1, y1].
_ROWS = {
    "u": (0.5, 0.0, 0.5, 0.0),
    "v": (0.0, 0.5, 0.0, 0.5),
    "h": (0.0, -1.0, 0.0, 1.0),
    "x0": (1.0, 0.0, 0.0, 0.0),
    "x1": (0.0, 0.0, 1.0, 0.0),
    "y0": (0.0, 1.0, 0.0, 0.0),
    "y1": (0.0, 0.0, 0.0, 1.0),
}


@dataclass(frozen=True)
class TrackerParams:
    """Every number of the tracker (``docs/tracker.md`` explains each one and its default).

    Attributes:
        accel_std_m_s2: horizontal acceleration noise: spectral density ``accel_std²`` (m²/s³) of
            the continuous white-noise acceleration, i.e. the velocity's random walk grows by this
            many m/s over one second.
        vertical_accel_std_m_s2: the same for the vertical axis (a person's pelvis hardly moves up
            or down).
        person_height_m: vertical extent of the nominal person as its box frames it (feet to head
            top plus the detector's box margin).
        person_width_m: horizontal extent of the nominal person (with the box margin).
        pelvis_height_m: height of the tracked centre above the bottom of the nominal person.
        use_box_height: measure the box height (gives the range from a single camera).
        center_noise_frac: std of the box centre (pixels per axis) as a fraction of the box height.
        edge_noise_frac: std of a single box edge (used when the opposite edge is cut by the image
            border), as a fraction of the box height.
        height_noise_frac: std of the box height as a fraction of it.
        noise_floor_px: added in quadrature to the centre and edge stds.
        camera_position_std_m: std of the prior camera positions; with the rotation std it adds
            ``f · sqrt((σ_t / depth)² + σ_R²)`` pixels in quadrature to the centre and edge stds.
        camera_rotation_std_deg: std of the prior camera orientations.
        gate_probability: chi² quantile of the Mahalanobis gate (0.99: a correct box is rejected
            1 time in 100).
        min_box_score: boxes scored below this are ignored.
        border_px: a box edge within this of the image border is cut, and not measured.
        keypoint_box_margin_frac: margin on each side (fraction of the height) of a box derived
            from keypoints when a detector has no boxes.
        keypoint_min_confidence: keypoints at or below this confidence do not make a box.
        min_keypoints: fewer present keypoints make no box.
        init_window_s: the initial position is found from the boxes of this first stretch of time.
        init_pair_max_dt_s: two boxes of different cameras at most this far apart in time make a
            ray-intersection candidate.
        init_inlier_frac: a box supports a candidate position when its centre is within this
            fraction of its height of the predicted centre.
        init_position_std_m: initial position std (per axis).
        init_velocity_std_m_s: initial velocity std (per axis).
        max_consecutive_rejections: after this many gated-out boxes in a row the filter tries to
            re-initialise from them (a lost track).
        observed_window_s: a track time is *observed* when an accepted box lies within this time
            of it (before or after); otherwise the filter coasts there.
        smooth: run the backward RTS pass (offline); False returns the forward filter.
    """

    accel_std_m_s2: float = 2.0
    vertical_accel_std_m_s2: float = 0.3
    person_height_m: float = 1.6
    person_width_m: float = 0.4
    pelvis_height_m: float = 0.9
    use_box_height: bool = True
    center_noise_frac: float = 0.06
    edge_noise_frac: float = 0.08
    height_noise_frac: float = 0.12
    noise_floor_px: float = 3.0
    camera_position_std_m: float = 0.5
    camera_rotation_std_deg: float = 1.0
    gate_probability: float = 0.99
    min_box_score: float = 0.0
    border_px: float = 2.0
    keypoint_box_margin_frac: float = 0.08
    keypoint_min_confidence: float = 0.05
    min_keypoints: int = 4
    init_window_s: float = 0.3
    init_pair_max_dt_s: float = 0.1
    init_inlier_frac: float = 0.5
    init_position_std_m: float = 1.0
    init_velocity_std_m_s: float = 1.5
    max_consecutive_rejections: int = 30
    observed_window_s: float = 0.2
    smooth: bool = True

    def __post_init__(self):
        positive = (
            "accel_std_m_s2", "vertical_accel_std_m_s2", "person_height_m", "person_width_m",
            "center_noise_frac", "edge_noise_frac", "height_noise_frac", "init_window_s",
            "init_inlier_frac", "init_position_std_m", "init_velocity_std_m_s", "observed_window_s",
        )  # fmt: skip
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not math.isfinite(value):
                raise MocapgraphError(f"TrackerParams.{f.name} must be finite, got {value}")
            if f.name in positive and not value > 0:
                raise MocapgraphError(f"TrackerParams.{f.name} must be positive, got {value}")
            if isinstance(value, (int, float)) and not isinstance(value, bool) and value < 0:
                raise MocapgraphError(f"TrackerParams.{f.name} must not be negative, got {value}")
        if not 0 < self.gate_probability < 1:
            raise MocapgraphError(f"TrackerParams.gate_probability must lie in (0, 1), got {self.gate_probability}")
        if self.max_consecutive_rejections < 1 or self.min_keypoints < 1:
            raise MocapgraphError("TrackerParams.max_consecutive_rejections and min_keypoints must be >= 1")


# ---------------------------------------------------------------------------------------------
# Motion model


def transition(dt: float) -> np.ndarray:
    """``(6, 6)`` constant-velocity transition over ``dt`` seconds (state ``[p, v]``)."""
    F = np.eye(6)
    F[:3, 3:] = dt * np.eye(3)
    return F


def process_noise(dt: float, params: TrackerParams) -> np.ndarray:
    """``(6, 6)`` process noise of continuous white-noise acceleration over ``|dt|`` seconds."""
    dt = abs(dt)
    q = np.array([params.accel_std_m_s2, params.accel_std_m_s2, params.vertical_accel_std_m_s2]) ** 2
    Q = np.zeros((6, 6))
    Q[:3, :3] = np.diag(q * dt**3 / 3)
    Q[:3, 3:] = Q[3:, :3] = np.diag(q * dt**2 / 2)
    Q[3:, 3:] = np.diag(q * dt)
    return Q


# ---------------------------------------------------------------------------------------------
# Measurement model: the box of a nominal person


def _across(world_T_camera: np.ndarray, extra_dims: int) -> np.ndarray:
    """Horizontal unit vector along each camera's x axis, shaped to broadcast over ``extra_dims``
    more leading dimensions of the points."""
    x = np.array(world_T_camera[..., :3, 0], dtype=float)
    x[..., 2] = 0.0
    n = np.linalg.norm(x, axis=-1, keepdims=True)
    x = np.where(n > 1e-6, x / np.maximum(n, 1e-12), np.array([1.0, 0.0, 0.0]))
    return x.reshape(x.shape[:-1] + (1,) * extra_dims + (3,))


def person_points(centres, world_T_camera, params: TrackerParams) -> np.ndarray:
    """``(..., 8, 3)`` corners of the nominal person around ``centres (..., 3)``: a vertical square
    prism ``person_width_m`` wide and ``person_height_m`` tall whose bottom is ``pelvis_height_m``
    below the centre, turned so that one side faces each camera (``world_T_camera (*B, 4, 4)``, B a
    prefix of the centres' leading shape)."""
    centres = np.asarray(centres, dtype=float)
    T = np.asarray(world_T_camera, dtype=float)
    across = _across(T, centres.ndim - 1 - (T.ndim - 2))
    along = np.stack([-across[..., 1], across[..., 0], across[..., 2]], axis=-1)  # UP × across
    half = 0.5 * params.person_width_m
    lateral = half * np.stack([across, -across, along, -along], axis=-2)  # (..., 4, 3)
    bottom = centres - params.pelvis_height_m * UP
    top = bottom + params.person_height_m * UP
    return np.concatenate([bottom[..., None, :] + lateral, top[..., None, :] + lateral], axis=-2)


def predicted_boxes(centres, world_T_camera, camera: Camera, params: TrackerParams) -> np.ndarray:
    """``(..., 4)`` box ``x0, y0, x1, y1`` of the nominal person at ``centres (..., 3)`` seen by
    ``camera`` posed at ``world_T_camera (*B, 4, 4)``; NaN where any corner is behind the camera."""
    corners = person_points(centres, world_T_camera, params)
    pixels, _ = project_points(corners, world_T_camera, camera.K, camera.distortion)
    return np.concatenate([pixels.min(axis=-2), pixels.max(axis=-2)], axis=-1)


def _pose_pixel_std(focal: float, depth, params: TrackerParams):
    """Pixel std caused by the uncertainty of the prior camera pose, at ``depth`` metres."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return focal * np.hypot(params.camera_position_std_m / depth, math.radians(params.camera_rotation_std_deg))


def _focal(camera: Camera) -> float:
    return 0.5 * float(camera.K[0, 0] + camera.K[1, 1])


def _measurement_rows(box: np.ndarray, image_size, params: TrackerParams) -> list[str]:
    """Which rows of :data:`_ROWS` a measured box supports: the centre where both edges are
    inside the image, the uncut edge where one is cut, nothing where both are."""
    x0, y0, x1, y1 = box[:4]
    w, h = image_size
    b = params.border_px
    left, right, top, bottom = x0 <= b, x1 >= w - 1 - b, y0 <= b, y1 >= h - 1 - b
    rows = []
    if not (left and right):
        rows.append("x1" if left else "x0" if right else "u")
    if not (top and bottom):
        rows.append("y1" if top else "y0" if bottom else "v")
    if params.use_box_height and not (top or bottom):
        rows.append("h")
    return rows


@dataclass
class _Linearised:
    z: np.ndarray  # (m,) measured
    z_pred: np.ndarray  # (m,) predicted at the linearisation point
    H: np.ndarray  # (m, 6)
    R: np.ndarray  # (m, m)


def _linearise(position, box, camera: Camera, world_T_camera, params: TrackerParams) -> _Linearised | None:
    """The box measurement linearised at ``position`` (numeric forward differences of 1 mm), or
    None when the box has no usable row or the nominal person is not in front of the camera."""
    rows = _measurement_rows(box, camera.image_size, params)
    if not rows:
        return None
    A = np.array([_ROWS[r] for r in rows])
    eps = _JACOBIAN_STEP_M
    probes = position + np.concatenate([np.zeros((1, 3)), eps * np.eye(3)])
    edges = predicted_boxes(probes, world_T_camera, camera, params)
    if not np.all(np.isfinite(edges)):
        return None
    H = np.zeros((len(rows), 6))
    H[:, :3] = A @ ((edges[1:4] - edges[0]).T / eps)
    depth = float(world_T_camera[:3, 2] @ (position - world_T_camera[:3, 3]))  # camera z
    # a box cut by the border is shorter than the person: scale its noise by the predicted height
    height = max(float(box[3] - box[1]), float(edges[0, 3] - edges[0, 1]))
    pose_px = float(_pose_pixel_std(_focal(camera), depth, params))
    frac = {"u": params.center_noise_frac, "v": params.center_noise_frac}
    var = []
    for r in rows:
        if r == "h":
            var.append((params.height_noise_frac * height) ** 2 + (height * params.camera_position_std_m / depth) ** 2)
        else:
            s = frac.get(r, params.edge_noise_frac) * height
            var.append(s**2 + params.noise_floor_px**2 + pose_px**2)
    return _Linearised(A @ box[:4], A @ edges[0], H, np.diag(var))


# ---------------------------------------------------------------------------------------------
# Boxes from detections


def boxes_from_keypoints(keypoints, image_size, params: TrackerParams = TrackerParams()) -> np.ndarray:
    """``(T, 5)`` person boxes ``x0, y0, x1, y1, score`` from keypoints ``(T, K, 3)``: the box of
    the points with confidence above ``keypoint_min_confidence``, each side widened by
    ``keypoint_box_margin_frac`` of its height, clipped to the image; score = mean confidence of
    those points × sqrt(the fraction present). NaN rows where fewer than ``min_keypoints``."""
    kp = np.asarray(keypoints, dtype=float)
    conf = kp[..., 2]
    with np.errstate(invalid="ignore"):
        present = np.isfinite(kp).all(axis=-1) & (conf > params.keypoint_min_confidence)
    xy = np.where(present[..., None], kp[..., :2], np.nan)
    count = present.sum(axis=-1)
    ok = count >= params.min_keypoints
    out = np.full((kp.shape[0], 5), np.nan)
    if not ok.any():
        return out
    lo, hi = np.nanmin(xy[ok], axis=-2), np.nanmax(xy[ok], axis=-2)
    margin = params.keypoint_box_margin_frac * (hi[:, 1] - lo[:, 1])[:, None]
    w, h = image_size
    limit = np.array([w - 1, h - 1], dtype=float)
    out[ok, :2] = np.clip(lo - margin, 0.0, limit)
    out[ok, 2:4] = np.clip(hi + margin, 0.0, limit)
    mean_conf = np.where(present[ok], conf[ok], 0.0).sum(axis=-1) / count[ok]
    out[ok, 4] = mean_conf * np.sqrt(count[ok] / kp.shape[1])
    return out


def camera_boxes(camera: Camera, detector: str | None = None, params: TrackerParams = TrackerParams()) -> np.ndarray:
    """``(T_c, 5)`` the person box the tracker uses in each frame of ``camera``.

    ``detector`` names one detector (its boxes, or boxes from its keypoints when it has none);
    None takes, per frame, the highest-scored box among all the camera's detectors. Boxes scored
    below ``min_box_score`` or without area are NaN."""
    if detector is not None and detector not in camera.detectors:
        known = ", ".join(camera.detectors) or "none"
        raise MocapgraphError(f"camera {camera.name!r} has no detector {detector!r} (detectors: {known})")
    names = [detector] if detector is not None else list(camera.detectors)
    best = np.full((camera.num_frames, 5), np.nan)
    best_score = np.full(camera.num_frames, -np.inf)
    for name in names:
        det = camera.detectors[name]
        boxes = det.boxes if det.boxes is not None else boxes_from_keypoints(det.keypoints, camera.image_size, params)
        boxes = np.array(boxes, dtype=float).reshape(camera.num_frames, 5)
        score = np.where(np.isfinite(boxes[:, 4]), boxes[:, 4], 0.0)
        with np.errstate(invalid="ignore"):
            usable = (
                np.isfinite(boxes[:, :4]).all(axis=1)
                & (boxes[:, 2] > boxes[:, 0])
                & (boxes[:, 3] > boxes[:, 1])
                & (score >= params.min_box_score)
            )
        better = usable & (score > best_score)
        best[better] = boxes[better]
        best[better, 4] = score[better]
        best_score[better] = score[better]
    return best


def _check_poses(capture: Capture, camera_poses: dict) -> dict[str, np.ndarray]:
    """Camera poses as ``(T_c, 4, 4)`` per camera name (a single ``(4, 4)`` or ``(1, 4, 4)`` pose is
    repeated for every frame)."""
    if not camera_poses:
        raise MocapgraphError("camera_poses is empty: the tracker needs a pose for at least one camera")
    out = {}
    for name, poses in camera_poses.items():
        cam = capture.camera(name)
        T = np.asarray(poses, dtype=float)
        if T.shape == (4, 4):
            T = T[None]
        if T.ndim != 3 or T.shape[1:] != (4, 4) or T.shape[0] not in (1, cam.num_frames):
            raise MocapgraphError(
                f"camera_poses[{name!r}]: expected (4, 4), (1, 4, 4) or ({cam.num_frames}, 4, 4), got {T.shape}"
            )
        if not np.all(np.isfinite(T)):
            raise MocapgraphError(f"camera_poses[{name!r}]: contains NaN or inf")
        out[name] = np.broadcast_to(T, (cam.num_frames, 4, 4))
    return out


# ---------------------------------------------------------------------------------------------
# The track


@dataclass
class Track:
    """The person's track: one state per camera frame of the cameras tracked, in time order.

    Attributes:
        times: ``(N,)`` seconds (non-decreasing; frames of different cameras may coincide).
        position: ``(N, 3)`` world, metres: the person's centre at pelvis height.
        velocity: ``(N, 3)`` m/s.
        covariance: ``(N, 6, 6)`` of ``[position, velocity]``.
        accepted: ``(N,)`` the frame's box passed the gate and updated the filter.
        detected: ``(N,)`` the frame had a usable box (accepted or not).
        observed: ``(N,)`` an accepted box lies within ``observed_window_s`` of the time; False
            where the filter coasts (predicts only).
        camera: ``(N,)`` name of the camera of each frame.
        frame: ``(N,)`` index of the frame in its camera.
        mahalanobis2: ``(N,)`` squared Mahalanobis distance of the box's innovation; NaN without one.
        reinitialised: ``(N,)`` the filter was re-initialised at this frame (a lost track found again).
        filtered_position, filtered_velocity, filtered_covariance: the forward filter (what an
            online tracker would have known then).
        params: the parameters used.
        detector: the detector used, or None (best-scored box per frame).
    """

    times: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    covariance: np.ndarray
    accepted: np.ndarray
    detected: np.ndarray
    observed: np.ndarray
    camera: np.ndarray
    frame: np.ndarray
    mahalanobis2: np.ndarray
    reinitialised: np.ndarray
    filtered_position: np.ndarray
    filtered_velocity: np.ndarray
    filtered_covariance: np.ndarray
    params: TrackerParams = field(default_factory=TrackerParams)
    detector: str | None = None

    def _interpolate(self, times) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.atleast_1d(np.asarray(times, dtype=float))
        N = len(self.times)
        pos, vel, cov = np.empty((len(t), 3)), np.empty((len(t), 3)), np.empty((len(t), 6, 6))
        i = np.searchsorted(self.times, t, side="right") - 1
        inner = (i >= 0) & (i < N - 1)
        inner[inner] = t[inner] > self.times[i[inner]]
        # at a state's time or outside the track: constant-velocity prediction from the nearest state
        for j in np.flatnonzero(~inner):
            k = min(max(i[j], 0), N - 1)
            dt = t[j] - self.times[k]
            F = transition(dt)
            x = F @ np.concatenate([self.position[k], self.velocity[k]])
            pos[j], vel[j] = x[:3], x[3:]
            cov[j] = F @ self.covariance[k] @ F.T + process_noise(dt, self.params)
        # between two states: cubic Hermite through both positions and velocities
        a = i[inner]
        h = (self.times[a + 1] - self.times[a])[:, None]
        s = (t[inner] - self.times[a])[:, None]
        s = s / h
        p0, p1, v0, v1 = self.position[a], self.position[a + 1], self.velocity[a], self.velocity[a + 1]
        pos[inner] = (
            (2 * s**3 - 3 * s**2 + 1) * p0 + (s**3 - 2 * s**2 + s) * h * v0
            + (-2 * s**3 + 3 * s**2) * p1 + (s**3 - s**2) * h * v1
        )  # fmt: skip
        vel[inner] = (6 * s**2 - 6 * s) * (p0 - p1) / h + (3 * s**2 - 4 * s + 1) * v0 + (3 * s**2 - 2 * s) * v1
        w = s[:, :, None]
        cov[inner] = (1 - w) * self.covariance[a] + w * self.covariance[a + 1]
        return pos, vel, cov

    def at(self, times) -> tuple[np.ndarray, np.ndarray]:
        """Positions ``(M, 3)`` and covariances ``(M, 6, 6)`` (of position and velocity) at ``times
        (M,)``: cubic Hermite between the neighbouring states, the covariance interpolated
        linearly; outside the track, constant-velocity extrapolation with growing covariance."""
        pos, _, cov = self._interpolate(times)
        return pos, cov

    def velocity_at(self, times) -> np.ndarray:
        """Velocities ``(M, 3)`` at ``times (M,)``, as :meth:`at` interpolates."""
        return self._interpolate(times)[1]

    def predicted_rois(
        self, capture: Capture, camera_poses: dict, margin: float = 0.2, n_sigma: float = 3.0
    ) -> dict[str, np.ndarray]:
        """Regions of interest ``(T_c, 4)`` ``x0, y0, x1, y1`` (pixels, not clipped to the image) per
        camera frame of each camera in ``camera_poses``: the nominal person's box at the tracked
        position, each side widened by ``margin`` × its height plus ``n_sigma`` pixel stds of the
        projected position uncertainty (the camera pose prior is already in it: the track was fitted
        through these poses). NaN where the person would be behind the camera."""
        poses = _check_poses(capture, camera_poses)
        out = {}
        for name, T in poses.items():
            cam = capture.camera(name)
            pos, cov = self.at(cam.timestamps)
            box = predicted_boxes(pos, T, cam, self.params)
            eps = _JACOBIAN_STEP_M
            probes = pos[:, None] + np.concatenate([eps * np.eye(3), -eps * np.eye(3)])[None]
            px, _ = project_points(probes, T, cam.K, cam.distortion)
            J = np.swapaxes(px[:, :3] - px[:, 3:], 1, 2) / (2 * eps)  # (T_c, 2, 3)
            S = J @ cov[:, :3, :3] @ np.swapaxes(J, 1, 2)
            grow = margin * (box[:, 3] - box[:, 1])
            ex = grow + n_sigma * np.sqrt(np.maximum(S[:, 0, 0], 0))
            ey = grow + n_sigma * np.sqrt(np.maximum(S[:, 1, 1], 0))
            roi = box + np.stack([-ex, -ey, ex, ey], axis=1)
            roi[~np.all(np.isfinite(roi), axis=1)] = np.nan
            out[name] = roi
        return out

    def inlier_detections(
        self,
        capture: Capture,
        camera_poses: dict,
        max_distance_px: float = 0.0,
        *,
        detector: str | None = None,
        margin: float = 0.2,
        n_sigma: float = 3.0,
    ) -> dict[str, np.ndarray]:
        """``(T_c, K)`` per camera: True where a keypoint of ``detector`` is present and lies within
        ``max_distance_px`` of the frame's ROI (:meth:`predicted_rois` with ``margin`` and
        ``n_sigma``, the gate); False for keypoints farther away (outliers), missing ones, and all
        of a frame where the person would be behind the camera.

        ``detector`` defaults to the one the track used, else each camera's first detector."""
        rois = self.predicted_rois(capture, camera_poses, margin=margin, n_sigma=n_sigma)
        out = {}
        for name, roi in rois.items():
            cam = capture.camera(name)
            det_name = detector or self.detector or next(iter(cam.detectors), None)
            if det_name is None or det_name not in cam.detectors:
                raise MocapgraphError(f"camera {name!r} has no detector {det_name!r}")
            kp = cam.detectors[det_name].keypoints
            u, v = kp[..., 0], kp[..., 1]
            with np.errstate(invalid="ignore"):
                dx = np.maximum(np.maximum(roi[:, None, 0] - u, u - roi[:, None, 2]), 0.0)
                dy = np.maximum(np.maximum(roi[:, None, 1] - v, v - roi[:, None, 3]), 0.0)
                out[name] = np.hypot(dx, dy) <= max_distance_px
        return out


# ---------------------------------------------------------------------------------------------
# Initialisation


@dataclass
class _Events:
    """Every camera frame of the tracked cameras, in time order."""

    times: np.ndarray  # (N,)
    camera: np.ndarray  # (N,) index into cameras
    frame: np.ndarray  # (N,)
    boxes: np.ndarray  # (N, 5)
    cameras: list[Camera]
    poses: list[np.ndarray]  # per camera (T_c, 4, 4)

    def pose(self, e: int) -> np.ndarray:
        return self.poses[self.camera[e]][self.frame[e]]


def _events(capture: Capture, poses: dict[str, np.ndarray], detector: str | None, params: TrackerParams) -> _Events:
    cams = [capture.camera(n) for n in poses]
    times, camera, frame, boxes = [], [], [], []
    for c, cam in enumerate(cams):
        times.append(np.asarray(cam.timestamps, dtype=float))
        camera.append(np.full(cam.num_frames, c))
        frame.append(np.arange(cam.num_frames))
        boxes.append(camera_boxes(cam, detector, params))
    times, camera, frame, boxes = map(np.concatenate, (times, camera, frame, boxes))
    order = np.lexsort((camera, times))
    return _Events(times[order], camera[order], frame[order], boxes[order], cams, [poses[c.name] for c in cams])


def _rays(ev: _Events, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera centres and unit rays ``(n, 3)`` through the box centres of events ``idx``."""
    centres, rays = np.empty((len(idx), 3)), np.empty((len(idx), 3))
    for j, e in enumerate(idx):
        cam, T = ev.cameras[ev.camera[e]], ev.pose(e)
        b = ev.boxes[e]
        uv = undistort_pixels(np.array([0.5 * (b[0] + b[2]), 0.5 * (b[1] + b[3])]), cam.K, cam.distortion)
        d = T[:3, :3] @ np.linalg.solve(cam.K, np.array([uv[0], uv[1], 1.0]))
        centres[j], rays[j] = T[:3, 3], d / np.linalg.norm(d)
    return centres, rays


def _candidates(ev: _Events, idx: np.ndarray, params: TrackerParams) -> np.ndarray:
    """Candidate positions: each box's ray at the range its height gives, and the closest points
    of the rays of two boxes from different cameras close in time."""
    C, d = _rays(ev, idx)
    heights = ev.boxes[idx, 3] - ev.boxes[idx, 1]
    focal = np.array([_focal(ev.cameras[ev.camera[e]]) for e in idx])
    out = [C + (focal * params.person_height_m / heights)[:, None] * d]
    i, j = np.triu_indices(len(idx), k=1)
    keep = (ev.camera[idx[i]] != ev.camera[idx[j]]) & (
        np.abs(ev.times[idx[i]] - ev.times[idx[j]]) <= params.init_pair_max_dt_s
    )
    i, j = i[keep], j[keep]
    b = np.einsum("ij,ij->i", d[i], d[j])
    w0 = C[i] - C[j]
    dd, ee = np.einsum("ij,ij->i", d[i], w0), np.einsum("ij,ij->i", d[j], w0)
    denom = 1.0 - b**2
    good = denom > math.sin(_MIN_RAY_ANGLE_RAD) ** 2
    s = (b * ee - dd)[good] / denom[good]
    t = (ee - b * dd)[good] / denom[good]
    ahead = (s > 0) & (t > 0)
    mid = 0.5 * (C[i][good] + s[:, None] * d[i][good] + C[j][good] + t[:, None] * d[j][good])
    out.append(mid[ahead])
    return np.concatenate(out)


def _support(ev: _Events, idx: np.ndarray, candidates: np.ndarray, params: TrackerParams) -> np.ndarray:
    """``(n, M)`` whether box ``idx[n]`` supports candidate ``m`` (centre and height agree)."""
    sup = np.zeros((len(idx), len(candidates)), dtype=bool)
    for c, cam in enumerate(ev.cameras):
        sel = np.flatnonzero(ev.camera[idx] == c)
        if not len(sel):
            continue
        e = idx[sel]
        T = np.stack([ev.pose(k) for k in e])
        pred = predicted_boxes(np.broadcast_to(candidates, (len(e),) + candidates.shape), T, cam, params)
        box = ev.boxes[e][:, None, :4]
        h = box[..., 3] - box[..., 1]
        du = 0.5 * (pred[..., 0] + pred[..., 2] - box[..., 0] - box[..., 2])
        dv = 0.5 * (pred[..., 1] + pred[..., 3] - box[..., 1] - box[..., 3])
        ratio = (pred[..., 3] - pred[..., 1]) / h
        with np.errstate(invalid="ignore"):
            ok = np.hypot(du, dv) <= params.init_inlier_frac * h
            if params.use_box_height:
                ok &= np.abs(np.log(ratio)) <= math.log(1.5)
        sup[sel] = ok
    return sup


def _refine(position: np.ndarray, ev: _Events, idx: np.ndarray, params: TrackerParams) -> np.ndarray:
    """Gauss–Newton on the whitened box residuals of events ``idx`` (a static person)."""
    for _ in range(_REFINE_ITERATIONS):
        Js, rs = [], []
        for e in idx:
            lin = _linearise(position, ev.boxes[e], ev.cameras[ev.camera[e]], ev.pose(e), params)
            if lin is None:
                continue
            w = 1.0 / np.sqrt(np.diag(lin.R))
            Js.append(lin.H[:, :3] * w[:, None])
            rs.append((lin.z - lin.z_pred) * w)
        if not Js:
            break
        J, r = np.concatenate(Js), np.concatenate(rs)
        step = np.linalg.lstsq(J, r, rcond=None)[0]
        position = position + step
        if np.linalg.norm(step) < 1e-4:
            break
    return position


def _initial_position(ev: _Events, idx: np.ndarray, params: TrackerParams) -> tuple[np.ndarray, int] | None:
    """Best-supported candidate position from the boxes of events ``idx``, refined on the boxes
    that support it, and how many do; None without a candidate in front of the cameras."""
    if not len(idx):
        return None
    cand = _candidates(ev, idx, params)
    cand = cand[np.all(np.isfinite(cand), axis=1)]
    if not len(cand):
        return None
    sup = _support(ev, idx, cand, params)
    count = sup.sum(axis=0)
    best = int(np.argmax(count))  # first of the best: the single-view candidates come first
    if count[best] == 0:
        return None
    inliers = idx[sup[:, best]]
    return _refine(cand[best], ev, inliers, params), int(count[best])


# ---------------------------------------------------------------------------------------------
# The filter


def track_person(
    capture: Capture,
    camera_poses: dict,
    *,
    detector: str | None = None,
    params: TrackerParams = TrackerParams(),
) -> Track:
    """Track the person in 3D from the person boxes of every camera in ``camera_poses``.

    Args:
        capture: its cameras' detections (boxes, or keypoints where a detector has no boxes).
        camera_poses: ``{camera name: world_T_camera (T_c, 4, 4)}`` prior poses (GPS/IMU, a
            calibration; not necessarily exact); ``(4, 4)`` for a static camera. Only these cameras
            are tracked.
        detector: the detector whose boxes are used; None takes each frame's best-scored box among
            all the camera's detectors.
        params: see :class:`TrackerParams`.

    Returns:
        a :class:`Track` with one state per frame of the tracked cameras, smoothed unless
        ``params.smooth`` is False.

    Raises:
        MocapgraphError: no usable box in any camera, or malformed poses.
    """
    poses = _check_poses(capture, camera_poses)
    ev = _events(capture, poses, detector, params)
    N = len(ev.times)
    has_box = np.isfinite(ev.boxes[:, 0])
    if not has_box.any():
        raise MocapgraphError(f"capture {capture.name!r}: no person box in any tracked camera, nothing to track")

    first = ev.times[np.argmax(has_box)]
    window = np.flatnonzero(has_box & (ev.times <= first + params.init_window_s))
    init = _initial_position(ev, window, params)
    if init is None:
        raise MocapgraphError(f"capture {capture.name!r}: the first person boxes give no position in front of the cameras")
    P0 = np.diag([params.init_position_std_m**2] * 3 + [params.init_velocity_std_m_s**2] * 3)

    ekf = ExtendedKalmanFilter(dim_x=6, dim_z=3)
    ekf.x = np.concatenate([init[0], np.zeros(3)])
    ekf.P = P0.copy()

    xs, Ps = np.empty((N, 6)), np.empty((N, 6, 6))
    Fs, Qs = np.empty((N, 6, 6)), np.empty((N, 6, 6))
    accepted, detected = np.zeros(N, dtype=bool), np.zeros(N, dtype=bool)
    reinit = np.zeros(N, dtype=bool)
    d2 = np.full(N, np.nan)
    gate = {m: chi2.ppf(params.gate_probability, m) for m in (1, 2, 3)}
    rejected_run: list[int] = []
    t_prev = ev.times[0]
    for k in range(N):
        dt = ev.times[k] - t_prev
        t_prev = ev.times[k]
        Fs[k], Qs[k] = transition(dt), process_noise(dt, params)
        ekf.F, ekf.Q = Fs[k], Qs[k]
        ekf.predict()
        if has_box[k]:
            cam, T = ev.cameras[ev.camera[k]], ev.pose(k)
            lin = _linearise(ekf.x[:3], ev.boxes[k], cam, T, params)
            if lin is not None:
                detected[k] = True
                y = lin.z - lin.z_pred
                S = lin.H @ ekf.P @ lin.H.T + lin.R
                d2[k] = float(y @ np.linalg.solve(S, y))
                if d2[k] <= gate[len(y)]:
                    ekf.update(lin.z, lambda x, H=lin.H: H, lambda x, z=lin.z_pred: z, R=lin.R)
                    accepted[k] = True
                    rejected_run.clear()
                else:
                    rejected_run.append(k)
            if len(rejected_run) >= params.max_consecutive_rejections:
                recent = np.array([e for e in rejected_run if ev.times[e] >= ev.times[k] - params.init_window_s])
                found = _initial_position(ev, recent, params)
                if found is not None and found[1] >= max(3, len(recent) // 2):
                    ekf.x = np.concatenate([found[0], np.zeros(3)])
                    ekf.P = P0.copy()
                    reinit[k] = True
                rejected_run.clear()
        xs[k], Ps[k] = ekf.x, 0.5 * (ekf.P + ekf.P.T)

    if params.smooth:
        xs_s, Ps_s = _smooth(xs, Ps, Fs, Qs, reinit)
    else:
        xs_s, Ps_s = xs, Ps
    return Track(
        times=ev.times.copy(),
        position=xs_s[:, :3].copy(),
        velocity=xs_s[:, 3:].copy(),
        covariance=Ps_s,
        accepted=accepted,
        detected=detected,
        observed=_near(ev.times, ev.times[accepted], params.observed_window_s),
        camera=np.array([ev.cameras[c].name for c in ev.camera]),
        frame=ev.frame.copy(),
        mahalanobis2=d2,
        reinitialised=reinit,
        filtered_position=xs[:, :3].copy(),
        filtered_velocity=xs[:, 3:].copy(),
        filtered_covariance=Ps,
        params=params,
        detector=detector,
    )


def _smooth(xs, Ps, Fs, Qs, reinit) -> tuple[np.ndarray, np.ndarray]:
    """RTS smoother (filterpy) over each stretch between re-initialisations."""
    kf = KalmanFilter(dim_x=6, dim_z=1)
    out_x, out_P = xs.copy(), Ps.copy()
    starts = [0, *np.flatnonzero(reinit[1:]) + 1, len(xs)]
    for a, b in zip(starts[:-1], starts[1:]):
        if b - a < 2:
            continue
        x, P, _, _ = kf.rts_smoother(xs[a:b], Ps[a:b], Fs[a:b], Qs[a:b])
        out_x[a:b], out_P[a:b] = x, 0.5 * (P + np.swapaxes(P, 1, 2))
    return out_x, out_P


def _near(times: np.ndarray, marks: np.ndarray, window: float) -> np.ndarray:
    """``(N,)`` whether a sorted ``marks`` time lies within ``window`` of each of ``times``."""
    if not len(marks):
        return np.zeros(len(times), dtype=bool)
    i = np.clip(np.searchsorted(marks, times), 1, len(marks) - 1) if len(marks) > 1 else np.zeros(len(times), int)
    gap = np.abs(marks[i] - times)
    if len(marks) > 1:
        gap = np.minimum(gap, np.abs(marks[i - 1] - times))
    return gap <= window
