"""What the uncalibrated pipelines (``airpose``, ``smartmocap``) share: synchronised views of the
person, their initial values, and the factors of a body seen by cameras whose poses are unknown.

A :class:`Rig` pairs the cameras' frames into body states (the reference camera's frames; every
other camera's closest frame within half a period, as the thesis' synchronised rigs) and holds
each state's keypoints, undistorted into the ideal pinhole image the reprojection factor models.
A static camera has one pose variable for the whole capture (``camera_key(c, 0)``), a moving one
a variable per frame (``camera_key(c, j)``).

:class:`Estimate` carries body states and camera poses as arrays ``(N, 4, 4)`` / ``(C, N, 4, 4)``
between solves, processes and Ray tasks (it pickles without GTSAM objects).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.data_tools.io.result import CameraTrack, Result
from mocapgraph.data_tools.geometry.triangulation import undistort_pixels
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.ground import camera_ground_factor, joint_ground_factor
from mocapgraph.factors.smoothness import joint_smoothness_factor
from mocapgraph.factors.body_priors import pose_regularizer_factor, shape_prior_factor
from mocapgraph.factors.smoothness import camera_smoothness_factor, pose_velocity_factor, root_smoothness_factor
from mocapgraph.factors.reprojection import ShapeTableCache, reprojection_factor
from mocapgraph.factors.robust import RobustScale
from mocapgraph.graphs.frame_groups import frame_groups
from mocapgraph.graphs.initialisation import pnp_view
from mocapgraph.factors.keys import camera_key, motion_frame_key, motion_latent_key, pose_key, root_key, shape_key
from mocapgraph.graphs.shape_bounds import shape_projection
from mocapgraph.graphs.solver import annealed_stages
from mocapgraph.graphs.uncertainty import joint_covariances
from mocapgraph.priors import load_default_pose_gmm, pose_gmm_factor
from mocapgraph.priors.fusion_regressor import ViewEstimate, ViewInput, coco_keypoints, load_default_fusion_regressor
from mocapgraph.priors.motion_windows import WINDOW

POSE_PRIORS = ("gmm", "none")
HOLD_SIGMA = 1e-5
"""σ (rad, m) of the priors that hold a variable at its value during a phase of a solve."""


@dataclass
class Observation:
    """One detector's keypoints of one camera at one body state."""

    camera: int
    frame: int
    fmt: str
    observed: np.ndarray  # (K, 2) undistorted pixels, NaN where missing
    weights: np.ndarray  # (K,) confidences, 0 where missing


@dataclass
class Rig:
    """The synchronised views of a capture.

    Attributes:
        names, moving, intrinsics ``(C, 4)`` (fx, fy, cx, cy): per camera of the capture.
        times: ``(N,)`` seconds of the body states (the reference camera's frames).
        frames: ``(C, N)`` each camera's frame at each state, -1 where it has none.
        states: per state, its observations.
        reference: index of the camera the states follow.
    """

    names: list[str]
    moving: list[bool]
    intrinsics: np.ndarray
    times: np.ndarray
    frames: np.ndarray
    states: list[list[Observation]]
    reference: int

    @property
    def num_cameras(self) -> int:
        return len(self.names)

    def camera_var(self, c: int, i: int) -> int:
        """The pose key of camera ``c`` at state ``i``."""
        return camera_key(c, int(self.frames[c, i])) if self.moving[c] else camera_key(c, 0)

    def keypoint_weight(self) -> np.ndarray:
        """``(N,)`` the sum of the keypoints' confidences over all views at each state."""
        return np.array([sum(float(o.weights.sum()) for o in obs) for obs in self.states])

    def view_keypoints(self, c: int) -> tuple[np.ndarray, str] | None:
        """``(N, K, 3)`` camera ``c``'s undistorted keypoints and confidences at every state (NaN
        where it has no frame or detection) of its first detector, and that detector's format;
        None when the camera has no detection at any state."""
        fmt = next((o.fmt for obs in self.states for o in obs if o.camera == c), None)
        if fmt is None:
            return None
        K = next(len(o.observed) for obs in self.states for o in obs if o.camera == c and o.fmt == fmt)
        out = np.full((len(self.states), K, 3), np.nan)
        for i, obs in enumerate(self.states):
            for o in obs:
                if o.camera == c and o.fmt == fmt:
                    out[i, :, :2] = o.observed
                    out[i, :, 2] = np.where(o.weights > 0, o.weights, np.nan)
        return out, fmt

    def coco_keypoints(self, c: int) -> np.ndarray | None:
        """``(N, 17, 3)`` camera ``c``'s COCO-17 points at every state, or None without detections."""
        view = self.view_keypoints(c)
        return None if view is None else coco_keypoints(*view)

    def camera_matrices(self) -> list[np.ndarray]:
        """Per camera, ``K (3, 3)`` of its undistorted image."""
        return [np.array([[f[0], 0, f[2]], [0, f[1], f[3]], [0, 0, 1.0]]) for f in self.intrinsics]

    def only(self, cameras: list[bool]) -> Rig:
        """The rig without the frames and observations of the cameras not in ``cameras`` (per camera)."""
        keep = np.asarray(cameras, dtype=bool)
        states = [[o for o in obs if keep[o.camera]] for obs in self.states]
        return replace(self, frames=np.where(keep[:, None], self.frames, -1), states=states)

    def subset(self, start: int, stop: int) -> Rig:
        """The states ``[start, stop)`` (frames and observations keep their camera frame indices)."""
        return replace(self, times=self.times[start:stop], frames=self.frames[:, start:stop], states=self.states[start:stop])


def rig_from_capture(capture: Capture, detectors: tuple[str, ...] | None = None, reference: int = 0) -> Rig:
    """The capture's views paired to the reference camera's frames, keypoints undistorted.

    Raises MocapgraphError when no camera has detections or the reference camera has no frames.
    """
    names = [cam.name for cam in capture.cameras]
    wanted = detectors or tuple(dict.fromkeys(n for cam in capture.cameras for n in cam.detectors))
    if not wanted:
        raise MocapgraphError(f"capture {capture.name!r}: no camera has detections")
    groups = frame_groups(capture, "closest", reference=reference)
    C, N = len(names), len(groups)
    frames = np.full((C, N), -1, dtype=int)
    states: list[list[Observation]] = []
    undistorted: dict[tuple[int, str], np.ndarray] = {}
    for i, group in enumerate(groups):
        obs = []
        for c, j in group.members:
            frames[c, i] = j
            cam = capture.cameras[c]
            for name in wanted:
                det = cam.detectors.get(name)
                if det is None:
                    continue
                if (c, name) not in undistorted:
                    undistorted[(c, name)] = undistort_pixels(det.keypoints[..., :2], cam.K, cam.distortion)
                weights = np.nan_to_num(det.keypoints[j, :, 2], nan=0.0)
                if np.any(weights > 0):
                    obs.append(Observation(c, j, det.format, undistorted[(c, name)][j].copy(), weights))
        states.append(obs)
    intrinsics = np.array([[c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2]] for c in capture.cameras])
    return Rig(names, [c.moving for c in capture.cameras], intrinsics, np.array([g.time for g in groups]), frames, states, reference)


INITIALISERS = ("pnp", "regressor")
DISAGREEMENT = 0.5
"""Median relative difference of the body's depth between the regressor and the PnP of the mean
body above which the regressor's view is replaced by the PnP: the network was trained on
synthetic views and can be far off on one unlike them, while PnP is only as wrong as the mean body."""


def view_bodies(rig: Rig, body: BodyModel, initialiser: str, variant: str = "full") -> tuple[list[ViewEstimate], str]:
    """Per camera, the body relative to it at every state, from ``initialiser``:

    - ``"pnp"``: the mean body (arms down) placed by PnP, the geometric initialiser;
    - ``"regressor"``: the fusion regressor (``variant`` of its ablation), AirPose's initialiser,
      with the PnP for a view where the two disagree by more than :data:`DISAGREEMENT` in depth,
      and for every view when the regressor's weights cannot be loaded (said in the description).

    Returns the views and a description of what was used."""
    if initialiser not in INITIALISERS:
        raise MocapgraphError(f"initialiser {initialiser!r}: choose one of {', '.join(INITIALISERS)}")
    kps = [rig.view_keypoints(c) for c in range(rig.num_cameras)]
    N = len(rig.states)
    K = rig.camera_matrices()
    empty = ViewEstimate(np.tile(np.eye(4), (N, 1, 1)), np.zeros((N, NUM_JOINTS - 1, 3)), np.tile(body.default_shape, (N, 1)), np.zeros(N, bool))
    pnp = [empty if kp is None else pnp_view(body, kp[0], kp[1], K[c]) for c, kp in enumerate(kps)]
    if initialiser == "pnp":
        return pnp, "pnp"
    try:
        regressor = load_default_fusion_regressor(variant)
    except MocapgraphError as exc:
        return pnp, f"pnp (the fusion regressor could not be loaded: {exc})"
    seen = [c for c in range(rig.num_cameras) if kps[c] is not None]
    out = list(pnp)
    fallback = []
    for c, p in zip(seen, regressor.predict([ViewInput(kps[c][0], kps[c][1], K[c]) for c in seen])):
        both = p.valid & pnp[c].valid
        depth = pnp[c].camera_T_root[both, 2, 3]
        if both.any() and np.median(np.abs(p.camera_T_root[both, 2, 3] - depth) / depth) > DISAGREEMENT:
            fallback.append(rig.names[c])
        else:
            out[c] = p
    used = "regressor" if variant == "full" else f"regressor ({variant})"
    return out, used + (f"; PnP for {', '.join(fallback)} (the two disagreed)" if fallback else "")


@dataclass
class Estimate:
    """Body states and cameras of a solve, as arrays.

    Attributes:
        roots: ``(N, 4, 4)`` world_T_root; poses ``(N, 21, 3)``; shape ``(S,)``.
        cameras: ``(C, N, 4, 4)`` world_T_camera at every state (a static camera's the same at all).
    """

    roots: np.ndarray
    poses: np.ndarray
    shape: np.ndarray
    cameras: np.ndarray

    def subset(self, start: int, stop: int) -> Estimate:
        return Estimate(self.roots[start:stop].copy(), self.poses[start:stop].copy(), self.shape.copy(), self.cameras[:, start:stop].copy())

    def transformed(self, A: np.ndarray) -> Estimate:
        """Everything moved by the rigid ``A (4, 4)`` (new world ← old world)."""
        return Estimate(A @ self.roots, self.poses.copy(), self.shape.copy(), A @ self.cameras)


@dataclass
class GraphOptions:
    """Weights of the terms (SmartMocap's, as factors; units in the names)."""

    noise_px: float = 3.0
    gm_sigma_px: float = 40.0
    pose_prior_sigma_rad: float = 0.8
    shape_prior_sigma: float = 0.1
    # Without calibration the body's size is the only scale, and every smoothness term (m/s) is
    # cheaper in a smaller scene: estimated, the shape shrank a 10 m airpose scene to 6.5 m
    # (a child's size, 3σ off the shape prior; measured). "hold" keeps the initial shape during
    # the solve; the covariances are still those of the graph with the shape free under its prior.
    shape: str = "hold"
    # SmartMocap's and AirPose+'s pose prior: the pelvis's pitch is nearly invisible in keypoints
    # (the hip points lie on its pitch axis), and without a prior the spine and legs make up for it.
    pose_prior: str = "gmm"
    root_sigma_rad_s: float = 4.0
    root_sigma_m_s: float = 3.0
    pose_sigma_rad_s: float = 6.0
    joint_sigma_m_s: float = 2.0
    camera_sigma_rad_s: float = 1.0
    camera_sigma_m_s: float = 2.0
    ground_sigma_m: float = 0.02
    camera_clearance_m: float = 0.3


@dataclass
class RigGraph:
    """Builds the factors of a :class:`Rig` over its states (local indices ``0..N-1``)."""

    rig: Rig
    body: BodyModel
    options: GraphOptions
    fixed_cameras: dict[int, np.ndarray] = field(default_factory=dict)  # camera -> (N, 4, 4) held poses (AirPose's reference)
    scale: RobustScale = field(default_factory=lambda: RobustScale(np.inf))
    caches: dict[str, ShapeTableCache] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.options.pose_prior not in POSE_PRIORS:
            raise MocapgraphError(f"pose_prior {self.options.pose_prior!r}: choose one of {', '.join(POSE_PRIORS)}")
        self.pose_gmm = load_default_pose_gmm() if self.options.pose_prior == "gmm" else None

    def cache(self, fmt: str) -> ShapeTableCache:
        if fmt not in self.caches:
            self.caches[fmt] = ShapeTableCache(self.body, fmt)
        return self.caches[fmt]

    def add_state(self, graph: gtsam.NonlinearFactorGraph, i: int) -> None:
        """State ``i``'s reprojection factors (one per keypoint format, all its cameras) and pose regulariser."""
        by_fmt: dict[str, list[Observation]] = {}
        for o in self.rig.states[i]:
            by_fmt.setdefault(o.fmt, []).append(o)
        for fmt, obs in by_fmt.items():
            keys, fixed = [], []
            for o in obs:
                held = self.fixed_cameras.get(o.camera)
                keys.append(None if held is not None else self.rig.camera_var(o.camera, i))
                fixed.append(held[i] if held is not None else None)
            graph.add(
                reprojection_factor(
                    self.body, self.cache(fmt), root_key(i), pose_key(i), shape_key(), keys, fixed,
                    self.rig.intrinsics[[o.camera for o in obs]], np.stack([o.observed for o in obs]),
                    np.stack([o.weights for o in obs]), fmt, self.scale, noise_px=self.options.noise_px,
                )  # fmt: skip
            )
        graph.add(pose_regularizer_factor(pose_key(i), self.options.pose_prior_sigma_rad))
        if self.pose_gmm is not None:
            graph.add(pose_gmm_factor(pose_key(i), self.pose_gmm))

    def add_smoothness(self, graph: gtsam.NonlinearFactorGraph, i: int) -> None:
        """Between states ``i - 1`` and ``i``: root, joint-rotation and 3D joint smoothness, and
        every moving camera's pose smoothness."""
        o = self.options
        dt = max(float(self.rig.times[i] - self.rig.times[i - 1]), 1e-3)
        graph.add(root_smoothness_factor(root_key(i - 1), root_key(i), dt, (o.root_sigma_rad_s, o.root_sigma_m_s)))
        graph.add(pose_velocity_factor(pose_key(i - 1), pose_key(i), dt, o.pose_sigma_rad_s))
        a, b = (root_key(i - 1), pose_key(i - 1)), (root_key(i), pose_key(i))
        graph.add(joint_smoothness_factor(self.cache("body"), a, b, shape_key(), dt, o.joint_sigma_m_s))
        for c in self.camera_vars_moving(i - 1, i):
            graph.add(camera_smoothness_factor(self.rig.camera_var(c, i - 1), self.rig.camera_var(c, i), dt, o.camera_sigma_rad_s, o.camera_sigma_m_s))

    def camera_vars_moving(self, i0: int, i1: int) -> list[int]:
        """Moving, not held cameras with a frame at both states."""
        f = self.rig.frames
        return [c for c in range(self.rig.num_cameras) if self.rig.moving[c] and c not in self.fixed_cameras and f[c, i0] >= 0 and f[c, i1] >= 0]

    def add_ground(self, graph: gtsam.NonlinearFactorGraph, i: int) -> None:
        """E_HGP on state ``i``'s joints (the world's z = 0 plane)."""
        graph.add(joint_ground_factor(self.cache("body"), root_key(i), pose_key(i), shape_key(), self.options.ground_sigma_m))

    def camera_keys(self, states=None) -> dict[int, tuple[int, int]]:
        """Every camera variable of ``states`` (default all) → (camera, first state using it)."""
        out: dict[int, tuple[int, int]] = {}
        for i in range(len(self.rig.states)) if states is None else states:
            for c in range(self.rig.num_cameras):
                if c in self.fixed_cameras or self.rig.frames[c, i] < 0:
                    continue
                out.setdefault(self.rig.camera_var(c, i), (c, i))
        return out

    def add_camera_ground(self, graph: gtsam.NonlinearFactorGraph) -> None:
        """E_CGP on every camera variable: its centre above the ground by the clearance."""
        for key in self.camera_keys():
            graph.add(camera_ground_factor(key, sigma_m=0.05, clearance_m=self.options.camera_clearance_m))

    def add_shape_prior(self, graph: gtsam.NonlinearFactorGraph) -> None:
        graph.add(shape_prior_factor(shape_key(), self.body.default_shape, self.options.shape_prior_sigma))

    def values(self, estimate: Estimate) -> gtsam.Values:
        """Body states, shape and camera variables of the rig at ``estimate``."""
        values = gtsam.Values()
        for i in range(len(self.rig.states)):
            values.insert(root_key(i), gtsam.Pose3(estimate.roots[i]))
            values.insert(pose_key(i), estimate.poses[i].ravel())
        values.insert(shape_key(), np.clip(estimate.shape, *(self.body.shape_bounds.T + [[1e-9], [-1e-9]])))
        for key, (c, i) in self.camera_keys().items():
            values.insert(key, gtsam.Pose3(estimate.cameras[c, i]))
        return values

    def read(self, values: gtsam.Values, start: Estimate) -> Estimate:
        """The estimate in ``values`` (held cameras and states not in ``values`` from ``start``)."""
        n = len(self.rig.states)
        roots = np.stack([values.atPose3(root_key(i)).matrix() for i in range(n)])
        poses = np.stack([values.atVector(pose_key(i)) for i in range(n)]).reshape(n, NUM_JOINTS - 1, 3)
        cameras = start.cameras.copy()
        for c in range(self.rig.num_cameras):
            for i in range(n):
                if c not in self.fixed_cameras and self.rig.frames[c, i] >= 0:
                    cameras[c, i] = values.atPose3(self.rig.camera_var(c, i)).matrix()
        return Estimate(roots, poses, values.atVector(shape_key()), cameras)

    def project_shape(self, values: gtsam.Values) -> gtsam.Values:
        """Clamp the shape into the body model's bounds after each accepted step."""
        return shape_projection(self.body)(values)

    def stages(self, iterations: int, ordering: str | list[int] = "colamd") -> list:
        """L2, then Geman-McClure at the options' scale (:func:`~mocapgraph.graphs.solver.annealed_stages`)."""
        return annealed_stages(self.scale, self.options.gm_sigma_px, iterations, ordering)


SHAPE_MODES = ("hold", "estimate")


def held_shape(options: GraphOptions) -> list[int]:
    """The shape's key when ``options.shape`` holds it, else nothing."""
    if options.shape not in SHAPE_MODES:
        raise MocapgraphError(f"shape {options.shape!r}: choose one of {', '.join(SHAPE_MODES)}")
    return [shape_key()] if options.shape == "hold" else []


def hold(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys) -> gtsam.NonlinearFactorGraph:
    """A copy of ``graph`` with every key of ``keys`` held at its value by a stiff prior."""
    held = gtsam.NonlinearFactorGraph(graph)
    for key in keys:
        if not values.exists(key):
            continue
        try:
            pose = values.atPose3(key)
        except RuntimeError:
            vec = values.atVector(key)
            held.add(gtsam.PriorFactorVector(key, vec, gtsam.noiseModel.Isotropic.Sigma(len(vec), HOLD_SIGMA)))
        else:
            held.add(gtsam.PriorFactorPose3(key, pose, gtsam.noiseModel.Isotropic.Sigma(6, HOLD_SIGMA)))
    return held


def log(pipeline: str, progress: bool, message: str) -> None:
    if progress:
        print(f"{pipeline}: {message}", file=sys.stderr, flush=True)


def time_ordering(rg: RigGraph, values: gtsam.Values, windows: list[int] = ()) -> list[int]:
    """Elimination order: states in time order with each moving camera's frame before its
    state; a motion window's latent and frame after its last state (eliminated early they would
    join its 25 states in one clique); then what all states share (shape, static cameras, ground)."""
    order: list[int] = []
    seen: set[int] = set()
    ends: dict[int, list[int]] = {}
    for w, s in enumerate(windows):
        ends.setdefault(s + WINDOW - 1, []).extend([motion_frame_key(w), motion_latent_key(w)])
    for i in range(len(rg.rig.states)):
        for c in range(rg.rig.num_cameras):
            if rg.rig.moving[c] and c not in rg.fixed_cameras and rg.rig.frames[c, i] >= 0:
                key = rg.rig.camera_var(c, i)
                if key not in seen:
                    order.append(key)
                    seen.add(key)
        order += [root_key(i), pose_key(i)] + ends.get(i, [])
    listed = set(order)
    return order + sorted(k for k in values.keys() if k not in listed)


def rig_result(
    pipeline: str, capture: Capture, rig: Rig, body: BodyModel, estimate: Estimate, world_frame: str, parameters: dict,
    capture_label: str = "", placed: list[bool] | None = None,
) -> Result:  # fmt: skip
    """The result of a rig's solve: body states, every placed camera's track (its frames at the
    states), per-state detection counts."""
    placed = placed or [True] * rig.num_cameras
    fmt = next(o.fmt for obs in rig.states for o in obs)
    fk = body.forward(estimate.shape, estimate.roots, estimate.poses)
    detections = np.array([int(sum((o.weights > 0).sum() for o in obs)) for obs in rig.states])
    result = Result(
        pipeline=pipeline, capture=capture_label or str(capture.path or capture.name), world_frame=world_frame,
        timestamps=rig.times, joints=fk.joints, body_model=body.name, root=estimate.roots, pose=estimate.poses,
        shape=estimate.shape, keypoints=body.forward(estimate.shape, estimate.roots, estimate.poses, keypoints=fmt).keypoints,
        keypoint_format=fmt, flags={"num_detections": detections, "unconstrained": detections == 0}, parameters=parameters,
    )  # fmt: skip
    for c, cam in enumerate(capture.cameras):
        frames = rig.frames[c]
        have = frames >= 0
        if placed[c] and have.any():
            result.cameras[cam.name] = CameraTrack(cam.timestamps[frames[have]], estimate.cameras[c, have])
    return result


def add_covariances(result: Result, rg: RigGraph, graph, values, estimate: Estimate) -> None:
    """Joints, root, shape and every estimated camera's pose covariance, from the graph's marginals."""
    marginals = gtsam.Marginals(graph.linearize(values), values)
    result.covariances["joints"], result.covariances["root"] = joint_covariances(
        rg.body, marginals, estimate.roots, estimate.poses, estimate.shape
    )
    result.covariances["shape"] = np.asarray(marginals.marginalCovariance(shape_key()))
    rig = rg.rig
    for c, name in enumerate(rig.names):
        have = np.flatnonzero(rig.frames[c] >= 0)
        if name not in result.cameras or c in rg.fixed_cameras:
            continue
        cache: dict[int, np.ndarray] = {}
        keys = [rig.camera_var(c, i) for i in have]
        result.covariances[f"camera:{name}"] = np.stack([cache[k] if k in cache else cache.setdefault(k, marginals.marginalCovariance(k)) for k in keys])
