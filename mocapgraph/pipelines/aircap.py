"""``mocapgraph run aircap``: body and UAV cameras from keypoints, held near their GPS/IMU priors.

AirCap's pipeline as factor graphs: camera priors from the UAVs' sensors (the onboard online
estimate, or the offline GPS/IMU re-run), a tracker that follows the person in 3D, then the body
fitted to the keypoints of several detectors while the cameras are refined. ``mode="per-frame"``
fits each body state alone, warm-started from the previous one, as the thesis did;
``mode="sequence"`` starts from that and solves the whole sequence jointly with temporal
smoothness. ``cameras`` reproduces the thesis' ablation:

- ``fixed``: cameras held at the onboard online GPS/IMU estimate (the ``self_pose`` log);
- ``prior``: cameras held at the offline GPS/IMU fusion (``graphs.vehicle_fusion``);
- ``refine``: cameras are variables, held near the offline fusion by robust priors.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import gtsam
import numpy as np

from mocapgraph.body import load_body_model
from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import axis_rotation
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.data_tools.io.capture import Capture, load_capture
from mocapgraph.data_tools.io.result import CameraTrack, Result, options_parameters, write_result
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.body_priors import pose_regularizer_factor, shape_prior_factor
from mocapgraph.factors.camera_priors import camera_offset_prior_factor, camera_prior_factor
from mocapgraph.factors.smoothness import camera_smoothness_factor, pose_smoothness_factor, pose_velocity_factor, root_smoothness_factor
from mocapgraph.factors.reprojection import ShapeTableCache, reprojection_factor
from mocapgraph.factors.robust import RobustScale
from mocapgraph.graphs.frame_groups import SYNC_POLICIES, FrameGroup, frame_groups
from mocapgraph.graphs.initialisation import neutral_pose
from mocapgraph.factors.keys import (
    camera_key,
    camera_offset_key,
    motion_frame_key,
    motion_latent_key,
    pose_key,
    pose_latent_key,
    root_key,
    shape_key,
)
from mocapgraph.graphs.shape_bounds import shape_projection
from mocapgraph.graphs.solver import annealed_stages, solve_staged
from mocapgraph.graphs.uncertainty import joint_covariances
from mocapgraph.priors import PoseGMM, load_default_pose_gmm, pose_gmm_factor
from mocapgraph.priors.motion_factor import MotionVAEPrior
from mocapgraph.priors.motion_vae import MotionVAE, load_default_motion_vae
from mocapgraph.priors.motion_windows import WINDOW
from mocapgraph.priors.pose_vae import PoseVAE, load_default_pose_vae
from mocapgraph.priors.pose_vae_factor import PoseVAEPrior

MODES = ("sequence", "per-frame")
CAMERA_MODES = ("refine", "prior", "fixed")
POSE_PRIORS = ("none", "gmm", "vae")
MOTION_PRIORS = ("none", "vae")


@dataclass
class AircapOptions:
    """Parameters of the AirCap pipeline (units in the names; defaults measured on ``aircap`` scenes)."""

    mode: str = "sequence"
    cameras: str = "refine"
    sync: str | None = None  # default: "closest" for per-frame (the thesis), "grid" for sequence
    grid_hz: float = 30.0  # body states per second with sync "grid"
    detectors: tuple[str, ...] | None = None
    gm_sigma_px: float = 40.0
    noise_px: float = 3.0
    pose_prior_sigma_rad: float = 0.8  # the weak regulariser every state keeps, on all 21 joints
    # Learned pose prior (docs/priors.md): "gmm" on every graph; "vae" on the sequence fit only
    # (its network runs once per linearisation for all states; per state it would cost 16 ms).
    pose_prior: str = "none"
    # SmartMocap's motion prior on 25-state windows of the sequence fit (needs 30 Hz grid states);
    # windows start every motion_window_stride states, each with its own latent. Off by default:
    # it lowers RA-MPJPE (4.9 -> 3.3 cm, mean of seeds 1-6) but its joint covariances are less
    # honest (pooled 95 % coverage 0.82 against 0.975 without; docs/priors.md).
    motion_prior: str = "none"
    motion_window_stride: int = 25
    shape_prior_sigma: float = 0.25
    root_sigma_rad_s: float = 4.0
    root_sigma_m_s: float = 3.0
    # Joint-rotation smoothness: "velocity" (first order, pairs of states) keeps the linear solve's
    # cliques at two states; "acceleration" (second order, triples) is smoother but about 4x slower.
    pose_smoothness: str = "velocity"
    pose_sigma_rad_s: float = 6.0
    pose_sigma_rad_s2: float = 60.0
    camera_sigma_rad_s: float = 1.0
    camera_sigma_m_s: float = 2.0
    camera_prior_kernel: str = "huber"
    camera_prior_white_fraction: float = 0.6  # frame-to-frame share of a GPS/IMU prior's std (pooled 95 % coverage 0.975 on seeds 1-6)
    per_frame_iterations: int = 8
    workers: int = 2  # processes for the per-frame pass (1: in this process)
    sequence_iterations: int = 30
    covariances: bool = True
    progress: bool = True

    def check(self) -> None:
        if self.mode not in MODES:
            raise MocapgraphError(f"mode {self.mode!r}: choose one of {', '.join(MODES)}")
        if self.cameras not in CAMERA_MODES:
            raise MocapgraphError(f"cameras {self.cameras!r}: choose one of {', '.join(CAMERA_MODES)}")
        if self.sync is not None and self.sync not in SYNC_POLICIES:
            raise MocapgraphError(f"sync {self.sync!r}: choose one of {', '.join(SYNC_POLICIES)}")
        if self.pose_prior not in POSE_PRIORS:
            raise MocapgraphError(f"pose_prior {self.pose_prior!r}: choose one of {', '.join(POSE_PRIORS)}")
        if self.mode == "per-frame" and self.pose_prior == "vae":
            raise MocapgraphError("pose_prior 'vae' runs on the sequence fit: use mode 'sequence', or pose_prior 'gmm' per frame")
        if self.motion_prior not in MOTION_PRIORS:
            raise MocapgraphError(f"motion_prior {self.motion_prior!r}: choose one of {', '.join(MOTION_PRIORS)}")
        if self.motion_prior == "vae":
            if self.mode != "sequence" or (self.sync or "grid") != "grid" or self.grid_hz != 30.0:
                raise MocapgraphError("motion_prior: its windows are 25 states at 30 Hz; use mode 'sequence' with sync 'grid' at grid_hz 30")
            if not (isinstance(self.motion_window_stride, int) and 1 <= self.motion_window_stride <= 25):
                raise MocapgraphError(f"motion_window_stride: a whole number of states in [1, 25], got {self.motion_window_stride!r}")
        if not 0.0 < self.camera_prior_white_fraction < 1.0:
            raise MocapgraphError(f"camera_prior_white_fraction: must lie in (0, 1), got {self.camera_prior_white_fraction}")
        if not (isinstance(self.workers, int) and self.workers >= 1):
            raise MocapgraphError(f"workers: a whole number of processes >= 1, got {self.workers!r}")
        if self.mode == "per-frame" and self.sync == "grid":
            raise MocapgraphError("sync 'grid' interpolates between neighbouring states: use it with mode 'sequence'")


@dataclass
class _Observation:
    """One detector's keypoints in one camera frame, ready for a reprojection factor."""

    camera: int
    frame: int
    fmt: str
    observed: np.ndarray  # (K, 2) pixels, NaN where missing
    weights: np.ndarray  # (K,) confidences, 0 where missing or rejected
    fraction: float = 0.0  # between this state (0) and the next (towards 1): sync "grid"


@dataclass
class _State:
    group: FrameGroup
    observations: list[_Observation] = field(default_factory=list)

    @property
    def num_detections(self) -> int:
        return int(sum((o.weights > 0).sum() for o in self.observations))


def _log(options: AircapOptions, message: str) -> None:
    if options.progress:
        print(f"aircap: {message}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------------------------
# Inputs: camera priors, tracker, observations


def camera_tracks(capture: Capture, mode: str) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], list[str]]:
    """Per usable camera: prior world_T_camera ``(T_c, 4, 4)`` and covariance ``(T_c, 6, 6)``; notes."""
    from mocapgraph.graphs.navigation import camera_priors

    tracks, notes = camera_priors(capture, source="online" if mode == "fixed" else "fused")
    out = {name: (track.world_T_camera, track.covariance) for name, track in tracks.items()}
    for cam in capture.cameras:
        if cam.name in out:
            continue
        if cam.extrinsics is not None:
            poses = np.broadcast_to(cam.extrinsics, (cam.num_frames, 4, 4)).copy()
            out[cam.name] = (poses, np.tile(np.diag([1e-6] * 3 + [1e-4] * 3), (cam.num_frames, 1, 1)))
            notes.append(f"camera {cam.name}: no GPS/IMU; using its calibration")
        else:
            notes.append(f"camera {cam.name}: no GPS/IMU and no calibration; its detections are not used")
    return out, notes


def _observations(capture: Capture, groups, detectors, usable: set[str], inliers) -> list[_State]:
    states = []
    for group in groups:
        state = _State(group)
        for m, (c, j) in enumerate(group.members):
            cam = capture.cameras[c]
            if cam.name not in usable:
                continue
            for name in detectors:
                det = cam.detectors.get(name)
                if det is None:
                    continue
                kp = det.keypoints[j]
                weights = np.nan_to_num(kp[:, 2], nan=0.0)
                if name in inliers.get(cam.name, {}):
                    weights = weights * inliers[cam.name][name][j]
                if np.any(weights > 0):
                    state.observations.append(_Observation(c, j, det.format, kp[:, :2].copy(), weights, group.fraction(m)))
        states.append(state)
    return states


def detections_per_state(states: list[_State]) -> np.ndarray:
    """``(N,)`` keypoints constraining each state: its own, plus those interpolated from the
    previous state towards it (``"grid"``)."""
    own = np.array([s.num_detections for s in states])
    incoming = np.zeros(len(states), dtype=own.dtype)
    for i, s in enumerate(states[:-1]):
        incoming[i + 1] = sum(int((o.weights > 0).sum()) for o in s.observations if o.fraction > 0)
    return own + incoming


def _upright(yaw: float, position: np.ndarray) -> gtsam.Pose3:
    """Root standing upright (body +Y up → world +Z) facing world direction ``yaw`` (radians)."""
    stand = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # body +Z forward → world −Y
    R = axis_rotation("z", yaw + np.pi / 2) @ stand
    return gtsam.Pose3(gtsam.Rot3(R), np.asarray(position, dtype=float))


# ---------------------------------------------------------------------------------------------
# Graphs


@dataclass
class _LearnedPriors:
    """The shipped learned priors the options ask for (None where not), loaded once per run."""

    pose_gmm: PoseGMM | None = None
    pose_vae: PoseVAE | None = None
    motion_vae: MotionVAE | None = None

    @classmethod
    def load(cls, options: AircapOptions) -> _LearnedPriors:
        return cls(
            load_default_pose_gmm() if options.pose_prior == "gmm" else None,
            load_default_pose_vae() if options.pose_prior == "vae" else None,
            load_default_motion_vae() if options.motion_prior == "vae" else None,
        )


class _Problem:
    """Everything the graphs of one run share: body, tables, camera priors, learned priors, robust scale."""

    def __init__(
        self, capture: Capture, body: BodyModel, options: AircapOptions, priors: dict, learned: _LearnedPriors, states: list[_State]
    ):
        self.capture, self.body, self.options, self.priors, self.states = capture, body, options, priors, states
        self.scale = RobustScale(np.inf)
        formats = {o.fmt for s in states for o in s.observations}
        self.tables = {fmt: ShapeTableCache(body, fmt) for fmt in formats}
        self.intrinsics = [np.array([c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2]]) for c in capture.cameras]
        self.refine = options.cameras == "refine"
        self.common: dict[int, np.ndarray] = {}  # camera index -> common_covariance
        self.pose_gmm, self.pose_vae, self.motion_vae = learned.pose_gmm, learned.pose_vae, learned.motion_vae
        self.windows = self.motion_windows(len(states)) if self.motion_vae is not None else []

    def camera_prior(self, c: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        poses, cov = self.priors[self.capture.cameras[c].name]
        return poses[j], cov[j]

    def add_state(self, graph: gtsam.NonlinearFactorGraph, i: int, state: _State, fixed_shape=None) -> None:
        """Reprojection factors of body state ``i`` (one per detector and camera frame) and the
        pose regulariser; ``fixed_shape`` holds the shape constant instead of estimating it."""
        o = self.options
        shape = (shape_key(), None) if fixed_shape is None else (None, fixed_shape)
        for obs in state.observations:
            prior, _ = self.camera_prior(obs.camera, obs.frame)
            key = camera_key(obs.camera, obs.frame) if self.refine else None
            between = {"next_state": (root_key(i + 1), pose_key(i + 1)), "fraction": obs.fraction} if obs.fraction else {}
            graph.add(
                reprojection_factor(
                    self.body, self.tables[obs.fmt], root_key(i), pose_key(i), shape[0], [key],
                    [None if self.refine else prior], self.intrinsics[obs.camera][None],
                    obs.observed[None], obs.weights[None], obs.fmt, self.scale, noise_px=o.noise_px,
                    fixed_shape=shape[1], **between,
                )  # fmt: skip
            )
        self.add_pose_prior(graph, i)

    def add_pose_prior(self, graph: gtsam.NonlinearFactorGraph, i: int) -> None:
        """The weak regulariser on every joint of state ``i`` and the learned pose prior, if any."""
        graph.add(pose_regularizer_factor(pose_key(i), self.options.pose_prior_sigma_rad))
        if self.pose_gmm is not None:
            graph.add(pose_gmm_factor(pose_key(i), self.pose_gmm))

    def camera_members(self, states) -> list[tuple[int, int]]:
        return sorted({(obs.camera, obs.frame) for s in states for obs in s.observations})

    def common_covariance(self, c: int) -> np.ndarray:
        """``(6, 6)``: camera ``c``'s prior covariance averaged over its frames, turned into the
        world frame (the offset's tangent: ``O`` multiplies from the left). Computed once per
        camera: the per-frame pass asks for it at every state."""
        if c not in self.common:
            poses, cov = self.priors[self.capture.cameras[c].name]
            adjoint = np.stack([gtsam.Pose3(T).AdjointMap() for T in poses])
            self.common[c] = np.mean(adjoint @ cov @ np.swapaxes(adjoint, 1, 2), axis=0)
        return self.common[c]

    def add_camera_priors(self, graph, values, members) -> None:
        """Each refined camera frame near its GPS/IMU prior, through one offset per camera.

        A prior's error is mostly the trajectory's slow drift, common to nearby frames. The
        prior's covariance is split between the two: each frame keeps ``white_fraction²`` of its
        own (the frame-to-frame part) and the offset takes the rest of the camera's typical
        covariance, so that every frame's total is its prior's. (The offset used to take the
        whole covariance of the first frame, the fusion's least certain: that counted the prior
        twice, and the joints' 95 % ellipsoids held 0.997–1.0 of the errors, measured on seeds
        0–6.)
        """
        o = self.options
        common = 1.0 - o.camera_prior_white_fraction**2
        for c in sorted({c for c, _ in members}):
            if not values.exists(camera_offset_key(c)):
                graph.add(camera_prior_factor(camera_offset_key(c), np.eye(4), common * self.common_covariance(c), kernel="none"))
                values.insert(camera_offset_key(c), gtsam.Pose3())
        for c, j in members:
            prior, cov = self.camera_prior(c, j)
            white = cov * o.camera_prior_white_fraction**2
            graph.add(camera_offset_prior_factor(camera_offset_key(c), camera_key(c, j), prior, white, kernel=o.camera_prior_kernel))
            if not values.exists(camera_key(c, j)):
                values.insert(camera_key(c, j), gtsam.Pose3(prior))

    def motion_windows(self, n: int) -> list[int]:
        """First states of the motion prior's windows over ``n`` states: every stride, plus one
        ending at the last state when the stride leaves a tail (none when ``n`` < 25)."""
        starts = list(range(0, n - WINDOW + 1, self.options.motion_window_stride))
        if starts and starts[-1] + WINDOW < n:
            starts.append(n - WINDOW)
        return starts

    def time_ordering(self, values: gtsam.Values) -> list[int]:
        """Elimination order for a sequence: body states and camera frames in time order (a
        camera frame before the state after it), then the shared shape and camera offsets.

        The graph is a chain in time with a few variables shared by all; eliminating along the
        chain keeps every clique to neighbouring states, where COLAMD's order grew faster than
        the sequence (solves 27 % faster at 60 s, 1.66 s against 2.29 s, measured).
        """
        # A pose latent goes before its state: it touches that state alone, so eliminating it first
        # adds no fill-in (last, it would ride along the whole chain).
        latent = [pose_latent_key(i) for i in range(len(self.states))] if self.pose_vae is not None else None
        # Every frame factor of a motion window touches the window's latent and canonical frame
        # (the frame's tie factor alone touches the window's first root). Eliminated early, either
        # would join all 25 states in one dense clique; so both go after the window's last state,
        # and the chain is eliminated through them (small frontier: 3 + 64 dims; with the first
        # state itself deferred, 69 + 64).
        deferred: dict[int, list[int]] = {}
        for w, i0 in enumerate(self.windows):
            deferred.setdefault(i0 + WINDOW - 1, []).extend([motion_frame_key(w), motion_latent_key(w)])
        timed = []
        for i, s in enumerate(self.states):
            keys = ([latent[i]] if latent else []) + [root_key(i), pose_key(i)]
            timed.append((s.group.time, 1, keys))
            if i in deferred:
                timed.append((s.group.time, 2, deferred[i]))
        if self.refine:
            cams = self.capture.cameras
            timed += [(cams[c].timestamps[j], 0, [camera_key(c, j)]) for c, j in self.camera_members(self.states)]
        timed.sort(key=lambda item: (item[0], item[1]))
        order = [key for _, _, keys in timed for key in keys]
        listed = set(order)
        return order + sorted(k for k in values.keys() if k not in listed)

    def stages(self, iterations: int, ordering: str | list[int] = "colamd") -> list:
        """L2, then Geman-McClure at the options' scale (:func:`~mocapgraph.graphs.solver.annealed_stages`)."""
        return annealed_stages(self.scale, self.options.gm_sigma_px, iterations, ordering)

    def project_shape(self, values: gtsam.Values) -> gtsam.Values:
        """Clamp the shape into the body model's bounds after each accepted step."""
        return shape_projection(self.body)(values)


# ---------------------------------------------------------------------------------------------
# Solves


@dataclass
class _Estimate:
    """Body states (and refined cameras) of a solve."""

    roots: list[gtsam.Pose3]
    poses: np.ndarray  # (N, 63)
    shape: np.ndarray  # (S,)
    cameras: dict[tuple[int, int], gtsam.Pose3]
    log: list[dict]

    def body_values(self) -> gtsam.Values:
        """The body variables (roots, joint rotations, shape); cameras are added by their priors."""
        values = gtsam.Values()
        for i, root in enumerate(self.roots):
            values.insert(root_key(i), root)
            values.insert(pose_key(i), self.poses[i])
        values.insert(shape_key(), self.shape)
        return values


def _read(values: gtsam.Values, i: int) -> tuple[gtsam.Pose3, np.ndarray]:
    return values.atPose3(root_key(i)), values.atVector(pose_key(i))


def solve_per_frame(problem: _Problem, positions: np.ndarray, yaws: np.ndarray, span: tuple[int, int] | None = None) -> _Estimate:
    """Each state alone, in time order, warm-started from the previous one (the thesis' mode).

    ``positions (N, 3)`` and ``yaws (N,)`` are the tracker's initial guesses. The shape is held at
    the body model's default (estimating it from one frame is ill-posed; the sequence fit does
    it). The first state with detections tries four headings and keeps the best; states without
    detections carry the previous estimate over (they are flagged unconstrained). ``span``
    ``(start, stop)`` solves only those states (default: all).
    """
    o = problem.options
    shape = problem.body.default_shape.copy()
    roots, poses, cameras, log = [], [], {}, []
    previous: tuple[gtsam.Pose3, np.ndarray] | None = None
    start, stop = span or (0, len(problem.states))
    for i in range(start, stop):
        state = problem.states[i]
        if not state.observations:
            root = previous[0] if previous else _upright(yaws[i], positions[i])
            roots.append(gtsam.Pose3(root.rotation(), positions[i]))
            poses.append(previous[1] if previous else neutral_pose().ravel())
            continue
        graph = gtsam.NonlinearFactorGraph()
        base = gtsam.Values()
        problem.add_state(graph, i, state, fixed_shape=shape)
        if problem.refine:
            problem.add_camera_priors(graph, base, problem.camera_members([state]))
        if previous is None:
            starts = [(_upright(yaws[i] + k * np.pi / 2, positions[i]), neutral_pose().ravel()) for k in range(4)]
        else:
            starts = [(gtsam.Pose3(previous[0].rotation(), positions[i]), previous[1])]
        best = None
        for root, pose in starts:
            values = gtsam.Values(base)
            values.insert(root_key(i), root)
            values.insert(pose_key(i), pose)
            result = solve_staged(graph, values, problem.stages(o.per_frame_iterations))
            if best is None or result.error < best.error:
                best = result
        previous = _read(best.values, i)
        roots.append(previous[0])
        poses.append(previous[1])
        for c, j in problem.camera_members([state]) if problem.refine else []:
            cameras[(c, j)] = best.values.atPose3(camera_key(c, j))
        log.append({"state": i, "iterations": len(best.log), "error": float(best.error)})
        if o.progress and i % 200 == 0:
            _log(o, f"per-frame {i + 1}/{len(problem.states)}")
    return _Estimate(roots, np.array(poses), shape, cameras, log)


_FORKED: tuple | None = None
"""(problem, positions, yaws) handed to forked workers by inheritance rather than pickling."""


def _solve_span(span: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, dict, list]:
    estimate = solve_per_frame(*_FORKED, span=span)
    cameras = {m: p.matrix() for m, p in estimate.cameras.items()}
    return np.stack([r.matrix() for r in estimate.roots]), estimate.poses, cameras, estimate.log


def solve_per_frame_parallel(problem: _Problem, positions: np.ndarray, yaws: np.ndarray, workers: int) -> _Estimate:
    """:func:`solve_per_frame` on ``workers`` consecutive spans of the states at once, one
    forked process each; every span starts cold (four headings at its first detected state).

    The states are independent but for the warm start, so the spans give the same answer up to
    that restart, in about 1/workers of the time on as many free cores.
    """
    global _FORKED
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    n = len(problem.states)
    bounds = np.linspace(0, n, workers + 1).round().astype(int)
    spans = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
    if len(spans) < 2:
        return solve_per_frame(problem, positions, yaws)
    _FORKED = (problem, positions, yaws)
    try:
        with ProcessPoolExecutor(len(spans), mp_context=multiprocessing.get_context("fork")) as pool:
            parts = list(pool.map(_solve_span, spans))
    finally:
        _FORKED = None
    roots = [gtsam.Pose3(T) for part in parts for T in part[0]]
    cameras = {m: gtsam.Pose3(T) for part in parts for m, T in part[2].items()}
    log = [row for part in parts for row in part[3]]
    return _Estimate(roots, np.concatenate([part[1] for part in parts]), problem.body.default_shape.copy(), cameras, log)


def resample(estimate: _Estimate, times: np.ndarray, new_times: np.ndarray) -> _Estimate:
    """The estimate at other times: root translation and joint vectors linear, root rotation slerp."""
    from scipy.spatial.transform import Rotation, Slerp

    t = np.clip(new_times, times[0], times[-1])
    R = Rotation.from_matrix(np.stack([r.rotation().matrix() for r in estimate.roots]))
    rot = Slerp(times, R)(t).as_matrix() if len(times) > 1 else np.repeat(R.as_matrix(), len(t), 0)
    trans = np.stack([np.interp(t, times, np.array([r.translation() for r in estimate.roots])[:, a]) for a in range(3)], 1)
    poses = np.stack([np.interp(t, times, estimate.poses[:, d]) for d in range(estimate.poses.shape[1])], 1)
    roots = [gtsam.Pose3(gtsam.Rot3(rot[i]), trans[i]) for i in range(len(t))]
    return _Estimate(roots, poses, estimate.shape.copy(), dict(estimate.cameras), list(estimate.log))


def sequence_graph(problem: _Problem, estimate: _Estimate) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The whole sequence: every state's factors, temporal smoothness, shape and camera priors."""
    o = problem.options
    graph = gtsam.NonlinearFactorGraph()
    states = problem.states
    times = np.array([s.group.time for s in states])
    for i, state in enumerate(states):
        if state.observations:
            problem.add_state(graph, i, state)
        else:
            problem.add_pose_prior(graph, i)
        if i > 0:
            dt = max(times[i] - times[i - 1], 1e-3)
            graph.add(root_smoothness_factor(root_key(i - 1), root_key(i), dt, (o.root_sigma_rad_s, o.root_sigma_m_s)))
            if o.pose_smoothness == "velocity":
                graph.add(pose_velocity_factor(pose_key(i - 1), pose_key(i), dt, o.pose_sigma_rad_s))
        if i > 1 and o.pose_smoothness == "acceleration":
            graph.add(pose_smoothness_factor([pose_key(i - 2), pose_key(i - 1), pose_key(i)], times[i - 2 : i + 1], o.pose_sigma_rad_s2))
    graph.add(shape_prior_factor(shape_key(), problem.body.default_shape, o.shape_prior_sigma))
    values = estimate.body_values()
    if problem.pose_vae is not None:
        PoseVAEPrior(problem.pose_vae, range(len(states))).add_to(graph, values, estimate.poses)
    if problem.windows:
        MotionVAEPrior(problem.motion_vae, problem.body, problem.windows, shape_key=shape_key()).add_to(graph, values)
    if problem.refine:
        members = problem.camera_members(states)
        problem.add_camera_priors(graph, values, members)
        for (c, j), pose in estimate.cameras.items():
            values.update(camera_key(c, j), pose)
        for (c0, j0), (c1, j1) in zip(members, members[1:]):
            if c0 == c1:
                dt = max(problem.capture.cameras[c0].timestamps[j1] - problem.capture.cameras[c0].timestamps[j0], 1e-3)
                graph.add(camera_smoothness_factor(camera_key(c0, j0), camera_key(c1, j1), dt, o.camera_sigma_rad_s, o.camera_sigma_m_s))
    return graph, values


def solve_sequence(problem: _Problem, start: _Estimate) -> tuple[_Estimate, gtsam.NonlinearFactorGraph, gtsam.Values]:
    graph, values = sequence_graph(problem, start)
    o = problem.options

    def progress(row):
        _log(o, f"sequence {row.get('stage')} iteration {row.get('iteration')}: cost {row.get('cost_after', row.get('cost', 0.0)):.4g}")

    result = solve_staged(
        graph, values, problem.stages(o.sequence_iterations, problem.time_ordering(values)), project=problem.project_shape,
        on_iteration=progress if o.progress else None,
    )  # fmt: skip
    v = result.values
    n = len(problem.states)
    roots = [v.atPose3(root_key(i)) for i in range(n)]
    poses = np.array([v.atVector(pose_key(i)) for i in range(n)])
    cameras = {m: v.atPose3(camera_key(*m)) for m in problem.camera_members(problem.states)} if problem.refine else {}
    return _Estimate(roots, poses, v.atVector(shape_key()), cameras, list(result.log)), graph, v


# ---------------------------------------------------------------------------------------------
# Uncertainty and output


def run_aircap(capture: Capture, options: AircapOptions | None = None, capture_label: str = "") -> Result:
    """Run the pipeline on a loaded capture and return the result (nothing written)."""
    from mocapgraph.data_tools.tracking.tracker import track_person

    options = options or AircapOptions()
    options.check()
    start = time.perf_counter()
    body = load_body_model()
    detectors = options.detectors or tuple(dict.fromkeys(n for cam in capture.cameras for n in cam.detectors))
    if not detectors:
        raise MocapgraphError(f"capture {capture.name!r}: no camera has detections")

    priors, camera_notes = camera_tracks(capture, options.cameras)
    notes = list(capture.notes) + camera_notes  # the loader's repairs first
    for note in notes:
        _log(options, note)
    if not priors:
        raise MocapgraphError(f"capture {capture.name!r}: no camera has a pose prior (GPS/IMU or calibration)")
    camera_poses = {name: poses for name, (poses, _) in priors.items()}
    track = track_person(capture, camera_poses)
    inliers: dict[str, dict[str, np.ndarray]] = {}
    for name in detectors:
        having = {n: p for n, p in camera_poses.items() if name in capture.camera(n).detectors}
        for cam_name, mask in track.inlier_detections(capture, having, detector=name).items():
            inliers.setdefault(cam_name, {})[name] = mask

    learned = _LearnedPriors.load(options)

    def problem_for(sync: str) -> tuple[_Problem, np.ndarray]:
        groups = frame_groups(capture, sync, rate_hz=options.grid_hz)
        states = _observations(capture, groups, detectors, set(priors), inliers)
        if not any(s.observations for s in states):
            raise MocapgraphError(f"capture {capture.name!r}: no usable detections in any camera")
        return _Problem(capture, body, options, priors, learned, states), np.array([g.time for g in groups])

    # The per-frame pass pairs the cameras' closest frames (several views per state, as the thesis
    # did); the sequence fit then starts from it, resampled onto its own states.
    per_frame_sync = options.sync if options.mode == "per-frame" and options.sync else "closest"
    problem, times = problem_for(per_frame_sync)
    positions, _ = track.at(times)
    velocity = track.velocity_at(times)
    yaws = np.unwrap(np.arctan2(velocity[:, 1], velocity[:, 0]))
    _log(options, f"per-frame: {len(times)} body states, cameras {options.cameras}")
    estimate = solve_per_frame_parallel(problem, positions, yaws, options.workers)
    per_frame_seconds = time.perf_counter() - start
    graph = values = None
    if options.mode == "sequence":
        pf_times = times
        problem, times = problem_for(options.sync or "grid")
        _log(options, f"sequence: {len(times)} body states")
        if options.motion_prior != "none":
            if problem.windows:
                _log(options, f"motion prior: {len(problem.windows)} windows of {WINDOW} states")
            else:
                notes.append(f"motion prior: {len(times)} body states are fewer than one window ({WINDOW}); not applied")
                _log(options, notes[-1])
        estimate, graph, values = solve_sequence(problem, resample(estimate, pf_times, times))
    seconds = time.perf_counter() - start
    states = problem.states

    n = len(states)
    root = np.stack([r.matrix() for r in estimate.roots])
    pose = estimate.poses.reshape(n, NUM_JOINTS - 1, 3)
    fk = body.forward(estimate.shape, root, pose)
    first_format = next(o.fmt for s in states for o in s.observations)
    keypoints = body.forward(estimate.shape, root, pose, keypoints=first_format).keypoints
    detections = detections_per_state(states)
    seen = {o.camera for s in states for o in s.observations}
    for c, cam in enumerate(capture.cameras):
        if cam.name in priors and c not in seen:
            notes.append(f"camera {cam.name}: no usable detections; it constrains nothing and keeps its prior trajectory")
            _log(options, notes[-1])
    if detections.min() == 0:
        notes.append(f"{int((detections == 0).sum())} of {n} body states have no detection near them: flagged unconstrained")
        _log(options, notes[-1])
    result = Result(
        pipeline="aircap", capture=capture_label or str(capture.path or capture.name), world_frame="capture",
        timestamps=times, joints=fk.joints, body_model=body.name, root=root, pose=pose, shape=estimate.shape,
        keypoints=keypoints, keypoint_format=first_format,
        flags={"num_detections": detections, "unconstrained": detections == 0},
        log=estimate.log, parameters=options_parameters(options),
    )  # fmt: skip
    for c, cam in enumerate(capture.cameras):
        if cam.name not in priors:
            continue
        poses = priors[cam.name][0].copy()
        for (cc, j), p in estimate.cameras.items():
            if cc == c:
                poses[j] = p.matrix()
        result.cameras[cam.name] = CameraTrack(cam.timestamps, poses)
    if options.covariances:
        if graph is None:
            graph, values = sequence_graph(problem, estimate)
        marginals = gtsam.Marginals(graph.linearize(values), values)
        roots = np.stack([r.matrix() for r in estimate.roots])
        result.covariances["joints"], result.covariances["root"] = joint_covariances(body, marginals, roots, estimate.poses, estimate.shape)
    result.parameters["seconds"] = round(seconds, 3)
    result.parameters["per_frame_seconds"] = round(per_frame_seconds, 3)
    result.parameters["notes"] = notes
    return result


def run_aircap_command(capture_path: Path, out: Path, options: AircapOptions, overwrite: bool = False) -> Result:
    """``mocapgraph run aircap``: load, run, write, and print a short summary."""
    capture = load_capture(capture_path)
    result = run_aircap(capture, options, capture_label=str(capture_path))
    write_result(result, out, overwrite=overwrite)
    flags = result.flags
    n = len(result.timestamps)
    print(
        f"aircap ({options.mode}, cameras {options.cameras}): {n} body states from {len(result.cameras)} cameras "
        f"in {result.parameters['seconds']:.1f} s ({n / max(result.parameters['seconds'], 1e-9):.0f} states/s); "
        f"{int(flags['unconstrained'].sum())} states without detections"
    )
    return result
