"""``mocapgraph run online``: body and cameras fused as the observations arrive, one smoother
update per body state, with a fixed lag.

:class:`OnlineFusion` is made from a capture's static description (:func:`static_rig`: cameras,
intrinsics, lenses, mounts, static calibrations, detector formats) and takes observations one at
a time with :meth:`OnlineFusion.update` ``(camera, timestamp, keypoints, box, sensors)``,
interleaved between cameras in time order. The graph is the offline one (:mod:`mocapgraph.graphs`):
body states on a regular time grid, every detection explained at its own timestamp by the state
interpolated between its two neighbours, the native reprojection factor with its left/right-swap
max-mixture and per-keypoint Geman-McClure, root and joint-rotation smoothness (on uncalibrated
rigs the joint rotations' constant velocity too: what a state's later neighbours correct it by), the
weak pose regulariser, and camera variables:

- **AirCap rigs** (cameras on vehicles with a mount and sensor logs): a pose per camera frame near
  its prior at that time, through one offset per camera that carries the prior's slow drift (as
  :class:`~mocapgraph.pipelines.aircap.CameraPriors`), and constant-pose smoothness between its
  frames (``cameras="refine"``); or held at the prior (``"prior"``). The prior
  (``camera_priors``): the vehicle's onboard estimate (the ``self_pose`` samples received so far,
  through :func:`~mocapgraph.graphs.navigation.online_track`), or its GPS/IMU fusion run on the
  samples received so far (:class:`~mocapgraph.graphs.navigation.IncrementalNavigation`); a GPS
  outage leaves that fusion coasting on the IMU (flag ``camera_prior_coasting``). A static camera
  with a calibration is held at it. A UAV detection may relabel its whole body (its detector's
  front/back flip) unless most of its update's cameras see one, in a tie (one of two, or alone) only
  on its onboard estimate (``uav_body_swaps``), and the joints the pose GMM leaves out (spine3, collars, feet) are held at
  0.2 rad (``unmodelled_sigma_rad``): else a flip was explained by turning the upper body round on them.
- **Uncalibrated rigs** (SmartMocap): a static camera is one variable kept in the window (under a
  prior at the bootstrap's estimate: the body states leaving the window leave their information on
  it) for ``static_refine_s``, then held at its estimate; a
  moving one a pose per frame tied by smoothness and a constant-velocity model; the world is
  SmartMocap's ground plane. The bootstrap's keypoint-definition offsets are held; its shape
  too, or (``shape="refine"``) the shape is a variable kept in the window as the static cameras
  are, under a prior that holds the directions the joints barely see. The joints the pose GMM
  leaves out are held at 0.2 rad here too (spine3 had taken the pelvis' pitch), and spine3 at 0.05 rad
  (the CMU takes the priors learned from never move it; free, it bent forward while the pelvis leant back).

**Bootstrap.** The first ``bootstrap_s`` seconds are buffered and solved in batch by the pipeline
the rig mirrors (:func:`~mocapgraph.pipelines.aircap.run_aircap` in sequence mode with the
cameras held at their onboard estimate, checked by a second batch with them refined near it and
their whole-body relabelling, as offline: ``bootstrap_cameras``; or
:func:`~mocapgraph.pipelines.smartmocap.run_smartmocap`). Its body shape is then held, its states
and cameras start the smoother, and the buffered observations are replayed into it. Those states
are flagged ``bootstrap`` in the results: their starting values saw the whole bootstrap window.

**The loop.** Observations are gathered per grid interval ``(t_i, t_{i+1}]``; the first one of a
later interval closes it: one smoother update creates the states up to ``t_{i+1}`` (each starting
from the tracker's constant-velocity prediction, held after ``coast_s`` without observations) and
adds the interval's factors; iSAM2 relinearises every 30 updates on uncalibrated rigs (what a state
leaves on the static cameras was otherwise linearised at its prediction) and never on AirCap ones
(:class:`OnlineOptions`); a second bootstrap may solve the stream so far in batch once (``resolve_s``). A
detection is first gated: its keypoints outside the region of interest the predicted body projects
to (its box widened by ``gate_margin`` of its height) lose their weight, and a detection left with
fewer than ``gate_min_keypoints`` is dropped and counted. After ``coast_s`` without detections the
track is lost: the gate stays open and the next state starts where its views triangulate the body;
so it does after ``gate_reacquire`` detections gated out in a row (the prediction, not the
detections, went wrong), or as many of one camera's while the others' pass (the prediction slid
along the direction only that camera sees across).
A moving uncalibrated camera whose frames all left the window is resected on the body when it
returns. An observation later than the open interval but whose states are still in the window is used; an
older one is counted and dropped (as is a frame more than the lag older than its camera's newest).

**Faults.** A static camera of an uncalibrated rig that the bootstrap did not see joins when its
first ``join_frames`` frames, resected together on the body, place it. A UAV camera's frame without
its onboard estimate near its time (an outage) is not used (``no_prior``). A smoother update that
throws (GTSAM's indeterminant-system error, ...) restarts the window from the tracker's prediction
(``solver_resets``). The results' per-state flags say which states saw such faults:
``no_camera_prior``, ``solver_reset`` (with ``unconstrained``: no detection at all).

**Outputs.** The *filtered* trajectory holds each state as first estimated: state ``i + 1`` right
after the update that closed interval ``i`` (it used no observation later than ``t_{i+1}``); a state
created inside a gap keeps its prediction; the bootstrap's states are as the replay's update left
them. The *smoothed* one holds each state at its last
estimate before it left the window (the smoother's lag); a refined static camera's frames all hold
its last estimate (from when it is held, or the stream's end). Both hold every camera (a held one at
the pose its frames were explained with). ``docs/online.md`` has the numbers.
"""

from __future__ import annotations

import bisect
import logging
import math
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Callable, Iterator

import gtsam
import numpy as np

from mocapgraph.body import load_body_model
from mocapgraph.body.definition_priors import prior_offsets
from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import SWAP_KINDS
from mocapgraph.body.rotations import relative_angle
from mocapgraph.body.skeleton import JOINT_NAMES, NUM_JOINTS
from mocapgraph.data_tools.evaluation.alignment import umeyama
from mocapgraph.data_tools.geometry.camera_model import project_points
from mocapgraph.data_tools.geometry.triangulation import triangulate_points
from mocapgraph.data_tools.io.capture import Camera, Capture, Detector
from mocapgraph.data_tools.io.result import CameraTrack, Result, options_parameters
from mocapgraph.errors import MocapgraphError, is_positive_number
from mocapgraph.factors.body_priors import pose_regularizer_factor
from mocapgraph.factors.camera_priors import camera_offset_prior_factor, camera_prior_factor
from mocapgraph.factors.keys import CAMERA_STRIDE, camera_key, camera_offset_key, pose_key, root_key, shape_key
from mocapgraph.factors.reprojection import Labelling, ShapeTableCache, reprojection_factor
from mocapgraph.factors.robust import RobustScale
from mocapgraph.factors.smoothness import camera_acceleration_factor, camera_smoothness_factor, pose_smoothness_factor, pose_velocity_factor, root_smoothness_factor, rotation_acceleration_factor
from mocapgraph.graphs.body_graph import GraphOptions, LearnedPriors, regularizer_sigmas, swap_hypotheses
from mocapgraph.graphs.fixed_lag import FixedLagSmoother, Relinearisation, UpdateReport
from mocapgraph.graphs.initialisation import resect
from mocapgraph.graphs.keypoint_fit import estimate_offsets, offsets_from_table
from mocapgraph.graphs.navigation import IncrementalNavigation, IncrementalOptions, OnlineNoise, online_track
from mocapgraph.graphs.state_model import Estimate, undistorted_keypoints
from mocapgraph.pipelines.observations import capture_state_model
from mocapgraph.priors.gmm_factor import pose_gmm_factor

log = logging.getLogger(__name__)

RIGS = ("aircap", "smartmocap")
CAMERA_MODES = ("refine", "prior")
PRIOR_SOURCES = ("auto", "fused", "self_pose")
UAV_BODY_SWAPS = ("minority", "none")
BOOTSTRAP_CAMERAS = ("check", "prior")
_HAND_OFF_S = 0.2  # the bootstrap's last states, where its two batches' headings are compared (bootstrap_cameras)
BOOTSTRAP_MOTION_PRIORS = ("vae", "none")
# The shape the loop publishes (its state, the gate's and the results' joints) follows the refined
# estimate once it moved this far (shape units; ~0.5 mm of height): each new shape costs a body
# table (~10 ms), so a shape creeping at every update is not followed update by update
_SHAPE_STEP = 1e-3
_SHAPE_WEAK, _SHAPE_HELD = 0.1, 1e-3  # OnlineFusion._shape_prior
RIG_RELINEARISATION = Relinearisation(0.01, 30)  # OnlineOptions.relinearisation "rig", uncalibrated rigs
_SNAP = 1e-6  # a grid fraction this close to 0 or 1 is the grid state itself (as graphs.sync)


@dataclass
class OnlineOptions:
    """Parameters of the online loop (units in the names).

    ``rig``: ``"aircap"`` or ``"smartmocap"``; None: aircap when a camera has a mount, else
    smartmocap. ``graph``: the terms' weights (only the per-state ones and the swaps are used).
    """

    rig: str | None = None
    lag_s: float = 1.0
    rate_hz: float = 30.0
    bootstrap_s: float = 1.0
    # An AirCap bootstrap's batch: "prior", the UAV cameras held at their priors (no whole-body
    # relabelling), as the loop holds them; "check", that batch and a second one with the cameras
    # refined near their priors and their whole-body relabelling (the offline pipeline's handling of
    # its detectors' flips): where their headings over the last 0.2 s are more than 90 deg apart, the
    # held batch was turned round by a flip in most views (aircap 10 s seed 0: 120-150 deg off at
    # 0.7-1.2 s, unwound by 1.6 s) and the loop starts from the refined one. Not the refined batch
    # always: its cameras move 0.3-0.65 m to explain flips (held: 0.25-0.3 m from the truth), its
    # states are then off the held cameras, and the loop lost the body in a later flip (aircap 3 s
    # seed 0: smoothed RA-MPJPE 0.0846 against 0.0685 m). aircap 10 s, smoothed RA-MPJPE seeds 0-2:
    # 0.0781 / 0.0682 / 0.0755 -> 0.0722 / 0.0682 / 0.0755 m (1.23x -> 1.14x offline on seed 0, the
    # only one whose batches disagree), for a second batch solve in the bootstrap (docs/online.md).
    bootstrap_cameras: str = "check"
    # "refine" measured worse than "prior" on aircap (docs/online.md): per-frame camera variables
    # near the onboard estimate drifted with the body's whole-body relabellings
    cameras: str = "prior"
    detector: str | None = None  # default: each camera's first detector
    # An uncalibrated rig's static cameras after the bootstrap: variables all along ("refine"),
    # each under a prior at the bootstrap's estimate (``static_camera_sigmas``, radians and metres),
    # so that every body state that leaves the window leaves its information on them; or held at
    # the bootstrap's estimate ("hold"). Without the prior "refine" diverged: the only gauge was the
    # first root's prior, weak in tilt and height (offline's ground term is not in the loop), and the
    # first update moved the cameras 0.3-1.3 m (rich 10 s: smoothed MPJPE 0.48 m). With it, rich
    # 10 s (smoothed, static cameras' MCPE / MPJPE): hold 18.2 / 23.0 mm, refine 12.7 / 21.8 mm
    # (seed 1: 25.1 / 25.3 and 12.6 / 24.4 mm), for ~1.3 ms more CPU per update (docs/online.md).
    static_cameras: str = "refine"
    static_camera_sigmas: tuple[float, float] = (0.01, 0.03)
    # Refined for this long (seconds from its first update), then held at its estimate and its
    # variable let leave the window (None: refined all along). The cameras settle within ~10 s (rich,
    # centres 22 -> 3 mm at 12 s); after that, refining costs ~1.3 ms an update and lets a long-lived,
    # ever more confident linearised marginal follow the body's faults (10 min of rich refined all
    # along: 78 detections gated out at 4-5 min and the cameras moved up to 24 mm there; 5.5 min: MPJPE
    # 20.2-21.3 mm per 30 s against 20.0-20.8 held from 30 s, CPU p50 8.1 against 6.7 ms).
    static_refine_s: float | None = 30.0
    # The body's shape after the bootstrap: held at the bootstrap's estimate ("hold"), or one
    # variable kept in the window as the static cameras are ("refine"; every state leaving the
    # window leaves its information on it), under a prior at the bootstrap's estimate that holds
    # the directions the joints barely see (OnlineFusion._shape_prior), for ``shape_refine_s``
    # seconds (None: all along), then held at its estimate. Not the default: on rich 10 s (seeds
    # 0-2) it moved the shape by under 0.01 and the smoothed MPJPE / MCPE by +0.3-1.9 / +0.3-2.9 mm
    # (docs/online.md, "The shape in the window").
    shape: str = "hold"
    shape_refine_s: float | None = 30.0
    # iSAM2's relinearisation; "rig": none on AirCap rigs (it changed no error measured there and
    # was the p95), on uncalibrated rigs every variable whose delta passed 0.01 every 30 updates
    # (RIG_RELINEARISATION). Without it every reprojection factor stays linearised at its state's
    # start (the tracker's prediction), and what a state leaves on the static cameras when it is
    # marginalised is that linearisation: rich 10 s seed 1, the static cameras' smoothed MCPE 12.5
    # -> 8.9 mm (offline 8.9), all cameras 17.1 -> 13.7 mm (1.26x -> 1.01x offline), for a
    # relinearisation step (~80 ms CPU, all but the newest states) once a second; relinearising the
    # cameras alone changed nothing (12.6 mm), as did a second batch solve (resolve_s)
    # (docs/online.md, "Static cameras and the states' linearisation").
    relinearisation: Relinearisation | str = "rig"
    # Constant-velocity priors over three consecutive states (None: off), beside the velocity
    # ones of ``graph``: a state's next neighbours then correct it while it is in the window, the
    # smoothed trajectory's gain over the filtered one. Without them each state of a synchronised
    # rig stayed about where its own frame put it (rich 6 s: smoothed MPJPE 20.8 against filtered
    # 21.0 mm after the bootstrap, acceleration error 15 against 16 m/s^2; with the joint
    # rotations' at 20 rad/s^2: 20.0 against 20.4 mm, 8.7 against 12.5 m/s^2; docs/online.md).
    # The root's (5 m/s^2) added little on rich (19.9 mm, 7.3 m/s^2) and cost aircap's
    # articulation (6 s, smoothed RA-MPJPE 0.100 -> 0.146 m), so it is off. "rig": the joint
    # rotations' on uncalibrated rigs only; on aircap (10 s) it took smoothed MPJPE 0.56 -> 0.38 m
    # on seed 1 but 0.45 -> 0.52 on seed 0 (a body turned round for a second at 6-7 s either way)
    # and 1.1x -> 1.3x the error without a UAV's onboard estimate for 2 s (40 rad/s^2 there: the
    # body lost), so not on aircap for now.
    root_sigma_m_s2: float | None = None
    pose_sigma_rad_s2: float | None | str = "rig"
    # The root rotation's constant angular velocity (rad/s^2, None: off): rich 10 s seed 0, smoothed
    # RA-MPJPE 51.4 -> 50.7 / 50.2 mm at 10 / 3 rad/s^2; the pitch drift it was meant for is not a
    # jitter a smoothness prior removes (docs/online.md)
    root_sigma_rad_s2: float | None = None
    # The hip joints' rotations in that constant-velocity prior (rad/s^2; None: as the others).
    # The pelvis' pitch is what only the pose priors split from the hips' and spine's rotations (the
    # hip keypoints lie on its left-right axis); at 20 rad/s^2 a step there stays: rich 10 s seed
    # 0, one camera's whole-body-swap frames at 4.7 s tilted the root by 5 deg for the rest of the
    # stream (smoothed RA-MPJPE 51.4 mm; 38.4 at 80 rad/s^2, MPJPE 21.8 -> 23.1 mm; seeds 1, 2
    # within 0.2 mm either way; docs/online.md, "The root's pitch and the shape in the window")
    hips_sigma_rad_s2: float | None = 80.0
    # The pose regulariser's width on the joints the pose GMM does not model (spine3, collars,
    # feet; graph.unmodelled_sigma_rad), in the loop and in an AirCap bootstrap's batch solve
    # ("rig": 0.2 rad on AirCap rigs, off, 0.8 rad as every joint, on uncalibrated ones). With only
    # 0.8 rad there, a UAV's whole-body detector flip (not relabelled on UAVs, above) was explained
    # by turning the upper body round on spine3 (up to 2.4 rad) and then the collars (3.4 rad), kept
    # for a second by the arms' relabellings it drew (aircap 10 s, smoothed RA-MPJPE seed 0 0.097 ->
    # 0.080 m, seed 1 0.080 -> 0.066 m; 0.1 rad: 0.088 m on seed 0); and on rich spine3 took the
    # pelvis' pitch (the direction the hip keypoints do not see: -4.6 deg from the bootstrap on):
    # at 0.2 rad, seeds 0-2 smoothed MPJPE 23.1 / 24.6 / 22.8 -> 21.0 / 22.8 / 20.9 mm, RA-MPJPE
    # 38.4 / 40.2 / 40.5 -> 30.6 / 32.7 / 30.0 mm (0.1 rad: MPJPE 19.7 / 21.6 / 19.1 but RA-MPJPE
    # 36.9 / 39.3 / 33.5 mm and seed 1's cameras 17.9 -> 21.7 mm; docs/online.md).
    unmodelled_sigma_rad: float | None | str = 0.2
    # spine3's regulariser width instead (radians; None: as the other joints the pose GMM leaves out;
    # "rig": 0.05 rad on uncalibrated rigs, None on AirCap ones). The CMU takes the learned priors
    # were trained on never move spine3 (their retargeting holds it at zero, so the pose GMM leaves
    # it out), and at 0.2 rad it took the bend that the pelvis' pitch then compensated: rich 10 s
    # seed 2, spine3 bent 22-27 deg forward and the pelvis leaning 5-10 deg back from 1 s on (the
    # direction the hip keypoints barely see), as the offline fit without its motion prior does
    # (spine3 24 deg, pelvis 5-7 deg back); smoothed RA-MPJPE 44.0 -> 31.1 mm, MPJPE 19.4 -> 18.0 mm
    # (offline 26.9, 15.2 mm); seeds 0 and 1 within 1.13x offline on every measure (RA-MPJPE 0.77 /
    # 0.79x -> 1.06 / 0.98x: their pelvis now leans forward as offline's does). On aircap (10 s,
    # seed 0) 0.05 rad took smoothed MPJPE 0.393 -> 0.412 m, so not there (docs/online.md, "The
    # root's pitch on seed 2: spine3")
    spine3_sigma_rad: float | None | str = "rig"
    # A UAV camera's whole-body relabelling (its detector's front/back flip): "minority", taken
    # unless more of an update's cameras take it than keep their body as detected; in a tie (one
    # camera of two, or alone in its update) only on the onboard estimate (decided at the new
    # states' prediction: when most views see the body flipped, the prediction is turned round,
    # not their detectors; a lone view refused it dragged the body 3.3 m round through a GPS
    # outage, one of two refused it lost the body after the outage); "none": never (as
    # graph.moving_body_swaps=False). Always allowed, a body once turned round stayed so (aircap
    # 10 s: 216 of 267 relabellings not in the truth); never allowed, a flip in one view of three
    # was explained by twisting the body (docs/online.md).
    uav_body_swaps: str = "minority"
    gate_margin: float = 1.0
    gate_min_keypoints: int = 4
    gate_reacquire: int = 10
    coast_s: float = 0.5
    # A UAV camera's frame with no sample of its onboard estimate within this of its time (a GPS
    # or telemetry outage) is not used (counted no_prior; its states flagged no_camera_prior)
    prior_timeout_s: float = 0.1
    # frames of a camera that joins an uncalibrated rig after the bootstrap, resected together on
    # the body's estimate before it is placed (a static one is then held there)
    join_frames: int = 8
    camera_prior_white_fraction: float = 0.6
    camera_prior_kernel: str = "huber"
    online_noise: OnlineNoise = field(default_factory=OnlineNoise)
    # A UAV camera's prior: "fused", the vehicle's GPS/IMU fusion run incrementally
    # (graphs.navigation.IncrementalNavigation) when it logs imu and gps, its onboard estimate
    # (self_pose) before that fusion's first solve or where it gives no pose; "self_pose": the
    # onboard estimate only; "auto": the onboard estimate where the vehicle logs one, else the
    # fusion. The stats count the frames resting on each (camera_priors). Not "fused" by
    # default: held there, the cameras are the fusion's 1.0-1.5 m off against the onboard
    # estimate's 0.25 m (aircap 10 s: smoothed MPJPE 1.76 against 0.45 m, RA-MPJPE 0.18 against
    # 0.11 m; docs/online.md).
    camera_priors: str = "auto"
    navigation: IncrementalOptions = field(default_factory=IncrementalOptions)
    # The motion prior in the bootstrap's batch solve (its windows, as offline): the held shape and
    # the first states' root orientation come out better (rich 10 s: RA-MPJPE 61 -> 41 mm, MPJPE
    # 32 -> 27 mm) for 0.6 s more of bootstrap; on aircap (its 25-state windows need rate_hz 30)
    # too: smoothed RA-MPJPE 0.112 -> 0.097 m, MPJPE 0.455 -> 0.411 m (10 s, seed 0)
    bootstrap_motion_prior: str = "vae"
    # The detector formats' keypoint-definition offsets estimated by the bootstrap's batch solve
    # (uncalibrated rigs, as offline) and held: a systematic error no window can average out
    bootstrap_keypoint_offsets: bool = True
    # Measured once: a second round, which measures them again (the offline default), overfits
    # a 1 s bootstrap (rich 10 s, smoothed RA-MPJPE 33 -> 41 mm, with the static cameras as the
    # body's solve leaves them). The static cameras adjusted on free points (the offline default)
    # bring the cameras from 28.7 to 23.7 mm (static 22.6 -> 18.2 mm) and RA-MPJPE 33 -> 38 mm.
    bootstrap_offset_rounds: int = 1
    # Times (seconds from the stream's start) at which an uncalibrated rig's keypoint-definition
    # offsets are measured again (graphs.keypoint_fit.estimate_offsets, as offline's later rounds)
    # on the states and camera frames that have left the window by then; the factors added after
    # that use them. The bootstrap's, measured once on 1 s, are shrunk (30 frames of prior against
    # 30 of data) and taken on a body that leaned towards the detector's points: the offline fit's
    # offsets in their place took rich's smoothed MPJPE 23.1 -> 19.9 mm (seed 0). Measured again
    # at 3 s they come nearer the simulator's and MPJPE improves by 0.7-1.6 mm (seeds 0-2), but
    # the root's pitch then drifts (RA-MPJPE 38-41 -> 49-52 mm), so empty (the bootstrap's kept)
    # by default (docs/online.md, "Where rich's MPJPE and MCPE excess lived").
    offset_updates_s: tuple[float, ...] = ()
    # A second bootstrap of an uncalibrated rig (seconds from the stream's start; None: off): the
    # rig's batch pipeline solved again on every frame so far, once, and the loop carried over to
    # its shape, keypoint-definition offsets and static cameras (moved rigidly onto the loop's
    # world), the window restarted from it with its observations replayed (OnlineFusion._resolve).
    # The 1 s bootstrap's shape and offsets are measured on 30 frames (shrunk towards the prior)
    # and held for the rest of the stream; its cameras are where the window starts refining.
    resolve_s: float | None = None
    resolve_offset_rounds: int = 2
    # The pose GMM and joint-rotation smoothness of 3 rad/s (offline: 6) keep iSAM2's undamped
    # Gauss-Newton out of the directions keypoints barely see (collars, shoulder twist): without
    # either, a shoulder's axis-angle ran past pi and the window diverged (rich 10 s: smoothed
    # MPJPE 137 -> 31 mm, filtered 233 -> 32 mm). No whole-body relabelling of moving cameras:
    # decided once, at a new state's prediction, it turned the body round (aircap 10 s: 216 of
    # 267 relabellings not in the truth, RA-MPJPE 0.19 -> 0.11 m without; docs/online.md), nor
    # in the AirCap bootstrap's batch solve, where the UAV cameras are held (held_body_swaps).
    graph: GraphOptions = field(
        default_factory=lambda: GraphOptions(pose_prior="gmm", pose_sigma_rad_s=3.0, joint_sigma_m_s=None, moving_body_swaps=False, held_body_swaps=False, camera_sigma_m_s2=4.0)
    )

    def check(self) -> None:
        self.graph.check()
        if self.relinearisation != "rig":
            if not isinstance(self.relinearisation, Relinearisation):
                raise MocapgraphError(f"relinearisation: a Relinearisation or 'rig', got {self.relinearisation!r}")
            self.relinearisation.check()
        if self.graph.pose_prior == "vae":
            raise MocapgraphError("graph.pose_prior 'vae': not available online (its latents span the whole sequence); choose gmm or none")
        if self.rig is not None and self.rig not in RIGS:
            raise MocapgraphError(f"rig {self.rig!r}: choose one of {', '.join(RIGS)}")
        if self.shape not in ("hold", "refine"):
            raise MocapgraphError(f"shape {self.shape!r}: choose hold or refine")
        if self.static_cameras not in ("hold", "refine"):
            raise MocapgraphError(f"static_cameras {self.static_cameras!r}: choose hold or refine")
        sigmas = self.static_camera_sigmas
        if not (isinstance(sigmas, (tuple, list)) and len(sigmas) == 2 and all(map(is_positive_number, sigmas))):
            raise MocapgraphError(f"static_camera_sigmas: (radians, metres), two finite numbers > 0, got {sigmas!r}")
        if self.cameras not in CAMERA_MODES:
            raise MocapgraphError(f"cameras {self.cameras!r}: choose one of {', '.join(CAMERA_MODES)}")
        if self.bootstrap_cameras not in BOOTSTRAP_CAMERAS:
            raise MocapgraphError(f"bootstrap_cameras {self.bootstrap_cameras!r}: choose one of {', '.join(BOOTSTRAP_CAMERAS)}")
        if self.uav_body_swaps not in UAV_BODY_SWAPS:
            raise MocapgraphError(f"uav_body_swaps {self.uav_body_swaps!r}: choose one of {', '.join(UAV_BODY_SWAPS)}")
        if self.bootstrap_motion_prior not in BOOTSTRAP_MOTION_PRIORS:
            raise MocapgraphError(f"bootstrap_motion_prior {self.bootstrap_motion_prior!r}: choose one of {', '.join(BOOTSTRAP_MOTION_PRIORS)}")
        if self.camera_priors not in PRIOR_SOURCES:
            raise MocapgraphError(f"camera_priors {self.camera_priors!r}: choose one of {', '.join(PRIOR_SOURCES)}")
        self.navigation.check()
        times = self.offset_updates_s
        if not (isinstance(times, (tuple, list)) and all(map(is_positive_number, times))):
            raise MocapgraphError(f"offset_updates_s: seconds from the stream's start, finite numbers > 0, got {times!r}")
        for name in ("static_refine_s", "shape_refine_s", "resolve_s"):
            value = getattr(self, name)
            if value is not None and not is_positive_number(value):
                raise MocapgraphError(f"{name}: a finite number of seconds > 0 or None, got {value!r}")
        for name in ("lag_s", "rate_hz", "bootstrap_s", "gate_margin", "coast_s", "prior_timeout_s"):
            value = getattr(self, name)
            if not is_positive_number(value):
                raise MocapgraphError(f"{name}: a finite number > 0, got {value!r}")
        if self.lag_s * self.rate_hz < 2:
            raise MocapgraphError(f"lag_s: the window must hold at least 2 states at {self.rate_hz} Hz, got {self.lag_s} s")
        for name in ("root_sigma_m_s2", "pose_sigma_rad_s2", "root_sigma_rad_s2", "hips_sigma_rad_s2", "unmodelled_sigma_rad", "spine3_sigma_rad"):
            value = getattr(self, name)
            if value is not None and not (value == "rig" and name in ("pose_sigma_rad_s2", "unmodelled_sigma_rad", "spine3_sigma_rad")) and not is_positive_number(value):
                raise MocapgraphError(f"{name}: a finite number > 0 or None (pose_sigma_rad_s2, unmodelled_sigma_rad, spine3_sigma_rad: or 'rig'), got {value!r}")
        for name in ("gate_min_keypoints", "gate_reacquire", "join_frames", "bootstrap_offset_rounds", "resolve_offset_rounds"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise MocapgraphError(f"{name}: a whole number >= 1, got {getattr(self, name)!r}")
        if not 0.0 < self.camera_prior_white_fraction < 1.0:
            raise MocapgraphError(f"camera_prior_white_fraction: must lie in (0, 1), got {self.camera_prior_white_fraction}")


@dataclass
class OnlineStats:
    """Counters of a stream and the latency of every smoother update (seconds)."""

    observations: int = 0
    used: int = 0
    late_used: int = 0
    late_dropped: int = 0
    gated: int = 0
    gated_keypoints: int = 0
    # states re-placed where their views triangulate the body after one camera's detections were
    # gated out gate_reacquire times in a row while the others' passed (OnlineFusion._add_observation)
    camera_reacquired: int = 0
    empty: int = 0
    unplaced: int = 0
    no_prior: int = 0  # UAV camera frames without an onboard estimate near their time, not used
    coasting: int = 0  # UAV camera frames whose fused prior rested on the IMU alone (no GPS fix within navigation.gps_timeout_s)
    # AirCap rigs, camera → {source: frames}, the sources its frames' poses rested on (only those that
    # occurred): "self_pose" (the onboard estimate), "fused" (its vehicle's GPS/IMU fusion),
    # "calibration" (a static camera held at it), "bootstrap" (no prior: the bootstrap's estimate),
    # "body" (no prior: its previous frame or a resection on the body), "none" (no prior, not used:
    # an outage, counted no_prior, or a camera the loop could not place)
    camera_priors: dict[str, dict[str, int]] = field(default_factory=dict)
    solver_resets: int = 0  # smoother updates that threw; the window restarted from the tracker's prediction
    relabelled: int = 0
    body_swaps_refused: int = 0  # UAV detections' whole-body relabellings refused: as many cameras of their update took one as not (uav_body_swaps)
    bootstrap_seconds: float = 0.0  # the bootstrap's batch solves, wall clock
    bootstrap_refined: bool = False  # an AirCap bootstrap started the loop from its batch with the cameras refined (bootstrap_cameras)
    bootstrap_observations: int = 0
    busy_seconds: float = 0.0  # inside update() after the bootstrap, wall clock
    busy_cpu_seconds: float = 0.0  # the same calls' CPU time (this thread): what the loop costs, other jobs on the machine aside
    latencies: list[float] = field(default_factory=list)  # of the update() calls that ran a smoother update
    cpu_latencies: list[float] = field(default_factory=list)  # the same calls' CPU time (this thread): other jobs on the machine aside
    solve_seconds: list[float] = field(default_factory=list)  # of the smoother updates alone
    relinearised: list[int] = field(default_factory=list)
    batches: int = 0  # smoother updates in which iSAM2 fell back to a batch step (every factor relinearised)
    offset_update_seconds: list[float] = field(default_factory=list)  # each measure of the keypoint offsets (offset_updates_s), inside its update's latency
    resolve_seconds: float = 0.0  # the second bootstrap's batch solve and replay (resolve_s), wall clock; outside the latencies, as the bootstrap's
    resolve_cpu_seconds: float = 0.0  # the same, CPU time of the loop's thread

    @property
    def dropped(self) -> int:
        """Observations not used: too late, gated out, or from a camera the loop could not place."""
        return self.late_dropped + self.gated + self.unplaced

    def summary(self) -> dict:
        lat = np.asarray(self.latencies) * 1e3
        cpu = np.asarray(self.cpu_latencies) * 1e3
        return {
            "observations": self.observations, "used": self.used, "late_used": self.late_used, "late_dropped": self.late_dropped,
            "gated": self.gated, "gated_keypoints": self.gated_keypoints, "camera_reacquired": self.camera_reacquired, "empty": self.empty, "unplaced": self.unplaced,
            "no_prior": self.no_prior, "coasting": self.coasting, "camera_priors": self.camera_priors, "solver_resets": self.solver_resets, "relabelled": self.relabelled, "body_swaps_refused": self.body_swaps_refused, "updates": len(lat), "bootstrap_s": round(self.bootstrap_seconds, 3), "bootstrap_refined": self.bootstrap_refined,
            "resolve_s": round(self.resolve_seconds, 3), "resolve_cpu_s": round(self.resolve_cpu_seconds, 3),
            "latency_ms": {q: round(float(np.percentile(lat, p)), 2) if len(lat) else None for q, p in (("p50", 50), ("p95", 95), ("max", 100))},
            "latency_cpu_ms": {q: round(float(np.percentile(cpu, p)), 2) if len(cpu) else None for q, p in (("p50", 50), ("p95", 95), ("max", 100))},
            "offset_updates_ms": [round(1e3 * x, 1) for x in self.offset_update_seconds],
            "solve_ms_p95": round(float(np.percentile(self.solve_seconds, 95)) * 1e3, 2) if self.solve_seconds else None, "batch_steps": self.batches,
            "updates_per_s": round(len(lat) / self.busy_seconds, 1) if len(lat) else None,
            "updates_per_cpu_s": round(len(lat) / self.busy_cpu_seconds, 1) if len(lat) and self.busy_cpu_seconds else None,
            "observations_per_s": round((self.observations - self.bootstrap_observations) / self.busy_seconds, 1) if self.busy_seconds else None,
        }  # fmt: skip


@dataclass
class OnlineState:
    """The newest body state after an update.

    Attributes:
        index, time: the state's index on the grid and its time, seconds (None during the bootstrap).
        root: ``(4, 4)`` world_T_root; pose: ``(21, 3)`` axis-angle; shape: ``(S,)``.
        cameras: by camera name, its newest ``(4, 4)`` world_T_camera (NaN while a UAV camera has
            no onboard estimate: its frames are then not used).
        updated: whether this call ran a smoother update.
    """

    index: int | None
    time: float | None
    root: np.ndarray | None = None
    pose: np.ndarray | None = None
    shape: np.ndarray | None = None
    cameras: dict[str, np.ndarray] = field(default_factory=dict)
    updated: bool = False


def static_rig(capture: Capture) -> Capture:
    """The capture's static description, what :class:`OnlineFusion` is made from: every camera's
    name, intrinsics, lens, image size, frame rate, whether it moves, its mount, a static
    camera's calibration, and its detectors' names and formats; no frames, detections or logs."""
    cameras = []
    for cam in capture.cameras:
        detectors = {n: Detector(n, d.format, np.zeros((0,) + d.keypoints.shape[1:])) for n, d in cam.detectors.items()}
        extrinsics = None if cam.moving or cam.extrinsics is None else np.asarray(cam.extrinsics).reshape(-1, 4, 4)[:1]
        # a phone's mount places its IMU, which the online loop does not use; a vehicle's makes the rig AirCap's
        mount = None if set(cam.sensors) == {"imu"} else cam.mount
        cameras.append(Camera(cam.name, cam.K, cam.distortion, cam.image_size, cam.moving, np.zeros(0), cam.frame_rate, detectors, extrinsics, mount))
    return Capture(capture.name, cameras, capture.world_frame, metadata=dict(capture.metadata))


@dataclass
class StreamFrame:
    """One camera frame as a stream delivers it (the arguments of :meth:`OnlineFusion.update`)."""

    camera: str
    timestamp: float
    keypoints: np.ndarray
    box: np.ndarray | None
    sensors: dict[str, dict[str, np.ndarray]]
    detector: str


def stream(capture: Capture, detector: str | None = None) -> Iterator[StreamFrame]:
    """Every camera frame of ``capture`` in time order (ties in camera order), each with the sensor
    samples its camera's vehicle logged since the camera's previous frame; ``detector`` (default
    each camera's first) gives the keypoints and box."""
    events = []
    for c, cam in enumerate(capture.cameras):
        name = detector or next(iter(cam.detectors), None)
        if name is None or name not in cam.detectors:
            continue
        events += [(float(t), c, j, name) for j, t in enumerate(cam.timestamps)]
    events.sort(key=lambda e: (e[0], e[1]))
    sent = {c: {kind: 0 for kind in cam.sensors} for c, cam in enumerate(capture.cameras)}
    for t, c, j, name in events:
        cam = capture.cameras[c]
        det = cam.detectors[name]
        samples = {}
        for kind, logged in cam.sensors.items():
            stop = int(np.searchsorted(logged["t"], t, side="right"))
            if stop > sent[c][kind]:
                samples[kind] = {f: np.asarray(v)[sent[c][kind] : stop] for f, v in logged.items()}
                sent[c][kind] = stop
        box = None if det.boxes is None or not np.isfinite(det.boxes[j, :4]).all() else det.boxes[j]
        yield StreamFrame(cam.name, t, det.keypoints[j], box, samples, name)


@dataclass
class _Frame:
    """A camera frame of the stream in the window: its key (None: fixed), pose and labelling."""

    key: int | None
    pose: np.ndarray
    time: float
    labellings: list[Labelling] = field(default_factory=list)
    no_prior: bool = False  # a UAV camera's frame without its onboard estimate
    coasting: bool = False  # a UAV camera's frame whose fused prior rested on the IMU alone
    fused: bool = False  # a UAV camera's frame whose prior is its vehicle's GPS/IMU fusion (not its onboard estimate)
    tied: bool = False  # a variable tied by smoothness to the camera's previous frame in the window


class OnlineFusion:
    """The online loop on one rig (see the module docstring).

    Args:
        rig: the capture's static description (:func:`static_rig`; a full capture works too:
            only its static fields are read).
        options: :class:`OnlineOptions`.
        record: keep the filtered and smoothed trajectories for :meth:`results` (memory grows
            with the stream); False keeps only the window.

    Attributes:
        stats: :class:`OnlineStats`.
    """

    def __init__(self, rig: Capture, options: OnlineOptions | None = None, *, record: bool = True):
        self.options = options = options or OnlineOptions()
        options.check()
        self.rig = static_rig(rig)
        if not self.rig.cameras:
            raise MocapgraphError(f"capture {rig.name!r}: no cameras")
        self.kind = options.rig or ("aircap" if any(cam.mount is not None for cam in self.rig.cameras) else "smartmocap")
        pose_sigma = options.pose_sigma_rad_s2
        pose_sigma = (20.0 if self.kind == "smartmocap" else None) if pose_sigma == "rig" else pose_sigma
        self._pose_sigma_rad_s2 = None
        if pose_sigma is not None:
            sigmas = np.full((NUM_JOINTS - 1, 3), float(pose_sigma))
            if options.hips_sigma_rad_s2 is not None:
                sigmas[[JOINT_NAMES.index("left_hip") - 1, JOINT_NAMES.index("right_hip") - 1]] = options.hips_sigma_rad_s2
            self._pose_sigma_rad_s2 = sigmas.ravel()
        relinearisation = options.relinearisation
        self._relinearisation = (RIG_RELINEARISATION if self.kind == "smartmocap" else Relinearisation(enabled=False)) if relinearisation == "rig" else relinearisation
        unmodelled = options.unmodelled_sigma_rad
        self._graph = replace(options.graph, unmodelled_sigma_rad=(0.2 if self.kind == "aircap" else None) if unmodelled == "rig" else unmodelled)
        self.index = {cam.name: c for c, cam in enumerate(self.rig.cameras)}
        self.body = load_body_model()
        self.record = record
        self.stats = OnlineStats()
        self.scale = RobustScale(options.graph.gm_sigma_px)
        self.period = 1.0 / options.rate_hz
        self.t0: float | None = None
        self.shape: np.ndarray | None = None  # the published shape (see _SHAPE_STEP)
        self._shape_key: int | None = None  # the shape's variable while it is refined
        self._shape_since: float | None = None
        self.world_frame = "capture" if self.kind == "aircap" else "ground_plane"
        self.smoother = self._new_smoother()
        self._pose_gmm = LearnedPriors.load(options.graph.pose_prior).pose_gmm
        self._regularizer_sigmas = regularizer_sigmas(self._graph, self._pose_gmm)
        spine3 = options.spine3_sigma_rad
        spine3 = (0.05 if self.kind == "smartmocap" else None) if spine3 == "rig" else spine3
        if spine3 is not None:
            sigmas = np.broadcast_to(self._regularizer_sigmas, (3 * (NUM_JOINTS - 1),)).reshape(NUM_JOINTS - 1, 3).copy()
            sigmas[JOINT_NAMES.index("spine3") - 1] = spine3
            self._regularizer_sigmas = sigmas.ravel()
        self._caches: dict[str, ShapeTableCache] = {}
        self._hypotheses: dict[str, np.ndarray] = {}  # by keypoint format, its (H, K) labelling hypotheses
        self._keypoint_offsets: dict[str, np.ndarray] = {}  # by detector format, (K, 3): the bootstrap's
        self._last_time = np.full(len(self.rig.cameras), -np.inf)
        self._buffer: list[StreamFrame] = []
        # while the keypoint offsets are still to be measured again (offset_updates_s): the stream's
        # frames so far, and the states and camera frames (pose, swap code) that left the window
        self._offset_times = sorted(options.offset_updates_s) if self.kind == "smartmocap" and options.bootstrap_keypoint_offsets else []
        self._kept: list[StreamFrame] = []
        # the second bootstrap's time from the stream's start (resolve_s), until it ran
        self._resolve_at = options.resolve_s if self.kind == "smartmocap" else None
        self._replaying = False  # the window's observations replayed into a new window (_resolve)
        self._left_states: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._left_frames: dict[int, dict[float, tuple[np.ndarray, int]]] = {c: {} for c in range(len(self.rig.cameras))}
        self._bootstrapped = False
        self._seed: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # state → bootstrap (root, pose)
        self._bootstrap_states = 0
        self._seed_cameras: dict[int, dict[float, np.ndarray]] = {}  # camera → {frame time: pose}
        self._static_keys: dict[int, int] = {}  # uncalibrated static camera → its key
        self._static_sigmas: dict[int, tuple[float, float]] = {}  # its prior's (rad, m) about where it was placed
        self._static_since: dict[int, float] = {}  # the end of the first update its variable was in
        self._offsets: set[int] = set()
        self._fixed: dict[int, np.ndarray] = {}  # calibrated static camera → world_T_camera
        self._self_pose: dict[int, deque] = {c: deque() for c in range(len(self.rig.cameras))}
        self._navigation: dict[int, IncrementalNavigation] = {}  # UAV camera → its vehicle's fusion (camera_priors "fused")
        self._frames: dict[int, dict[float, _Frame]] = {c: {} for c in range(len(self.rig.cameras))}
        self._frame_count = np.zeros(len(self.rig.cameras), dtype=int)
        self._gauge: Estimate | None = None
        self.open: int | None = None  # the grid interval gathering observations
        self.newest = -1  # the newest state created
        self._last_observed = -1
        self._rejected = 0  # detections gated out in a row
        self._camera_rejected: dict[int, int] = {}  # by camera, its detections gated out in a row
        # states first seen again after the track was lost: their views, to re-place the body
        self._reacquiring: dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray, str]]] = {}
        # the views of the states still to be created, gated in: what re-places the body when one
        # camera's run of rejections says the prediction slid where only that camera sees
        self._new_views: dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray, str]]] = {}
        # cameras joining an uncalibrated rig after the bootstrap: body points and keypoints so far
        self._joining: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        # the last states that left the window (the tracker's velocity reads them after a restart)
        self._recent: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        # per-state flags of what the loop could not determine (results' flags)
        self._flagged: dict[str, set[int]] = {"no_camera_prior": set(), "camera_prior_coasting": set(), "solver_reset": set()}
        self._pending = gtsam.NonlinearFactorGraph()
        self._body_votes: list[tuple[int, Labelling, gtsam.NonlinearFactor, bool]] = []  # UAV detections of the update that may relabel their whole body (and whether their prior is the fusion's)
        self._pending_values = gtsam.Values()
        self._pending_stamps: dict[int, float] = {}
        self.filtered: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.smoothed: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.filtered_cameras: dict[int, dict[float, np.ndarray]] = {c: {} for c in range(len(self.rig.cameras))}
        self.smoothed_cameras: dict[int, dict[float, np.ndarray]] = {c: {} for c in range(len(self.rig.cameras))}
        self.swaps: dict[int, dict[float, int]] = {c: {} for c in range(len(self.rig.cameras))}
        self.detections: dict[int, int] = {}
        for c, cam in enumerate(self.rig.cameras):
            if cam.extrinsics is not None and self.kind == "aircap":
                self._fixed[c] = np.asarray(cam.extrinsics)[0]

    def _new_smoother(self) -> FixedLagSmoother:
        return FixedLagSmoother(self.options.lag_s, self._relinearisation, {"r": 6, "q": 3 * (NUM_JOINTS - 1), "c": 6, "o": 6})

    # -- input ----------------------------------------------------------------------------------

    def update(self, camera: str, timestamp: float, keypoints, box=None, sensors: dict | None = None, detector: str | None = None) -> OnlineState:
        """Take one camera frame's detection and return the newest state.

        Args:
            camera: the camera's name.
            timestamp: seconds, on the capture's clock.
            keypoints: ``(K, 3)`` pixels of the distorted image and confidences, NaN where
                missing; K points of the detector's format.
            box: ``(4,)`` or ``(5,)`` the detector's person box ``x0, y0, x1, y1[, score]``, or None
                (the box of the keypoints is used for the gate).
            sensors: the camera's vehicle's log samples since its previous frame, by kind (the
                capture format's sensor fields, e.g. ``{"self_pose": {"t", "rotation", "position"}}``).
            detector: the detector's name (default: the options', else the camera's first).
        """
        start, cpu_start = time.perf_counter(), time.thread_time()
        c = self.index.get(camera)
        if c is None:
            raise MocapgraphError(f"update: unknown camera {camera!r} (cameras: {', '.join(self.index)})")
        cam = self.rig.cameras[c]
        name = detector or self.options.detector or next(iter(cam.detectors), None)
        if name not in cam.detectors:
            raise MocapgraphError(f"update: camera {camera!r} has no detector {name!r} (detectors: {', '.join(cam.detectors) or 'none'})")
        fmt = cam.detectors[name].format
        K = get_format(fmt).num_points
        kp = np.asarray(keypoints, dtype=float)
        if kp.shape != (K, 3):
            raise MocapgraphError(f"update: camera {camera!r}: keypoints of detector {name!r} ({fmt}) must be ({K}, 3), got {kp.shape}")
        t = float(timestamp)
        if not math.isfinite(t):
            raise MocapgraphError(f"update: camera {camera!r}: timestamp must be finite, got {timestamp!r}")
        samples = self._take_sensors(c, sensors or {})
        if t < self._last_time[c] - self.options.lag_s:
            # delayed by more than the lag behind the camera's own newest frame (a stalled link):
            # whatever the window still holds, it is counted and dropped like any late frame
            self.stats.observations += 1
            self.stats.late_dropped += 1
            return self.state()
        self._last_time[c] = max(self._last_time[c], t)
        box = None if box is None else np.asarray(box, dtype=float)
        if box is not None and (box.shape not in ((4,), (5,))):
            raise MocapgraphError(f"update: camera {camera!r}: box must be (4,) or (5,), got {box.shape}")
        self.stats.observations += 1
        frame = StreamFrame(camera, t, kp, box, samples, name)
        if self.t0 is None:
            self.t0 = t
        if not self._bootstrapped:
            self._buffer.append(frame)
            if t - self.t0 >= self.options.bootstrap_s:
                self._bootstrap()
                return self.state(updated=True)
            return self.state()
        if self._keeping:
            self._kept.append(frame)
        resolved = (self.stats.resolve_seconds, self.stats.resolve_cpu_seconds)
        updated = self._observe(c, frame)
        out = self.state(updated=updated)
        # the second bootstrap is counted apart, as the first is (OnlineStats.resolve_seconds)
        seconds = time.perf_counter() - start - (self.stats.resolve_seconds - resolved[0])
        cpu = time.thread_time() - cpu_start - (self.stats.resolve_cpu_seconds - resolved[1])
        self.stats.busy_seconds += seconds
        self.stats.busy_cpu_seconds += cpu
        if updated:
            self.stats.latencies.append(seconds)
            self.stats.cpu_latencies.append(cpu)
        return out

    @property
    def _keeping(self) -> bool:
        """Whether the stream's frames are kept: for a measure of the keypoint offsets or a second
        bootstrap still to come."""
        return bool(self._offset_times) or self._resolve_at is not None

    def _take_sensors(self, c: int, sensors: dict) -> dict:
        cam = self.rig.cameras[c]
        out = {}
        for kind, samples in sensors.items():
            if not isinstance(samples, dict) or "t" not in samples:
                raise MocapgraphError(f"update: camera {cam.name!r}: sensors[{kind!r}] must be a dict of arrays with a 't' field")
            out[kind] = {f: np.asarray(v) for f, v in samples.items()}
        fused = self.kind == "aircap" and cam.mount is not None and self.options.camera_priors != "self_pose"
        if fused and (c in self._navigation or ("imu" in out and (self.options.camera_priors == "fused" or not self._self_pose[c] and "self_pose" not in out))):
            if c not in self._navigation:
                self._navigation[c] = IncrementalNavigation(cam.name, cam.mount, self.options.navigation)
            self._navigation[c].add(out)
        for kind in out:
            if kind == "self_pose":
                kept = self._self_pose[c]
                for k in range(len(out[kind]["t"])):
                    kept.append((float(out[kind]["t"][k]), out[kind]["rotation"][k], out[kind]["position"][k]))
                # what a frame still to come may need: late frames within the lag, the bootstrap's replay
                horizon = self.options.lag_s + self.options.bootstrap_s + 1.0
                while kept and kept[0][0] < kept[-1][0] - horizon:
                    kept.popleft()
        return out

    # -- bootstrap ------------------------------------------------------------------------------

    def _buffered_capture(self, buffer: list[StreamFrame]) -> Capture:
        """Stream frames (the bootstrap's buffer, ...) as a capture of the rig (its frames,
        detections and sensor logs; the cameras without a frame left out)."""
        cameras = []
        for c, cam in enumerate(self.rig.cameras):
            frames = [f for f in buffer if f.camera == cam.name]
            times = np.array(sorted({f.timestamp for f in frames}))
            detectors = {}
            for name, det in cam.detectors.items():
                kp = np.full((len(times),) + det.keypoints.shape[1:], np.nan)
                boxes = np.full((len(times), 5), np.nan)
                for f in frames:
                    if f.detector == name:
                        j = int(np.searchsorted(times, f.timestamp))
                        kp[j] = f.keypoints
                        if f.box is not None:
                            boxes[j, : len(f.box)] = f.box
                if any(f.detector == name for f in frames):
                    detectors[name] = Detector(name, det.format, kp, boxes if np.isfinite(boxes[:, :4]).any() else None)
            sensors: dict[str, dict[str, np.ndarray]] = {}
            for f in frames:
                for kind, samples in f.sensors.items():
                    sensors.setdefault(kind, {k: [] for k in samples})
                    for k, v in samples.items():
                        sensors[kind][k].append(v)
            sensors = {kind: {k: np.concatenate(v) for k, v in s.items()} for kind, s in sensors.items()}
            sensors = {kind: s for kind, s in sensors.items() if len(s["t"])}
            cameras.append(replace(cam, timestamps=times, detectors=detectors, sensors=sensors))
        return replace(self.rig, cameras=[cam for cam in cameras if cam.num_frames])

    def _bootstrap(self) -> None:
        """The buffered stream solved in batch by the rig's pipeline; its states and cameras start
        the smoother, and the buffered observations are replayed into it. On an AirCap rig a second
        batch with the UAV cameras refined near their priors and their whole-body relabelling (as
        offline) checks the first one, held at the priors: where their headings at the end are more
        than 90 deg apart, the held one was turned round by a whole-body flip in most views, and
        the loop starts from the refined one (``bootstrap_cameras="check"``)."""
        from mocapgraph.pipelines.aircap import AircapOptions, resample, run_aircap

        start = time.perf_counter()
        o = self.options
        if self.kind == "aircap":
            mini = self._buffered_capture(self._buffer)
            detectors = tuple(dict.fromkeys(f.detector for f in self._buffer))
            # the cameras' priors are the loop's: the fusion's first solve is the offline fusion of
            # the same logs
            fused = self._navigation and o.camera_priors == "fused" and all(c in self._navigation for c, cam in enumerate(self.rig.cameras) if cam.mount is not None)
            held = AircapOptions(
                mode="sequence", cameras="fixed", prior_source="fused" if fused else "online", sync="grid", grid_hz=o.rate_hz, detectors=detectors,
                covariances=False, workers=1, graph=replace(self._graph, focal="fixed", shape="estimate"), motion_prior=o.bootstrap_motion_prior if o.rate_hz == 30.0 else "none",
            )  # fmt: skip
            result = run_aircap(mini, held)
            if o.bootstrap_cameras == "check":
                refined = run_aircap(mini, replace(held, cameras="refine", graph=replace(held.graph, moving_body_swaps=True)))
                turned = _heading_apart_rad(result, refined, _HAND_OFF_S)
                log.info("online: the bootstrap's held and refined batches %.0f deg apart at their end", math.degrees(turned))
                if turned > 0.5 * math.pi:
                    result, self.stats.bootstrap_refined = refined, True
        else:
            result = self._smartmocap_batch(self._buffer, o.bootstrap_offset_rounds)
        self.stats.bootstrap_seconds = time.perf_counter() - start
        span = self._buffer[-1].timestamp - self.t0
        self.shape = np.asarray(result.shape, dtype=float)
        self._keypoint_offsets = {fmt: offsets_from_table(fmt, table) for fmt, table in result.parameters.get("keypoint_offsets_m", {}).items()}
        self._caches.clear()
        self.world_frame = result.world_frame
        n = int(math.floor((self._buffer[-1].timestamp - self.t0) / self.period + _SNAP)) + 2
        grid = self.t0 + self.period * np.arange(n)
        est = resample(Estimate(result.root, result.pose, self.shape, []), np.asarray(result.timestamps), grid)
        self._seed = {i: (est.roots[i], est.poses[i]) for i in range(n)}
        self._bootstrap_states = n
        for name, track in result.cameras.items():
            c = self.index[name]
            if c in self._fixed:
                continue
            if not self.rig.cameras[c].moving and self.kind == "smartmocap":
                if o.static_cameras == "hold":
                    self._fixed[c] = track.world_T_camera[0]
                    continue
                self._static_keys[c] = camera_key(c, 0)
                self._static_sigmas[c] = o.static_camera_sigmas
            self._seed_cameras[c] = {float(t): T for t, T in zip(track.timestamps, track.world_T_camera)}
        if self.kind == "smartmocap":
            self._gauge = Estimate(est.roots[:1], est.poses[:1], self.shape, [])
        if o.shape == "refine":
            self._shape_key = shape_key()
        self._bootstrapped = True
        self.stats.bootstrap_observations = len(self._buffer)
        log.info("online: bootstrap of %.2f s (%d states, %s) in %.1f s", span, n, self.kind, self.stats.bootstrap_seconds)
        # One smoother update with every buffered observation, from the batch solution: replayed
        # an interval at a time, the first updates saw a state or two and one or two views,
        # and iSAM2's undamped Gauss-Newton steps threw them metres off (measured).
        buffered, self._buffer = self._buffer, []
        if self._keeping:
            self._kept = list(buffered)
        for frame in buffered:
            i, a = self._grid(frame.timestamp)
            self.open = self._interval(i, a) if self.open is None else max(self.open, self._interval(i, a))
            self._add_observation(self.index[frame.camera], frame, i, a)
        self._flush()
        self.stats.batches = 0  # the bootstrap's update is one by construction

    def _smartmocap_batch(self, frames: list[StreamFrame], offset_rounds: int) -> Result:
        """An uncalibrated rig's batch solve of ``frames`` (the bootstrap's, the second bootstrap's):
        ``run_smartmocap`` with the loop's motion prior and keypoint offsets, its focal held."""
        from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap

        o = self.options
        options = SmartmocapOptions(
            motion_prior=o.bootstrap_motion_prior, keypoint_offsets=o.bootstrap_keypoint_offsets, offset_rounds=offset_rounds,
            covariances=False, workers=1, detectors=tuple(dict.fromkeys(f.detector for f in frames)), drift_sigmas_m=None,  # the result's keypoints are not read
            graph=replace(SmartmocapOptions().graph, focal="fixed", swaps=o.graph.swaps),
        )  # fmt: skip
        return run_smartmocap(self._buffered_capture(frames), options)

    # -- the loop -------------------------------------------------------------------------------

    def _grid(self, t: float) -> tuple[int, float]:
        position = (t - self.t0) / self.period
        i = int(math.floor(position + _SNAP))
        a = position - i
        return i, (0.0 if a < _SNAP else a)

    @staticmethod
    def _interval(i: int, a: float) -> int:
        """The grid interval ``(t_j, t_{j+1}]`` an observation at grid position ``i + a`` belongs
        to: one exactly at a state's time closes the interval that ends there, so the update
        creating that state already uses it (synchronised cameras would otherwise leave every
        new state without its own observations until the next update)."""
        return i if a else i - 1

    def _observe(self, c: int, frame: StreamFrame) -> bool:
        """One observation into the open interval (closing it first when the observation is
        later); returns whether a smoother update ran."""
        i, a = self._grid(frame.timestamp)
        if i < 0:
            self.stats.late_dropped += 1
            return False
        interval = self._interval(i, a)
        updated = False
        if self.open is not None and interval < self.open:
            needed = [i, i + 1] if a else [i]
            # states after the newest are created by the next update (the open interval jumped
            # over this one: an observation of a later interval came first)
            if not all(k > self.newest or self.smoother.holds(root_key(k)) or self._pending_values.exists(root_key(k)) for k in needed):
                self.stats.late_dropped += 1
                return False
            self.stats.late_used += 1
        elif self.open is None or interval > self.open:
            if self.open is not None:
                self._flush()
                updated = True
            self.open = interval
        self._add_observation(c, frame, i, a)
        return updated

    def _cache(self, fmt: str) -> ShapeTableCache:
        if fmt not in self._caches:
            self._caches[fmt] = ShapeTableCache(self.body, fmt, offsets=self._keypoint_offsets.get(fmt))
        return self._caches[fmt]

    def _body_at(self, i: int, a: float) -> tuple[np.ndarray, np.ndarray]:
        """The body's current guess at grid position ``i + a``: states' estimates or predictions."""
        root, pose = self._state_guess(i)
        if a and (i + 1 <= self.newest):
            root1, pose1 = self._state_guess(i + 1)
            root = root.copy()
            root[:3, 3] = (1 - a) * root[:3, 3] + a * root1[:3, 3]
            pose = (1 - a) * pose + a * pose1
        return root, pose

    def _state_guess(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        if i > self.newest:
            return self._predict(i)
        key = root_key(i)
        for values in (self.smoother.estimate, self._pending_values):
            if values.exists(key):
                return values.atPose3(key).matrix(), values.atVector(pose_key(i)).reshape(NUM_JOINTS - 1, 3)
        if i in self._recent:
            return self._recent[i]
        return self._predict(i)

    def _predict(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """State ``i``'s start: the bootstrap's value, else constant velocity (root position and
        rotation) from the two newest states, held once ``coast_s`` passed without observations."""
        if i in self._seed:
            return self._seed[i][0], self._seed[i][1]
        if self.newest < 0:
            raise MocapgraphError("online: no state to predict from (the bootstrap gave none)")
        last = min(i - 1, self.newest)
        root, pose = self._state_guess(last)
        steps = i - last
        coasting = (i - self._last_observed) * self.period > self.options.coast_s
        if last < 3 or coasting:
            return root.copy(), pose.copy()
        # the velocity between the second and the fourth newest states: the newest one is seen
        # only through the interval before it, and its difference to the next is noise
        a, _ = self._state_guess(last - 1)
        b, _ = self._state_guess(last - 3)
        out = root.copy()
        out[:3, 3] = root[:3, 3] + 0.5 * steps * (a[:3, 3] - b[:3, 3])
        delta = gtsam.Rot3.Logmap(gtsam.Rot3(b[:3, :3].T @ a[:3, :3]))
        out[:3, :3] = root[:3, :3] @ gtsam.Rot3.Expmap(0.5 * steps * delta).matrix()
        return out, pose.copy()

    def _reacquire(self, k: int, root: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """State ``k``'s start after the track was lost: the prediction moved so that its
        keypoints sit on those the views of ``k`` triangulate (two views or more), else as predicted."""
        views = self._reacquiring.pop(k, [])
        self._new_views.pop(k, None)
        fmt = views[0][3] if views else None
        views = [v for v in views if v[3] == fmt]
        if len(views) < 2:
            return root, pose
        seen = triangulate_points(np.stack([v[0] for v in views]), np.stack([v[1] for v in views]), np.stack([v[2] for v in views]))
        predicted = self.body.forward(self.shape, root[None], pose[None], keypoints=fmt).keypoints[0]
        both = np.isfinite(seen).all(-1) & np.isfinite(predicted).all(-1)
        if both.sum() < self.options.gate_min_keypoints:
            return root, pose
        out = root.copy()
        out[:3, 3] += np.median(seen[both] - predicted[both], axis=0)
        log.info("online: track re-acquired at %.2f s, body moved %.2f m from its prediction", self.t0 + k * self.period, np.linalg.norm(out[:3, 3] - root[:3, 3]))
        return out, pose

    def _camera_prior(self, c: int, t: float) -> tuple[np.ndarray, np.ndarray, bool, bool] | None:
        """Camera ``c``'s pose, covariance, whether it rests on the IMU alone (a GPS outage) and
        whether it is the fusion's at ``t``: from its vehicle's GPS/IMU fusion so far (``camera_priors="fused"``), else its
        onboard estimate so far."""
        cam = self.rig.cameras[c]
        nav = self._navigation.get(c)
        fused = nav.camera_prior(t) if nav is not None else None
        if fused is not None:
            return fused.world_T_camera, fused.covariance, fused.coasting, True
        samples = self._self_pose[c]
        if cam.mount is None or not samples:
            return None
        # (t,) sorts before a sample at t: the samples' times, searched without building an array of them
        k = bisect.bisect_left(samples, (t,))
        if min(abs(t - samples[max(k - 1, 0)][0]), abs(samples[min(k, len(samples) - 1)][0] - t)) > self.options.prior_timeout_s:
            return None  # an outage: holding the last sample would hold a moving camera still
        near = [samples[j] for j in range(max(k - 2, 0), min(k + 2, len(samples)))]  # the neighbours online_track interpolates
        log_ = {"self_pose": {"t": np.array([s[0] for s in near]), "rotation": np.array([s[1] for s in near]), "position": np.array([s[2] for s in near])}}
        track = online_track(log_, cam.mount, np.array([t]), cam.name, noise=self.options.online_noise)
        return track.world_T_camera[0], track.covariance[0], False, False

    def _count_source(self, c: int, source: str) -> None:
        """One more frame of camera ``c`` resting on ``source`` (:attr:`OnlineStats.camera_priors`; AirCap rigs)."""
        if self.kind == "aircap":
            counts = self.stats.camera_priors.setdefault(self.rig.cameras[c].name, {})
            counts[source] = counts.get(source, 0) + 1

    def _camera(self, c: int, t: float, seen: tuple[np.ndarray, str, int, float] | None = None) -> _Frame | None:
        """Camera ``c``'s frame at ``t``: held, or a variable (created with its priors and
        smoothness the first time); None when the loop cannot place the camera. ``seen``: the
        frame's keypoints ``(K, 3)`` (undistorted pixels, weights), their format and the grid
        position ``(i, a)`` they are explained at, to resect a moving uncalibrated camera on the
        body's current estimate when nothing else places it (it returned after more than the lag)."""
        frames = self._frames[c]
        if t in frames:
            return frames[t]
        if c in self._fixed:
            self._count_source(c, "calibration")
            frames[t] = _Frame(None, self._fixed[c], t)
            return frames[t]
        if c in self._static_keys:
            key = self._static_keys[c]
            if not (self.smoother.holds(key) or self._pending_values.exists(key)):
                seed = next(iter(self._seed_cameras[c].values()))
                self._pending_values.insert(key, gtsam.Pose3(seed))
                self._pending_stamps[key] = t
                self._pending.add(camera_prior_factor(key, seed, sigmas=self._static_sigmas[c], kernel="none"))
            values = self.smoother.estimate if self.smoother.estimate.exists(key) else self._pending_values
            frames[t] = _Frame(key, values.atPose3(key).matrix(), t)
            return frames[t]
        o = self.options
        cam = self.rig.cameras[c]
        if not cam.moving and self.kind == "smartmocap":
            return self._join(c, t, seen)  # a static camera the bootstrap did not see
        prior = self._camera_prior(c, t) if self.kind == "aircap" else None
        seed = self._seed_cameras.get(c, {}).get(t)
        if prior is None and seed is None and self.kind == "aircap" and cam.mount is not None:
            # no onboard estimate near t (an outage): a UAV camera's pose from the body alone was
            # too weak (one view of a person 10 m off; the body's error doubled on aircap), so its
            # frames wait for the estimate to come back
            self._count_source(c, "none")
            frames[t] = _Frame(None, np.full((4, 4), np.nan), t, no_prior=True)
            return frames[t]
        previous = max((f for f in frames.values() if f.time < t), key=lambda f: f.time, default=None)
        if prior is None and seed is None and previous is None:
            seed = self._resect(c, *seen) if seen is not None and cam.moving else None
            if seed is None:
                self._count_source(c, "none")
                return None
        if prior is not None:
            self._count_source(c, "fused" if prior[3] else "self_pose")
        else:
            self._count_source(c, "bootstrap" if seed is not None and t in self._seed_cameras.get(c, {}) else "body")
        if prior is not None and o.cameras == "prior":
            frames[t] = _Frame(None, prior[0], t, coasting=prior[2], fused=prior[3])
            return frames[t]
        key = camera_key(c, int(self._frame_count[c] % CAMERA_STRIDE))
        self._frame_count[c] += 1
        tied = previous is not None and previous.key is not None and self._in_window(previous.key)
        before = max((f for f in frames.values() if f.time < previous.time), key=lambda f: f.time, default=None) if tied and previous.tied else None
        start = seed if seed is not None else prior[0] if prior is not None else previous.pose
        if seed is None and prior is None and before is not None:
            # the centre at constant velocity: each factor is linearised where its variables start
            start = previous.pose.copy()
            start[:3, 3] += (previous.pose[:3, 3] - before.pose[:3, 3]) * (t - previous.time) / (previous.time - before.time)
        self._pending_values.insert(key, gtsam.Pose3(start))
        self._pending_stamps[key] = t
        if prior is not None:
            offset = camera_offset_key(c)
            if offset not in self._offsets:
                Ad = gtsam.Pose3(prior[0]).AdjointMap()
                common = (1.0 - o.camera_prior_white_fraction**2) * Ad @ prior[1] @ Ad.T
                self._pending.add(camera_prior_factor(offset, np.eye(4), common, kernel="none"))
                self._pending_values.insert(offset, gtsam.Pose3())
                self._pending_stamps[offset] = t
                self._offsets.add(offset)
            self._pending.add(camera_offset_prior_factor(offset, key, prior[0], prior[1] * o.camera_prior_white_fraction**2, kernel=o.camera_prior_kernel))
        if tied:
            dt = max(t - previous.time, 1e-3)
            self._pending.add(camera_smoothness_factor(previous.key, key, dt, o.graph.camera_sigma_rad_s, o.graph.camera_sigma_m_s))
        if before is not None and o.graph.camera_sigma_m_s2 is not None and self._in_window(before.key):
            self._pending.add(camera_acceleration_factor([before.key, previous.key, key], [before.time, previous.time, t], o.graph.camera_sigma_m_s2))
        frames[t] = _Frame(key, start, t, tied=tied, coasting=prior is not None and prior[2], fused=prior is not None and prior[3])
        return frames[t]

    def _in_window(self, key: int) -> bool:
        """Whether ``key`` is a variable of the window or of the update being gathered."""
        return self.smoother.holds(key) or self._pending_values.exists(key)

    def _join(self, c: int, t: float, seen: tuple[np.ndarray, str, int, float] | None) -> _Frame | None:
        """A static camera of an uncalibrated rig that the bootstrap did not see: its first
        ``join_frames`` frames' keypoints are resected together on the body's estimates at their
        times (they are not used otherwise: None), then it starts a variable there under a loose
        prior (0.05 rad, 0.1 m: a resection on the body is less sure than the bootstrap), or with
        ``static_cameras="hold"`` is held there."""
        if seen is None:
            return None
        keypoints, fmt, i, a = seen
        root, pose = self._body_at(i, a)
        points = self.body.forward(self.shape, root[None], pose[None], keypoints=fmt).keypoints[0]
        joining = self._joining.setdefault(c, [])
        joining.append((points, keypoints))
        if len(joining) < self.options.join_frames:
            return None
        cam = self.rig.cameras[c]
        found = resect(np.concatenate([p for p, _ in joining]), np.concatenate([k for _, k in joining]), cam.K)
        if found is None:
            joining.pop(0)  # the oldest frames give way: the body or the detections may be better later
            return None
        del self._joining[c]
        log.info("online: camera %r joined at %.2f s, placed by resection of %d frames on the body (%d inliers)", cam.name, t, self.options.join_frames, found[1])
        if self.options.static_cameras == "hold":
            self._fixed[c] = found[0]
        else:
            key = camera_key(c, 0)
            self._static_keys[c] = key
            self._seed_cameras[c] = {t: found[0]}
            self._static_sigmas[c] = (0.05, 0.1)
        return self._camera(c, t)

    def _resect(self, c: int, keypoints: np.ndarray, fmt: str, i: int, a: float) -> np.ndarray | None:
        """``(4, 4)`` world_T_camera of camera ``c`` from its keypoints and the body's current
        estimate at grid position ``i + a`` (PnP), or None."""
        root, pose = self._body_at(i, a)
        points = self.body.forward(self.shape, root[None], pose[None], keypoints=fmt).keypoints[0]
        found = resect(points, keypoints, self.rig.cameras[c].K)
        if found is None:
            return None
        log.info("online: camera %r placed again at %.2f s by resection on the body (%d inliers)", self.rig.cameras[c].name, self.t0 + (i + a) * self.period, found[1])
        return found[0]

    def _gate(self, c: int, pose: np.ndarray, frame: StreamFrame, pixels: np.ndarray, weights: np.ndarray, i: int, a: float) -> np.ndarray | None:
        """The weights with the keypoints outside the predicted body's region of interest at 0;
        None when too few are left (the detection is dropped)."""
        cam = self.rig.cameras[c]
        root, body_pose = self._body_at(i, a)
        joints, _ = self._cache("body").state_joints(root, body_pose.ravel(), self.shape, False)
        px, depth = project_points(joints, pose, cam.K, None)
        if not np.all(depth > 0.05):
            return weights
        lo, hi = px.min(0), px.max(0)
        grow = self.options.gate_margin * max(hi[1] - lo[1], 1.0)
        inside = np.all((pixels >= lo - grow) & (pixels <= hi + grow), axis=1)
        gated = (weights > 0) & ~inside
        self.stats.gated_keypoints += int(gated.sum())
        out = np.where(inside, weights, 0.0)
        if frame.box is not None:
            box = frame.box[:4]
            centre = 0.5 * (box[:2] + box[2:])
            if np.any(centre < lo - grow) or np.any(centre > hi + grow):
                return None
        if np.count_nonzero(out) < self.options.gate_min_keypoints:
            return None
        return out

    def _add_observation(self, c: int, frame: StreamFrame, i: int, a: float) -> None:
        cam = self.rig.cameras[c]
        fmt = cam.detectors[frame.detector].format
        pixels, weights = undistorted_keypoints(frame.keypoints, cam.K, cam.distortion, f"update: camera {cam.name!r}")
        if np.count_nonzero(weights) == 0:
            self.stats.empty += 1
            return
        view = self._camera(c, frame.timestamp, (np.column_stack([pixels, weights]), fmt, i, a))
        if view is None:
            self.stats.unplaced += 1
            return
        if view.no_prior:
            self.stats.no_prior += 1
            self._flagged["no_camera_prior"].add(int(round(i + a)))
            return
        if view.coasting:
            self.stats.coasting += 1
            self._flagged["camera_prior_coasting"].add(int(round(i + a)))
        # The bootstrap's states were solved on these very observations; and after a run of
        # rejections every camera's detections are taken again, as the tracker re-acquires a
        # lost track (the prediction, not the detections, is then what went wrong).
        k = int(round(i + a))
        lost = self._last_observed >= 0 and (k - self._last_observed) * self.period > self.options.coast_s
        # a run of gate_reacquire rejections says the same of the prediction as a lost track
        stale = self._rejected >= self.options.gate_reacquire
        # So does such a run of one camera's while the others' detections pass: the prediction
        # slid along the direction only that camera sees across (aircap 10 s seed 1: uav2 and uav3
        # 12-32 deg apart, the body slid 2.7 m along their rays at 6.1-7.1 s while uav1, the only
        # view across, was gated out 53 times, its runs reset by the others' detections). The
        # state then starts where all its views triangulate the body, as after a lost track.
        ungated = weights

        def view_of() -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
            """The view as _reacquire triangulates it (its weights before the gate); built only for
            a state still to be created, not on every observation's path."""
            return cam.K @ np.linalg.inv(view.pose)[:3], pixels, ungated, fmt

        if self._camera_rejected.get(c, 0) >= self.options.gate_reacquire and k > self.newest and k not in self._reacquiring:
            self._reacquiring[k] = list(self._new_views.get(k, []))
            self.stats.camera_reacquired += 1
        if (lost or stale or k in self._reacquiring) and k > self.newest:
            # the track was lost: the prediction is stale, so no gate, and the new state will
            # start where the views triangulate the body (_reacquire)
            self._reacquiring.setdefault(k, []).append(view_of())
        elif i not in self._seed and self._rejected < self.options.gate_reacquire:
            gated = self._gate(c, view.pose, frame, pixels, weights, i, a)
            if gated is None:
                self.stats.gated += 1
                self._rejected += 1
                self._camera_rejected[c] = self._camera_rejected.get(c, 0) + 1
                return
            weights = gated
            if k > self.newest:
                self._new_views.setdefault(k, []).append(view_of())
        self._rejected = 0
        self._camera_rejected[c] = 0
        o = self.options.graph
        labelling = None
        if o.swaps:
            allowed = np.ones((1, len(SWAP_KINDS)), dtype=bool)
            # A whole-body relabelling of a moving camera only where something holds its pose on
            # the person's side: a prior (AirCap, moving_body_swaps), or an uncalibrated camera's
            # previous frame, which its variable starts at and is tied to: the hypotheses are
            # decided there. Without it the handheld camera of rich went round the person for
            # each of its detector's whole-body flips (3 m off for 0.7 s, 10 s capture).
            voted = self.kind == "aircap" and cam.moving and self.options.uav_body_swaps == "minority"
            allowed[0, SWAP_KINDS.index("body")] = not cam.moving or (o.moving_body_swaps and self.kind == "aircap") or (self.kind == "smartmocap" and view.tied) or voted
            if fmt not in self._hypotheses:
                self._hypotheses[fmt] = swap_hypotheses(self.body, fmt)
            labelling = Labelling(self._hypotheses[fmt], 0.5 * o.swap_cost_sigmas**2, allowed=allowed)
            view.labellings.append(labelling)
        between = {"next_state": (root_key(i + 1), pose_key(i + 1)), "fraction": a} if a else {}
        factor = reprojection_factor(
            self.body, self._cache(fmt), root_key(i), pose_key(i), self._shape_key, [view.key], [None if view.key is not None else view.pose],
            np.array([[cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]]]), pixels[None], weights[None], fmt, self.scale,
            noise_px=o.noise_px, fixed_shape=None if self._shape_key is not None else self.shape, labelling=labelling, **between,
        )  # fmt: skip
        self._pending.add(factor)
        if labelling is not None and labelling.allowed[0, SWAP_KINDS.index("body")] and voted:
            self._body_votes.append((c, labelling, factor, view.fused))
        if self._replaying:
            return  # counted when it first came
        self.stats.used += 1
        self._last_observed = max(self._last_observed, i + (1 if a else 0))
        if self.record:
            count = int(np.count_nonzero(weights))
            self.detections[i] = self.detections.get(i, 0) + count
            if a:
                self.detections[i + 1] = self.detections.get(i + 1, 0) + count

    def _flush(self) -> None:
        """Close the open interval: create the states up to its end and update the smoother."""
        end = self.open + 1
        o = self.options
        created = []
        if self._shape_key is not None and not self._in_window(self._shape_key):
            # its table stays the bootstrap's: without relinearisation every factor on the shape is
            # linearised there, and the estimate moves by the solution's delta
            self._pending_values.insert(self._shape_key, self.shape)
            self._pending_stamps[self._shape_key] = self.t0 + end * self.period
            self._pending.add(self._shape_prior())
        for k in range(self.newest + 1, end + 1):
            root, pose = self._reacquire(k, *self._predict(k))
            self._pending_values.insert(root_key(k), gtsam.Pose3(root))
            self._pending_values.insert(pose_key(k), pose.ravel())
            t = self.t0 + k * self.period
            self._pending_stamps[root_key(k)] = self._pending_stamps[pose_key(k)] = t
            self._pending.add(pose_regularizer_factor(pose_key(k), self._regularizer_sigmas))
            if self._pose_gmm is not None:
                self._pending.add(pose_gmm_factor(pose_key(k), self._pose_gmm))
            if k == 0 and self._gauge is not None:
                from mocapgraph.pipelines.smartmocap import SmartmocapOptions, gauge_factor

                self._pending.add(gauge_factor(self._gauge, SmartmocapOptions().gauge_sigmas))
            if k > 0 and self._in_window(root_key(k - 1)):  # not the first state of a new window (_resolve)
                self._pending.add(root_smoothness_factor(root_key(k - 1), root_key(k), self.period, (o.graph.root_sigma_rad_s, o.graph.root_sigma_m_s)))
                self._pending.add(pose_velocity_factor(pose_key(k - 1), pose_key(k), self.period, o.graph.pose_sigma_rad_s))
            if k > 1 and self._in_window(root_key(k - 2)):
                times = self.t0 + self.period * np.arange(k - 2, k + 1)
                if o.root_sigma_m_s2 is not None:
                    # the camera's constant-velocity factor, on the root's Pose3 as on a camera's
                    self._pending.add(camera_acceleration_factor([root_key(k - 2), root_key(k - 1), root_key(k)], times, o.root_sigma_m_s2))
                if o.root_sigma_rad_s2 is not None:
                    self._pending.add(rotation_acceleration_factor([root_key(k - 2), root_key(k - 1), root_key(k)], times, o.root_sigma_rad_s2))
                if self._pose_sigma_rad_s2 is not None:
                    self._pending.add(pose_smoothness_factor([pose_key(k - 2), pose_key(k - 1), pose_key(k)], times, self._pose_sigma_rad_s2))
            self.newest = k
            created.append((k, root, pose))
        self._hold_refined(self.t0 + end * self.period)
        keep = [*self._static_keys.values(), *self._offsets, *([self._shape_key] if self._shape_key is not None else [])]
        keep = [k for k in keep if self.smoother.holds(k) or self._pending_values.exists(k)]
        self._vote_body_swaps()
        try:
            report = self.smoother.update(self._pending, self._pending_values, self._pending_stamps, keep=keep)
        except RuntimeError as error:  # GTSAM's exceptions (an indeterminant system, ...) come as RuntimeError
            report = self._restart(error, created)
        self.stats.solve_seconds.append(report.seconds)
        self.stats.relinearised.append(report.relinearised)
        self.stats.batches += int(report.batch)
        self._pending, self._pending_values, self._pending_stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
        if self._shape_key is not None and self.smoother.estimate.exists(self._shape_key):
            self._publish_shape(self.smoother.estimate.atVector(self._shape_key))
        if self.record:
            # this update's estimate of a variable, in the window or just left it (a lag shorter
            # than the bootstrap lets its first states and frames leave in the replay's update)
            def after(key: int) -> gtsam.Values | None:
                return next((v for v in (self.smoother.estimate, report.left) if v.exists(key)), None)

            for k, root, pose in created:
                if k in self.filtered:
                    continue  # replayed into a new window (_resolve): the record is as first estimated
                # the bootstrap's states are all created by the replay's update: as its newest
                # state is, each is recorded as that update left it (not the batch solution, in
                # the frame the update then moved: the filtered joints' alignment to the truth
                # took the cameras, recorded from the update, with it)
                values = after(root_key(k)) if k == end or k < self._bootstrap_states else None
                if values is not None:
                    root, pose = values.atPose3(root_key(k)).matrix(), values.atVector(pose_key(k)).reshape(NUM_JOINTS - 1, 3)
                self.filtered[k] = (root, pose, self.shape)
            for c, frames in self._frames.items():
                for t, f in frames.items():
                    if t in self.filtered_cameras[c] or f.no_prior:
                        continue
                    # a held camera (a static one at the bootstrap's estimate, a UAV's at its onboard
                    # one) too: the pose its frame was explained with
                    values = after(f.key) if f.key is not None else None
                    self.filtered_cameras[c][t] = values.atPose3(f.key).matrix() if values is not None else f.pose
        self._retire(report.left)
        if self._offset_times and self._left_states and end * self.period >= self._offset_times[0] - _SNAP:
            self._offset_times.pop(0)
            self._measure_offsets()
        if self._resolve_at is not None and end * self.period >= self._resolve_at - _SNAP:
            self._resolve()
        # the camera frames' current estimates, for the gate and the next frames' starts
        for frames in self._frames.values():
            for f in frames.values():
                if f.key is not None and self.smoother.estimate.exists(f.key):
                    f.pose = self.smoother.estimate.atPose3(f.key).matrix()

    def _resolve(self) -> None:
        """The second bootstrap (``resolve_s``): the rig's batch pipeline on every frame so far;
        the loop takes its shape and keypoint-definition offsets, its static cameras (as the
        window's priors' centres) and its states and moving cameras' frames in the window (as their
        starts), all moved by the rigid map of the batch's world onto the loop's (fitted on the
        static cameras' centres and optical axes: the records so far stay in the loop's world). The
        window is then started again from them with its observations replayed in one update, as
        the bootstrap's (the factors already in it were made with the old shape and offsets).
        Nothing is replayed that left the window: the batch holds it."""
        from mocapgraph.pipelines.aircap import resample

        start, cpu_start = time.perf_counter(), time.thread_time()
        self._resolve_at = None
        newest = self.t0 + (self.newest + _SNAP) * self.period
        frames = [f for f in self._kept if f.timestamp <= newest]
        self._kept = self._kept if self._keeping else []
        result = self._smartmocap_batch(frames, self.options.resolve_offset_rounds)
        placed = {c: key for c, key in self._static_keys.items() if self.rig.cameras[c].name in result.cameras and self.smoother.estimate.exists(key)}
        if len(placed) < 2:
            log.warning("online: the second bootstrap placed %d of the window's static cameras; two are needed to carry it over: not taken", len(placed))
            return
        loop = np.stack([self.smoother.estimate.atPose3(key).matrix() for key in placed.values()])
        batch = np.stack([result.cameras[self.rig.cameras[c].name].world_T_camera[0] for c in placed])

        def axes(T: np.ndarray) -> np.ndarray:
            return np.concatenate([T[:, :3, 3], T[:, :3, 3] + T[:, :3, 2]])  # centres, and a metre along each optical axis

        onto = umeyama(axes(batch), axes(loop), with_scale=False).apply_pose
        self.shape = np.asarray(result.shape, dtype=float)
        self._keypoint_offsets = {fmt: offsets_from_table(fmt, table) for fmt, table in result.parameters.get("keypoint_offsets_m", {}).items()}
        self._caches.clear()
        first = min(int(gtsam.Symbol(k).index()) for k in self.smoother.timestamps if chr(gtsam.Symbol(k).chr()) == "r")
        window = np.arange(first, self.newest + 1)
        est = resample(Estimate(onto(np.asarray(result.root)), result.pose, self.shape, []), np.asarray(result.timestamps), self.t0 + self.period * window)
        self._seed = {int(k): (est.roots[j], est.poses[j]) for j, k in enumerate(window)}
        for c in self._static_keys:
            pose = onto(result.cameras[self.rig.cameras[c].name].world_T_camera[0]) if c in placed else self.smoother.estimate.atPose3(self._static_keys[c]).matrix()
            self._seed_cameras[c] = {newest: pose}
        for name, track in result.cameras.items():
            c = self.index[name]
            if self.rig.cameras[c].moving:
                self._seed_cameras[c] = {float(t): T for t, T in zip(track.timestamps, onto(track.world_T_camera))}
        # a new window, the observations of its states replayed into it
        replay = [f for f in frames if self._grid(f.timestamp)[0] >= first]
        self.newest, self.open = first - 1, self.newest - 1
        self.smoother = self._new_smoother()
        self._frames = {c: {} for c in self._frames}
        self._replaying = True
        for frame in replay:
            self._add_observation(self.index[frame.camera], frame, *self._grid(frame.timestamp))
        self._flush()
        self._replaying = False
        self.stats.resolve_seconds = time.perf_counter() - start
        self.stats.resolve_cpu_seconds = time.thread_time() - cpu_start
        log.info("online: second bootstrap on %.2f s of stream (%d states replayed) in %.1f s", newest - self.t0, len(window), self.stats.resolve_seconds)

    def _measure_offsets(self) -> None:
        """The detector formats' keypoint-definition offsets measured again
        (:func:`~mocapgraph.graphs.keypoint_fit.estimate_offsets`, shrunk towards the format's
        fitted table or zero, as offline) on the states and camera frames that have left the
        window, their detections labelled as the loop relabelled them; the factors added from now
        on use them (those in the window keep the ones they were made with)."""
        start = time.perf_counter()
        last = max(self._left_states)
        frames = [f for f in self._kept if f.timestamp in self._left_frames[self.index[f.camera]] and f.timestamp <= self.t0 + (last + _SNAP) * self.period]
        mini = self._buffered_capture(frames)
        model = capture_state_model(mini, "grid", detectors=tuple(dict.fromkeys(f.detector for f in frames)), rate_hz=self.options.rate_hz)
        first = int(round((model.times[0] - self.t0) / self.period))
        states = [self._left_states.get(first + i) for i in range(model.num_states)]
        # a state that never left the window as a state (a solver reset's) has no estimate to measure on
        model = replace(model, states=[obs if state is not None else [] for obs, state in zip(model.states, states)])
        roots = np.stack([np.eye(4) if state is None else state[0] for state in states])
        poses = np.stack([np.zeros((NUM_JOINTS - 1, 3)) if state is None else state[1] for state in states])
        left = [self._left_frames[self.index[cam.name]] for cam in mini.cameras]
        cameras = [np.stack([kept[float(t)][0] for t in cam.timestamps]) for kept, cam in zip(left, mini.cameras)]
        codes = {c: np.array([kept[float(t)][1] for t in cam.timestamps]) for c, (kept, cam) in enumerate(zip(left, mini.cameras))}
        model = model.relabelled(codes)
        estimate = Estimate(roots, poses, self.shape, cameras)
        for fmt in model.formats:
            fit = estimate_offsets(self.body, model, estimate, fmt, prior_offsets(fmt))
            self._keypoint_offsets[fmt] = fit.offsets
            self._caches.pop(fmt, None)
        if not self._offset_times:
            self._kept = self._kept if self._keeping else []
            self._left_states = {}
            self._left_frames = {c: {} for c in self._left_frames}
        self.stats.offset_update_seconds.append(time.perf_counter() - start)
        log.info("online: keypoint offsets measured again on %d states (%.2f s of stream) in %.2f s", sum(s is not None for s in states), (last + 1) * self.period, self.stats.offset_update_seconds[-1])

    def _shape_prior(self) -> gtsam.PriorFactorVector:
        """The refined shape's prior at the published shape: ``graph.shape_prior_sigma`` along the
        shape directions that move the joints, stiff along the others.

        The directions are the rest joints' Jacobian's right singular vectors; those whose singular
        value is below ``_SHAPE_WEAK`` of the largest are held (Anny: muscle and weight move the
        joints by ~1 % of what age and height do; free, they drifted by a whole unit in 10 s of
        rich, fitting the keypoints' systematic errors along a direction linearised far outside
        the model's bounds)."""
        _, d_joints = self._cache("body").state_joints(np.eye(4), np.zeros(3 * (NUM_JOINTS - 1)), self.shape, True)
        _, values, vt = np.linalg.svd(d_joints.reshape(3 * NUM_JOINTS, -1)[:, 6 + 3 * (NUM_JOINTS - 1) :], full_matrices=False)
        sigmas = np.where(values >= _SHAPE_WEAK * values[0], self.options.graph.shape_prior_sigma, _SHAPE_HELD)
        return gtsam.PriorFactorVector(self._shape_key, self.shape, gtsam.noiseModel.Gaussian.Information(vt.T @ np.diag(sigmas**-2.0) @ vt))

    def _publish_shape(self, estimate: np.ndarray, exact: bool = False) -> None:
        """The refined shape estimate, within the model's bounds, becomes the published one when
        it moved more than ``_SHAPE_STEP`` (``exact``: whatever it moved)."""
        lo, hi = self.body.shape_bounds.T
        estimate = np.clip(estimate, lo, hi)
        if exact or np.abs(estimate - self.shape).max() > _SHAPE_STEP:
            self.shape = estimate

    def _vote_body_swaps(self) -> None:
        """``uav_body_swaps="minority"``: each UAV camera of the update sees the body flipped or
        not at the new states' prediction (its newest detection's labelling there); when more of
        the update's cameras see it flipped than not, none may relabel (the prediction is what is
        turned round). A tie (one camera of two, or a camera alone in its update) may relabel on
        the onboard estimate: nothing says the prediction is turned, and it cannot turn round in
        a grid interval, while a body held to a flipped view was dragged round (a camera alone:
        3.3 m and 75 deg off; one of two, with a UAV's onboard estimate out: lost, 2.5 m and 118
        deg off after the estimate returned); not where a flipped camera rests on the GPS/IMU
        fusion's prior, 1 m off, where such lone flips were not the detector's (aircap 10 s: 6 of
        6 not in the truth, MPJPE 0.98 -> 2.99 m; docs/online.md, "Ties in the vote")."""
        votes, self._body_votes = self._body_votes, []
        if not votes:
            return
        # a copy of the window (~60 keys) costs what a Values of each factor's own keys built in
        # Python does (aircap 10 s: 0.67 against 0.69 ms per update for ~3 votes): the votes' cost
        # is the factors' evaluation
        values = gtsam.Values(self.smoother.estimate)
        values.insert(self._pending_values)
        body = SWAP_KINDS.index("body")
        seen: dict[int, tuple[bool, bool]] = {}
        for c, labelling, factor, fused in votes:
            factor.error(values)  # sets labelling.choice at these values
            seen[c] = (bool(labelling.choice[0] == body), fused)
        flipped = sum(f for f, _ in seen.values())
        # one camera alone is a tie too: it against the prediction
        tie = len(seen) == 1 or 2 * flipped == len(seen)
        most = len(seen) > 1 and 2 * flipped > len(seen)
        if most or (flipped and tie and any(f and fused for f, fused in seen.values())):
            for _, labelling, _, _ in votes:
                self.stats.body_swaps_refused += int(labelling.choice[0] == body)
                labelling.allowed[0, body] = False

    def _hold_refined(self, now: float) -> None:
        """The static cameras refined for ``static_refine_s`` and the shape refined for
        ``shape_refine_s`` are held from now on at their estimate; their variables, no longer
        kept, leave the window with the states of their time (the factors already in the window
        stay on them)."""
        if self._shape_key is not None and self.options.shape_refine_s is not None:
            self._shape_since = now if self._shape_since is None else self._shape_since
            if now - self._shape_since >= self.options.shape_refine_s and self.smoother.estimate.exists(self._shape_key):
                self._publish_shape(self.smoother.estimate.atVector(self._shape_key), exact=True)
                self._shape_key = None
                log.info("online: shape held from %.1f s at its refined estimate", now)
        if self.options.static_refine_s is None:
            return
        for c in list(self._static_keys):
            # the bootstrap's replay starts its cameras' variables with frames from the stream's start
            if now - self._static_since.setdefault(c, now) < self.options.static_refine_s:
                continue
            key = self._static_keys.pop(c)
            if self.smoother.estimate.exists(key):
                self._fixed[c] = self.smoother.estimate.atPose3(key).matrix()
            else:
                self._fixed[c] = self._pending_values.atPose3(key).matrix()
            self._settle_static(c, self._fixed[c])
            log.info("online: camera %r held from %.1f s at its refined estimate", self.rig.cameras[c].name, now)

    def _settle_static(self, c: int, pose: np.ndarray) -> None:
        """A refined static camera is one variable: once it is held (or the stream ends) its smoothed
        pose, as a state's, is its last estimate, for every frame recorded so far (before, each frame
        kept the estimate of when it left the window: rich 10 s, the static cameras' smoothed MCPE
        10.6 / 13.3 / 12.3 -> 8.4 / 11.3 / 9.8 mm on seeds 0-2). The filtered track keeps each frame's
        pose as estimated at its time."""
        if self.record:
            for t in self.smoothed_cameras[c]:
                self.smoothed_cameras[c][t] = pose

    def _restart(self, error: RuntimeError, created: list[tuple[int, np.ndarray, np.ndarray]]) -> UpdateReport:
        """The smoother threw: its window is taken as smoothed as it is, the states this update
        created keep the tracker's prediction (flagged ``solver_reset``), and a new window starts
        from the newest of them, held near its prediction by a loose prior; this update's
        observations are not used (the stream goes on from the next interval)."""
        end = self.newest
        root, pose = (created[-1][1], created[-1][2]) if created else self._state_guess(end)
        log.warning("online: the smoother failed at %.2f s (%s); the window restarts from the prediction", self.t0 + end * self.period, str(error).strip().splitlines()[0])
        self.stats.solver_resets += 1
        old = self.smoother.estimate
        self._retire(old)
        # camera frames whose variables were in the failed update only
        for c, frames in self._frames.items():
            for t in [t for t, f in frames.items() if f.key is not None]:
                f = frames.pop(t)
                if self.record:
                    self.smoothed_cameras[c][t] = f.pose
                self._record_swaps(c, t, f)
        for k, root, pose in created:
            self._flagged["solver_reset"].add(k)
            self._recent[k] = (root, pose)
            if self.record:
                self.smoothed[k] = (root, pose, self.shape)
        self._offsets.clear()
        self.smoother = self._new_smoother()
        factors, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(root_key(end), gtsam.Pose3(root))
        values.insert(pose_key(end), pose.ravel())
        factors.add(gtsam.PriorFactorPose3(root_key(end), gtsam.Pose3(root), gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, 0.2), np.full(3, 0.2)])))
        factors.add(gtsam.PriorFactorVector(pose_key(end), pose.ravel(), gtsam.noiseModel.Isotropic.Sigma(pose.size, 0.3)))
        stamps = {root_key(end): self.t0 + end * self.period, pose_key(end): self.t0 + end * self.period}
        for c, key in self._static_keys.items():
            start = old.atPose3(key) if old.exists(key) else gtsam.Pose3(next(iter(self._seed_cameras[c].values())))
            values.insert(key, start)
            factors.add(gtsam.PriorFactorPose3(key, start, gtsam.noiseModel.Isotropic.Sigma(6, 0.01)))
            stamps[key] = stamps[root_key(end)]
        if self._shape_key is not None:
            # the new window's shape starts at the published one, as sure as the bootstrap's
            values.insert(self._shape_key, self.shape)
            factors.add(self._shape_prior())
            stamps[self._shape_key] = stamps[root_key(end)]
        self._pending, self._pending_values, self._pending_stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
        return self.smoother.update(factors, values, stamps)

    def _retire(self, left: gtsam.Values, everything: bool = False) -> None:
        """Record what left the window (states and camera frames; ``everything``: all of the
        window's, at the end of the stream) and forget it."""
        for key in left.keys():
            symbol = gtsam.Symbol(key)
            if chr(symbol.chr()) == "r":
                k = int(symbol.index())
                state = (left.atPose3(key).matrix(), left.atVector(pose_key(k)).reshape(NUM_JOINTS - 1, 3))
                self._recent[k] = state
                if self.record:
                    self.smoothed[k] = (*state, self.shape)
                if self._offset_times:
                    self._left_states[k] = state
                self._seed.pop(k, None)
        for k in [k for k in self._recent if k < self.newest - 8]:
            del self._recent[k]
        bound = np.inf if everything else self.smoother.newest - self.options.lag_s
        for c, frames in self._frames.items():
            for t in [t for t, f in frames.items() if t < bound or (f.key is not None and left.exists(f.key))]:
                f = frames.pop(t)
                if f.key is not None:
                    f.pose = (left if left.exists(f.key) else self.smoother.estimate).atPose3(f.key).matrix()
                if self.record and not f.no_prior:
                    self.smoothed_cameras[c][t] = f.pose
                code = self._record_swaps(c, t, f)
                if self._offset_times and not f.no_prior:
                    self._left_frames[c][t] = (f.pose, code)

    def _record_swaps(self, c: int, t: float, f: _Frame) -> int:
        """Count and record the relabelling the frame's detections took; returns its code (0: none)."""
        codes = [int(lab.choice[0]) for lab in f.labellings if len(lab.choice)]
        if not codes:
            return 0
        code = max(codes)
        self.stats.relabelled += int(code > 0)
        if self.record:
            self.swaps[c][t] = code
        return code

    # -- output ---------------------------------------------------------------------------------

    def state(self, updated: bool = False) -> OnlineState:
        """The newest state and every camera's newest pose."""
        if self.newest < 0:
            return OnlineState(None, None, updated=updated)
        root, pose = self._state_guess(self.newest)
        cameras = {}
        for c, frames in self._frames.items():
            if frames:
                cameras[self.rig.cameras[c].name] = frames[max(frames)].pose
        return OnlineState(self.newest, self.t0 + self.newest * self.period, root, pose, self.shape, cameras, updated)

    def covariances(self) -> dict[str, np.ndarray]:
        """Marginal covariances in the window: ``root (6, 6)`` and ``pose (63, 63)`` of the newest
        state, ``camera:<name> (6, 6)`` of every camera's newest frame variable (Pose3 tangents,
        rotation first)."""
        if self.newest < 0:
            raise MocapgraphError("covariances: no state yet (still bootstrapping)")
        out = {"root": self.smoother.marginal_covariance(root_key(self.newest)), "pose": self.smoother.marginal_covariance(pose_key(self.newest))}
        for c, frames in self._frames.items():
            keyed = [f for f in frames.values() if f.key is not None and self.smoother.holds(f.key)]
            if keyed:
                out[f"camera:{self.rig.cameras[c].name}"] = self.smoother.marginal_covariance(max(keyed, key=lambda f: f.time).key)
        return out

    def finish(self) -> None:
        """End of stream: close the open interval and take every state still in the window as smoothed."""
        if not self._bootstrapped and self._buffer:
            self._bootstrap()
        if self.open is None:
            return
        self._flush()
        self.open = None
        self._retire(self.smoother.estimate, everything=True)
        for c, key in self._static_keys.items():
            if self.smoother.estimate.exists(key):
                self._settle_static(c, self.smoother.estimate.atPose3(key).matrix())

    def results(self, capture_label: str = "", parameters: dict | None = None) -> tuple[Result, Result]:
        """``(filtered, smoothed)`` as results (after :meth:`finish`, with ``record``)."""
        if not self.record:
            raise MocapgraphError("results: the fusion was made with record=False; nothing was kept")
        if not self.smoothed:
            raise MocapgraphError("results: no body state was estimated (was the stream shorter than the bootstrap, or empty?)")
        params = {**options_parameters(self.options), **(parameters or {}), "rig": self.kind, "stats": self.stats.summary()}
        out = []
        for kind, states, cams in (("filtered", self.filtered, self.filtered_cameras), ("smoothed", self.smoothed, self.smoothed_cameras)):
            idx = np.array(sorted(states))
            roots = np.stack([states[i][0] for i in idx])
            poses = np.stack([states[i][1] for i in idx])
            shapes = np.stack([states[i][2] for i in idx])
            # each state with the shape published when it was recorded (the refined shape moves
            # in steps of _SHAPE_STEP: one body table per step)
            joints = np.empty((len(idx), NUM_JOINTS, 3))
            distinct, which = np.unique(shapes, axis=0, return_inverse=True)
            for u, shape in enumerate(distinct):
                sel = which.ravel() == u
                joints[sel] = self.body.forward(shape, roots[sel], poses[sel]).joints
            detections = np.array([self.detections.get(int(i), 0) for i in idx])
            result = Result(
                pipeline="online", capture=capture_label or self.rig.name, world_frame=self.world_frame, timestamps=self.t0 + idx * self.period,
                joints=joints, body_model=self.body.name, root=roots, pose=poses, shape=shapes[-1].copy(),
                flags={
                    "num_detections": detections, "unconstrained": detections == 0, "bootstrap": idx < self._bootstrap_states,
                    **{name: np.isin(idx, sorted(states_flagged)) for name, states_flagged in self._flagged.items()},
                },
                parameters={**params, "trajectory": kind},
            )  # fmt: skip
            for c, poses_c in cams.items():
                if poses_c:
                    ts = np.array(sorted(poses_c))
                    codes = np.array([self.swaps[c].get(float(t), 0) for t in ts], dtype=np.int8)
                    result.cameras[self.rig.cameras[c].name] = CameraTrack(ts, np.stack([poses_c[t] for t in ts]), codes)
            out.append(result)
        return out[0], out[1]


def _heading_apart_rad(a: Result, b: Result, seconds: float) -> float:
    """The median angle (radians) between the root orientations of ``a``'s states in its last
    ``seconds`` and of ``b``'s nearest in time (two batches of the same frames)."""
    last = np.asarray(a.timestamps) > a.timestamps[-1] - seconds - _SNAP
    near = np.abs(np.asarray(b.timestamps)[None] - np.asarray(a.timestamps)[last][:, None]).argmin(1)
    return float(np.median(relative_angle(a.root[last][:, :3, :3], b.root[near][:, :3, :3])))


@dataclass
class OnlineRun:
    """What :func:`run_online` returns: both trajectories and the stream's counters."""

    filtered: Result
    smoothed: Result
    stats: OnlineStats
    seconds: float


def run_online(
    capture: Capture, options: OnlineOptions | None = None, capture_label: str = "", *, realtime: bool = False,
    on_update: Callable[[OnlineFusion, OnlineState], None] | None = None,
) -> OnlineRun:  # fmt: skip
    """Replay ``capture`` as a stream (:func:`stream`) through an :class:`OnlineFusion`; with
    ``realtime``, at the capture's own rate (waiting for each frame's time). ``on_update`` is
    called after every observation (e.g. a live status line)."""
    options = options or OnlineOptions()
    fusion = OnlineFusion(static_rig(capture), options)
    start = time.perf_counter()
    first = None
    for frame in stream(capture, options.detector):
        if realtime:
            first = frame.timestamp if first is None else first
            wait = (frame.timestamp - first) - (time.perf_counter() - start)
            if wait > 0:
                time.sleep(wait)
        state = fusion.update(frame.camera, frame.timestamp, frame.keypoints, frame.box, frame.sensors, frame.detector)
        if on_update is not None:
            on_update(fusion, state)
    fusion.finish()
    seconds = time.perf_counter() - start
    filtered, smoothed = fusion.results(capture_label, {"seconds": round(seconds, 3)})
    return OnlineRun(filtered, smoothed, fusion.stats, seconds)


_SOURCE_NAMES = {
    "self_pose": "the onboard estimate", "fused": "the GPS/IMU fusion", "calibration": "its calibration", "bootstrap": "the bootstrap's estimate",
    "body": "the body (no prior)", "none": "nothing (not used)",
}  # fmt: skip


def summary(run: OnlineRun) -> str:
    """The lines ``run online`` prints at the end."""
    s = run.stats.summary()
    lat = s["latency_ms"]
    return (
        f"online ({run.smoothed.parameters['rig']}): {len(run.smoothed.timestamps)} body states in {run.seconds:.1f} s "
        f"(bootstrap {s['bootstrap_s']:.1f} s); {s['updates']} updates, {s['updates_per_s']} updates/s, latency p50 {lat['p50']} ms, "
        f"p95 {lat['p95']} ms, max {lat['max']} ms (wall clock); CPU {s['updates_per_cpu_s']} updates/s, p50 {s['latency_cpu_ms']['p50']} ms, "
        f"p95 {s['latency_cpu_ms']['p95']} ms\n"
        f"  observations {s['observations']}: used {s['used']} (late {s['late_used']}), dropped late {s['late_dropped']}, "
        f"gated {s['gated']}, unplaced {s['unplaced']}, empty {s['empty']}; relabelled {s['relabelled']}"
    ) + "".join(
        f"\n  camera {name}: " + ", ".join(f"{n} frames on {_SOURCE_NAMES[source]}" for source, n in counts.items()) for name, counts in s["camera_priors"].items()
    ) + (f"\n  {s['coasting']} frames on a fusion coasting on the IMU (no GPS fix), {s['no_prior']} without a prior" if s["coasting"] or s["no_prior"] else "")
