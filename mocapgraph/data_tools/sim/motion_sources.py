"""Ground-truth body motion for synthetic scenes: procedural motions and retargeted CMU takes.

Every source returns a :class:`Motion`: root poses ``world_T_root (T, 4, 4)`` in the Z-up world
(metres), local joint rotations ``(T, 21, 3)`` and a shape vector for one body model, sampled at
``timestamps`` (seconds from 0). ``Motion.sample`` interpolates at arbitrary times.

- :func:`procedural_motion` builds walks, turns, arm actions, AirCap's zigzag-then-act scenario and
  a near-still stand from gait curves, with no data files. The feet touch the floor z = 0 in every
  frame and the body faces where it walks.
- :func:`cmu_motion` retargets a CMU take (``shared/motion/cmu_train``) onto the body with a shape
  fitted to the take's bone lengths (:func:`fit_shape_to_bone_lengths`) and puts its feet on z = 0.

See ``docs/motion-sources.md``.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import axis_rotation, matrix_to_rotvec, rotvec_to_matrix
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES, JOINT_NAMES, NUM_JOINTS
from mocapgraph.data_tools.sim.cmu_motion import CMUTake, load_cmu_take, retarget
from mocapgraph.data_tools.sim.cmu_motion import motion_dir as default_motion_dir
from mocapgraph.errors import MocapgraphError, as_checked_array

# Times this close outside a motion's range are clamped to it rather than refused (seconds).
TIME_TOLERANCE = 1e-6

FOOT_KEYPOINTS = np.array(
    [BODY_KEYPOINT_NAMES.index(f"{side}_{part}") for side in ("left", "right")
     for part in ("ankle", "big_toe", "small_toe", "heel")]
)  # fmt: skip


# --------------------------------------------------------------------------------------------
# The Motion container
# --------------------------------------------------------------------------------------------


@dataclass
class Motion:
    """A body motion sampled at ``timestamps``.

    Attributes:
        body_model: name of the body model the pose and shape belong to (``BodyModel.name``).
        fps: nominal frame rate.
        timestamps: ``(T,)`` seconds, strictly increasing, starting at 0.
        root: ``(T, 4, 4)`` ``world_T_root`` in the Z-up world; translation = pelvis position.
        pose: ``(T, 21, 3)`` local axis-angle of joints 1…21.
        shape: ``(S,)`` shape vector of the body model.
        source: human-readable description of where the motion came from.
        info: source-specific extras (e.g. the bone-length fit of a CMU take).
    """

    body_model: str
    fps: float
    timestamps: np.ndarray
    root: np.ndarray
    pose: np.ndarray
    shape: np.ndarray
    source: str
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        self.timestamps = as_checked_array(self.timestamps, "motion timestamps", (None,))
        T = len(self.timestamps)
        if T == 0:
            raise MocapgraphError("motion timestamps: a motion needs at least one frame")
        if np.any(np.diff(self.timestamps) <= 0):
            raise MocapgraphError("motion timestamps: must be strictly increasing")
        self.root = as_checked_array(self.root, "motion root poses world_T_root", (T, 4, 4))
        self.pose = as_checked_array(self.pose, "motion joint rotations", (T, NUM_JOINTS - 1, 3))
        self.shape = as_checked_array(self.shape, "motion shape vector", (None,))
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise MocapgraphError(f"motion fps: must be positive, got {self.fps}")

    @property
    def num_frames(self) -> int:
        return len(self.timestamps)

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return float(self.timestamps[-1] - self.timestamps[0])

    def sample(self, times) -> tuple[np.ndarray, np.ndarray]:
        """``root (N, 4, 4)`` and ``pose (N, 21, 3)`` at ``times (N,)`` seconds.

        Translation is interpolated linearly; the root rotation and every joint's local rotation
        follow the geodesic (slerp) between the neighbouring frames. Times at a frame give that
        frame exactly. Times outside ``[timestamps[0], timestamps[-1]]`` by more than
        ``TIME_TOLERANCE`` are an error.
        """
        times = as_checked_array(np.atleast_1d(np.asarray(times, dtype=float)), "sample times", (None,))
        ts = self.timestamps
        lo, hi = ts[0], ts[-1]
        outside = (times < lo - TIME_TOLERANCE) | (times > hi + TIME_TOLERANCE)
        if np.any(outside):
            bad = float(times[np.argmax(outside)])
            raise MocapgraphError(
                f"sample time {bad:.6g} s is outside the motion's range [{lo:.6g}, {hi:.6g}] s "
                f"({self.source})"
            )
        times = np.clip(times, lo, hi)
        if len(ts) == 1:
            return np.repeat(self.root, len(times), 0), np.repeat(self.pose, len(times), 0)
        i0 = np.clip(np.searchsorted(ts, times, side="right") - 1, 0, len(ts) - 2)
        i1 = i0 + 1
        f = np.clip((times - ts[i0]) / (ts[i1] - ts[i0]), 0.0, 1.0)

        root = np.tile(np.eye(4), (len(times), 1, 1))
        root[:, :3, 3] = (1 - f)[:, None] * self.root[i0, :3, 3] + f[:, None] * self.root[i1, :3, 3]
        root[:, :3, :3] = _geodesic(self.root[i0, :3, :3], self.root[i1, :3, :3], f)
        local0, local1 = rotvec_to_matrix(self.pose[i0]), rotvec_to_matrix(self.pose[i1])
        pose = matrix_to_rotvec(_geodesic(local0, local1, np.repeat(f[:, None], NUM_JOINTS - 1, 1)))
        # Frames hit exactly are returned as stored (no round trip through matrices).
        at0, at1 = f == 0.0, f == 1.0
        root[at0], pose[at0] = self.root[i0[at0]], self.pose[i0[at0]]
        root[at1], pose[at1] = self.root[i1[at1]], self.pose[i1[at1]]
        return root, pose

    def _check_body(self, body: BodyModel) -> None:
        if body.name != self.body_model:
            raise MocapgraphError(
                f"this motion is for the {self.body_model!r} body model, not {body.name!r}"
            )

    def joints(self, body: BodyModel) -> np.ndarray:
        """``(T, 22, 3)`` world joint positions by ``body.forward``."""
        self._check_body(body)
        return body.forward(self.shape, self.root, self.pose).joints

    def keypoints(self, body: BodyModel, keypoints: str = "body") -> np.ndarray:
        """``(T, K, 3)`` world keypoints (body keypoints or a detector format of the registry)."""
        self._check_body(body)
        return body.forward(self.shape, self.root, self.pose, keypoints=keypoints).keypoints


def _geodesic(Ra: np.ndarray, Rb: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``Ra · Exp(f · Log(Raᵀ Rb))``: the point at fraction ``f`` on the geodesic from Ra to Rb."""
    delta = matrix_to_rotvec(np.swapaxes(Ra, -1, -2) @ Rb)
    return Ra @ rotvec_to_matrix(f[..., None] * delta)


def _resolve_body(body: BodyModel | None) -> BodyModel:
    if body is not None:
        return body
    from mocapgraph.body import load_body_model

    return load_body_model()


# --------------------------------------------------------------------------------------------
# Procedural motions
# --------------------------------------------------------------------------------------------

PROCEDURAL_KINDS = ("walk", "turn", "arms", "zigzag_then_act", "stand")

WALK_SPEED = 1.3  # m/s, nominal straight walk (and the zigzag's legs)
CIRCLE_SPEED = 1.0  # m/s, walking on a circle
STRIDE_HZ = 0.95  # strides (two steps) per second
TURN_RATE = np.deg2rad(60.0)  # rad/s, turning on the spot
_SUBSTEP_HZ = 240.0  # internal rate of the generator (the root is integrated at this rate)

# Sagittal joint angles over one gait cycle (degrees; phase 0 = heel strike of that leg, stance
# until 0.6), after the normal-gait curves of the biomechanics literature (Winter, Perry). "hip" is
# the thigh against the vertical, "ankle" is positive in dorsiflexion (toes up).
_GAIT_TABLE = {
    "hip": ([0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.55, 0.6, 0.7, 0.8, 0.87, 0.95],
            [22, 20, 13, 4, -5, -13, -15, -12, 3, 20, 25, 23]),
    "knee": ([0, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.75, 0.8, 0.85, 0.9, 0.95],
             [3, 15, 18, 16, 9, 5, 10, 37, 60, 62, 56, 43, 24, 8]),
    "ankle": ([0, 0.07, 0.15, 0.3, 0.45, 0.52, 0.6, 0.65, 0.7, 0.78, 0.85, 0.92],
              [0, -6, 0, 6, 10, 6, -12, -17, -7, 2, 3, 2]),
}  # fmt: skip
_GAIT_SPLINES: dict = {}

# Arm actions: target (abduction, flexion, elbow forward bend, elbow upward bend) in degrees for
# the acting arm(s). Abduction is measured from hanging down (90 = T-pose), flexion swings the arm
# forward. A wave's upward elbow bend oscillates around its target.
_ARM_TARGETS = {
    "raise": (165.0, 10.0, 5.0, 0.0),
    "wave": (100.0, 10.0, 0.0, 70.0),
    "reach": (20.0, 85.0, 5.0, 0.0),
    "out": (90.0, 0.0, 0.0, 0.0),
}
_ARM_ACTIONS = ("raise_both", "raise_left", "raise_right", "wave_left", "wave_right",
                "reach_left", "reach_right", "reach_both", "out_both")  # fmt: skip


def _gait_curve(name: str, phase: np.ndarray) -> np.ndarray:
    """Joint angle (radians) of the gait table at ``phase`` (cycles; any real number)."""
    if name not in _GAIT_SPLINES:
        from scipy.interpolate import CubicSpline

        x, y = _GAIT_TABLE[name]
        _GAIT_SPLINES[name] = CubicSpline(np.r_[x, 1.0], np.deg2rad(np.r_[y, y[0]]), bc_type="periodic")
    return _GAIT_SPLINES[name](np.mod(phase, 1.0))


def _smoothstep(x: np.ndarray) -> np.ndarray:
    """0 below 0, 1 above 1, C¹ cubic in between."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _window(t: np.ndarray, start: float, end: float, ramp: float) -> np.ndarray:
    """1 inside ``[start, end]`` with smooth ramps of ``ramp`` seconds inside its ends, 0 outside."""
    if end <= start:
        return np.zeros_like(t)
    ramp = max(min(ramp, 0.5 * (end - start)), 1e-6)
    return _smoothstep((t - start) / ramp) * _smoothstep((end - t) / ramp)


def _integrate(rate: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Cumulative trapezoid integral of ``rate`` over ``t``, starting at 0."""
    out = np.zeros_like(rate)
    if len(t) > 1:
        out[1:] = np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))
    return out


@dataclass
class _Style:
    """Per-seed variation of the generator."""

    stride_hz: float
    phase0: float
    amp: np.ndarray  # scales of hip, knee, ankle, arm swing, pelvis motion, trunk lean
    sway_amp: np.ndarray  # relative amplitudes of the standing sway (sideways, forward)
    sway_hz: np.ndarray
    sway_phase: np.ndarray

    @classmethod
    def sample(cls, rng: np.random.Generator) -> "_Style":
        return cls(
            stride_hz=STRIDE_HZ * (1 + 0.04 * rng.uniform(-1, 1)),
            phase0=rng.uniform(0, 1),
            amp=1 + 0.08 * rng.uniform(-1, 1, size=6),
            sway_amp=np.array([rng.uniform(0.7, 1.0), rng.uniform(0.4, 0.7)]),
            sway_hz=rng.uniform(0.15, 0.35, 2),
            sway_phase=rng.uniform(0, 2 * np.pi, 2),
        )


@dataclass
class _Plan:
    """Time series (T,) that drive the generator."""

    heading: np.ndarray  # facing direction, radians from world +X towards +Y
    speed: np.ndarray  # wanted walking speed, m/s
    stepping: np.ndarray  # 0..1, stepping on the spot (while turning in place)
    actions: list = field(default_factory=list)  # (name, start, end) arm actions
    sway: float = 0.0  # amplitude (m) of the slow standing sway


def _plan(kind: str, t: np.ndarray, duration: float, rng: np.random.Generator) -> _Plan:
    """Heading, speed, stepping and arm actions of one of :data:`PROCEDURAL_KINDS`."""
    T = len(t)
    zeros = np.zeros(T)
    if kind == "walk":
        return _Plan(zeros, np.full(T, WALK_SPEED * (1 + 0.04 * rng.uniform(-1, 1))), zeros)
    if kind == "stand":
        return _Plan(zeros, zeros, zeros, sway=0.008)
    if kind == "arms":
        return _Plan(zeros, zeros, zeros, actions=_schedule_actions(rng, 0.3, duration - 0.2), sway=0.004)
    sign = float(rng.choice([-1.0, 1.0]))
    if kind == "turn":
        # A circle for 65 % of the time, then stop and keep turning on the spot.
        radius = rng.uniform(1.6, 2.4)
        walk_end = 0.65 * duration
        speed = CIRCLE_SPEED * (1 + 0.04 * rng.uniform(-1, 1)) * (1 - _smoothstep((t - walk_end + 0.6) / 0.6))
        on_the_spot = _smoothstep((t - walk_end) / 0.5)
        heading = _integrate(sign * (speed / radius + on_the_spot * TURN_RATE), t)
        return _Plan(heading, speed, on_the_spot * _window(t, 0.0, duration, 0.3))
    # zigzag_then_act: legs of about 2 s at ±(30..40)° about +X for 60 % of the time, stop, then
    # arm actions, a turn on the spot (90..150°, the other way than the first leg), more actions.
    walk_end = 0.6 * duration
    legs = max(3, int(round(walk_end / 2.0)))
    angle = np.deg2rad(rng.uniform(30, 40))
    heading = np.full(T, sign * angle)
    ramp = min(0.7, 0.4 * walk_end / legs)
    for i in range(1, legs):
        boundary = walk_end * i / legs
        heading -= sign * (-1) ** (i + 1) * 2 * angle * _smoothstep((t - boundary + ramp / 2) / ramp)
    stop_ramp = min(0.7, 0.5 * walk_end / legs)
    stop = _smoothstep((t - walk_end + stop_ramp) / stop_ramp)
    speed = WALK_SPEED * (1 + 0.04 * rng.uniform(-1, 1)) * (1 - stop)
    act_start, act_end = walk_end + 0.2, duration - 0.1
    act = act_end - act_start
    turn_start, turn_end = act_start + 0.35 * act, act_end - 0.35 * act
    turn_angle = -sign * np.deg2rad(rng.uniform(90, 150))
    heading = heading + turn_angle * _smoothstep((t - turn_start) / max(turn_end - turn_start, 1e-6))
    stepping = _window(t, turn_start - 0.1, turn_end + 0.1, 0.3)
    actions = _schedule_actions(rng, act_start, turn_start - 0.1)
    actions += _schedule_actions(rng, turn_end + 0.1, act_end)
    return _Plan(heading, speed, stepping, actions=actions, sway=0.004)


def _schedule_actions(rng: np.random.Generator, start: float, end: float) -> list:
    """Random arm actions of 1.6–2.6 s with short rests filling ``[start, end]`` (at least one
    action when the interval is 0.8 s or longer)."""
    actions, now = [], start
    while end - now >= 0.8:
        length = min(rng.uniform(1.6, 2.6), end - now)
        actions.append((str(rng.choice(_ARM_ACTIONS)), now, now + length))
        now += length + rng.uniform(0.2, 0.6)
    return actions


def _mirror(rotvec: np.ndarray) -> np.ndarray:
    """The left↔right mirror (x → −x) of a local rotation: ``(x, y, z) → (x, −y, −z)``."""
    return rotvec * np.array([1.0, -1.0, -1.0])


def _build_pose(t, heading, gait, stepping, actions, sway, style: _Style):
    """Local pose ``(T, 21, 3)``, root rotation ``(T, 3, 3)`` and a small sway offset ``(T, 3)``
    of the root in its heading frame (x left, z forward)."""
    T = len(t)
    amp, a = style.amp, gait
    pose = np.zeros((T, NUM_JOINTS - 1, 3))
    j = {name: JOINT_NAMES.index(name) - 1 for name in JOINT_NAMES[1:]}
    p_left = style.phase0 + style.stride_hz * t
    phases = {"left": p_left, "right": p_left + 0.5}
    adduction = np.full(T, np.deg2rad(3.0))  # feet under the body (the rest legs splay out)
    same = lambda x: x  # noqa: E731

    hip = {}
    for side, p in phases.items():
        # Stepping on the spot: each foot lifts straight up in the second half of its cycle.
        lift = stepping * np.deg2rad(50.0) * np.maximum(-np.sin(2 * np.pi * p), 0.0) ** 2
        # Slow steps still lift the swinging leg (hip and knee) enough for the foot to clear the
        # floor: in swing the amplitude falls off only as the square root of ``a``.
        q = np.mod(p, 1.0)
        swing = _smoothstep((q - 0.5) / 0.12) * _smoothstep((1.0 - q) / 0.12)
        lifted = (1 - swing) * a + swing * np.sqrt(np.minimum(a, 1.0)) * np.maximum(a, 1.0)
        hip[side] = lifted * amp[0] * _gait_curve("hip", p) + 0.5 * lift
        knee = lifted * amp[1] * _gait_curve("knee", p) + lift + np.deg2rad(2.0)
        # In swing the ankle also lifts the toes by a third of the shank's backward tilt.
        ankle = a * amp[2] * _gait_curve("ankle", p) + swing * np.maximum(knee - hip[side], 0.0) / 3
        mirror = _mirror if side == "right" else same
        pose[:, j[f"{side}_hip"]] = mirror(matrix_to_rotvec(axis_rotation("x", -hip[side]) @ axis_rotation("z", -adduction)))
        pose[:, j[f"{side}_knee"], 0] = knee
        pose[:, j[f"{side}_ankle"]] = mirror(matrix_to_rotvec(axis_rotation("x", -ankle) @ axis_rotation("z", adduction)))

    # Arms: swing against the same-side leg, overridden by the planned actions.
    arm = {}
    for side, other in (("left", "right"), ("right", "left")):
        flex = amp[3] * 0.6 * hip[other] + np.deg2rad(2.0) * a
        abduction = np.deg2rad(10.0) + np.deg2rad(2.0) * a
        elbow = np.deg2rad(12.0) + np.deg2rad(8.0) * a + 0.4 * np.maximum(flex, 0.0)
        arm[side] = [abduction, flex, elbow, np.zeros(T)]
    lean = np.deg2rad(4.0) * amp[5] * np.minimum(a, 1.2)
    for name, start, end in actions:
        what, sides = name.split("_")
        weight = _window(t, start, end, min(0.6, 0.3 * (end - start)))
        target = [np.full(T, np.deg2rad(x)) for x in _ARM_TARGETS[what]]
        if what == "wave":
            target[3] = target[3] + np.deg2rad(25.0) * np.sin(2 * np.pi * 1.8 * (t - start))
        if what == "reach":
            lean = lean + np.deg2rad(8.0) * weight
        for side in ("left", "right") if sides == "both" else (sides,):
            arm[side] = [(1 - weight) * x + weight * y for x, y in zip(arm[side], target)]
    for side in ("left", "right"):
        abd, flex, elbow_fwd, elbow_up = arm[side]
        mirror = _mirror if side == "right" else same
        pose[:, j[f"{side}_shoulder"]] = mirror(matrix_to_rotvec(axis_rotation("x", -flex) @ axis_rotation("z", abd - np.pi / 2)))
        pose[:, j[f"{side}_elbow"]] = mirror(matrix_to_rotvec(axis_rotation("z", elbow_up) @ axis_rotation("y", -elbow_fwd)))

    # Pelvis: yaw with the swinging leg, drop on the swing side; the thorax counter-rotates.
    c, s = np.cos(2 * np.pi * p_left), np.sin(2 * np.pi * p_left)
    yaw = -np.deg2rad(4.0) * amp[4] * a * c
    roll = np.deg2rad(3.0) * amp[4] * a * s
    sway_yaw = np.deg2rad(100.0) * sway * np.sin(2 * np.pi * 0.8 * style.sway_hz[0] * t + style.sway_phase[1])
    spine_yaw = (-yaw + np.deg2rad(3.0) * a * c - sway_yaw) / 3
    spine = matrix_to_rotvec(axis_rotation("x", lean / 3) @ axis_rotation("y", spine_yaw))
    for name in ("spine1", "spine2", "spine3"):
        pose[:, j[name]] = spine
    pose[:, j["neck"], 0] = -0.6 * lean

    # Heading frame: body +X (left) → world left of the heading, +Y (up) → +Z, +Z → heading.
    ch, sh = np.cos(heading), np.sin(heading)
    H = np.zeros((T, 3, 3))
    H[:, :2, 0] = np.stack([-sh, ch], -1)
    H[:, 2, 1] = 1.0
    H[:, :2, 2] = np.stack([ch, sh], -1)
    rotation = H @ axis_rotation("y", yaw + sway_yaw) @ axis_rotation("z", roll)
    offset = np.zeros((T, 3))
    for axis, k in ((0, 0), (2, 1)):
        wave = np.sin(2 * np.pi * style.sway_hz[k] * t + style.sway_phase[k])
        offset[:, axis] = sway * style.sway_amp[k] * wave
    return pose, rotation, np.einsum("tij,tj->ti", H, offset)


def _place_root(body, shape, rotation, pose, phase) -> np.ndarray:
    """Root translations ``(T, 3)`` for feet that touch z = 0 and do not slide.

    In every frame the pelvis height puts the lowest foot keypoint on the floor. Horizontally the
    root moves so that the supporting point stays where it is: the lowest keypoint of the feet
    that may be on the ground, i.e. that are not swinging (left-leg ``phase`` from just before
    heel strike, 0, to toe-off, 0.62; the right leg half a cycle later). The body is thus carried
    over its feet, rolling from heel to toe, and turns about the standing foot.
    """
    T = len(rotation)
    root = np.tile(np.eye(4), (T, 1, 1))
    root[:, :3, :3] = rotation
    feet = body.forward(shape, root, pose).keypoints[:, FOOT_KEYPOINTS]  # relative to the pelvis
    half = len(FOOT_KEYPOINTS) // 2  # left foot keypoints first
    swinging = []
    for offset in (0.0, 0.5):
        q = np.mod(phase + offset, 1.0)
        swinging.append(np.repeat(((q >= 0.62) & (q < 0.95))[:, None], half, axis=1))
    height = np.where(np.concatenate(swinging, axis=1), np.inf, feet[..., 2])
    contact = np.argmin(height, axis=1)
    rows = np.arange(T - 1)
    step = feet[rows, contact[:-1], :2] - feet[rows + 1, contact[:-1], :2]
    out = np.zeros((T, 3))
    out[1:, :2] = np.cumsum(step, axis=0)
    out[:, 2] = -feet[..., 2].min(axis=1)
    return out


def _speed_of_gait(body, shape, style: _Style) -> tuple[np.ndarray, np.ndarray]:
    """Walking speed (m/s) produced by gait amplitudes 0…1.6 for this body and style."""
    amplitudes = np.linspace(0.0, 1.6, 9)
    period = 1.0 / style.stride_hz
    t = np.linspace(0.0, period, int(np.ceil(period * _SUBSTEP_HZ)) + 1)
    speeds = []
    for a in amplitudes:
        zeros = np.zeros_like(t)
        pose, rotation, _ = _build_pose(t, zeros, np.full_like(t, a), zeros, [], 0.0, style)
        path = _place_root(body, shape, rotation, pose, style.phase0 + style.stride_hz * t)
        speeds.append((path[-1, 0] - path[0, 0]) / period)
    # Increasing for the inverse lookup (the speed of amplitude 0 is 0).
    speeds = np.maximum.accumulate(np.maximum(speeds, 0.0)) + 1e-9 * np.arange(len(amplitudes))
    return amplitudes, speeds


def procedural_motion(
    kind: str,
    duration_s: float,
    fps: float = 30.0,
    seed: int = 0,
    body: BodyModel | None = None,
    shape=None,
) -> Motion:
    """A procedural motion on the body (default: Anny with its default shape).

    ``kind``: ``"walk"`` (straight along +X at about 1.3 m/s), ``"turn"`` (a circle of radius
    1.6–2.4 m at about 1 m/s for 65 % of the time, then turning on the spot), ``"arms"``
    (standing; arm raises, waves and reaches), ``"zigzag_then_act"`` (a zigzag walk for 60 % of
    the time, then arm actions and a turn on the spot), ``"stand"`` (nearly still, a slow sway).

    The legs follow normal-gait joint curves whose amplitude is calibrated on this body so that it
    walks at the wanted speed. The pelvis height puts the lowest foot keypoint of each frame on
    z = 0 (in the rest pose: the body's rest foot height), and the root moves horizontally so
    that the supporting point (lowest keypoint of the feet not in swing) stays put: the feet do
    not skate. The body faces its walking direction. The same seed gives the same arrays; seeds
    vary cadence, phase, amplitudes, speed, turns and the actions.
    """
    if kind not in PROCEDURAL_KINDS:
        known = ", ".join(PROCEDURAL_KINDS)
        raise MocapgraphError(f"unknown procedural motion {kind!r}; choose one of {known}")
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise MocapgraphError(f"procedural motion duration must be positive, got {duration_s}")
    if not (np.isfinite(fps) and fps > 0):
        raise MocapgraphError(f"procedural motion fps must be positive, got {fps}")
    body = _resolve_body(body)
    shape = body.check_shape(body.default_shape if shape is None else shape)
    rng = np.random.default_rng(seed)
    style = _Style.sample(rng)
    frames = int(np.floor(duration_s * fps + 1e-9)) + 1
    sub = max(1, int(np.ceil(_SUBSTEP_HZ / fps)))
    t = np.arange((frames - 1) * sub + 1) / (fps * sub)
    plan = _plan(kind, t, duration_s, rng)

    amplitudes, speeds = _speed_of_gait(body, shape, style)
    gait = np.interp(plan.speed, speeds, amplitudes)
    pose, rotation, offset = _build_pose(t, plan.heading, gait, plan.stepping, plan.actions, plan.sway, style)
    translation = _place_root(body, shape, rotation, pose, style.phase0 + style.stride_hz * t) + offset
    keep = slice(None, None, sub)
    root = np.tile(np.eye(4), (frames, 1, 1))
    root[:, :3, :3] = rotation[keep]
    root[:, :3, 3] = translation[keep]
    return Motion(
        body_model=body.name,
        fps=float(fps),
        timestamps=np.arange(frames) / fps,
        root=root,
        pose=pose[keep],
        shape=shape.copy(),
        source=f"procedural {kind} ({duration_s:g} s, seed {seed})",
        info={"kind": kind, "seed": seed, "actions": list(plan.actions), "stride_hz": style.stride_hz},
    )


# --------------------------------------------------------------------------------------------
# Shape from bone lengths
# --------------------------------------------------------------------------------------------

# Our bone (joint pair) → the CMU take's joint pair with the same meaning.
CMU_BONES: dict[tuple[str, str], tuple[str, str]] = {
    ("left_hip", "left_knee"): ("lThigh", "lShin"),
    ("right_hip", "right_knee"): ("rThigh", "rShin"),
    ("left_knee", "left_ankle"): ("lShin", "lFoot"),
    ("right_knee", "right_ankle"): ("rShin", "rFoot"),
    ("left_shoulder", "left_elbow"): ("lShldr", "lForeArm"),
    ("right_shoulder", "right_elbow"): ("rShldr", "rForeArm"),
    ("left_elbow", "left_wrist"): ("lForeArm", "lHand"),
    ("right_elbow", "right_wrist"): ("rForeArm", "rHand"),
    ("pelvis", "neck"): ("hip", "neck"),
    ("left_shoulder", "right_shoulder"): ("lShldr", "rShldr"),
}

# The CMU library's rig puts its shoulder joints about 5 cm medial of where the body models put
# the shoulder (glenohumeral) joint, so its shoulder width is a different measurement; it only
# nudges the fit.
CMU_BONE_WEIGHTS: dict[tuple[str, str], float] = {("left_shoulder", "right_shoulder"): 0.25}


def cmu_bone_lengths(take: CMUTake) -> dict[tuple[str, str], float]:
    """The take's rest-pose lengths (metres) of the bones of :data:`CMU_BONES`, keyed by our pairs."""
    rest = np.zeros((len(take.joint_names), 3))
    for j, p in enumerate(take.parents):
        if p >= 0:
            rest[j] = rest[p] + take.offsets[j]
    index = take.joint_names.index
    return {
        ours: float(np.linalg.norm(rest[index(b)] - rest[index(a)])) for ours, (a, b) in CMU_BONES.items()
    }


def _bone_indices(lengths: dict) -> np.ndarray:
    pairs = []
    for pair in lengths:
        if len(pair) != 2 or any(name not in JOINT_NAMES for name in pair):
            known = ", ".join(JOINT_NAMES)
            raise MocapgraphError(f"bone {pair!r}: expected a pair of joint names from {known}")
        pairs.append([JOINT_NAMES.index(pair[0]), JOINT_NAMES.index(pair[1])])
    return np.array(pairs, dtype=int).reshape(-1, 2)


def _bone_lengths_and_jacobian(body: BodyModel, shape: np.ndarray, pairs: np.ndarray):
    """Rest bone lengths ``(B,)`` and their exact derivatives ``(B, S)`` with respect to the shape."""
    from mocapgraph.body.kinematics import SHAPE_START

    res = body.forward(shape, np.eye(4)[None], np.zeros((1, NUM_JOINTS - 1, 3)), jacobians=True)
    joints, d_shape = res.joints[0], res.d_joints[0, :, :, SHAPE_START:]
    vec = joints[pairs[:, 1]] - joints[pairs[:, 0]]
    length = np.linalg.norm(vec, axis=-1)
    unit = vec / np.maximum(length, 1e-12)[:, None]
    jac = np.einsum("bx,bxs->bs", unit, d_shape[pairs[:, 1]] - d_shape[pairs[:, 0]])
    return length, jac


def bone_length_residuals(body: BodyModel, shape, lengths: dict) -> dict[tuple[str, str], float]:
    """Body bone length minus target (metres) for every bone of ``lengths``."""
    pairs = _bone_indices(lengths)
    ours, _ = _bone_lengths_and_jacobian(body, body.check_shape(shape), pairs)
    return {pair: float(o - target) for pair, o, target in zip(lengths, ours, lengths.values())}


def fit_shape_to_bone_lengths(
    body: BodyModel,
    lengths: dict[tuple[str, str], float],
    initial=None,
    weights: dict[tuple[str, str], float] | None = None,
    prior_weight: float = 1e-4,
) -> np.ndarray:
    """The shape whose rest bone lengths best match ``lengths`` (metres), within the shape bounds.

    ``lengths`` is keyed by joint pairs of our skeleton, e.g. ``("left_hip", "left_knee")``;
    ``weights`` scales single bones' residuals (default 1). Bounded least squares (scipy's
    ``least_squares``, trust-region reflective) with the exact shape Jacobian of the forward
    kinematics. A weak pull towards ``initial`` (default: the model's default shape) of
    ``prior_weight`` metres per unit of shape keeps directions the bones do not determine
    (Anny's muscle and weight barely change the skeleton) where they started. Use
    :func:`bone_length_residuals` for the remaining error.
    """
    from scipy.optimize import least_squares

    if not lengths:
        raise MocapgraphError("fit_shape_to_bone_lengths: no bone lengths given")
    pairs = _bone_indices(lengths)
    target = np.array([float(v) for v in lengths.values()])
    if not np.all(np.isfinite(target)) or np.any(target <= 0):
        raise MocapgraphError("fit_shape_to_bone_lengths: bone lengths must be positive and finite")
    w = np.array([1.0 if weights is None else float(weights.get(pair, 1.0)) for pair in lengths])
    lo, hi = body.shape_bounds.T
    x0 = body.check_shape(body.default_shape if initial is None else initial).copy()
    # least_squares wants a strictly feasible start.
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    x0 = np.clip(x0, lo + 1e-9 * span, hi - 1e-9 * span)
    prior = np.full(len(x0), prior_weight)
    cache: dict = {}

    def evaluate(x):
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = _bone_lengths_and_jacobian(body, np.clip(x, lo, hi), pairs)
        return cache[key]

    def residual(x):
        length, _ = evaluate(x)
        return np.r_[w * (length - target), prior * (x - x0)]

    def jacobian(x):
        _, jac = evaluate(x)
        return np.vstack([w[:, None] * jac, np.diag(prior)])

    result = least_squares(
        residual, x0, jac=jacobian, bounds=(lo, hi), x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12
    )
    return np.clip(result.x, lo, hi)


# --------------------------------------------------------------------------------------------
# CMU takes
# --------------------------------------------------------------------------------------------


def list_cmu_takes(motion_dir: str | Path | None = None, tags=None) -> list[Path]:
    """Take files listed in ``index.json`` of the CMU directory (default: ``motion_dir()``).

    ``tags`` (a tag or a list of tags, e.g. ``"walk"``) keeps the takes with any of them.
    """
    directory = Path(motion_dir) if motion_dir is not None else default_motion_dir()
    index = directory / "index.json"
    if not index.exists():
        raise MocapgraphError(
            f"{index}: CMU motion index not found (set MOCAPGRAPH_MOTION_DIR or pass motion_dir)"
        )
    try:
        entries = json.loads(index.read_text())
    except (OSError, ValueError) as exc:
        raise MocapgraphError(f"{index}: not readable JSON ({exc})") from None
    if not isinstance(entries, list):
        raise MocapgraphError(f"{index}: expected a list of takes")
    wanted = None if tags is None else {tags} if isinstance(tags, str) else set(tags)
    takes = []
    for i, entry in enumerate(entries):
        if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
            raise MocapgraphError(f"{index}: entry {i} has no 'file'")
        if wanted is None or wanted & set(entry.get("tags", [])):
            takes.append(directory / entry["file"])
    return takes


def _take_description(path: Path) -> str:
    try:
        with np.load(path, allow_pickle=False) as d:
            return str(d["description"]) if "description" in d.files else ""
    except (OSError, ValueError):
        return ""


def cmu_motion(
    path: str | Path,
    body: BodyModel | None = None,
    fit_shape: bool = True,
    start_s: float = 0.0,
    duration_s: float | None = None,
) -> Motion:
    """A CMU take on the body: shape fitted to the take's bone lengths, feet on z = 0.

    The take is cut to ``[start_s, start_s + duration_s]`` (frames at 30 fps), retargeted with
    :func:`~mocapgraph.data_tools.sim.cmu_motion.retarget`, and the root is moved vertically so that
    the lowest foot keypoint over the cut sits on z = 0. With ``fit_shape=False`` the body's
    default shape is used. ``info`` holds the bone lengths, the fit residuals and the floor shift.
    """
    body = _resolve_body(body)
    path = Path(path)
    take = load_cmu_take(path)
    frames = take.world_rotations.shape[0]
    first = int(round(start_s * take.fps))
    if not (0 <= first < frames):
        end = (frames - 1) / take.fps
        raise MocapgraphError(f"{path}: start {start_s:g} s is outside the take (0 to {end:.2f} s)")
    if duration_s is not None and not duration_s >= 0:
        raise MocapgraphError(f"{path}: duration must not be negative, got {duration_s:g}")
    last = frames if duration_s is None else min(frames, first + int(round(duration_s * take.fps)) + 1)
    take = dataclasses.replace(
        take,
        world_rotations=take.world_rotations[first:last],
        root_translation=take.root_translation[first:last],
    )
    lengths = cmu_bone_lengths(take)
    shape = body.default_shape
    if fit_shape:
        shape = fit_shape_to_bone_lengths(body, lengths, weights=CMU_BONE_WEIGHTS)
    residuals = bone_length_residuals(body, shape, lengths)
    root, pose = retarget(take, body, shape)
    feet = body.forward(shape, root, pose).keypoints[:, FOOT_KEYPOINTS, 2]
    floor = float(feet.min())
    root[:, 2, 3] -= floor
    description = _take_description(path)
    return Motion(
        body_model=body.name,
        fps=float(take.fps),
        timestamps=np.arange(last - first) / take.fps,
        root=root,
        pose=pose,
        shape=np.array(shape, dtype=float),
        source=f"CMU {take.name}" + (f" ({description})" if description else "") + f", frames {first}-{last - 1}",
        info={
            "take": str(path),
            "first_frame": first,
            "bone_lengths": lengths,
            "bone_residuals": residuals,
            "fit_shape": fit_shape,
            "floor_shift": -floor,
        },
    )
