"""``mocapgraph run aircap``: body and UAV cameras from keypoints, held near their GPS/IMU priors.

AirCap's pipeline as factor graphs on the shared state model (:mod:`mocapgraph.graphs`): camera
priors from the UAVs' sensors (the onboard online estimate, or the offline GPS/IMU re-run), a
tracker that follows the person in 3D and gates the detections, then the body fitted to the
keypoints of several detectors while the cameras are refined. ``mode="per-frame"`` fits each
body state alone, warm-started from the previous one, as the thesis did; ``mode="sequence"``
starts from that and solves the whole sequence jointly with temporal smoothness. ``cameras``
reproduces the thesis' ablation:

- ``fixed``: cameras held at the onboard online GPS/IMU estimate (the ``self_pose`` log);
- ``prior``: cameras held at the offline GPS/IMU fusion (:mod:`mocapgraph.graphs.navigation`);
- ``refine``: cameras are variables, held near the offline fusion by robust priors.

What is AirCap's own here: the GPS/IMU camera priors (:class:`CameraPriors`), the tracker, and
the per-frame pass.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from mocapgraph.body import load_body_model
from mocapgraph.body.rotations import axis_rotation
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.data_tools.io.result import Result, options_parameters
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.camera_priors import camera_offset_prior_factor, camera_prior_factor
from mocapgraph.factors.keys import camera_offset_key, pose_key, root_key
from mocapgraph.graphs.body_graph import BodyGraph, GraphOptions, LearnedPriors, motion_windows
from mocapgraph.graphs.initialisation import neutral_pose
from mocapgraph.graphs.solver import solve_staged
from mocapgraph.graphs.state_model import Estimate, StateModel
from mocapgraph.graphs.sync import SYNC_POLICIES
from mocapgraph.pipelines.camera_priors import SOURCES, camera_priors
from mocapgraph.pipelines.executors import make_executor
from mocapgraph.pipelines.observations import capture_state_model, detector_names
from mocapgraph.pipelines.results import estimate_result, focal_notes, swap_notes
from mocapgraph.priors.motion_windows import WINDOW
from mocapgraph.progress import progress_bar

log = logging.getLogger(__name__)

MODES = ("sequence", "per-frame")
CAMERA_MODES = ("refine", "prior", "fixed")
MOTION_PRIORS = ("none", "vae")


@dataclass
class AircapOptions:
    """Parameters of the AirCap pipeline (units in the names; defaults measured on ``aircap`` scenes)."""

    mode: str = "sequence"
    cameras: str = "refine"
    # the UAV cameras' priors: "fused" (the offline GPS/IMU fusion) or "online" (the onboard
    # estimate, self_pose); None: fused to refine the cameras, online to hold them ("fixed")
    prior_source: str | None = None
    sync: str | None = None  # default: "closest" for per-frame (the thesis), "grid" for sequence
    grid_hz: float = 30.0  # body states per second with sync "grid"
    detectors: tuple[str, ...] | None = None
    # SmartMocap's motion prior on 25-state windows of the sequence fit (needs 30 Hz grid states);
    # windows start every motion_window_stride states, each with its own latent. Off by default:
    # it lowers RA-MPJPE (4.9 -> 3.3 cm, mean of seeds 1-6) but its joint covariances are less
    # honest (pooled 95 % coverage 0.82 against 0.975 without; docs/priors.md).
    motion_prior: str = "none"
    motion_window_stride: int = 25
    camera_prior_kernel: str = "huber"
    camera_prior_white_fraction: float = 0.6  # frame-to-frame share of a GPS/IMU prior's std (pooled 95 % coverage 0.975 on seeds 1-6)
    per_frame_iterations: int = 8
    workers: int = 2  # processes for the per-frame pass (1: in this process)
    sequence_iterations: int = 30
    covariances: bool = True
    # The learned pose prior is off by default ("gmm" on every graph; "vae" on the sequence fit
    # only: its network runs once per linearisation for all states, per state it would cost 16 ms).
    # The UAVs' GPS/IMU priors pin their poses, so their whole-body swaps can be undone in the solve.
    graph: GraphOptions = field(
        default_factory=lambda: GraphOptions(pose_prior="none", shape_prior_sigma=0.25, shape="estimate", joint_sigma_m_s=None, moving_body_swaps=True)
    )

    def check(self) -> None:
        self.graph.check()
        if self.mode not in MODES:
            raise MocapgraphError(f"mode {self.mode!r}: choose one of {', '.join(MODES)}")
        if self.cameras not in CAMERA_MODES:
            raise MocapgraphError(f"cameras {self.cameras!r}: choose one of {', '.join(CAMERA_MODES)}")
        if self.prior_source not in (None, *SOURCES):
            raise MocapgraphError(f"prior_source {self.prior_source!r}: choose one of {', '.join(SOURCES)}")
        if self.sync is not None and self.sync not in SYNC_POLICIES:
            raise MocapgraphError(f"sync {self.sync!r}: choose one of {', '.join(SYNC_POLICIES)}")
        if self.mode == "per-frame" and self.graph.pose_prior == "vae":
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


# ---------------------------------------------------------------------------------------------
# Camera priors


def camera_tracks(capture: Capture, mode: str, source: str | None = None) -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], list[str]]:
    """Per usable camera (by index): prior world_T_camera ``(F_c, 4, 4)`` and covariance
    ``(F_c, 6, 6)``; and notes on the cameras that have none. ``source``: as
    :attr:`AircapOptions.prior_source`."""
    tracks, notes = camera_priors(capture, source=source or ("online" if mode == "fixed" else "fused"))
    out = {}
    for c, cam in enumerate(capture.cameras):
        if cam.name in tracks:
            out[c] = (tracks[cam.name].world_T_camera, tracks[cam.name].covariance)
        elif cam.extrinsics is not None:
            poses = np.broadcast_to(cam.extrinsics, (cam.num_frames, 4, 4)).copy()
            out[c] = (poses, np.tile(np.diag([1e-6] * 3 + [1e-4] * 3), (cam.num_frames, 1, 1)))
            notes.append(f"camera {cam.name}: no GPS/IMU; using its calibration")
        else:
            notes.append(f"camera {cam.name}: no GPS/IMU and no calibration; its detections are not used")
    return out, notes


@dataclass
class CameraPriors:
    """Each refined camera frame near its GPS/IMU prior, through one offset per camera.

    A prior's error is mostly the trajectory's slow drift, common to nearby frames. The prior's
    covariance is split between the two: each frame keeps ``white_fraction²`` of its own (the
    frame-to-frame part) and the offset takes the rest of the camera's typical covariance, so
    that every frame's total is its prior's. (The offset used to take the whole covariance of the
    first frame, the fusion's least certain: that counted the prior twice, and the joints' 95 %
    ellipsoids held 0.997–1.0 of the errors, measured on seeds 0–6.)

    Attributes:
        tracks: per camera index, ``(poses (F_c, 4, 4), covariances (F_c, 6, 6))``.
    """

    tracks: dict[int, tuple[np.ndarray, np.ndarray]]
    white_fraction: float
    kernel: str
    _common: dict[int, np.ndarray] = field(default_factory=dict)

    def common_covariance(self, c: int) -> np.ndarray:
        """``(6, 6)``: camera ``c``'s prior covariance averaged over its frames, turned into the
        world frame (the offset's tangent: ``O`` multiplies from the left). Computed once per
        camera: the per-frame pass asks for it at every state."""
        if c not in self._common:
            poses, cov = self.tracks[c]
            adjoint = np.stack([gtsam.Pose3(T).AdjointMap() for T in poses])
            self._common[c] = np.mean(adjoint @ cov @ np.swapaxes(adjoint, 1, 2), axis=0)
        return self._common[c]

    def add(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, camera_vars: dict[int, tuple[int, int]]) -> None:
        """The offsets of the cameras of ``camera_vars`` (key → camera, frame) and a prior per key."""
        common = 1.0 - self.white_fraction**2
        for c in sorted({c for c, _ in camera_vars.values()}):
            if not values.exists(camera_offset_key(c)):
                graph.add(camera_prior_factor(camera_offset_key(c), np.eye(4), common * self.common_covariance(c), kernel="none"))
                values.insert(camera_offset_key(c), gtsam.Pose3())
        for key, (c, j) in camera_vars.items():
            poses, cov = self.tracks[c]
            graph.add(camera_offset_prior_factor(camera_offset_key(c), key, poses[j], cov[j] * self.white_fraction**2, kernel=self.kernel))


# ---------------------------------------------------------------------------------------------
# Solves


def _upright(yaw: float, position: np.ndarray) -> np.ndarray:
    """``(4, 4)`` root standing upright (body +Y up → world +Z) facing world direction ``yaw`` (radians)."""
    stand = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # body +Z forward → world −Y
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = axis_rotation("z", yaw + np.pi / 2) @ stand, position
    return T


@dataclass
class PerFrameTask:
    """What every span of the per-frame pass shares (handed to forked workers once)."""

    graph: BodyGraph
    priors: CameraPriors | None
    start: Estimate
    positions: np.ndarray  # (N, 3) the tracker's positions
    yaws: np.ndarray  # (N,) its headings
    iterations: int


def solve_span(task: PerFrameTask, span: tuple[int, int]) -> tuple[Estimate, list[dict]]:
    """Each state of ``span`` ``[start, stop)`` alone, in time order, warm-started from the previous one.

    The shape is held (estimating it from one frame is ill-posed; the sequence fit does it). The
    first state with detections tries four headings and keeps the best; states without
    detections carry the previous estimate over at the tracker's position (they are flagged
    unconstrained). Returns the estimate with the span's states and cameras filled in, and the
    solves' log.
    """
    bg, est = task.graph, task.start.span(0, task.graph.model.num_states)
    log_rows = []
    previous: tuple[np.ndarray, np.ndarray] | None = None
    states = range(*span)
    # Spans are equal and run side by side: the first one's bar stands for all of them.
    for i in progress_bar(states, desc="aircap per-frame", unit="state") if span[0] == 0 else states:
        position = task.positions[i]
        if not bg.model.states[i]:
            est.roots[i] = previous[0].copy() if previous else _upright(task.yaws[i], position)
            est.roots[i, :3, 3] = position
            est.poses[i] = previous[1] if previous else neutral_pose()
            continue
        graph = gtsam.NonlinearFactorGraph()
        bg.add_state(graph, i)
        base = gtsam.Values()
        one = range(i, i + 1)
        if task.priors is not None:
            cams = bg.camera_vars(one)
            task.priors.add(graph, base, cams)
            for key, (c, j) in cams.items():
                base.insert(key, gtsam.Pose3(est.cameras[c][j]))
        if previous is None:
            starts = [(_upright(task.yaws[i] + k * np.pi / 2, position), neutral_pose()) for k in range(4)]
        else:
            root = previous[0].copy()
            root[:3, 3] = position
            starts = [(root, previous[1])]
        best = None
        for root, pose in starts:
            values = gtsam.Values(base)
            values.insert(root_key(i), gtsam.Pose3(root))
            values.insert(pose_key(i), pose.ravel())
            result = solve_staged(graph, values, bg.stages(task.iterations))
            if best is None or result.error < best.error:
                best = result
        bg.update(est, best.values, one)
        previous = (est.roots[i], est.poses[i])
        log_rows.append({"state": i, "iterations": len(best.log), "error": float(best.error)})
    return est, log_rows


def solve_per_frame(task: PerFrameTask, workers: int) -> Estimate:
    """:func:`solve_span` on ``workers`` consecutive spans of the states at once (forked
    processes through the local executor); every span starts cold (four headings at its first
    detected state). The states are independent but for the warm start, so the spans give the
    same answer up to that restart, in about 1/workers of the time on as many free cores."""
    n = task.graph.model.num_states
    bounds = np.linspace(0, n, workers + 1).round().astype(int)
    spans = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
    with make_executor("local", min(workers, len(spans))) as executor:
        parts = executor.map(solve_span, spans, context=task)
    out = task.start.span(0, n)
    out.log = []
    for (a, b), (part, rows) in zip(spans, parts):
        out.roots[a:b], out.poses[a:b] = part.roots[a:b], part.poses[a:b]
        for c in task.graph.estimated:
            frames = task.graph.model.camera_frames(c, range(a, b))
            out.cameras[c][frames] = part.cameras[c][frames]
        out.log += rows
    return out


def resample(estimate: Estimate, times: np.ndarray, new_times: np.ndarray) -> Estimate:
    """The body at other times: root translation and joint vectors linear, root rotation slerp
    (held beyond the ends); cameras as they are (they are indexed by frame)."""
    t = np.clip(new_times, times[0], times[-1])
    R = Rotation.from_matrix(estimate.roots[:, :3, :3])
    roots = np.tile(np.eye(4), (len(t), 1, 1))
    roots[:, :3, :3] = Slerp(times, R)(t).as_matrix() if len(times) > 1 else np.repeat(R.as_matrix(), len(t), 0)
    roots[:, :3, 3] = np.stack([np.interp(t, times, estimate.roots[:, a, 3]) for a in range(3)], 1)
    flat = estimate.pose_vectors
    poses = np.stack([np.interp(t, times, flat[:, d]) for d in range(flat.shape[1])], 1).reshape(len(t), -1, 3)
    return Estimate(roots, poses, estimate.shape.copy(), [c.copy() for c in estimate.cameras], list(estimate.log), estimate.focal_log.copy())


def sequence_graph(bg: BodyGraph, priors: CameraPriors | None, estimate: Estimate, windows: list[int]) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The whole sequence: every state's factors, temporal smoothness, shape prior, learned
    priors, and each refined camera frame near its prior."""
    graph, values = bg.sequence(estimate)
    bg.add_motion_prior(graph, values, windows)
    if priors is not None:
        priors.add(graph, values, bg.camera_vars())
    return graph, values


# ---------------------------------------------------------------------------------------------
# The pipeline


def _gates(capture: Capture, track, detectors: tuple[str, ...], camera_poses: dict[str, np.ndarray]) -> dict[tuple[str, str], np.ndarray]:
    """The tracker's gate per (camera, detector): ``(F_c, K)`` whether each keypoint lies in the
    region of interest its track predicts."""
    gates = {}
    for name in detectors:
        having = {n: p for n, p in camera_poses.items() if name in capture.camera(n).detectors}
        for cam_name, mask in track.inlier_detections(capture, having, detector=name).items():
            gates[(cam_name, name)] = mask
    return gates


def run_aircap(capture: Capture, options: AircapOptions | None = None, capture_label: str = "") -> Result:
    """Run the pipeline on a loaded capture and return the result (nothing written)."""
    from mocapgraph.data_tools.tracking.tracker import track_person

    options = options or AircapOptions()
    options.check()
    start_time = time.perf_counter()
    body = load_body_model()
    detectors = detector_names(capture, options.detectors)
    tracks, camera_notes = camera_tracks(capture, options.cameras, options.prior_source)
    notes = list(capture.notes) + camera_notes  # the loader's repairs first
    for note in notes:
        log.info("aircap: %s", note)
    if not tracks:
        raise MocapgraphError(f"capture {capture.name!r}: no camera has a pose prior (GPS/IMU or calibration)")
    camera_poses = {capture.cameras[c].name: poses for c, (poses, _) in tracks.items()}
    track = track_person(capture, camera_poses)
    gates = _gates(capture, track, detectors, camera_poses)
    learned = LearnedPriors.load(options.graph.pose_prior, options.motion_prior)
    refine = options.cameras == "refine"
    priors = CameraPriors(tracks, options.camera_prior_white_fraction, options.camera_prior_kernel) if refine else None
    fixed = {} if refine else {c: poses for c, (poses, _) in tracks.items()}
    cameras = [tracks[c][0].copy() if c in tracks else np.tile(np.eye(4), (cam.num_frames, 1, 1)) for c, cam in enumerate(capture.cameras)]

    def model_for(sync: str) -> StateModel:
        model = capture_state_model(capture, sync, detectors=detectors, cameras=set(camera_poses), gates=gates, rate_hz=options.grid_hz)
        if not model.observed_cameras():
            raise MocapgraphError(f"capture {capture.name!r}: no usable detections in any camera")
        return model

    # The per-frame pass pairs the cameras' closest frames (several views per state, as the thesis
    # did); the sequence fit then starts from it, resampled onto its own states.
    model = model_for(options.sync if options.mode == "per-frame" and options.sync else "closest")
    times = model.times
    positions, _ = track.at(times)
    velocity = track.velocity_at(times)
    yaws = np.unwrap(np.arctan2(velocity[:, 1], velocity[:, 0]))
    log.info("aircap: per-frame, %d body states, cameras %s", len(times), options.cameras)
    n = len(times)
    start = Estimate(np.tile(np.eye(4), (n, 1, 1)), np.zeros((n, NUM_JOINTS - 1, 3)), body.default_shape.copy(), cameras)
    # the focal lengths, where estimated, are the whole sequence's: the per-frame pass holds them
    per_frame = BodyGraph(model, body, replace(options.graph, focal="fixed"), learned=learned, fixed_cameras=fixed, fixed_shape=body.default_shape)
    estimate = solve_per_frame(PerFrameTask(per_frame, priors, start, positions, yaws, options.per_frame_iterations), options.workers)
    per_frame_seconds = time.perf_counter() - start_time
    windows: list[int] = []
    graph = values = None
    if options.mode == "sequence":
        pf_times = times
        model = model_for(options.sync or "grid")
        times = model.times
        log.info("aircap: sequence, %d body states", len(times))
        if options.motion_prior != "none":
            windows = motion_windows(len(times), options.motion_window_stride)
            if windows:
                log.info("aircap: motion prior, %d windows of %d states", len(windows), WINDOW)
            else:
                notes.append(f"motion prior: {len(times)} body states are fewer than one window ({WINDOW}); not applied")
                log.info("aircap: %s", notes[-1])
        bg = BodyGraph(model, body, options.graph, learned=learned, fixed_cameras=fixed)
        sequence_start = resample(estimate, pf_times, times)
        graph, values = sequence_graph(bg, priors, sequence_start, windows)
        solved = solve_staged(
            graph, values, bg.stages(options.sequence_iterations, bg.time_ordering(values)), progress="aircap sequence", project=bg.project_shape
        )  # fmt: skip
        values = solved.values
        estimate = bg.read(values, sequence_start)
        estimate.log = list(solved.log)
    seconds = time.perf_counter() - start_time

    seen = set(model.observed_cameras())
    for c in tracks:
        if c not in seen:
            notes.append(f"camera {capture.cameras[c].name}: no usable detections; it constrains nothing and keeps its prior trajectory")
            log.info("aircap: %s", notes[-1])
    detections = model.detections_per_state()
    if detections.min() == 0:
        notes.append(f"{int((detections == 0).sum())} of {len(times)} body states have no detection near them: flagged unconstrained")
        log.info("aircap: %s", notes[-1])
    last = bg if options.mode == "sequence" else per_frame
    swaps = last.relabelled(estimate)
    notes += swap_notes(model.names, swaps) + focal_notes(model, last.focal_lengths(estimate))
    result = estimate_result(
        "aircap", capture, model, body, estimate, "capture", options_parameters(options), capture_label, cameras=sorted(tracks), all_frames=True,
        swaps=swaps,
    )  # fmt: skip
    if options.covariances:
        if graph is None:
            bg = BodyGraph(model, body, options.graph, learned=learned, fixed_cameras=fixed)
            graph, values = sequence_graph(bg, priors, estimate, windows)
        result.covariances.update(bg.covariances(graph, values, estimate, cameras=False))
    result.parameters.update(seconds=round(seconds, 3), per_frame_seconds=round(per_frame_seconds, 3), notes=notes, focal_px=last.focal_lengths(estimate))
    return result


def summary(result: Result) -> str:
    """The one line ``run aircap`` prints."""
    p, n = result.parameters, len(result.timestamps)
    return (
        f"aircap ({p['mode']}, cameras {p['cameras']}): {n} body states from {len(result.cameras)} cameras "
        f"in {p['seconds']:.1f} s ({n / max(p['seconds'], 1e-9):.0f} states/s); "
        f"{int(result.flags['unconstrained'].sum())} states without detections"
    )
