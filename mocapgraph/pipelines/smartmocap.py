"""``mocapgraph run smartmocap``: body and every camera, static or moving, uncalibrated, in the
ground plane's frame (SmartMocap, Saini et al., RA-L 2023).

1. **Initialise**: per view, the body relative to the camera (fusion regressor or PnP of the
   mean body); cameras relative to a reference camera (the first static one) from the body both
   see; the ground plane under the feet; SmartMocap's world: origin at the ground projection
   of the first root, Z up, +Y the person's facing direction then.
2. **Chunks** of 25 states, each solved in three phases (cameras alone; + roots; + everything
   but the first state's root), in parallel on an executor (local processes or Ray).
3. **Stitch** neighbouring chunks on their shared state and shared static cameras, pairwise and
   then pairs of pairs, so that a chunk's error in heading moves only its own subtree instead of
   accumulating along the sequence.
4. **Optimise-final**: the whole sequence with every term: 2D reprojection (Geman-McClure),
   motion prior (25-state windows), root, joint-rotation and 3D joint smoothness, camera
   smoothness, pose and shape priors, human and camera ground penetration.

The world's gauge: the ground is z = 0 (the motion prior's ground held there), and the first
root's horizontal position and heading are held by a stiff prior; its height and tilt only by
a weak one, so the data decide them. The scale comes from the body model's size alone.
"""

from __future__ import annotations

import hashlib
import logging
import os
import pickle
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import gtsam
import numpy as np

from mocapgraph.body import load_body_model
from mocapgraph.body.definition_priors import PROVENANCE, prior_offsets
from mocapgraph.body.labelling import SWAP_KINDS, part_name
from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import axis_rotation, skew
from mocapgraph.data_tools.evaluation.alignment import align_camera_centres
from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.data_tools.io.result import Result, options_parameters
from mocapgraph.errors import MocapgraphError, is_positive_number
from mocapgraph.factors.keys import pose_key, root_key, shape_key
from mocapgraph.graphs.body_graph import BodyGraph, GraphOptions, LearnedPriors, motion_windows
from mocapgraph.graphs.camera_imu import check_max_offset, estimated_clock_offsets, start_from_gyroscopes
from mocapgraph.graphs.initialisation import (
    INITIALISERS,
    coco_views,
    fuse_bodies,
    fused_shape,
    ground_frame,
    moving_cameras_from_static,
    posed_view_swaps,
    relative_cameras,
    rotation_mean,
    view_bodies,
    view_swaps,
)
from mocapgraph.graphs.keypoint_fit import estimate_drift, estimate_offsets, outlier_views, refine_drift_in_images, reprojection_medians
from mocapgraph.graphs.point_bundle import StaticRefinement, refine_static_cameras
from mocapgraph.graphs.solver import held, solve_staged
from mocapgraph.graphs.state_model import Estimate, StateModel
from mocapgraph.pipelines.executors import make_executor
from mocapgraph.pipelines.observations import camera_imus, capture_state_model
from mocapgraph.pipelines.reference_cameras import SOURCES as CAMERA_SOURCES
from mocapgraph.pipelines.reference_cameras import ReferenceTracks, load_camera_reference, reference_clock_offsets, reference_tracks
from mocapgraph.pipelines.results import (
    clock_offset_parameters,
    combined_swaps,
    estimate_result,
    focal_notes,
    frame_ranges,
    imu_support_notes,
    joint_motion_m,
    still_body_notes,
    swap_notes,
)
from mocapgraph.priors.motion_windows import WINDOW

log = logging.getLogger(__name__)

MOTION_PRIORS = ("vae", "none")
OFFSET_ESTIMATIONS = ("joint", "alternation")
OFFSET_PRIORS = ("fitted", "zero")
STATIC_CAMERAS = ("points", "body")
REFINE_THRESHOLD_PX = 15.0
"""Inlier threshold of the RANSAC triangulation that starts the static cameras' free points."""
REFINE_ITERATIONS = 50
"""Levenberg-Marquardt iterations of that adjustment at most (the generic baseline's)."""
REFINE_KEEP_FACTOR = 1.5
"""The static cameras' adjustment on free points is kept only if the body, solved again to the
adjusted cameras, reprojects at most this many times its median before: free points of a person
who barely moves can pull the cameras metres away (pose2sim 0.8.4's BODY_25B trial, its second
person: 1-2 m, 692 px after against 11 px before), where a body cannot follow."""
MOTION_GROUND_SIGMAS = (1e-4, 1e-4)
"""σ (rad, m) of the motion prior's ground at z = 0: SmartMocap's world is the ground plane."""


@dataclass
class SmartmocapOptions:
    """Parameters of the SmartMocap pipeline (units in the names)."""

    # The mean body's PnP: as a starting point it beat the fusion regressor (whose root is ~17°
    # off per view) on airpose, before and after the bundle adjustment (bench airpose).
    initialiser: str = "pnp"
    motion_prior: str = "vae"
    chunk_size: int = WINDOW
    chunk_iterations: int = 3  # per stage and phase: the chunks only warm-start the final pass
    final_iterations: int = 30
    # The detector's keypoint definitions estimated from the final pass (graphs.keypoint_fit) and
    # the sequence solved again with them.
    keypoint_offsets: bool = True
    # "alternation": held at the ones the first solve shows; "joint": those of the points the
    # graph options name (`offset_parts`) are variables of that second solve, started there. On
    # rich (10 s) joint shoulders lowered MPE with realistic faults (1.98 -> 1.59 cm) but raised
    # RA-MPJPE (3.41 -> 3.71) and the static cameras' error (0.82 -> 1.10 cm), and without
    # faults too (3.09 -> 3.62 cm, 0.57 -> 0.79 cm): the pelvis's orientation trades with them.
    offset_estimation: str = "alternation"
    offset_iterations: int = 15
    # Rounds of: views left out, the sequence solved again, the offsets measured again on it
    # (with "joint": rounds only while more views show up). Each round recovers more of what the
    # body's lean hid: on rich (10 s, seed 0, bench faults) 4 rounds against 2 took MPE with
    # realistic faults 1.74 -> 1.53 cm (cameras 1.34 -> 1.32) and without faults RA-MPJPE
    # 2.83 -> 2.65, cameras 0.91 -> 0.86 cm. 8 rounds (each shrinking only its correction) took
    # MPE on (6 s: 1.33 cm) but the cameras back and the offsets drifting along what the body
    # cannot tell apart (docs/smartmocap.md, "Keypoint-definition offsets").
    offset_rounds: int = 4
    # "fitted": a format measured on real footage (body.definition_priors: BlazePose on the lab
    # clip) starts the rounds at that table and its measures are shrunk towards it; "zero":
    # every format starts from the first solve's measure, shrunk towards zero (the only choice
    # for formats never fitted on real footage).
    offset_prior: str = "fitted"
    # The hips' up and forward offsets held at the prior (graphs.keypoint_fit.estimate_offsets'
    # hold_root_shift): the root's own position, which the rounds cannot tell from them.
    hold_root_offsets: bool = True
    # "points": the static cameras adjusted last on free points, as the generic self-calibration
    # does (graphs.point_bundle), then held while the body is solved once more to them: a
    # detector's points are not the body's, and free points absorb that where a body cannot.
    # "body": the static cameras as the body's solve leaves them.
    static_cameras: str = "points"
    static_gm_sigma_px: float = 10.0  # Geman-McClure scale of that adjustment
    # Geman-McClure scale of the body's solve with those cameras held, the last pass (None: the
    # graph's, 40 px). At 40 px a detector's gross misses (on the lab clip cam02's right foot
    # 150-450 px off for half a second; 21 % of the body's residuals there above 20 px, 12 %
    # above 40) still pull the body. That pass from the same solve, the cameras held (the body's
    # reprojection median, every view): 40 px 8.10, 30 px 7.76, 25 px 7.51, 20 px 7.22, 15 px
    # 6.95, 10 px 6.96. But with the drift on (the result's keypoints) bench real moved little:
    # 20 px took the largest person 7.23 -> 7.1 px and the second 5.05 -> 5.4 (cameras held, so
    # the same); on the BODY_25B clip the largest 7.3 -> 6.2 px (cameras 2.95 -> 3.0 cm). On rich (6 s, seed 0, one run each; RA-MPJPE, MPE, MPJPE, static cameras in cm),
    # 40 -> 20 px with realistic faults: 3.33 -> 3.17, 1.57 -> 1.55, 1.71 -> 1.68, 1.10 -> 1.09;
    # without faults 2.58 -> 2.50, 1.00 -> 1.08, 1.28 -> 1.31, 0.75 -> 0.79 (the pelvis further
    # off). 15 px: with faults 3.11, 1.56, 1.68, 1.09, without MPE 1.15; 10 px (an earlier
    # session): MPE 1.31 without faults, 1.74 with. Not the default: the body worse without faults.
    held_gm_sigma_px: float | None = None
    # After the last pass, each detector point's drift from its constant definition offset, per
    # state (graphs.keypoint_fit.estimate_drift: σ of a state's triangulated sample, of the change
    # from one state to the next and of the drift itself, metres): in the result's keypoints and
    # its reprojection, the body and cameras as solved (so neither can change). On the lab clip
    # (largest person, one run) the reprojection went 8.67 -> 7.30 px, the drift 1.0 cm median,
    # 4.0 cm at the 90th percentile; (1, 2, 5) cm: 7.0 px, measured after the fact. None: off.
    # The σs by maximum likelihood of that model on each real clip's samples (the body's points
    # against the points its cameras triangulate): BlazePose (0.74, 0.67, 2.84) cm, BODY_25B
    # (0.65, 0.52, 2.94) cm; these are both rounded, and each clip's reprojection with the other
    # clip's σs is the same to 0.03 px (docs/smartmocap.md, "Definitions that move").
    drift_sigmas_m: tuple[float, float, float] | None = (0.007, 0.006, 0.03)
    # After the first final pass, every camera-frame's labels checked against all the placed
    # cameras' epipolar geometry (graphs.initialisation.posed_view_swaps) and the sequence solved
    # again on them (with graph.swaps only).
    posed_swaps: bool = True
    # Moving cameras' IMU logs (gyroscope and accelerometer, with the capture's mount) as
    # preintegrated factors between their frames (mocapgraph.graphs.camera_imu).
    imu: bool = True
    # The largest offset of a log's clock from its camera's searched for, after the chunks, on
    # the stitched body (graphs.camera_imu.estimated_clock_offsets); None: the clocks taken as one.
    imu_max_offset_s: float | None = 0.05
    executor: str = "local"
    workers: int = 2
    address: str | None = None
    detectors: tuple[str, ...] | None = None
    # The first root holds the world's gauge: stiff horizontally and in heading, weak in height and tilt.
    gauge_sigmas: tuple[float, float] = (1e-3, 0.1)
    covariances: bool = True
    # The error the calibrated covariances (docs/uncertainty.md) still leave out, as variance
    # factors of the joints (and root), the static cameras and the moving ones: measured on
    # `phones` takes of subjects the motion prior never trained on and that no benchmark uses
    # (cmu 08_04, 49_02, 49_10, 18_08, 27_01; seeds 100-104; 1.5 s and 3 s, the bench's
    # settings): the factor that, with the rotation below, puts 95 % of their errors inside the
    # 95 % ellipsoids. Biases (a detector's person size, the swaps' residue) the graph has no
    # variable for.
    covariance_model_error: tuple[float, float, float] = (2.28, 15.1, 5.67)
    # And a rotation of each quantity about the joints' centroid, σ in radians per kind (joints
    # and root, static cameras, moving cameras): an error that grows with the distance from the
    # centroid, as the person walks away from it in a long take and as a camera stands metres
    # off; σ by maximum likelihood on the same takes, then the factors above by the 95 % rule
    # with it (docs/uncertainty.md, "The take's length").
    covariance_lever_error_rad: tuple[float, float, float] = (0.006, 0.012, 0.022)
    # And the joints' (and root's) factor of each state times 1 + gain·μ, μ the motion prior's
    # own misfit of its window (graphs.uncertainty.window_misfit, χ² per row; the result's
    # flag ``motion_prior_misfit``): what the prior does not know of a motion, a pirouette or a
    # walk unlike its training's, shows there and in the joints' errors alike. The gain by
    # maximum likelihood on the same takes (docs/uncertainty.md, "The motion prior's misfit").
    covariance_misfit_gain: float = 1.8
    # The shape estimated: with several views it is observable, and on a CMU walk seen by the rich
    # rig it halved the root orientation error (RA-MPJPE 3.7 -> 2.1 cm) and brought the scene's
    # scale within 4.4 % instead of 7.2 % for the held average body (measured). AirPose's two far
    # cameras cannot hold it (docs/airpose.md).
    # Moving cameras: a constant-velocity model, so that the final pass may relabel their whole
    # body (a camera without it goes round the person to explain a swap: 6 m on rich, 2 s).
    graph: GraphOptions = field(default_factory=lambda: GraphOptions(shape="estimate", moving_body_swaps=True, camera_sigma_m_s2=4.0))
    # A directory where each chunk's solution is kept as it finishes, and read back instead of
    # solved again by a later run of the same chunk (``run smartmocap --resume`` after a kill);
    # where the run keeps its work, not how it solves: left out of the result's parameters.
    checkpoint: str | None = None
    # Moving cameras' tracks from a reconstruction of the background: "colmap" reads the
    # capture's references/<camera_reference> (`mocapgraph colmap`); after the first final pass
    # its tracks are mapped into the solution's world and the motion between consecutive
    # registered frames is a prior of sigmas (rad, m) in the passes after it
    # (mocapgraph.pipelines.reference_cameras). On a 3 s rendered phones capture the walking
    # phone COLMAP registered went from 4.3 cm / 3.8° to 0.44 cm / 0.21° after its Procrustes
    # (σ 0.01: 1.9 cm / 1.2°; 0.003: 1.0 cm / 0.34°); the static phones from 5.5 to 7.2 cm.
    cameras_from: str | None = None
    camera_reference: str = "colmap"
    reference_sigmas: tuple[float, float] = (0.001, 0.001)

    def check(self) -> None:
        self.graph.check()
        if self.initialiser not in INITIALISERS:
            raise MocapgraphError(f"initialiser {self.initialiser!r}: choose one of {', '.join(INITIALISERS)}")
        if self.motion_prior not in MOTION_PRIORS:
            raise MocapgraphError(f"motion_prior {self.motion_prior!r}: choose one of {', '.join(MOTION_PRIORS)}")
        if not (len(self.covariance_model_error) == 3 and all(isinstance(k, (int, float)) and np.isfinite(k) and k >= 1 for k in self.covariance_model_error)):
            raise MocapgraphError(f"covariance_model_error: three finite variance factors >= 1 (joints, static cameras, moving cameras), got {self.covariance_model_error!r}")
        if not (isinstance(self.covariance_misfit_gain, (int, float)) and np.isfinite(self.covariance_misfit_gain) and self.covariance_misfit_gain >= 0):
            raise MocapgraphError(f"covariance_misfit_gain: a finite number >= 0, got {self.covariance_misfit_gain!r}")
        if not (len(self.covariance_lever_error_rad) == 3 and all(isinstance(g, (int, float)) and 0 <= g <= 0.5 for g in self.covariance_lever_error_rad)):
            raise MocapgraphError(f"covariance_lever_error_rad: three angles in [0, 0.5] rad (joints, static cameras, moving cameras), got {self.covariance_lever_error_rad!r}")
        if not (isinstance(self.chunk_size, int) and 2 <= self.chunk_size):
            raise MocapgraphError(f"chunk_size: a whole number of states >= 2, got {self.chunk_size!r}")
        if self.motion_prior == "vae" and self.chunk_size != WINDOW:
            raise MocapgraphError(f"chunk_size: the motion prior's windows are {WINDOW} states; use {WINDOW} or motion_prior 'none'")
        if self.offset_estimation not in OFFSET_ESTIMATIONS:
            raise MocapgraphError(f"offset_estimation {self.offset_estimation!r}: choose one of {', '.join(OFFSET_ESTIMATIONS)}")
        if self.held_gm_sigma_px is not None and not is_positive_number(self.held_gm_sigma_px):
            raise MocapgraphError(f"held_gm_sigma_px: a finite number > 0 or None, got {self.held_gm_sigma_px!r}")
        if self.offset_prior not in OFFSET_PRIORS:
            raise MocapgraphError(f"offset_prior {self.offset_prior!r}: choose one of {', '.join(OFFSET_PRIORS)}")
        if self.drift_sigmas_m is not None and not (len(self.drift_sigmas_m) == 3 and all(is_positive_number(v) for v in self.drift_sigmas_m)):
            raise MocapgraphError(f"drift_sigmas_m: three finite numbers > 0 (metres) or None, got {self.drift_sigmas_m!r}")
        if not (isinstance(self.offset_rounds, int) and self.offset_rounds >= 1):
            raise MocapgraphError(f"offset_rounds: a whole number >= 1, got {self.offset_rounds!r}")
        if self.static_cameras not in STATIC_CAMERAS:
            raise MocapgraphError(f"static_cameras {self.static_cameras!r}: choose one of {', '.join(STATIC_CAMERAS)}")
        if not (isinstance(self.static_gm_sigma_px, (int, float)) and np.isfinite(self.static_gm_sigma_px) and self.static_gm_sigma_px > 0):
            raise MocapgraphError(f"static_gm_sigma_px: a positive number of pixels, got {self.static_gm_sigma_px!r}")
        if not (isinstance(self.offset_iterations, int) and self.offset_iterations >= 1):
            raise MocapgraphError(f"offset_iterations: a whole number >= 1, got {self.offset_iterations!r}")
        if not (isinstance(self.workers, int) and self.workers >= 1):
            raise MocapgraphError(f"workers: a whole number of processes >= 1, got {self.workers!r}")
        if self.cameras_from is not None and self.cameras_from not in CAMERA_SOURCES:
            raise MocapgraphError(f"cameras_from {self.cameras_from!r}: choose one of {', '.join(CAMERA_SOURCES)}")
        check_max_offset(self.imu_max_offset_s)
        if len(self.reference_sigmas) != 2 or not all(np.isfinite(v) and v > 0 for v in self.reference_sigmas):
            raise MocapgraphError(f"reference_sigmas: two finite numbers > 0 (rad, m), got {self.reference_sigmas!r}")


# ---------------------------------------------------------------------------------------------
# Graphs


def gauge_factor(estimate: Estimate, sigmas: tuple[float, float]) -> gtsam.PriorFactorPose3:
    """The first root's horizontal position and heading held stiffly, its tilt and height weakly.

    The root's frame has +Y up (body axes), so near upright its tangent's rotation about y is the
    heading and its translation along x and z the horizontal position.
    """
    stiff, weak = sigmas
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([weak, stiff, weak, stiff, weak, stiff]))
    return gtsam.PriorFactorPose3(root_key(0), gtsam.Pose3(estimate.roots[0]), noise)


def sequence_graph(bg: BodyGraph, estimate: Estimate, gauge_sigmas) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """Every SmartMocap term over the model's states (the motion prior on windows side by side
    when the model has at least one); the values at ``estimate``."""
    graph, values = bg.sequence(estimate, ground=True)
    graph.add(gauge_factor(estimate, gauge_sigmas))
    bg.add_motion_prior(graph, values, motion_windows(bg.model.num_states), MOTION_GROUND_SIGMAS)
    return graph, values


# ---------------------------------------------------------------------------------------------
# Chunks


@dataclass
class ChunkTask:
    """One chunk, self-contained so that it pickles for a process or a Ray task."""

    model: StateModel
    start: Estimate
    options: SmartmocapOptions
    imu: dict = field(default_factory=dict)


def solve_chunk(task: ChunkTask) -> tuple[Estimate, float]:
    """SmartMocap's three phases on one chunk: cameras alone; cameras and roots; everything
    but the first state's root. Returns the estimate and the seconds it took."""
    import torch

    # Chunks run side by side, one per core: a second torch thread each would only contend.
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    o = task.options
    n = task.model.num_states
    # A chunk is too short to tell a camera's focal length from its distance: focal lengths are
    # estimated in the final pass over the whole sequence only. Nor may a chunk relabel a moving
    # camera's whole body: from its rough start the camera's pose goes round the person as
    # readily (false relabelled runs, 0.2-0.5 m off, on rich without swaps); the final pass,
    # from the stitched cameras, does it (moving_body_swaps).
    graph_options = replace(o.graph, focal="fixed", moving_body_swaps=False)
    learned = LearnedPriors.load(o.graph.pose_prior, o.motion_prior if n == WINDOW else "none")
    bg = BodyGraph(task.model, load_body_model(), graph_options, learned=learned, imu=task.imu)
    graph, values = sequence_graph(bg, task.start, o.gauge_sigmas)
    body_keys = [root_key(i) for i in range(n)] + [pose_key(i) for i in range(n)] + [shape_key()]
    phases = [
        ("cameras", body_keys),
        ("cameras+roots", [pose_key(i) for i in range(n)] + [shape_key()]),
        ("all but the first root", [root_key(0)] + bg.held_keys()),
    ]
    ordering = bg.time_ordering(values)
    for k, (_, keys) in enumerate(phases):
        # Labels are re-decided only once the body is free: against the initial mean body (held
        # in the first two phases) a camera seen from the side "fits" swapped as often as not.
        bg.relabel(k == len(phases) - 1)
        # The cameras' phase and the pose's anneal from L2 to Geman-McClure, each starting far
        # from its solution: the cameras from their rough placement, the pose from the mean
        # body's, where a limb far from it (a bent elbow puts the wrist 60-100 px off on the
        # real clip) lies in the kernel's flat tail and nothing pulls it in. The roots' phase
        # starts near its solution and stays robust (an L2 stage there cost a third of a
        # chunk's solves for nothing, measured).
        stages = bg.stages(o.chunk_iterations, ordering)[1 if k == 1 else 0 :]
        values = solve_staged(held(graph, values, keys), values, stages, project=bg.project_shape).values
    return bg.read(values, task.start), time.perf_counter() - t0


def chunk_bounds(n: int, size: int) -> list[tuple[int, int]]:
    """``[start, stop)`` of chunks of ``size`` states, each sharing its first state with the
    previous chunk's last; a tail shorter than half a chunk joins the last chunk."""
    bounds = []
    start = 0
    while start < n - 1:
        stop = min(start + size, n)
        if n - stop < size // 2:
            stop = n
        bounds.append((start, stop))
        start = stop - 1
    return bounds or [(0, n)]


# ---------------------------------------------------------------------------------------------
# Stitching


def _yaw_alignment(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``(4, 4)``: the rotation about Z and translation taking ``source (P, 3)`` onto
    ``target (P, 3)`` in least squares (both chunks stand on the same ground, z = 0)."""
    s, t = source - source.mean(0), target - target.mean(0)
    angle = np.arctan2(np.sum(s[:, 0] * t[:, 1] - s[:, 1] * t[:, 0]), np.sum(s[:, 0] * t[:, 0] + s[:, 1] * t[:, 1]))
    A = np.eye(4)
    A[:3, :3] = axis_rotation("z", angle)
    A[:3, 3] = target.mean(0) - A[:3, :3] @ source.mean(0)
    return A


def stitch(body: BodyModel, model: StateModel, parts: list[tuple[int, int, Estimate]]) -> Estimate:
    """One estimate from chunk estimates that share their boundary states.

    Neighbours are merged pairwise, then pairs of pairs (a tree, not a chain). Each merge moves
    the right block onto the left by the heading and translation that best align their shared
    state's joints and the static cameras both blocks estimated; the shared state keeps the left
    block's body, a moving camera the right block's frames after it, a static camera the chordal
    mean of both weighted by their states (the shape and focal lengths too).
    """
    static = [c for c in range(model.num_cameras) if not model.cameras[c].moving]
    blocks = list(parts)
    while len(blocks) > 1:
        merged = []
        for p in range(0, len(blocks) - 1, 2):
            (a0, b0, left), (a1, b1, right) = blocks[p], blocks[p + 1]
            s = a1 - a0  # the shared state, in the left block's numbering
            fk = body.forward(left.shape, np.stack([left.roots[s], right.roots[0]]), np.stack([left.poses[s], right.poses[0]]))
            src = np.concatenate([fk.joints[1]] + [right.cameras[c][:1, :3, 3] for c in static])
            dst = np.concatenate([fk.joints[0]] + [left.cameras[c][:1, :3, 3] for c in static])
            moved = right.transformed(_yaw_alignment(src, dst))
            cameras = [c.copy() for c in left.cameras]
            for c in range(model.num_cameras):
                after = model.camera_frames(c, range(a1 + 1, b1))
                cameras[c][after] = moved.cameras[c][after]
            wl, wr = b0 - a0, b1 - a1
            for c in static:
                cameras[c][:, :3, :3] = rotation_mean(np.stack([left.cameras[c][0, :3, :3], moved.cameras[c][0, :3, :3]]), [wl, wr])
                cameras[c][:, :3, 3] = (wl * left.cameras[c][0, :3, 3] + wr * moved.cameras[c][0, :3, 3]) / (wl + wr)
            shape = (wl * left.shape + wr * moved.shape) / (wl + wr)
            focal_log = (wl * left.focal_log + wr * moved.focal_log) / (wl + wr)
            est = Estimate(np.concatenate([left.roots, moved.roots[1:]]), np.concatenate([left.poses, moved.poses[1:]]), shape, cameras, focal_log=focal_log)
            merged.append((a0, b1, est))
        if len(blocks) % 2:
            merged.append(blocks[-1])
        blocks = merged
    return blocks[0][2]


# ---------------------------------------------------------------------------------------------
# The pipeline


def _reference_camera(capture: Capture, seen: list[bool]) -> int:
    """The first static camera that sees the person, else the first camera that does."""
    for c, cam in enumerate(capture.cameras):
        if seen[c] and not cam.moving:
            return c
    return seen.index(True)


def initial_estimate(
    model: StateModel, body: BodyModel, options: SmartmocapOptions, reference: int, notes: list[str]
) -> tuple[Estimate, list[bool], str, dict[int, np.ndarray]]:
    """Body and cameras in SmartMocap's world from the views; which cameras could be placed;
    which initialiser gave the views; per moving camera with back views its detector labelled as
    front ones, ``(F_c,)`` the swap codes of its frames that undo them (``StateModel.relabelled``)."""
    views, used = view_bodies(model, body, options.initialiser)
    notes.append(f"initialised from the {used}")
    moving = [cam.moving for cam in model.cameras]
    ref_T_c, known = relative_cameras(views, moving, reference)
    ref_T_c, known, back_views = moving_cameras_from_static(coco_views(model), model.camera_matrices(), ref_T_c, known, moving)
    back_swaps = {}
    for c, turned in back_views.items():
        frames = model.camera_frames(c)
        codes = np.zeros(len(model.cameras[c].timestamps), dtype=np.int8)
        codes[frames] = np.where(turned[model.frame_state[c][frames]], SWAP_KINDS.index("body"), 0)
        back_swaps[c] = codes
    placed = [bool(known[c].any()) for c in range(model.num_cameras)]
    fused = fuse_bodies(views, ref_T_c, known)
    shape = fused_shape(body, fused)
    ground = ground_frame(body, fused, shape)
    if not ground.from_feet:
        notes.append(
            f"the feet spread only {ground.foot_spread_m:.2f} m (std): the ground's tilt was first taken from the body's mean up "
            "direction and rests on the motion prior and the weak gauge prior (its covariance says how well)"
        )
    world_T_ref = np.linalg.inv(ground.ref_T_world)
    cameras = [model.frames_from_states(c, world_T_ref @ ref_T_c[c]) for c in range(model.num_cameras)]
    return Estimate(world_T_ref @ fused.camera_T_root, fused.pose, shape, cameras), placed, used, back_swaps


def _solve_chunks(tasks: list[ChunkTask], options: SmartmocapOptions) -> list[tuple[Estimate, float]]:
    """Every chunk's solution and seconds, in order; with ``options.checkpoint``, those kept by an
    earlier run are read back and the others kept as they finish."""
    if options.checkpoint is None:
        with make_executor(options.executor, options.workers, options.address) as executor:
            return executor.map(solve_chunk, tasks, progress="smartmocap chunks")
    Path(options.checkpoint).mkdir(parents=True, exist_ok=True)
    files = [_chunk_file(options.checkpoint, task) for task in tasks]
    solved: dict[int, tuple[Estimate, float]] = {}
    for i, file in enumerate(files):
        if file.is_file():
            with open(file, "rb") as f:
                solved[i] = pickle.load(f)  # written by solve_and_keep_chunk, whole (renamed into place)
    todo = [i for i in range(len(tasks)) if i not in solved]
    log.info("smartmocap: %d of %d chunks kept from an earlier run (%s)", len(solved), len(tasks), options.checkpoint)
    with make_executor(options.executor, options.workers, options.address) as executor:
        fresh = executor.map(solve_and_keep_chunk, [(tasks[i], str(files[i])) for i in todo], progress="smartmocap chunks")
    solved.update(zip(todo, fresh))
    return [solved[i] for i in range(len(tasks))]


def _chunk_file(directory: str, task: ChunkTask) -> Path:
    """Where a chunk's solution is kept: named by a digest of everything its solve depends on."""
    digest = hashlib.sha256(pickle.dumps((task.model, task.start, replace(task.options, checkpoint=None), task.imu))).hexdigest()
    return Path(directory) / f"chunk-{digest[:24]}.pkl"


def solve_and_keep_chunk(job: tuple[ChunkTask, str]) -> tuple[Estimate, float]:
    """:func:`solve_chunk`, its solution then written to ``file`` (a temporary name, then renamed,
    so a kill never leaves half a file there)."""
    task, file = job
    solved = solve_chunk(task)
    tmp = f"{file}.tmp-{os.getpid()}"
    with open(tmp, "wb") as f:
        pickle.dump(solved, f)
    os.replace(tmp, file)
    return solved


def _degeneracy_notes(model: StateModel, placed: list[bool]) -> list[str]:
    notes = ["absolute scale: from the body model's size (shape prior) alone; the shape's covariance carries it"]
    used = [c for c in range(model.num_cameras) if placed[c]]
    if len(used) == 1:
        notes.append("a single camera: depth along its rays rests on the body's size and the priors; expect large covariances along them")
    if all(model.cameras[c].moving for c in used):
        notes.append("no static camera: the split between the person's motion and the cameras' rests on the motion prior and smoothness")
    return notes


def run_smartmocap(capture: Capture, options: SmartmocapOptions | None = None, capture_label: str = "", held_cameras: dict[str, np.ndarray] | None = None) -> Result:
    """Run the pipeline on a loaded capture and return the result (nothing written). With
    ``held_cameras`` (camera name → ``(4, 4)`` world_T_camera of a static camera, in any world and
    scale: a lab's calibration), after the swaps are settled those cameras are moved there (by
    the similarity onto the solve's centres, :func:`aligned_to`) and held in every later pass;
    the keypoint offsets are then measured against a calibrated rig (:func:`mocapgraph.benchmarks.real.fit_clip_offsets`)."""
    options = options or SmartmocapOptions()
    options.check()
    t_start = time.perf_counter()
    body = load_body_model()
    notes = list(capture.notes)
    # read before the solve: a missing or mismatched reference fails now, not after minutes
    camera_reference = load_camera_reference(capture, options.cameras_from, options.camera_reference) if options.cameras_from else None
    seen = [bool(cam.detectors) and any(np.isfinite(d.keypoints[..., 2]).any() for d in cam.detectors.values()) for cam in capture.cameras]
    if not any(seen):
        raise MocapgraphError(f"capture {capture.name!r}: no camera has detections")
    reference = _reference_camera(capture, seen)
    model = capture_state_model(capture, "closest", detectors=options.detectors, reference=reference)
    # Swapped views are undone before they place the cameras, by the views' epipolar geometry.
    before = view_swaps(model) if options.graph.swaps else {}
    model = model.relabelled(before)
    start, placed, used, back_swaps = initial_estimate(model, body, options, reference, notes)
    if options.graph.swaps and back_swaps:
        before = {**before, **back_swaps}
        model = model.relabelled(back_swaps)
    for c, name in enumerate(model.names):
        if not placed[c]:
            notes.append(f"camera {name}: never saw the person together with the reference camera {model.names[reference]}; not estimated")
    model = model.only(placed)
    notes += _degeneracy_notes(model, placed)
    imu, imu_skipped = camera_imus(capture) if options.imu else ({}, [])
    notes += imu_skipped
    # the views' per-frame rotations of a moving camera are noisy and sometimes flipped: its
    # gyroscope's track, turned onto them as a whole, starts every solve instead
    start_from_gyroscopes(imu, model, start.cameras, options.graph.imu_noise)
    for note in notes:
        log.info("smartmocap: %s", note)
    n = model.num_states
    bounds = chunk_bounds(n, options.chunk_size)
    log.info("smartmocap: %d body states, %d chunks of <= %d, executor %s (%d workers)", n, len(bounds), options.chunk_size, options.executor, options.workers)
    tasks = [ChunkTask(model.span(a, b), start.span(a, b), options, imu) for a, b in bounds]
    solved = _solve_chunks(tasks, options)
    chunk_seconds = [s for _, s in solved]
    stitched = stitch(body, model, [(a, b, est) for (a, b), (est, _) in zip(bounds, solved)])
    clock_offsets: dict[int, float] = {}
    if imu and options.imu_max_offset_s is not None:
        # each log's clock against its camera's: on a reference's rotations where it registered
        # the camera, else on the stitched body (docs/phone-imu.md)
        from_reference = {} if camera_reference is None else reference_clock_offsets(
            camera_reference, model, imu, options.imu_max_offset_s, options.reference_sigmas[0], options.graph.imu_noise
        )  # fmt: skip
        rest = {c: log for c, log in imu.items() if c not in from_reference}
        shifted, clock_offsets = estimated_clock_offsets(body, model, stitched, rest, options.imu_max_offset_s, options.graph.imu_noise)
        imu = {**shifted, **{c: imu[c].shifted(offset) for c, offset in from_reference.items()}}
        clock_offsets.update(from_reference)
        notes += [f"camera {model.names[c]}: its IMU log's clock offset found on its turns between the frames the reference {camera_reference.name!r} registered"
                  for c in from_reference]  # fmt: skip
    log.info("smartmocap: chunks %.2f s median; stitched; final optimisation", np.median(chunk_seconds))

    learned = LearnedPriors.load(options.graph.pose_prior, options.motion_prior)
    bg, graph, solved_final = final_pass(model, body, options, learned, stitched, {}, options.final_iterations, imu=imu)
    estimate = bg.read(solved_final.values, stitched)
    estimate.log = list(solved_final.log)
    tracks = None
    if camera_reference is not None:
        tracks, reference_notes = reference_tracks(camera_reference, model, estimate, options.reference_sigmas)
        notes += reference_notes
        if tracks.frames:
            estimate = tracks.started(estimate, model)
            bg, graph, solved_final = final_pass(model, body, options, learned, estimate, {}, options.final_iterations, imu=imu, tracks=tracks)
            estimate = bg.read(solved_final.values, estimate)
            estimate.log += list(solved_final.log)
        else:
            tracks = None
    if options.graph.swaps and options.posed_swaps:
        # Every camera placed: each camera-frame's labels checked against all the others'
        # epipolar geometry at that state, the moving cameras' too. Where a single static camera
        # sees the person, its swapped view and the moving cameras' outvote each other there,
        # which the solve's per-camera choice cannot (on phones, 10 s, it relabelled the clean
        # static phone and kept the carried phones' runs: precision and recall 0.51; with this
        # check 0.96); then the sequence solved again on them.
        # From the labels as detected (a swap is its own inverse): two static phones alone could
        # not tell which of them swapped the legs, all four can.
        detected = model.relabelled(before)
        posed = posed_view_swaps(detected, estimate.cameras)
        if any(not np.array_equal(np.maximum(codes, 0), np.maximum(before.get(c, codes * 0), 0)) for c, codes in posed.items()):
            before = {**before, **posed}
            model = detected.relabelled(before)
            # held as checked: the solve's own choice, from a body fitted to the swapped views,
            # put the swaps back (phones, 10 s: the same frames recorded before and after)
            bg, graph, solved_final = final_pass(
                model, body, options, learned, estimate, {}, options.offset_iterations, imu=imu, tracks=tracks, solved_start=True, relabel=False
            )
            estimate = bg.read(solved_final.values, estimate)
            estimate.log += list(solved_final.log)
    # every view the solve was given: the reprojection report counts the ones left out too
    every_view = model
    hold: tuple[int, ...] = ()
    if held_cameras is not None:
        estimate, hold = held_at(model, estimate, held_cameras)
        bg, graph, solved_final = final_pass(
            model, body, options, learned, estimate, {}, options.final_iterations, imu=imu, tracks=tracks, hold=hold, solved_start=True
        )
        estimate = bg.read(solved_final.values, estimate)
        estimate.log += list(solved_final.log)
    offsets: dict[str, np.ndarray] = {}
    if options.keypoint_offsets:
        # the keypoints' definitions seen by the solve, then the solve again with them, without
        # the views it could not explain at all (a detector on someone else for a frame), in
        # rounds that measure them again on the body the last one left
        priors = {fmt: prior_offsets(fmt) for fmt in model.formats} if options.offset_prior == "fitted" else {}
        priors = {fmt: prior for fmt, prior in priors.items() if prior is not None}
        solved_model = model.relabelled(bg.relabelled(estimate))
        fits = [estimate_offsets(body, solved_model, estimate, fmt, priors.get(fmt), options.hold_root_offsets) for fmt in model.formats]
        # a format fitted on real footage starts at its table: the first measure is taken on a
        # body that leaned towards the detector's points, and the rounds keep much of that lean
        # (a wider pelvis explains a lateral hip offset as well as the offset does)
        fits = [replace(fit, offsets=priors[fit.fmt]) if fit.fmt in priors else fit for fit in fits]
        offsets = {fit.fmt: fit.offsets for fit in fits}
        joint = options.offset_estimation == "joint"
        left_out: dict[int, list[np.ndarray]] = {}
        for attempt in range(options.offset_rounds):
            # a view left out lets the body go back to the person, which can show more such views
            outliers = outlier_views(body, solved_model, estimate, offsets)
            if attempt and not outliers and joint:
                break
            for c, frames in outliers.items():
                left_out.setdefault(c, []).append(frames)
            model = model.without(outliers)
            bg, graph, solved_final = final_pass(
                model, body, options, learned, estimate, offsets, options.offset_iterations, estimate_offsets=joint, imu=imu, tracks=tracks, hold=hold
            )
            estimate = bg.read(solved_final.values, estimate)
            estimate.log += list(solved_final.log)
            if joint:
                offsets = bg.offsets(solved_final.values)
            if attempt + 1 < options.offset_rounds:
                solved_model = model.relabelled(bg.relabelled(estimate))
                if not joint:
                    # measured again on a body that no longer leans towards the detector's
                    # points, they come out nearer the truth each round. Each measure is shrunk
                    # towards zero (or the table), not towards the last round's offsets: that
                    # (rich 6 s: MPE 1.50 cm with 4 rounds) let the lab clip's offsets, fitted
                    # with its cameras held, drift along the limbs (ankles 1.4 -> 3.1 cm up,
                    # heels 1.6 -> 3.3, reprojection 9.9 px), where the body's bone lengths trade with them
                    fits = [estimate_offsets(body, solved_model, estimate, fmt, priors.get(fmt), options.hold_root_offsets) for fmt in model.formats]
                    offsets = {fit.fmt: fit.offsets for fit in fits}
        for fit in fits:
            notes.append(f"{fit.fmt} keypoints: definition offsets estimated from {int(fit.frames.max(initial=0))} frames, up to "
                         f"{100 * np.linalg.norm(fit.offsets, axis=1).max(initial=0):.1f} cm" + (f"; {', '.join(fit.dropped)} implausible, not used" if fit.dropped else "")
                         + (f"; prior: the table fitted on {PROVENANCE[fit.fmt]['clip']}" if fit.fmt in priors else "; prior: zero (no fit on real footage)"))  # fmt: skip
        for c, parts in sorted(left_out.items()):
            frames = np.sort(np.concatenate(parts))
            notes.append(f"camera {model.names[c]}: {len(frames)} frames left out of the last pass, explained far worse than the others (frames {frame_ranges(frames)})")
        if joint:
            fits = [replace(fit, offsets=offsets[fit.fmt]) for fit in fits]
            notes += [f"{fit.fmt} keypoints: the offsets of {', '.join(options.graph.offset_parts)} points estimated with the body: "
                      + ", ".join(f"{name} {100 * np.linalg.norm(v):.1f} cm" for name, v in fit.as_table().items() if part_name(name) in options.graph.offset_parts)
                      for fit in fits]  # fmt: skip
    labels = bg.relabelled(estimate)
    if options.static_cameras == "points" and not hold:
        refined = refine_static_cameras(model, estimate, labels, options.static_gm_sigma_px, REFINE_THRESHOLD_PX, REFINE_ITERATIONS)
        if refined is not None:
            cameras = aligned_to(refined.cameras, estimate)
            note = static_refinement_note(model, estimate, refined, cameras)
            trial = replace(estimate, cameras=list(estimate.cameras), log=list(estimate.log))
            for c, T in cameras.items():
                trial.cameras[c] = np.repeat(T[None], len(trial.cameras[c]), axis=0)
            # On the labels the cameras were just adjusted on, held: re-decided from the body as
            # it stood against the cameras before they moved (8-25 cm on the lab clip), the legs'
            # labels of the clip's second person, whose feet stand 20 cm apart, went over to the
            # other leg in every camera at once, and the body crossed its legs to follow them
            # (frames 3-24; the lab's triangulation has them uncrossed). A swap shared by every
            # camera is the body's side, which the epipolar check's anatomy decides, not a solve.
            trial_bg, _, trial_solved = final_pass(
                model.relabelled(labels), body, options, learned, trial, offsets, options.offset_iterations, imu=imu, tracks=tracks,
                hold=tuple(refined.cameras), gm_sigma_px=options.held_gm_sigma_px, relabel=False,
            )
            trial = trial_bg.read(trial_solved.values, trial)
            trial.log += list(trial_solved.log)
            px_before = reprojection_medians(body, every_view.relabelled(labels), estimate, offsets)["all"]
            px_after = reprojection_medians(body, every_view.relabelled(labels), trial, offsets)["all"]
            if px_after <= REFINE_KEEP_FACTOR * px_before:
                notes.append(note)
                bg, solved_final, estimate = trial_bg, trial_solved, trial
            else:
                log.warning("smartmocap: the static cameras' adjustment on free points not kept (body reprojection %.1f px on them, %.1f px before)", px_after, px_before)
                notes.append(f"{note.replace('then held while', 'not kept: held while', 1)}, the body reprojected at {px_after:.1f} px against {px_before:.1f} px before")
    drift: dict[str, np.ndarray] = {}
    if options.drift_sigmas_m is not None and options.keypoint_offsets:
        # measured on the body as solved, which stays as it is: solved again with the drift held,
        # the body moved back towards its priors and the reprojection came out 0.5 px higher
        # (lab clip, the largest person: 7.86 against 7.38 px)
        labelled = model.relabelled(labels)
        # then against the views themselves (each weighed by its own reprojection, a gross miss
        # left aside by the free points' kernel): on the lab clips, with the σs learned on the
        # other clip, 6.74 -> 6.46 px (BlazePose) and 6.17 -> 5.95 px (BODY_25B); docs/smartmocap.md
        drift = {
            fmt: refine_drift_in_images(body, labelled, estimate, fmt, offsets.get(fmt), options.drift_sigmas_m,
                                        estimate_drift(body, labelled, estimate, fmt, offsets.get(fmt), options.drift_sigmas_m))
            for fmt in model.formats if fmt != "body"
        }  # fmt: skip
        for fmt, d in drift.items():
            size = np.linalg.norm(d, axis=-1)[:, np.any(d != 0, axis=(0, 2))]
            if size.size == 0:
                continue  # no view of this format fell on a state (e.g. its camera's clock is off the capture's)
            notes.append(f"{fmt} keypoints: their definitions' drift over the capture estimated per state, median {100 * np.median(size):.1f} cm, 90th percentile {100 * np.percentile(size, 90):.1f} cm")
    swaps = combined_swaps(model, before, labels)
    notes += swap_notes(model.names, swaps) + focal_notes(model, bg.focal_lengths(estimate)) + imu_support_notes(bg, clock_offsets)
    reprojection = reprojection_medians(body, every_view.relabelled(labels), estimate, offsets, drift)
    log.info("smartmocap: reprojection median %.1f px (per camera %s)", reprojection["all"], reprojection["camera"])
    seconds = time.perf_counter() - t_start
    placed_cameras = [c for c in range(model.num_cameras) if placed[c]]
    result = estimate_result(
        "smartmocap", capture, model, body, estimate, "ground_plane", options_parameters(replace(options, checkpoint=None)), capture_label, cameras=placed_cameras, swaps=swaps,
        keypoint_offsets=offsets, drift=drift,
    )
    notes += still_body_notes(result.joints)
    if options.covariances:
        cov_bg, cov_graph, cov_values = definition_graph(bg, options, learned, estimate, solved_final.values, offsets, imu, tracks)
        covariances = cov_bg.covariances(cov_graph, cov_values, estimate, calibrate=True)
        if cov_bg.windows:
            result.flags["motion_prior_misfit"] = cov_bg.motion_misfit
        result.covariances.update(
            with_model_error(covariances, result, capture, options.covariance_model_error, options.covariance_lever_error_rad, options.covariance_misfit_gain)
        )
        result.parameters["variance_factors"] = {g: round(float(s2), 4) for g, s2 in cov_bg.variance_factors.items()}
    result.parameters.update(
        initialiser_used=used, seconds=round(seconds, 3), seconds_per_chunk=round(float(np.median(chunk_seconds)), 3), chunks=len(bounds), notes=notes,
        focal_px=bg.focal_lengths(estimate), reprojection_px=reprojection,
        keypoint_offsets_m={fit.fmt: fit.as_table() for fit in fits} if options.keypoint_offsets else {},
        imu_clock_offsets_s=clock_offset_parameters(model, clock_offsets), joint_motion_m=round(joint_motion_m(result.joints), 4),
    )
    return result


def definition_graph(
    bg: BodyGraph, options: SmartmocapOptions, learned: LearnedPriors, estimate: Estimate, solved: gtsam.Values, offsets: dict, imu: dict,
    tracks: ReferenceTracks | None,
) -> tuple[BodyGraph, gtsam.NonlinearFactorGraph, gtsam.Values]:  # fmt: skip
    """The final pass's graph (of ``bg``, solved at ``estimate``, all of its variables in
    ``solved``) with every detector point's definition offset a variable (``θ ~ N(current,
    offset_sigma_m²)``, left and right mirrored, at the offsets the solve used) and its values:
    the graph the covariances come from.

    A detector's points are not the body's joints, and by how much is known only to within
    ``offset_sigma_m``; held at one value, the offsets' uncertainty is missing from every
    marginal, while it is the largest error the body carries (docs/detector_faults.md: 1.1 →
    2.5 cm MPJPE). Shared by all frames, it does not average out over them as the detector's
    noise does; as variables, the graph knows that. Built as the final pass's, the labels chosen
    at the robust scale the solve ended with; nothing is solved on it."""
    graph_options = replace(bg.options, offsets="estimate", offset_parts=None)
    out = BodyGraph(bg.model, bg.body, graph_options, learned=learned, keypoint_offsets=offsets, imu=imu)
    graph, values = sequence_graph(out, estimate, options.gauge_sigmas)
    if tracks is not None:
        tracks.add_to(graph, bg.model)
    out.scale.sigma_px = bg.scale.sigma_px
    # the solve's values (its priors' latents too), the offsets' parameters the new variables
    merged = gtsam.Values(solved)
    offset_keys = {out.offset_key(fmt) for fmt in out.format_index}
    for key in solved.keys():
        if not values.exists(key) or key in offset_keys:
            merged.erase(key)
    for key in values.keys():
        if not merged.exists(key):
            merged.insert(key, values.atVector(key))
    return out, graph, merged


def lever_covariance(lever: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)``: the covariance of the displacement ``δθ × r`` of a point at ``lever`` (``(...,
    3)``, metres from the pivot) under a small rotation ``δθ ~ N(0, I)`` (radians) about the pivot:
    ``|r|² I − r rᵀ``."""
    return (lever * lever).sum(-1)[..., None, None] * np.eye(3) - lever[..., :, None] * lever[..., None, :]


def pose_lever_covariance(world_T_pose: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """``(N, 6, 6)``: the covariance in GTSAM's tangent of poses ``(N, 4, 4)`` (rotation first, both
    in the pose's own frame) under a small world rotation ``δθ ~ N(0, I)`` about ``pivot (3,)``:
    ``G Gᵀ`` with ``G = [Rᵀ; −Rᵀ [r]×]``, ``r`` the pose's position from the pivot."""
    R, r = world_T_pose[:, :3, :3], world_T_pose[:, :3, 3] - pivot
    G = np.concatenate([np.swapaxes(R, 1, 2), -np.swapaxes(R, 1, 2) @ skew(r)], axis=1)
    return G @ np.swapaxes(G, 1, 2)


def with_model_error(
    covariances: dict[str, np.ndarray], result: Result, capture: Capture, factors: tuple[float, float, float], lever_rad: tuple[float, float, float],
    misfit_gain: float = 0.0,
) -> dict[str, np.ndarray]:  # fmt: skip
    """``covariances`` (:meth:`BodyGraph.covariances`, of ``result``'s joints ``(T, 22, 3, 3)``,
    root and cameras ``(N, 6, 6)``) with the model error added, per kind (joints and root, the
    static cameras, the moving ones; ``SmartmocapOptions.covariance_model_error`` and
    ``covariance_lever_error_rad``): each times its variance factor, plus a rotation by ``σ``
    radians about the joints' centroid (:func:`lever_covariance`, :func:`pose_lever_covariance`);
    the joints' and root's factor of state ``i`` also times ``1 + misfit_gain·μ_i``, ``μ`` the
    result's flag ``motion_prior_misfit`` ``(T,)`` (none: 0)."""
    (k_joints, k_static, k_moving), (s_joints, s_static, s_moving) = factors, lever_rad
    centroid = np.nanmean(result.joints.reshape(-1, 3), axis=0)
    misfit = result.flags.get("motion_prior_misfit", np.zeros(len(result.joints)))
    k_states = k_joints * (1.0 + misfit_gain * np.asarray(misfit, dtype=float))[:, None, None]
    out = dict(covariances)
    out["joints"] = k_states[:, None] * covariances["joints"] + s_joints**2 * lever_covariance(result.joints - centroid)
    out["root"] = k_states * covariances["root"] + s_joints**2 * pose_lever_covariance(result.root, centroid)
    for name, track in result.cameras.items():
        key = f"camera:{name}"
        if key in out:
            k, s = (k_moving, s_moving) if capture.camera(name).moving else (k_static, s_static)
            out[key] = k * covariances[key] + s**2 * pose_lever_covariance(track.world_T_camera, centroid)
    return out


def final_pass(
    model: StateModel, body: BodyModel, options: SmartmocapOptions, learned: LearnedPriors, start: Estimate, offsets: dict, iterations: int,
    estimate_offsets: bool = False, imu: dict | None = None, tracks: ReferenceTracks | None = None, hold: tuple[int, ...] = (),
    solved_start: bool = False, relabel: bool = True, gm_sigma_px: float | None = None,
):  # fmt: skip
    """The whole sequence solved from ``start`` with the formats' keypoint ``offsets`` (held, or
    the start of their estimate with ``estimate_offsets``), the cameras' ``imu`` logs and the
    motion priors of a reference's ``tracks``, the cameras of ``hold`` held: its graph builder,
    graph and solve; robust from the first step when ``start`` is a solve's (``solved_start``, or
    any ``offsets``, ``tracks`` or ``hold``); the labels as the model has them without ``relabel``;
    Geman-McClure at ``gm_sigma_px`` instead of the graph options' where given."""
    graph_options = replace(options.graph, offsets="estimate") if estimate_offsets else options.graph
    if gm_sigma_px is not None:
        graph_options = replace(graph_options, gm_sigma_px=gm_sigma_px)
    bg = BodyGraph(model, body, graph_options, learned=learned, keypoint_offsets=offsets, imu=imu)
    graph, values = sequence_graph(bg, start, options.gauge_sigmas)
    if tracks is not None:
        tracks.add_to(graph, model)
    bg.relabel(relabel)
    stages = bg.stages(iterations, bg.time_ordering(values))
    if offsets or hold or solved_start or tracks is not None:
        stages = stages[1:]  # from a solved start: robust from the first step
    solved = solve_staged(held(graph, values, bg.held_keys() + [k for k, (c, _) in bg.camera_vars().items() if c in hold]), values, stages, progress="smartmocap final", project=bg.project_shape)
    return bg, graph, solved


def held_at(model: StateModel, estimate: Estimate, held_cameras: dict[str, np.ndarray]) -> tuple[Estimate, tuple[int, ...]]:
    """``estimate`` with the static cameras named in ``held_cameras`` at those poses (moved onto
    its world by :func:`aligned_to`) and their indices, the cameras to hold."""
    unknown = sorted(set(held_cameras) - set(model.names))
    moving = [name for name in held_cameras if name in model.names and model.cameras[model.names.index(name)].moving]
    if unknown or moving:
        raise MocapgraphError(f"held cameras: {', '.join(unknown)} not placed in the solve" if unknown else f"held cameras: {', '.join(moving)} moving; only static cameras are held")
    cameras = aligned_to({model.names.index(name): np.asarray(T, dtype=float) for name, T in held_cameras.items()}, estimate)
    estimate = replace(estimate, cameras=list(estimate.cameras))
    for c, T in cameras.items():
        estimate.cameras[c] = np.repeat(T[None], len(estimate.cameras[c]), axis=0)
    return estimate, tuple(sorted(cameras))


def aligned_to(cameras: dict[int, np.ndarray], estimate: Estimate) -> dict[int, np.ndarray]:
    """``cameras`` (index → ``(4, 4)`` world_T_camera, in any frame and scale) moved by the
    similarity that best maps their centres onto the same cameras' in ``estimate``: the solve's
    world and metric scale kept, spread over every camera rather than resting on one or two.
    Fewer than three cameras, or collinear ones, fix no similarity: as given."""
    try:
        similarity = align_camera_centres([T[None, :3, 3] for T in cameras.values()], [estimate.cameras[c][:1, :3, 3] for c in cameras])
    except MocapgraphError:
        return cameras
    return {c: similarity.apply_pose(T[None])[0] for c, T in cameras.items()}


def static_refinement_note(model: StateModel, estimate: Estimate, refined: StaticRefinement, cameras: dict[int, np.ndarray]) -> str:
    """What the static cameras' adjustment on free points did: how far it moved each camera
    (``cameras``, its result in ``estimate``'s world) from where the body's solve had put it."""
    moved = {model.names[c]: 100 * float(np.linalg.norm(T[:3, 3] - estimate.cameras[c][0, :3, 3])) for c, T in cameras.items()}
    return (
        f"static cameras adjusted on {refined.points} free {refined.fmt} points (median {refined.reprojection_px:.1f} px), then held while the body "
        f"was solved to them; moved {', '.join(f'{n} {cm:.1f} cm' for n, cm in moved.items())}"
    )


def summary(result: Result) -> str:
    """What ``run smartmocap`` prints: a line and the notes."""
    p = result.parameters
    lines = [
        f"smartmocap: {len(result.timestamps)} body states, {len(result.cameras)} cameras, {p['chunks']} chunks "
        f"({p['seconds_per_chunk']:.2f} s each) in {p['seconds']:.1f} s; world: ground plane"
    ]
    if "reprojection_px" in p:
        per_camera = ", ".join(f"{name} {px:.1f}" for name, px in p["reprojection_px"]["camera"].items())
        lines.append(f"  reprojection median {p['reprojection_px']['all']:.1f} px (per camera: {per_camera})")
    return "\n".join(lines + [f"  note: {note}" for note in p["notes"]])
