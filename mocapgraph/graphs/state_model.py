"""The one state model every pipeline builds from: observations, body states, camera variables.

A keypoint reaches a factor by one road: a pipeline hands :func:`build_state_model` each
camera's raw detections (:class:`CameraDetections`, pixels of the distorted image); they are
undistorted once, here, into the ideal pinhole image that the reprojection factor models, and
become :class:`Observation` s of the body state the camera frame belongs to under a
synchronisation policy (:mod:`mocapgraph.graphs.sync`).

Variables (keys from :mod:`mocapgraph.factors.keys`):

- body state ``i``: ``root_key(i)`` (world_T_root) and ``pose_key(i)`` (21 axis-angle joints),
  at ``times[i]``; one ``shape_key()`` for the sequence;
- a **static** camera: one pose ``camera_key(c, 0)`` for the whole capture;
- a **moving** camera: a pose ``camera_key(c, j)`` per frame ``j`` that belongs to a state.

:class:`Estimate` carries a solution as arrays between solves, processes and Ray tasks (it
pickles without GTSAM objects); :class:`~mocapgraph.graphs.body_graph.BodyGraph` turns a
model into factors.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import SWAP_KINDS, swap_permutation
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES, NUM_JOINTS
from mocapgraph.data_tools.geometry.camera_model import undistort_pixels
from mocapgraph.data_tools.geometry.timing import match_times
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.keys import camera_key
from mocapgraph.graphs.sync import SYNC_POLICIES, timeline


@dataclass(frozen=True)
class CameraInfo:
    """What the graphs know of a camera.

    Attributes:
        name: for messages and results.
        K: ``(3, 3)`` intrinsics; the observations are undistorted into the pinhole image of this K.
        moving: a pose per frame (True) or one for the capture (False).
        timestamps: ``(F,)`` seconds of its frames, increasing.
        frame_rate: Hz (``"closest"`` pairs frames within half a period).
        focal_guessed: ``K``'s focal length is a guess (no calibration), not a measurement.
    """

    name: str
    K: np.ndarray
    moving: bool
    timestamps: np.ndarray
    frame_rate: float
    focal_guessed: bool = False

    @property
    def intrinsics(self) -> np.ndarray:
        """``(4,)`` fx, fy, cx, cy in pixels, as the reprojection factor takes them."""
        return np.array([self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]])


@dataclass
class CameraDetections:
    """One detector's keypoints in one camera, as loaded.

    Attributes:
        camera: index into the model's cameras.
        detector: its name; fmt: its keypoint format (``coco17``, …).
        keypoints: ``(F, K, 3)`` pixels of the distorted image and confidences, NaN where missing.
        distortion: OpenCV coefficients of the camera (None or zeros: an ideal pinhole).
        gate: ``(F, K)`` or ``(F,)`` multipliers of the confidences (e.g. a tracker's inliers), or None.
    """

    camera: int
    detector: str
    fmt: str
    keypoints: np.ndarray
    distortion: np.ndarray | None = None
    gate: np.ndarray | None = None


@dataclass
class Observation:
    """One detector's keypoints of one camera frame, ready for a reprojection factor.

    Attributes:
        camera, frame: which camera frame.
        fmt: keypoint format.
        observed: ``(K, 2)`` pixels of the ideal pinhole image, NaN where missing.
        weights: ``(K,)`` confidences (gated), 0 where missing.
        fraction: where the frame lies between its state (0) and the next (``"grid"``).
    """

    camera: int
    frame: int
    fmt: str
    observed: np.ndarray
    weights: np.ndarray
    fraction: float = 0.0

    @property
    def count(self) -> int:
        return int((self.weights > 0).sum())


@dataclass
class StateModel:
    """Body states on a time line, the cameras, and each state's observations.

    Attributes:
        cameras: per camera of the capture (indices as the capture's).
        times: ``(N,)`` seconds of the body states.
        frame_state: per camera, ``(F_c,)`` the state each frame belongs to (-1: none).
        frame_fraction: per camera, ``(F_c,)`` the frame's place towards the next state.
        states: per state, its observations.
        sync: the policy that made the time line.
    """

    cameras: list[CameraInfo]
    times: np.ndarray
    frame_state: list[np.ndarray]
    frame_fraction: list[np.ndarray]
    states: list[list[Observation]]
    sync: str

    @property
    def num_states(self) -> int:
        return len(self.times)

    @property
    def num_cameras(self) -> int:
        return len(self.cameras)

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    @property
    def formats(self) -> list[str]:
        """Keypoint formats of the observations, in order of first appearance."""
        return list(dict.fromkeys(o.fmt for obs in self.states for o in obs))

    def observed_cameras(self) -> list[int]:
        """Cameras with at least one observation, in index order."""
        return sorted({o.camera for obs in self.states for o in obs})

    def camera_frames(self, c: int, states: range | None = None) -> np.ndarray:
        """``(M,)`` camera ``c``'s frames that belong to a state (of ``states``, default all), in order."""
        s = self.frame_state[c]
        keep = s >= 0 if states is None else (s >= states.start) & (s < states.stop)
        return np.flatnonzero(keep)

    def frame_time(self, c: int, j: int) -> float:
        """Where frame ``j`` of camera ``c`` sits on the state time line (its own time under
        ``"grid"`` and ``"states"``, its state's under ``"closest"``)."""
        i, a = int(self.frame_state[c][j]), float(self.frame_fraction[c][j])
        return float(self.times[i] + a * (self.times[i + 1] - self.times[i])) if a else float(self.times[i])

    def frames_from_states(self, c: int, per_state: np.ndarray) -> np.ndarray:
        """``(F_c, …)``: a per-state array ``(N, …)`` of camera ``c`` spread to its frames, each
        frame taking its state's entry, a frame of no state the entry of the state nearest in time."""
        nearest = match_times(self.times, self.cameras[c].timestamps, tolerance=np.inf)
        state = np.where(self.frame_state[c] >= 0, self.frame_state[c], nearest)
        return np.asarray(per_state)[state]

    def camera_var(self, c: int, j: int) -> int:
        """The pose key of camera ``c`` at its frame ``j``."""
        return camera_key(c, int(j)) if self.cameras[c].moving else camera_key(c, 0)

    def camera_matrices(self) -> list[np.ndarray]:
        return [c.K for c in self.cameras]

    def detections_per_state(self) -> np.ndarray:
        """``(N,)`` keypoints constraining each state: its own, plus those interpolated from the
        previous state towards it (``"grid"``)."""
        own = np.array([sum(o.count for o in obs) for obs in self.states], dtype=int)
        incoming = np.zeros_like(own)
        incoming[1:] = [sum(o.count for o in obs if o.fraction > 0) for obs in self.states[:-1]]
        return own + incoming

    def keypoint_weight(self) -> np.ndarray:
        """``(N,)`` the sum of the keypoints' confidences over all views at each state."""
        return np.array([sum(float(o.weights.sum()) for o in obs) for obs in self.states])

    def view_keypoints(self, c: int) -> tuple[np.ndarray, str] | None:
        """``(N, K, 3)`` camera ``c``'s undistorted keypoints and confidences at every state
        (NaN where it has no observation) of its first format, and that format; None when the
        camera has no observation at all."""
        fmt = next((o.fmt for obs in self.states for o in obs if o.camera == c), None)
        if fmt is None:
            return None
        K = next(len(o.observed) for obs in self.states for o in obs if o.camera == c and o.fmt == fmt)
        out = np.full((self.num_states, K, 3), np.nan)
        for i, obs in enumerate(self.states):
            for o in obs:
                if o.camera == c and o.fmt == fmt:
                    out[i, :, :2] = o.observed
                    out[i, :, 2] = np.where(o.weights > 0, o.weights, np.nan)
        return out, fmt

    def select(self, indices) -> StateModel:
        """The states ``indices`` (increasing), renumbered from 0. A frame interpolated towards
        a state that is not kept loses that observation (it would need the missing state)."""
        idx = np.asarray(indices, dtype=int)
        new = np.full(self.num_states, -1, dtype=int)
        new[idx] = np.arange(len(idx))
        follows = np.zeros(self.num_states, dtype=bool)
        follows[idx[:-1][np.diff(idx) == 1]] = True
        states = [[o for o in self.states[i] if o.fraction == 0 or follows[i]] for i in idx]
        frame_state, frame_fraction = [], []
        for s, a in zip(self.frame_state, self.frame_fraction):
            keep = (s >= 0) & (new[np.maximum(s, 0)] >= 0) & ((a == 0) | follows[np.maximum(s, 0)])
            frame_state.append(np.where(keep, new[np.maximum(s, 0)], -1))
            frame_fraction.append(np.where(keep, a, 0.0))
        return replace(self, times=self.times[idx], frame_state=frame_state, frame_fraction=frame_fraction, states=states)

    def span(self, start: int, stop: int) -> StateModel:
        """The states ``[start, stop)``, renumbered from 0."""
        return self.select(np.arange(start, stop))

    def only(self, cameras) -> StateModel:
        """Without the frames and observations of the cameras not in ``cameras`` (a bool per camera)."""
        keep = np.asarray(cameras, dtype=bool)
        states = [[o for o in obs if keep[o.camera]] for obs in self.states]
        frame_state = [s if keep[c] else np.full_like(s, -1) for c, s in enumerate(self.frame_state)]
        return replace(self, frame_state=frame_state, states=states)

    def relabelled(self, codes: dict[int, np.ndarray]) -> StateModel:
        """The same model with camera ``c``'s observation at frame ``j`` relabelled by the swap
        ``SWAP_KINDS[codes[c][j]]`` (:mod:`mocapgraph.body.labelling`; 0 or -1: as it is)."""
        states = []
        for obs in self.states:
            out = []
            for o in obs:
                code = int(codes[o.camera][o.frame]) if o.camera in codes else 0
                if code > 0:
                    names = BODY_KEYPOINT_NAMES if o.fmt == "body" else get_format(o.fmt).names
                    perm = swap_permutation(names, SWAP_KINDS[code])
                    o = replace(o, observed=o.observed[perm], weights=o.weights[perm])
                out.append(o)
            states.append(out)
        return replace(self, states=states)

    def without(self, views: dict[int, np.ndarray]) -> StateModel:
        """The same model without the observations of camera ``c`` at its frames ``views[c]``
        (the frames keep their states, so a camera's variables stay where they were)."""
        drop = {(c, int(j)) for c, frames in views.items() for j in frames}
        return replace(self, states=[[o for o in obs if (o.camera, o.frame) not in drop] for obs in self.states])

    def with_moving(self, moving) -> StateModel:
        """The same model with camera ``c`` moving where ``moving[c]``."""
        return replace(self, cameras=[replace(cam, moving=bool(m)) for cam, m in zip(self.cameras, moving)])


def undistorted_keypoints(keypoints: np.ndarray, K: np.ndarray, distortion, where: str) -> tuple[np.ndarray, np.ndarray]:
    """``(..., K, 2)`` pixels of the ideal pinhole image and ``(..., K)`` confidences (0 where
    missing) of detected keypoints ``(..., K, 3)`` (distorted pixels and confidences, NaN where
    missing); ``where`` names the source in the error a negative confidence raises."""
    pixels = keypoints[..., :2] if distortion is None else undistort_pixels(keypoints[..., :2], K, distortion)
    weights = np.where(np.isfinite(pixels).all(-1), np.nan_to_num(keypoints[..., 2], nan=0.0), 0.0)
    if np.any(weights < 0):
        raise MocapgraphError(f"{where}: confidences must be >= 0")
    return pixels, weights


def _observations(det: CameraDetections, camera: CameraInfo) -> tuple[np.ndarray, np.ndarray]:
    """``(F, K, 2)`` undistorted pixels and ``(F, K)`` gated confidences of one detector."""
    kp = np.asarray(det.keypoints, dtype=float)
    F = len(camera.timestamps)
    if kp.ndim != 3 or kp.shape[0] != F or kp.shape[2] != 3:
        raise MocapgraphError(f"camera {camera.name!r}: detector {det.detector!r}: keypoints must be ({F}, K, 3), got {kp.shape}")
    pixels, weights = undistorted_keypoints(kp, camera.K, det.distortion, f"camera {camera.name!r}: detector {det.detector!r}")
    if det.gate is not None:
        gate = np.asarray(det.gate, dtype=float)
        weights = weights * (gate[:, None] if gate.ndim == 1 else gate)
    return pixels, weights


def build_state_model(
    cameras: list[CameraInfo],
    detections: list[CameraDetections],
    sync: str = "grid",
    *,
    reference: int = 0,
    rate_hz: float = 30.0,
    merge_s: float = 2e-3,
) -> StateModel:
    """Observations of every detection on the body states of the ``sync`` policy.

    Every camera's frames place the states (:func:`~mocapgraph.graphs.sync.timeline`); a frame
    with no usable point of a detector adds no observation of it. ``reference``: the camera whose
    frames are the states under ``"closest"``.
    """
    if sync not in SYNC_POLICIES:
        raise MocapgraphError(f"sync {sync!r}: choose one of {', '.join(SYNC_POLICIES)}")
    line = timeline(
        [c.timestamps for c in cameras], sync, frame_rates=[c.frame_rate for c in cameras], reference=reference,
        merge_s=merge_s, rate_hz=rate_hz,
    )  # fmt: skip
    states: list[list[Observation]] = [[] for _ in line.times]
    for det in detections:
        pixels, weights = _observations(det, cameras[det.camera])
        state, fraction = line.state[det.camera], line.fraction[det.camera]
        for j in np.flatnonzero((state >= 0) & (weights > 0).any(axis=1)):
            states[state[j]].append(Observation(det.camera, int(j), det.fmt, pixels[j], weights[j], float(fraction[j])))
    for obs in states:
        obs.sort(key=lambda o: (o.camera, o.frame))
    return StateModel(cameras, line.times, line.state, line.fraction, states, sync)


@dataclass
class Estimate:
    """Body states and cameras of a solve, as arrays.

    Attributes:
        roots: ``(N, 4, 4)`` world_T_root; poses: ``(N, 21, 3)`` axis-angle; shape: ``(S,)``.
        cameras: per camera ``(F_c, 4, 4)`` world_T_camera at every frame (a static camera's the
            same at all; frames no solve touched keep their initial value).
        log: rows of the solver's log.
        focal_log: ``(C,)`` per camera, the log of its focal length's ratio to the model's ``K``
            (0: as given; see :func:`~mocapgraph.factors.keys.focal_key`).
    """

    roots: np.ndarray
    poses: np.ndarray
    shape: np.ndarray
    cameras: list[np.ndarray]
    log: list[dict] = field(default_factory=list)
    focal_log: np.ndarray | None = None

    def __post_init__(self):
        if self.focal_log is None:
            self.focal_log = np.zeros(len(self.cameras))

    def span(self, start: int, stop: int) -> Estimate:
        """The body states ``[start, stop)`` (cameras copied whole: they are indexed by frame)."""
        return Estimate(
            self.roots[start:stop].copy(), self.poses[start:stop].copy(), self.shape.copy(), [c.copy() for c in self.cameras], focal_log=self.focal_log.copy()
        )

    def transformed(self, A: np.ndarray) -> Estimate:
        """Everything moved by the rigid ``A (4, 4)`` (new world ← old world)."""
        return Estimate(A @ self.roots, self.poses.copy(), self.shape.copy(), [A @ c for c in self.cameras], list(self.log), self.focal_log.copy())

    @property
    def pose_vectors(self) -> np.ndarray:
        """``(N, 63)`` the joint rotations as the graphs' pose variables."""
        return self.poses.reshape(len(self.poses), 3 * (NUM_JOINTS - 1))
