"""The factors of a :class:`~mocapgraph.graphs.state_model.StateModel`: every pipeline's graph.

:class:`BodyGraph` adds, per body state, the reprojection of its observations (one factor per
keypoint format and interpolation fraction, all its cameras at once so that forward kinematics
is shared) and the pose priors; between states, the temporal smoothness of root, joint rotations
and (optionally) 3D joints; per moving camera, the smoothness of its consecutive frames and,
with an IMU log, GTSAM's preintegrated IMU factors between them (:mod:`~mocapgraph.graphs.camera_imu`); and on
request the shape prior, the ground terms, the pose VAE and the motion prior. It inserts initial
values from an :class:`~mocapgraph.graphs.state_model.Estimate`, reads one back, orders the
elimination along time, and computes the covariances a result reports.

A camera is **estimated** when it has observations in the model and is not held fixed
(``fixed_cameras``: per camera ``(F_c, 4, 4)`` poses used as constants, e.g. AirPose's camera 1,
or AirCap's cameras held at their GPS/IMU track).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.keypoint_offsets import offset_basis, offset_parameters
from mocapgraph.body.labelling import SWAP_KINDS, swap_permutations
from mocapgraph.body.model import BodyModel
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.errors import MocapgraphError, is_positive_number
from mocapgraph.factors.body_priors import pose_regularizer_factor, shape_prior_factor
from mocapgraph.factors.camera_priors import camera_gyro_factor
from mocapgraph.factors.ground import camera_ground_factor, joint_ground_factor
from mocapgraph.factors.keys import (
    camera_bias_key,
    camera_velocity_key,
    focal_key,
    keypoint_offset_key,
    motion_frame_key,
    motion_latent_key,
    pose_key,
    pose_latent_key,
    root_key,
    shape_key,
)
from mocapgraph.factors.navigation import FusionNoise
from mocapgraph.factors.reprojection import Labelling, ShapeTableCache, reprojection_factor
from mocapgraph.factors.robust import RobustScale
from mocapgraph.factors.smoothness import (
    camera_acceleration_factor,
    camera_smoothness_factor,
    joint_smoothness_factor,
    pose_smoothness_factor,
    pose_velocity_factor,
    root_smoothness_factor,
)
from mocapgraph.graphs.camera_imu import PHONE_GYRO_NOISE, CameraImu, bias_prior, bias_walk_factor, imu_factor
from mocapgraph.graphs.solver import annealed_stages
from mocapgraph.graphs.state_model import Estimate, Observation, StateModel
from mocapgraph.graphs.uncertainty import (
    calibrated,
    factor_groups,
    joint_covariances,
    joints_datum,
    joints_in_datum,
    poses_in_datum,
    window_misfit,
    with_shape_cross,
)
from mocapgraph.priors.motion_windows import WINDOW

POSE_PRIORS = ("none", "gmm", "vae")
SHAPE_MODES = ("hold", "estimate")
POSE_SMOOTHNESS = ("velocity", "acceleration")
FOCAL_MODES = ("guessed", "all", "fixed")
OFFSET_MODES = ("fixed", "estimate")


@dataclass
class GraphOptions:
    """Weights of the terms, as factors (units in the names). Each pipeline's options carry one,
    with its own defaults (measured on its scenes)."""

    noise_px: float = 3.0
    gm_sigma_px: float = 40.0
    pose_prior_sigma_rad: float = 0.8  # the weak regulariser every state keeps, on all 21 joints
    # The regulariser's width on the joints the pose GMM leaves out (its training takes never move
    # them: spine3, the feet, the collars on CMU); None: pose_prior_sigma_rad. At 0.8 rad only it held
    # them, and the online loop's single Gauss-Newton steps turned the upper body round on spine3 and
    # the collars to explain a UAV's whole-body detector flips (docs/online.md).
    unmodelled_sigma_rad: float | None = None
    # The learned pose prior: the pelvis's pitch is nearly invisible in keypoints (the hip points
    # lie on its pitch axis), and without a prior the spine and legs make up for it. "vae" runs
    # its network once per linearisation for all states.
    pose_prior: str = "gmm"
    shape_prior_sigma: float = 0.1
    # "hold" keeps the initial shape during the solve (held by a stiff prior, so the covariances
    # are still those of the graph with the shape free under its prior): without calibration the
    # body's size is the only scale, and every smoothness term is cheaper in a smaller scene.
    shape: str = "hold"
    root_sigma_rad_s: float = 4.0
    root_sigma_m_s: float = 3.0
    # Joint-rotation smoothness: "velocity" (pairs of states) keeps the linear solve's cliques at
    # two states; "acceleration" (triples) is smoother but about 4x slower.
    pose_smoothness: str = "velocity"
    pose_sigma_rad_s: float = 6.0
    pose_sigma_rad_s2: float = 60.0
    joint_sigma_m_s: float | None = 2.0  # SmartMocap's 3D joint smoothness; None: not used
    camera_sigma_rad_s: float = 1.0
    camera_sigma_m_s: float = 2.0
    # Moving cameras' constant-velocity model (camera_acceleration_factor); None: not used. The
    # simulated hand-held phones accelerate 1-4 m/s² rms per axis, the UAVs 0.1-2.7. SmartMocap
    # uses 4; AirPose+ from the fusion regressor's start was worse with it (camera 2 at 3.5
    # against 0.9 m on airpose, 3 s), and AirCap's cameras are pinned by their GPS/IMU priors.
    camera_sigma_m_s2: float | None = None
    ground_sigma_m: float = 0.02
    camera_clearance_m: float = 0.3
    # Left/right swaps of the detector (mocapgraph.body.labelling): each camera-frame's labelling
    # is the hypothesis with the lower robust cost, re-decided at every linearisation; a
    # relabelling costs as much as one point `swap_cost_sigmas` times noise_px off.
    swaps: bool = True
    swap_cost_sigmas: float = 8.0
    # Whole-body relabelling of moving cameras in the solve: only where something holds their
    # poses in place (AirCap's GPS/IMU priors, SmartMocap's final pass from stitched chunks);
    # from a rough start the camera's pose at that frame goes round the person as readily
    # (0.2-0.5 m off on rich without any swap, measured).
    moving_body_swaps: bool = False
    # With moving_body_swaps False, whether a held moving camera (AirPose's reference) may still
    # relabel its whole body. The online loop's AirCap bootstrap holds its UAV cameras at the
    # onboard estimate and says no: with it, aircap 10 s online MPJPE 0.56 -> 0.72 m (smoothed
    # 0.45 -> 0.58, a body turned round at 7 s).
    held_body_swaps: bool = True
    # Focal lengths as variables: "guessed" (the cameras whose intrinsics are a guess), "all" or
    # "fixed"; each held near its given value by a log-normal prior of this width.
    focal: str = "guessed"
    focal_sigma_log: float = 0.3
    # Cameras whose focal lengths were guessed alike (the same guessed K, so the same image size:
    # most often the same camera model) share one focal variable. Each its own, on the real
    # clip's four identical cameras, scattered them 9-24 % off and bent the rig (27 cm).
    focal_shared: bool = True
    # Keypoint-definition offsets (mocapgraph.body.keypoint_offsets): "fixed" at the ones the
    # BodyGraph is given (none by default), or "estimate"d with the body as one variable per
    # detector format, starting at the given ones, each parameter ~ N(0, offset_sigma_m²), for
    # the points of `offset_parts` (the others held). With every point free the body drifted away
    # from its keypoints where the pose and motion priors liked it better (half a metre on rich).
    offsets: str = "fixed"
    offset_sigma_m: float = 0.015
    offset_parts: tuple[str, ...] = ("shoulder",)
    # Moving cameras' IMU logs, when the graph is given any (mocapgraph.graphs.camera_imu): the
    # gyroscope at its datasheet noise, the accelerometer down-weighted. At its datasheet noise
    # the accelerometer took two of five 3 s phones takes metres away (bench smartmocap phones).
    imu_noise: FusionNoise = PHONE_GYRO_NOISE

    def check(self) -> None:
        for name, value, choices in (
            ("pose_prior", self.pose_prior, POSE_PRIORS),
            ("shape", self.shape, SHAPE_MODES),
            ("pose_smoothness", self.pose_smoothness, POSE_SMOOTHNESS),
            ("focal", self.focal, FOCAL_MODES),
            ("offsets", self.offsets, OFFSET_MODES),
        ):
            if value not in choices:
                raise MocapgraphError(f"{name} {value!r}: choose one of {', '.join(choices)}")
        for name in ("noise_px", "gm_sigma_px", "pose_prior_sigma_rad", "shape_prior_sigma", "root_sigma_rad_s", "root_sigma_m_s",
                     "pose_sigma_rad_s", "pose_sigma_rad_s2", "camera_sigma_rad_s", "camera_sigma_m_s", "ground_sigma_m",
                     "swap_cost_sigmas", "focal_sigma_log", "offset_sigma_m"):  # fmt: skip
            value = getattr(self, name)
            if not is_positive_number(value):
                raise MocapgraphError(f"{name}: a finite number > 0, got {value!r}")
        for name in ("joint_sigma_m_s", "camera_sigma_m_s2", "unmodelled_sigma_rad"):
            value = getattr(self, name)
            if value is not None and not is_positive_number(value):
                raise MocapgraphError(f"{name}: a finite number > 0 or None, got {value!r}")


@dataclass
class LearnedPriors:
    """The shipped learned priors a run asks for (None where not), loaded once per run."""

    pose_gmm: object | None = None
    pose_vae: object | None = None
    motion_vae: object | None = None

    @classmethod
    def load(cls, pose_prior: str = "none", motion_prior: str = "none") -> LearnedPriors:
        from mocapgraph.priors import load_default_pose_gmm
        from mocapgraph.priors.motion_vae import load_default_motion_vae
        from mocapgraph.priors.pose_vae import load_default_pose_vae

        return cls(
            load_default_pose_gmm() if pose_prior == "gmm" else None,
            load_default_pose_vae() if pose_prior == "vae" else None,
            load_default_motion_vae() if motion_prior == "vae" else None,
        )


def regularizer_sigmas(options: GraphOptions, pose_gmm) -> float | np.ndarray:
    """The weak pose regulariser's standard deviations, radians: ``pose_prior_sigma_rad``, or
    ``(63,)`` with ``unmodelled_sigma_rad`` on the joints ``pose_gmm`` does not model (when both
    are given and the mixture covers some joints only)."""
    if options.unmodelled_sigma_rad is None or pose_gmm is None or pose_gmm.joints is None:
        return options.pose_prior_sigma_rad
    sigmas = np.full((NUM_JOINTS - 1, 3), float(options.unmodelled_sigma_rad))
    sigmas[np.asarray(pose_gmm.joints)] = options.pose_prior_sigma_rad
    return sigmas.ravel()


def motion_windows(n: int, stride: int = WINDOW) -> list[int]:
    """First states of the motion prior's windows over ``n`` states: every ``stride``, plus one
    ending at the last state when the stride leaves a tail (none when ``n`` < 25)."""
    starts = list(range(0, n - WINDOW + 1, stride))
    if starts and starts[-1] + WINDOW < n:
        starts.append(n - WINDOW)
    return starts


def swap_hypotheses(body: BodyModel, fmt: str) -> np.ndarray:
    """``(H, K)`` the labelling hypotheses of format ``fmt`` (:data:`~mocapgraph.body.labelling.SWAP_KINDS` order)."""
    names = body.keypoint_names if fmt == "body" else get_format(fmt).names
    return swap_permutations(names)


class BodyGraph:
    """Builds the factors of ``model`` over its states (indices ``0..N-1``).

    Args:
        model: the state model.
        body: the body model.
        options: the terms' weights.
        learned: the learned priors (default: the pose prior ``options`` asks for, loaded now).
        fixed_cameras: per camera, ``(F_c, 4, 4)`` constant world_T_camera (no variable).
        fixed_shape: ``(S,)`` a constant shape (no shape variable), e.g. a per-frame fit's.
        keypoint_offsets: per keypoint format, ``(K, 3)`` its points' definition offsets
            (:mod:`mocapgraph.body.keypoint_offsets`), e.g. from :func:`~mocapgraph.graphs.keypoint_fit.estimate_offsets`:
            held, or the start of their estimate with ``options.offsets == "estimate"``.
        imu: per camera, its IMU log (:mod:`mocapgraph.graphs.camera_imu`): an estimated moving
            camera's consecutive frames the log covers get an IMU factor, with a velocity and a
            bias at each.
        imu_reference: None when the world's −Z is gravity (SmartMocap's ground frame): the IMU
            factors are GTSAM's ``CombinedImuFactor``. Else the held camera whose frame the world
            is (AirPose's camera 1): the gravity direction is unknown there, so each step gets
            the gyroscope's rotation relative to that camera
            (:func:`~mocapgraph.factors.camera_priors.camera_gyro_factor`: no velocity, the bias
            with its random walk), the reference's own gyroscope over the same step when it
            moves (a step its log does not cover gets no factor; its gyroscope bias one
            variable, ``camera_bias_key(reference, 0)``).
    """

    def __init__(
        self, model: StateModel, body: BodyModel, options: GraphOptions, *, learned: LearnedPriors | None = None,
        fixed_cameras: dict[int, np.ndarray] | None = None, fixed_shape=None, keypoint_offsets: dict[str, np.ndarray] | None = None,
        imu: dict[int, CameraImu] | None = None, imu_reference: int | None = None,
    ):  # fmt: skip
        options.check()
        self.keypoint_offsets = dict(keypoint_offsets or {})
        self.model, self.body, self.options = model, body, options
        self.learned = learned if learned is not None else LearnedPriors.load(options.pose_prior)
        self.fixed_cameras = dict(fixed_cameras or {})
        self.fixed_shape = None if fixed_shape is None else body.check_shape(fixed_shape)
        self.scale = RobustScale(np.inf)
        self.caches: dict[str, ShapeTableCache] = {}
        self.estimated = [c for c in model.observed_cameras() if c not in self.fixed_cameras]
        self.focal_cameras = [
            c for c in model.observed_cameras() if options.focal == "all" or (options.focal == "guessed" and model.cameras[c].focal_guessed)
        ]
        # per focal camera, the camera whose focal variable it uses (itself, or the first one
        # guessed alike with focal_shared)
        self.focal_leader: dict[int, int] = {}
        for c in self.focal_cameras:
            cam = self.model.cameras[c]
            alike = [d for d in self.focal_leader if options.focal_shared and cam.focal_guessed and self.model.cameras[d].focal_guessed
                     and np.allclose(self.model.cameras[d].K, cam.K)]  # fmt: skip
            self.focal_leader[c] = self.focal_leader[alike[0]] if alike else c
        # the detector formats whose offsets are variables, with their parametrisation
        self.format_index = {fmt: f for f, fmt in enumerate(model.formats)}
        bases = {fmt: offset_basis(body.table(body.default_shape, keypoints=fmt), options.offset_parts) for fmt in self.format_index if fmt != "body" and options.offsets == "estimate"}
        self.offset_bases = {fmt: basis for fmt, basis in bases.items() if basis.shape[-1]}
        self.windows: list[int] = []
        # per estimated moving camera with an IMU log, the pairs of its consecutive frames the log covers
        self.imu = {c: log for c, log in (imu or {}).items() if c in self.estimated and model.cameras[c].moving}
        self.imu_reference = imu_reference
        # a moving reference turns the world with it: its own log must cover a step too
        self.reference_imu = (imu or {}).get(imu_reference) if imu_reference is not None and model.cameras[imu_reference].moving else None
        reference_needed = imu_reference is not None and model.cameras[imu_reference].moving
        self.imu_steps: dict[int, list[tuple[int, int]]] = {}
        for c, log in self.imu.items():
            frames, times = self.model.camera_frames(c), self.model.cameras[c].timestamps
            self.imu_steps[c] = [
                (int(a), int(b)) for a, b in zip(frames[:-1], frames[1:])
                if log.covers(times[a], times[b]) and (not reference_needed or (self.reference_imu is not None and self.reference_imu.covers(times[a], times[b])))
            ]  # fmt: skip
        # per state, its reprojection factors' labellings and the observations they cover
        self.labellings: dict[int, list[tuple[Labelling, list[Observation]]]] = {}
        # per factor group, its variance factor, once calibrated covariances were computed
        self.variance_factors: dict[str, float] = {}
        # per state, the motion prior's misfit of its window (uncertainty.window_misfit), likewise
        self.motion_misfit: np.ndarray = np.zeros(0)

    # -- variables ------------------------------------------------------------------------------

    @property
    def shape_key(self) -> int | None:
        return None if self.fixed_shape is not None else shape_key()

    def cache(self, fmt: str) -> ShapeTableCache:
        if fmt not in self.caches:
            if fmt in self.offset_bases:
                # the given offsets the parameters cannot express stay, held
                held = self.keypoint_offsets.get(fmt)
                held = None if held is None else held - self.offset_bases[fmt] @ offset_parameters(self.offset_bases[fmt], held)
                self.caches[fmt] = ShapeTableCache(self.body, fmt, offsets=held, offset_basis=self.offset_bases[fmt])
            else:
                self.caches[fmt] = ShapeTableCache(self.body, fmt, offsets=self.keypoint_offsets.get(fmt))
        return self.caches[fmt]

    def camera_vars(self, states: range | None = None) -> dict[int, tuple[int, int]]:
        """Every estimated camera's pose key over ``states`` (default all) → (camera, its first frame)."""
        out: dict[int, tuple[int, int]] = {}
        for c in self.estimated:
            for j in self.model.camera_frames(c, states):
                out.setdefault(self.model.camera_var(c, j), (c, int(j)))
        return out

    def held_keys(self) -> list[int]:
        """Keys the options hold during a solve (the shape, with ``shape="hold"``)."""
        return [shape_key()] if self.options.shape == "hold" and self.shape_key is not None else []

    def values(self, estimate: Estimate, states: range | None = None) -> gtsam.Values:
        """Body states (of ``states``, default all), shape and estimated cameras at ``estimate``."""
        values = gtsam.Values()
        for i in range(self.model.num_states) if states is None else states:
            values.insert(root_key(i), gtsam.Pose3(estimate.roots[i]))
            values.insert(pose_key(i), estimate.poses[i].ravel())
        if self.shape_key is not None:
            lo, hi = self.body.shape_bounds.T
            values.insert(shape_key(), np.clip(estimate.shape, lo + 1e-9, hi - 1e-9))
        for key, (c, j) in self.camera_vars(states).items():
            values.insert(key, gtsam.Pose3(estimate.cameras[c][j]))
        for c in self.focal_cameras:
            if self.focal_leader[c] == c:
                shared = [d for d in self.focal_cameras if self.focal_leader[d] == c]
                values.insert(focal_key(c), np.array([np.mean(estimate.focal_log[shared])]))
        for fmt, basis in self.offset_bases.items():
            start = self.keypoint_offsets.get(fmt, np.zeros(basis.shape[:2]))
            values.insert(self.offset_key(fmt), offset_parameters(basis, start))
        for c in self.imu:
            frames = self.imu_frames(c, states)
            if len(frames):
                # started at the central differences of the camera's centres (the velocity is no output)
                times = self.model.cameras[c].timestamps[frames]
                centres = estimate.cameras[c][frames, :3, 3]
                velocity = np.gradient(centres, times, axis=0) if len(frames) > 1 else np.zeros((1, 3))
                for j, v in zip(frames, velocity):
                    if self.imu_reference is None:
                        values.insert(camera_velocity_key(c, j), v)
                    values.insert(camera_bias_key(c, j), gtsam.imuBias.ConstantBias())
        if self.reference_imu is not None and any(self.imu_steps.values()) and not values.exists(camera_bias_key(self.imu_reference, 0)):
            values.insert(camera_bias_key(self.imu_reference, 0), gtsam.imuBias.ConstantBias())
        return values

    def imu_frames(self, c: int, states: range | None = None) -> np.ndarray:
        """``(M,)`` camera ``c``'s frames (of ``states``, default all) in an IMU step: those with a velocity and a bias."""
        frames = np.unique(np.array(self.imu_steps.get(c, []), dtype=int).ravel())
        return np.intersect1d(frames, self.model.camera_frames(c, states))

    def offset_key(self, fmt: str) -> int:
        """The key of detector format ``fmt``'s offset parameters."""
        return keypoint_offset_key(self.format_index[fmt])

    def offsets(self, values: gtsam.Values) -> dict[str, np.ndarray]:
        """Per detector format, ``(K, 3)`` its keypoint offsets (metres, carrier frames): the
        estimated ones in ``values``, else the ones given."""
        out = dict(self.keypoint_offsets)
        for fmt, basis in self.offset_bases.items():
            out[fmt] = self.keypoint_offsets.get(fmt, 0.0) + basis @ (values.atVector(self.offset_key(fmt)) - offset_parameters(basis, self.keypoint_offsets.get(fmt, np.zeros(basis.shape[:2]))))
        return out

    def read(self, values: gtsam.Values, start: Estimate, states: range | None = None) -> Estimate:
        """The estimate in ``values`` over ``states`` (default all); everything else from ``start``."""
        out = Estimate(start.roots.copy(), start.poses.copy(), start.shape.copy(), [c.copy() for c in start.cameras], list(start.log), start.focal_log.copy())
        self.update(out, values, states)
        return out

    def update(self, estimate: Estimate, values: gtsam.Values, states: range | None = None) -> None:
        """Write the body states ``states`` (default all), the shape and those states' estimated
        camera frames from ``values`` into ``estimate``, in place."""
        for i in range(self.model.num_states) if states is None else states:
            estimate.roots[i] = values.atPose3(root_key(i)).matrix()
            estimate.poses[i] = values.atVector(pose_key(i)).reshape(NUM_JOINTS - 1, 3)
        if self.shape_key is not None:
            estimate.shape = values.atVector(shape_key())
        for c in self.focal_cameras:
            estimate.focal_log[c] = values.atVector(focal_key(self.focal_leader[c]))[0]
        for c in self.estimated:
            frames = self.model.camera_frames(c, states)
            if len(frames) == 0:
                continue
            if self.model.cameras[c].moving:
                estimate.cameras[c][frames] = [values.atPose3(self.model.camera_var(c, j)).matrix() for j in frames]
            else:
                estimate.cameras[c][:] = values.atPose3(self.model.camera_var(c, 0)).matrix()

    # -- factors --------------------------------------------------------------------------------

    def add_state(self, graph: gtsam.NonlinearFactorGraph, i: int) -> None:
        """State ``i``'s reprojection factors (one per keypoint format and fraction, all its
        cameras) and pose priors."""
        groups: dict[tuple[str, float], list] = {}
        self.labellings[i] = []
        for o in self.model.states[i]:
            groups.setdefault((o.fmt, o.fraction), []).append(o)
        for (fmt, fraction), obs in groups.items():
            keys, fixed = [], []
            for o in obs:
                held = self.fixed_cameras.get(o.camera)
                keys.append(None if held is not None else self.model.camera_var(o.camera, o.frame))
                fixed.append(held[o.frame] if held is not None else None)
            between = {"next_state": (root_key(i + 1), pose_key(i + 1)), "fraction": fraction} if fraction else {}
            labelling = None
            if self.options.swaps:
                # A moving camera's pose at a frame can go round to the person's other side:
                # relabelling its whole body there would trade against that (moving_body_swaps).
                # A held camera (AirPose's reference) cannot go anywhere (held_body_swaps).
                whole = SWAP_KINDS.index("body")
                allowed = np.ones((len(obs), len(SWAP_KINDS)), dtype=bool)
                if not self.options.moving_body_swaps:
                    held_ok = self.options.held_body_swaps
                    allowed[[self.model.cameras[o.camera].moving and (pose is None or not held_ok) for o, pose in zip(obs, fixed)], whole] = False
                labelling = Labelling(self.permutations(fmt), 0.5 * self.options.swap_cost_sigmas**2, allowed=allowed)
                self.labellings[i].append((labelling, obs))
            graph.add(
                reprojection_factor(
                    self.body, self.cache(fmt), root_key(i), pose_key(i), self.shape_key, keys, fixed,
                    np.stack([self.model.cameras[o.camera].intrinsics for o in obs]), np.stack([o.observed for o in obs]),
                    np.stack([o.weights for o in obs]), fmt, self.scale, noise_px=self.options.noise_px,
                    fixed_shape=self.fixed_shape, labelling=labelling,
                    focal_keys=[focal_key(self.focal_leader[o.camera]) if o.camera in self.focal_leader else None for o in obs],
                    offset_key=self.offset_key(fmt) if fmt in self.offset_bases else None, **between,
                )  # fmt: skip
            )
        self.add_pose_priors(graph, i)

    def relabel(self, enabled: bool) -> None:
        """Switch the labelling hypotheses of every reprojection factor built so far on or off
        (off: the points as detected)."""
        for groups in self.labellings.values():
            for labelling, _ in groups:
                labelling.enabled = enabled

    def permutations(self, fmt: str) -> np.ndarray:
        """``(H, K)`` the labelling hypotheses of format ``fmt`` (:func:`swap_hypotheses`)."""
        return swap_hypotheses(self.body, fmt)

    def relabelled(self, estimate: Estimate) -> dict[int, np.ndarray]:
        """Per camera, ``(F_c,)`` int8 the labelling its detections take at ``estimate``: the index into :data:`~mocapgraph.body.labelling.SWAP_KINDS` (0 as
        detected) of every frame with observations, -1 for the others. All zeros without ``swaps``.
        Decided at the robust scale the solves end with (``gm_sigma_px``)."""
        self.scale.sigma_px = self.options.gm_sigma_px
        graph = gtsam.NonlinearFactorGraph()
        for i in range(self.model.num_states):
            self.add_state(graph, i)
        graph.error(self.values(estimate))  # every labelling takes its choice at the estimate
        out = {c: np.full(len(cam.timestamps), -1, dtype=np.int8) for c, cam in enumerate(self.model.cameras)}
        for i in range(self.model.num_states):
            for o in self.model.states[i]:
                out[o.camera][o.frame] = max(out[o.camera][o.frame], 0)
            for labelling, obs in self.labellings[i]:
                for o, h in zip(obs, labelling.choice):
                    if h:  # with several detectors: any relabelling shows
                        out[o.camera][o.frame] = h
        return out

    def add_pose_priors(self, graph: gtsam.NonlinearFactorGraph, i: int) -> None:
        """The weak regulariser on every joint of state ``i`` and the pose GMM, if loaded (the
        pose VAE covers all states at once: :meth:`add_pose_vae`)."""
        graph.add(pose_regularizer_factor(pose_key(i), regularizer_sigmas(self.options, self.learned.pose_gmm)))
        if self.learned.pose_gmm is not None:
            from mocapgraph.priors import pose_gmm_factor

            graph.add(pose_gmm_factor(pose_key(i), self.learned.pose_gmm))

    def add_smoothness(self, graph: gtsam.NonlinearFactorGraph, i: int) -> None:
        """Between states ``i - 1`` and ``i``: root, joint-rotation (velocity, or acceleration
        over ``i - 2 .. i``) and, with ``joint_sigma_m_s``, 3D joint smoothness."""
        o, t = self.options, self.model.times
        dt = max(float(t[i] - t[i - 1]), 1e-3)
        graph.add(root_smoothness_factor(root_key(i - 1), root_key(i), dt, (o.root_sigma_rad_s, o.root_sigma_m_s)))
        if o.pose_smoothness == "velocity":
            graph.add(pose_velocity_factor(pose_key(i - 1), pose_key(i), dt, o.pose_sigma_rad_s))
        elif i > 1:
            graph.add(pose_smoothness_factor([pose_key(i - 2), pose_key(i - 1), pose_key(i)], t[i - 2 : i + 1], o.pose_sigma_rad_s2))
        if o.joint_sigma_m_s is not None:
            a, b = (root_key(i - 1), pose_key(i - 1)), (root_key(i), pose_key(i))
            graph.add(joint_smoothness_factor(self.cache("body"), a, b, self.shape_key, dt, o.joint_sigma_m_s, fixed_shape=self.fixed_shape))

    def add_camera_smoothness(self, graph: gtsam.NonlinearFactorGraph) -> None:
        """Every estimated moving camera's consecutive frames in the model: constant-pose
        smoothness on pairs, and the constant-velocity model of the centre on triples."""
        o = self.options
        for c in self.estimated:
            cam = self.model.cameras[c]
            if not cam.moving:
                continue
            frames = self.model.camera_frames(c)
            for j0, j1 in zip(frames[:-1], frames[1:]):
                dt = max(float(cam.timestamps[j1] - cam.timestamps[j0]), 1e-3)
                graph.add(camera_smoothness_factor(self.model.camera_var(c, j0), self.model.camera_var(c, j1), dt, o.camera_sigma_rad_s, o.camera_sigma_m_s))
            if o.camera_sigma_m_s2 is not None:
                for triple in zip(frames[:-2], frames[1:-1], frames[2:]):
                    keys = [self.model.camera_var(c, j) for j in triple]
                    graph.add(camera_acceleration_factor(keys, cam.timestamps[list(triple)], o.camera_sigma_m_s2))

    def add_camera_imu(self, graph: gtsam.NonlinearFactorGraph) -> None:
        """Every IMU step of every camera with a log: its ``CombinedImuFactor`` (or, in a
        reference camera's world, its gyroscope's relative rotation and the bias's random walk),
        and the bias's prior where a run of steps starts (the first frame, or after a gap)."""
        noise = self.options.imu_noise
        reference_bias = camera_bias_key(self.imu_reference, 0) if self.reference_imu is not None else None
        if reference_bias is not None and any(self.imu_steps.values()):
            graph.add(bias_prior(reference_bias, noise))
        for c, log in self.imu.items():
            params, times = log.params(noise), self.model.cameras[c].timestamps
            previous = None
            for a, b in self.imu_steps[c]:
                if a != previous:
                    graph.add(bias_prior(camera_bias_key(c, a), noise))
                keys = (self.model.camera_var(c, a), self.model.camera_var(c, b))
                biases = (camera_bias_key(c, a), camera_bias_key(c, b))
                t0, t1 = float(times[a]), float(times[b])
                if self.imu_reference is None:
                    velocities = (camera_velocity_key(c, a), camera_velocity_key(c, b))
                    graph.add(imu_factor(keys, velocities, biases, log.preintegrate(t0, t1, params)))
                else:
                    reference = None if reference_bias is None else self.reference_imu.gyro_increment(t0, t1, self.reference_imu.params(noise))
                    graph.add(camera_gyro_factor(*keys, biases[0], log.gyro_increment(t0, t1, params), reference_bias_key=reference_bias, reference=reference))
                    graph.add(bias_walk_factor(*biases, t1 - t0, noise))
                previous = b

    def add_ground(self, graph: gtsam.NonlinearFactorGraph, i: int) -> None:
        """E_HGP on state ``i``'s joints (the world's z = 0 plane)."""
        graph.add(joint_ground_factor(self.cache("body"), root_key(i), pose_key(i), self.shape_key, self.options.ground_sigma_m, fixed_shape=self.fixed_shape))

    def add_camera_ground(self, graph: gtsam.NonlinearFactorGraph) -> None:
        """E_CGP on every camera variable: its centre above the ground by the clearance."""
        for key in self.camera_vars():
            graph.add(camera_ground_factor(key, sigma_m=0.05, clearance_m=self.options.camera_clearance_m))

    def add_focal_priors(self, graph: gtsam.NonlinearFactorGraph) -> None:
        """Each variable focal length near the given one: ``s ~ N(0, focal_sigma_log²)``."""
        noise = gtsam.noiseModel.Isotropic.Sigma(1, self.options.focal_sigma_log)
        for c in sorted(set(self.focal_leader.values())):
            graph.add(gtsam.PriorFactorVector(focal_key(c), np.zeros(1), noise))

    def add_offset_priors(self, graph: gtsam.NonlinearFactorGraph) -> None:
        """Each estimated offset parameter near zero: ``θ ~ N(0, offset_sigma_m²)``."""
        for fmt, basis in self.offset_bases.items():
            noise = gtsam.noiseModel.Isotropic.Sigma(basis.shape[-1], self.options.offset_sigma_m)
            graph.add(gtsam.PriorFactorVector(self.offset_key(fmt), np.zeros(basis.shape[-1]), noise))

    def focal_lengths(self, estimate: Estimate) -> dict[str, float]:
        """``{camera name: fx}`` in pixels of the cameras whose focal length was estimated."""
        return {self.model.cameras[c].name: float(self.model.cameras[c].K[0, 0] * np.exp(estimate.focal_log[c])) for c in self.focal_cameras}

    def add_shape_prior(self, graph: gtsam.NonlinearFactorGraph) -> None:
        if self.shape_key is not None:
            graph.add(shape_prior_factor(shape_key(), self.body.default_shape, self.options.shape_prior_sigma))

    def add_pose_vae(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, estimate: Estimate) -> None:
        """The pose VAE's latent per state, if loaded."""
        if self.learned.pose_vae is not None:
            from mocapgraph.priors.pose_vae_factor import PoseVAEPrior

            PoseVAEPrior(self.learned.pose_vae, range(self.model.num_states)).add_to(graph, values, estimate.pose_vectors)

    def add_motion_prior(
        self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, windows: list[int], ground_sigmas: tuple[float, float] | None = None
    ) -> None:
        """SmartMocap's motion prior on the 25-state windows starting at ``windows``, if loaded;
        ``ground_sigmas`` ``(tilt_rad, height_m)`` of its ground plane at the world's z = 0
        (default: the prior's)."""
        if self.learned.motion_vae is None or not windows:
            return
        from mocapgraph.priors.motion_factor import MotionVAEPrior

        extra = {} if ground_sigmas is None else {"ground_sigmas": ground_sigmas}
        prior = MotionVAEPrior(
            self.learned.motion_vae, self.body, windows, shape_key=self.shape_key, fixed_shape=self.fixed_shape,
            table_cache=self.cache("body"), **extra,
        )  # fmt: skip
        prior.add_to(graph, values)
        self.windows = list(windows)

    def sequence(self, estimate: Estimate, *, ground: bool = False) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """Every state's factors, body and camera smoothness, the shape prior, the pose VAE and,
        with ``ground``, the ground terms of body and cameras; the values at ``estimate``."""
        graph = gtsam.NonlinearFactorGraph()
        for i in range(self.model.num_states):
            self.add_state(graph, i)
            if ground:
                self.add_ground(graph, i)
            if i:
                self.add_smoothness(graph, i)
        self.add_shape_prior(graph)
        self.add_focal_priors(graph)
        self.add_offset_priors(graph)
        self.add_camera_smoothness(graph)
        self.add_camera_imu(graph)
        if ground:
            self.add_camera_ground(graph)
        values = self.values(estimate)
        self.add_pose_vae(graph, values, estimate)
        return graph, values

    # -- solving --------------------------------------------------------------------------------

    def time_ordering(self, values: gtsam.Values) -> list[int]:
        """Elimination order: body states and camera frames in time order (a camera frame before
        the state at its time), then what all states share (shape, static cameras, offsets, ground).

        The graph is a chain in time with a few variables shared by all; eliminating along the
        chain keeps every clique to neighbouring states, where COLAMD's order grew faster than
        the sequence (AirCap at 60 s: solves 27 % faster, measured). A pose latent goes before
        its state: it touches that state alone, so eliminating it first adds no fill-in. A
        motion window's latent and canonical frame touch all its 25 states: eliminated early,
        either would join them in one dense clique, so both go after the window's last state.
        """
        n = self.model.num_states
        deferred: dict[int, list[int]] = {}
        for w, i0 in enumerate(self.windows):
            deferred.setdefault(i0 + WINDOW - 1, []).extend([motion_frame_key(w), motion_latent_key(w)])
        latent = self.learned.pose_vae is not None
        timed = []
        for i in range(n):
            t = float(self.model.times[i])
            timed.append((t, 1, ([pose_latent_key(i)] if latent else []) + [root_key(i), pose_key(i)]))
            if i in deferred:
                timed.append((t, 2, deferred[i]))
        for key, (c, j) in self.camera_vars().items():
            if self.model.cameras[c].moving:
                timed.append((self.model.frame_time(c, j), 0, [key, camera_velocity_key(c, j), camera_bias_key(c, j)]))
        timed.sort(key=lambda item: (item[0], item[1]))
        order = [key for _, _, keys in timed for key in keys if values.exists(key)]
        listed = set(order)
        return order + sorted(k for k in values.keys() if k not in listed)

    def stages(self, iterations: int, ordering: str | list[int] = "colamd") -> list:
        """L2, then Geman-McClure at the options' scale (:func:`~mocapgraph.graphs.solver.annealed_stages`)."""
        return annealed_stages(self.scale, self.options.gm_sigma_px, iterations, ordering)

    def project_shape(self, values: gtsam.Values) -> gtsam.Values:
        """Clamp the shape into the body model's bounds (the body table is undefined outside
        them), returning the same ``Values`` when nothing moved."""
        if self.shape_key is None:
            return values
        lo, hi = self.body.shape_bounds.T
        shape = values.atVector(shape_key())
        clamped = np.clip(shape, lo + 1e-9, hi - 1e-9)
        if np.array_equal(clamped, shape):
            return values
        out = gtsam.Values(values)
        out.update(shape_key(), clamped)
        return out

    def covariances(
        self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, estimate: Estimate, cameras: bool = True, calibrate: bool = False
    ) -> dict[str, np.ndarray]:
        """Marginal covariances at the solution: ``joints (N, 22, 3, 3)`` m², ``root (N, 6, 6)``,
        ``shape (S, S)`` and, with ``cameras``, ``camera:<name> (M, 6, 6)`` at each of the
        camera's frames in the model (Pose3 tangents, rotation first).

        With ``calibrate`` (docs/uncertainty.md): each factor group's noise scaled by its
        variance factor (:func:`~mocapgraph.graphs.uncertainty.variance_factors`, the
        reprojection factors' measured robustly), then joints, root and cameras taken into the
        datum of a similarity over all joints (:class:`~mocapgraph.graphs.uncertainty.SimilarityDatum`),
        the frame any comparison with another frame aligns by (a world pinned to a body
        state, as SmartMocap's; not a world of its own such as AirCap's GPS frame); the shape's as it is. The factors
        are kept in ``self.variance_factors``, the motion prior's misfit per state in
        ``self.motion_misfit`` (:func:`~mocapgraph.graphs.uncertainty.window_misfit`)."""
        calibration = calibrated(graph, values, {g for g in factor_groups(graph) if "r" in g and "c" in g}) if calibrate else None
        marginals = gtsam.Marginals(calibration.linear if calibrate else graph.linearize(values), values)
        n = self.model.num_states
        fk = self.body.forward(estimate.shape, estimate.roots, estimate.poses.reshape(n, NUM_JOINTS - 1, 3), jacobians=True)
        out = {}
        out["joints"], out["root"] = joint_covariances(self.body, marginals, estimate.roots, estimate.poses, estimate.shape, fk=fk)
        if self.shape_key is not None:
            out["shape"] = np.asarray(marginals.marginalCovariance(shape_key()))
        camera_keys = {}
        for c in self.estimated if cameras else []:
            cache: dict[int, np.ndarray] = {}
            keys = [self.model.camera_var(c, j) for j in self.model.camera_frames(c)]
            camera_keys[c] = keys
            out[f"camera:{self.model.cameras[c].name}"] = np.stack(
                [cache[k] if k in cache else cache.setdefault(k, marginals.marginalCovariance(k)) for k in keys]
            )
        if calibrate:
            roots, poses = [root_key(i) for i in range(n)], [pose_key(i) for i in range(n)]
            if self.shape_key is not None:
                out["joints"] = with_shape_cross(calibration, fk, roots, poses, self.shape_key, out["joints"])
            datum = joints_datum(calibration, fk, roots, poses, self.shape_key)
            out["joints"] = joints_in_datum(datum, fk.joints, out["joints"])
            out["root"] = poses_in_datum(datum, calibration, roots, estimate.roots, out["root"])
            for c, keys in camera_keys.items():
                name = f"camera:{self.model.cameras[c].name}"
                out[name] = poses_in_datum(datum, calibration, keys, estimate.cameras[c][self.model.camera_frames(c)], out[name])
            self.variance_factors = calibration.factors
            self.motion_misfit = window_misfit(calibration.system, graph, chr(gtsam.Symbol(motion_latent_key(0)).chr()), self.windows, WINDOW, n)
        return out
