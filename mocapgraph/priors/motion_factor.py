"""SmartMocap's motion prior in a GTSAM graph, in latent-variable form.

Window ``w`` covers the body states ``i0 … i0+24`` (30 Hz states, ``i0 = window_starts[w]``).
It gets a latent variable ``z_w = motion_latent_key(w)`` (``Vector(L)``) with the unit Gaussian
prior :func:`~mocapgraph.priors.latent.latent_prior_factor`, and one factor per frame ``t`` of
the window tying that frame's 22 joint positions to the decoder's (66 rows):

    r_t = (C(c_w)⁻¹ · p_t − dec_pos(z_w)_t) / σ_t,

where ``p_t (22, 3)`` are the world joint positions from forward kinematics of ``root_key(i0+t)``,
``pose_key(i0+t)`` and the shape, ``C(c_w)`` the window's canonical frame (a variable held on
``C(root_i0)`` by a stiff tie factor, below; ``C(root_i0)`` is the ground projection of the
first root with the yaw turning its forward direction onto +Y, :mod:`mocapgraph.priors.motion_windows`),
``dec_pos(z_w)_t`` the decoded positions of frame ``t`` (canonical
frame, metres) and ``σ_t (66,)`` the model's decoder σ of that frame. So the factors add
``½‖z_w‖² + Σ_t ½‖r_t‖²``, the negative log joint density ``−log p(z_w) p(positions | z_w)``
of the VAE up to a constant (the positions' part of it: the 6D orientation channels are not tied).

**Ground-plane variable.** The windows are relative to the ground, and the graph's world need
not be level with it: one variable ``g = ground_key()`` (``Vector(3)``: tilts ``a, b`` about
world X and Y in radians, height ``h`` in metres) places the plane through ``c = (x_c, y_c, h)``,
``world_T_ground = (Rx(a) Ry(b), c)``, and the factors read every world point in its frame,
``p' = Ry(b)ᵀ Rx(a)ᵀ (p − c)``. ``g`` has a Gaussian prior at the world's ``z = 0`` plane
(:meth:`MotionVAEPrior.ground_prior_factor`). The pivot ``(x_c, y_c)`` is where the person is
(the mean of the windows' first roots), so a tilt does not lever the height there: pivoted on
the world origin, a 0.04 rad tilt put the body 17 cm under its ground on seed 1 (measured).

Why the variable (measured on 10 s AirCap captures, seeds 1–6): without it the ground was the
world's ``z = 0`` plane exactly, and 300 frames of windows pinned it. The fit then paid for the
disagreement with the cameras' attitude offsets (camera orientation error 0.019 → 0.031 rad on
seed 1), which moved the body's absolute position by decimetres while its covariance claimed
centimetres: 95 % coverage of the joints 0.08–0.83 per seed, against 0.92–1.0 without the prior.
With it, 0.14–1.0 (four seeds at 0.99–1.0). A lean of the whole motion in each window's canonical
frame, tried instead (the decoder's reconstructions lean 0.03 rad), did not help: the shift was
in the world's frame, not the person's.

**Canonical-frame variable.** Each window also has ``c_w = motion_frame_key(w)``
(``Vector(3)``: the frame's ground origin ``o_x, o_y`` in metres and yaw ``γ`` in radians), and
the frame factors read ``C`` from it: ``C = (Rz(γ), o = (o_x, o_y, 0))`` in the ground's frame.
One stiff *tie* factor per window holds ``c_w`` on the first root's canonical frame:

    r_tie = ((o_x, o_y) − (P t0')_xy, wrap(γ − γ(root_i0'))) / σ_tie,

with ``root_i0' = world_T_ground⁻¹ root_i0``, ``σ_tie`` = :data:`TIE_SIGMA_M` and
:data:`TIE_SIGMA_RAD`, the yaw difference wrapped into ``(−π, π]``. Keys of the frame-``t``
factor: ``(z_w, c_w, g, root_t, pose_t, shape)`` for every ``t`` (without a shape key the shape
is held fixed), of the tie factor ``(c_w, g, root_i0)``.
A dense factor over the 25 states would make GTSAM eliminate a dense 25-state clique per window
(10× slower solves, ``../shared/notes/gtsam_performance.md`` §4); this form keeps the graph sparse.

**Why ``c_w``: the frontier.** With the frame read off ``root_i0`` directly, every frame factor
touched the first root, so eliminating the window's states in time order kept ``root_i0`` and
``pose_i0`` (its forward kinematics share the factor: 69 dims) plus ``z_w`` (64) in every clique
along the window. Through ``c_w`` the frame factors only share ``c_w`` (3) and ``z_w``: the first
state is eliminated in its time slot, and ``c_w`` and ``z_w`` after the window's last state
(``_Problem.time_ordering`` of :mod:`mocapgraph.pipelines.aircap`). Either of them eliminated
first joins all 25 states in one dense clique. Measured on the 10 s AirCap sequence fit (13
windows, 2 cores): 0.37 s per linear solve against 0.50 s with the first state deferred with
the latent (0.25 s without the prior); the fit's ra/pa-MPJPE unchanged to 0.1 mm with
``σ_tie`` = 1 mm, 1 mrad.

The decoder outputs and their Jacobians ``(25·66, L)`` of every window come from one
:class:`~mocapgraph.priors.latent.BatchedDecoder`: the first factor of a linearisation triggers
one batched run (forward-mode over the L latent columns) for all windows, the others read it.

Jacobians (Pose3 tangent, rotation first, right perturbation: ``R ← R Exp(ω)``, ``t ← t + R v``
at first order, which is GTSAM's retract for both of its Pose3 charts). With ``A = Ry(b)ᵀ Rx(a)ᵀ``,
``p' = A (p − c)`` and ``q = Rz(γ)ᵀ(p' − o)``:

- the frame's own variables: ``∂q/∂x = Rz(γ)ᵀ A ∂p/∂x`` (native forward kinematics);
- ``c_w``: ``∂q/∂(o_x, o_y) = −Rz(γ)ᵀ[:, :2]`` and ``∂q/∂γ = (q_y, −q_x, 0)``;
- ``g``: ``∂q/∂a = Rz(γ)ᵀ (∂A/∂a)(p − c)``, the same for ``b``, ``∂q/∂h = −Rz(γ)ᵀ A e_z``;
- the tie's ``root_i0`` rotation, through the yaw ``γ0 = atan2(−f_x, f_y)`` of its forward axis
  in the ground's frame ``f = A R0 e_z``: ``∂f/∂ω = A R0 [[0, 1, 0], [−1, 0, 0], [0, 0, 0]]``
  (``δf = A R0 (ω × e_z)``), ``∂γ0 = (f_x ∂f_y − f_y ∂f_x) / (f_x² + f_y²)``;
- the tie's ``root_i0`` translation, through the origin ``P t0'`` (``P = diag(1, 1, 0)``,
  ``t0' = A (t0 − c)``): ``∂(P t0')/∂v = P A R0``;
- the tie's ``g``: ``∂f/∂a = (∂A/∂a) R0 e_z``, ``∂t0'/∂a = (∂A/∂a)(t0 − c)`` (and ``b``),
  ``∂t0'/∂h = −A e_z``.
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import axis_rotation
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.keys import ground_key, motion_frame_key, motion_latent_key, pose_key, root_key
from mocapgraph.factors.reprojection import ShapeTableCache
from mocapgraph.priors.latent import BatchedDecoder, latent_prior_factor
from mocapgraph.priors.motion_vae import JACOBIAN_CHUNK, MotionVAE
from mocapgraph.priors.motion_windows import POSITION_CHANNELS, WINDOW, canonical_frame, motion_features

POSE_DIM = 3 * (NUM_JOINTS - 1)
_D_FORWARD_D_OMEGA = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
"""``δf = R0 (ω × e_z) = R0 · this · ω``."""
TIE_SIGMA_M = 1e-3
"""σ of the tie factor's origin rows (metres)."""
TIE_SIGMA_RAD = 1e-3
"""σ of the tie factor's yaw row (radians)."""
GROUND_TILT_SIGMA_RAD = 0.05
"""Default σ of the ground prior's tilts (radians)."""
GROUND_HEIGHT_SIGMA_M = 0.05
"""Default σ of the ground prior's height (metres): the decoder's joints sit up to 1.2 cm low on
held-out walks, and a body shape away from the training subjects' moves them more."""


def _wrap(angle: float) -> float:
    """``angle`` wrapped into ``(−π, π]``."""
    return float(np.pi - np.mod(np.pi - angle, 2.0 * np.pi))


class _Ground:
    """The ground plane ``g = (a, b, h)`` about the pivot ``(x_c, y_c)``: ``A = Ry(b)ᵀ Rx(a)ᵀ``
    (world → ground rotation), its derivatives ``dA = (∂A/∂a, ∂A/∂b)`` and ``c = (x_c, y_c, h)``."""

    def __init__(self, g, pivot):
        a, b, h = (float(x) for x in g)
        self.c = np.array([pivot[0], pivot[1], h])
        ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
        rx_t = np.array([[1.0, 0.0, 0.0], [0.0, ca, sa], [0.0, -sa, ca]])
        ry_t = np.array([[cb, 0.0, -sb], [0.0, 1.0, 0.0], [sb, 0.0, cb]])
        drx_t = np.array([[0.0, 0.0, 0.0], [0.0, -sa, ca], [0.0, -ca, -sa]])
        dry_t = np.array([[-sb, 0.0, -cb], [0.0, 0.0, 0.0], [cb, 0.0, -sb]])
        self.A = ry_t @ rx_t
        self.dA = (ry_t @ drx_t, dry_t @ rx_t)

    def lowered(self, points: np.ndarray) -> np.ndarray:
        """``p − c`` of world points ``(..., 3)``."""
        return points - self.c

    def to_ground(self, world_T: np.ndarray) -> np.ndarray:
        """``(..., 4, 4)`` world poses in the ground's frame."""
        out = np.array(world_T, dtype=float)
        out[..., :3, :3] = self.A @ out[..., :3, :3]
        out[..., :3, 3] = self.lowered(out[..., :3, 3]) @ self.A.T
        return out


def _yaw_derivative(f: np.ndarray, df: np.ndarray) -> np.ndarray:
    """``∂γ`` of ``γ = atan2(−f_x, f_y)`` for ``δf = df · δ`` (``df (3, n)``)."""
    return (f[0] * df[1] - f[1] * df[0]) / (f[0] ** 2 + f[1] ** 2)


class _TieError:
    """The error function of a window's tie factor on ``(c_w, g, root_i0)`` (see the module docstring)."""

    def __init__(self, prior: MotionVAEPrior, keys: list[int]):
        self.prior, self.keys = prior, keys

    def __call__(self, this, values: gtsam.Values, H) -> np.ndarray:
        frame = values.atVector(self.keys[0])
        ground = _Ground(values.atVector(self.keys[1]), self.prior.ground_pivot)
        world_root0 = values.atPose3(self.keys[2]).matrix()
        yaw0, origin0 = canonical_frame(ground.to_ground(world_root0))
        residual = np.array([frame[0] - origin0[0], frame[1] - origin0[1], _wrap(frame[2] - yaw0)])
        if H is not None:
            AR0 = ground.A @ world_root0[:3, :3]
            f = AR0[:, 2]
            d_root0 = np.zeros((3, 6))
            d_root0[:2, 3:] = -AR0[:2]
            d_root0[2, :3] = -_yaw_derivative(f, AR0 @ _D_FORWARD_D_OMEGA)
            t0 = ground.lowered(world_root0[:3, 3])
            d_ground = np.zeros((3, 3))
            for k, dA in enumerate(ground.dA):
                d_ground[:2, k] = -(dA @ t0)[:2]
                d_ground[2, k] = -_yaw_derivative(f, (dA @ world_root0[:3, 2])[:, None])[0]
            d_ground[:2, 2] = ground.A[:2, 2]
            H[0] = np.eye(3)
            H[1] = d_ground
            H[2] = d_root0
        return residual


class _FrameError:
    """The error function of the frame-``t`` factor of one window (see the module docstring)."""

    def __init__(self, prior: MotionVAEPrior, t: int, keys: list[int], fixed_shape):
        self.prior, self.decoder, self.cache, self.t = prior, prior.decoder, prior.cache, t
        self.keys, self.fixed_shape = keys, fixed_shape
        self.sigma = prior.vae.position_sigma[t]
        self.rows = slice(t * POSITION_CHANNELS, (t + 1) * POSITION_CHANNELS)

    def __call__(self, this, values: gtsam.Values, H) -> np.ndarray:
        latent, frame_key, ground_key_, root_key_, pose_key_ = self.keys[:5]
        shape = self.fixed_shape if self.fixed_shape is not None else values.atVector(self.keys[-1])
        ox, oy, yaw = values.atVector(frame_key)
        ground = _Ground(values.atVector(ground_key_), self.prior.ground_pivot)
        joints, d_joints = self.cache.state_joints(values.atPose3(root_key_).matrix(), values.atVector(pose_key_), shape, H is not None)
        Rt = axis_rotation("z", yaw).T
        lowered = ground.lowered(joints)
        q = (lowered @ ground.A.T - np.array([ox, oy, 0.0])) @ Rt.T
        decoded, d_decoded = self.decoder(values, latent, H is not None)
        residual = (q.ravel() - decoded[self.rows]) / self.sigma
        if H is not None:
            scale = 1.0 / self.sigma[:, None]
            d_state = np.matmul(Rt @ ground.A, d_joints).reshape(POSITION_CHANNELS, -1) * scale
            d_frame = np.empty((len(q), 3, 3))
            d_frame[:, :, :2] = -Rt[:, :2]
            d_frame[:, 0, 2], d_frame[:, 1, 2], d_frame[:, 2, 2] = q[:, 1], -q[:, 0], 0.0
            d_ground = np.empty((len(q), 3, 3))
            for k, dA in enumerate(ground.dA):
                d_ground[:, :, k] = lowered @ (Rt @ dA).T
            d_ground[:, :, 2] = -(Rt @ ground.A)[:, 2]
            H[0] = -d_decoded[self.rows] * scale
            H[1] = d_frame.reshape(POSITION_CHANNELS, 3) * scale
            H[2] = d_ground.reshape(POSITION_CHANNELS, 3) * scale
            H[3] = d_state[:, :6]
            H[4] = d_state[:, 6 : 6 + POSE_DIM]
            if self.fixed_shape is None:
                H[5] = d_state[:, 6 + POSE_DIM :]
        return residual


class MotionVAEPrior:
    """The motion VAE as latent variables and per-frame factors on windows of body states.

    Args:
        vae: the trained model, e.g. :func:`load_default_motion_vae`.
        body: the body model of the graph (its joints are what the windows hold).
        window_starts: ``(W,)`` the first body state of each window (30 Hz states); windows may
            overlap (a stride below 25), each has its own latent ``motion_latent_key(w)``.
        shape_key: the shape's ``Vector(S)`` key, or None to hold ``fixed_shape``.
        fixed_shape: ``(S,)`` the shape when ``shape_key`` is None.
        table_cache: a :class:`~mocapgraph.factors.reprojection.ShapeTableCache` of ``body`` with
            format ``"body"`` to share with other factors (a new one when None).
        ground_sigmas: σ of the ground prior at the world's ``z = 0`` plane: ``(tilt_rad,
            height_m)``, the tilt's for both axes.

    Attributes:
        decoder: the :class:`~mocapgraph.priors.latent.BatchedDecoder` of all windows.
        ground_pivot: ``(2,)`` world x, y (metres) the ground's tilts turn about; :meth:`add_to`
            sets it to the mean of the windows' first roots when it inserts the ground.
    """

    def __init__(
        self,
        vae: MotionVAE,
        body: BodyModel,
        window_starts: Sequence[int],
        shape_key: int | None = None,
        fixed_shape=None,
        table_cache: ShapeTableCache | None = None,
        ground_sigmas: tuple[float, float] = (GROUND_TILT_SIGMA_RAD, GROUND_HEIGHT_SIGMA_M),
    ):
        if (shape_key is None) == (fixed_shape is None):
            raise MocapgraphError("MotionVAEPrior: give exactly one of shape_key and fixed_shape")
        if vae.body_model != body.name:
            raise MocapgraphError(
                f"MotionVAEPrior: the motion VAE was trained on the {vae.body_model!r} body, the graph uses {body.name!r}"
            )
        starts = np.asarray(window_starts)
        if starts.ndim != 1 or len(starts) == 0 or not np.issubdtype(starts.dtype, np.integer) or np.any(starts < 0):
            raise MocapgraphError(f"window_starts: expected a non-empty list of state indices >= 0, got {window_starts!r}")
        if table_cache is not None and table_cache.keypoint_format != "body":
            raise MocapgraphError(
                f"MotionVAEPrior: needs a ShapeTableCache of format 'body', got {table_cache.keypoint_format!r}"
            )
        tilt, height = (float(x) for x in ground_sigmas)
        if not (np.isfinite([tilt, height]).all() and tilt > 0 and height > 0):
            raise MocapgraphError(f"MotionVAEPrior: ground_sigmas (tilt_rad, height_m) must be finite and > 0, got {ground_sigmas!r}")
        self.ground_sigmas = np.array([tilt, tilt, height])
        self.ground_pivot = np.zeros(2)
        self.vae, self.body, self.starts = vae, body, [int(s) for s in starts]
        self.shape_key = None if shape_key is None else int(shape_key)
        self.fixed_shape = None if fixed_shape is None else body.check_shape(fixed_shape)
        self.cache = table_cache if table_cache is not None else ShapeTableCache(body, "body")
        self.latent_keys = [motion_latent_key(w) for w in range(len(self.starts))]
        self.frame_keys = [motion_frame_key(w) for w in range(len(self.starts))]
        self.decoder = BatchedDecoder(vae.decode_positions, self.latent_keys, vae.latent_dim, chunk_size=JACOBIAN_CHUNK)

    def frame_factor(self, w: int, t: int) -> gtsam.CustomFactor:
        """The factor tying frame ``t`` (0–24) of window ``w`` to the decoder (66 rows, unit noise)."""
        i = self.starts[w] + t
        keys = [self.latent_keys[w], self.frame_keys[w], ground_key(), root_key(i), pose_key(i)]
        keys += [] if self.shape_key is None else [self.shape_key]
        error = _FrameError(self, t, keys, self.fixed_shape)
        return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(POSITION_CHANNELS), keys, error)

    def tie_factor(self, w: int) -> gtsam.CustomFactor:
        """The stiff factor holding window ``w``'s canonical frame ``c_w`` on its first root (3 rows)."""
        keys = [self.frame_keys[w], ground_key(), root_key(self.starts[w])]
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([TIE_SIGMA_M, TIE_SIGMA_M, TIE_SIGMA_RAD]))
        return gtsam.CustomFactor(noise, keys, _TieError(self, keys))

    def ground_prior_factor(self) -> gtsam.NonlinearFactor:
        """The ground plane ``g`` near the world's ``z = 0`` plane, σ ``ground_sigmas``."""
        return gtsam.PriorFactorVector(ground_key(), np.zeros(3), gtsam.noiseModel.Diagonal.Sigmas(self.ground_sigmas))

    def _ground_roots(self, values: gtsam.Values, states) -> np.ndarray:
        """``(N, 4, 4)``: the roots of ``states`` in ``values``, in the frame of its ground ``g``."""
        if not values.exists(ground_key()):
            raise MocapgraphError("MotionVAEPrior: the ground plane (ground_key) is not in the values")
        roots = np.stack([values.atPose3(root_key(i)).matrix() for i in states])
        return _Ground(values.atVector(ground_key()), self.ground_pivot).to_ground(roots)

    def initial_frames(self, values: gtsam.Values) -> np.ndarray:
        """``(W, 3)``: each window's canonical frame ``(o_x, o_y, γ)`` of its first root in ``values``."""
        yaw, origin = canonical_frame(self._ground_roots(values, self.starts))
        return np.column_stack([origin[:, :2], yaw])

    def initial_latents(self, values: gtsam.Values) -> np.ndarray:
        """``(W, L)``: the encoder's μ of each window of the body states in ``values``."""
        states = sorted({s + t for s in self.starts for t in range(WINDOW)})
        missing = [i for i in states if not (values.exists(root_key(i)) and values.exists(pose_key(i)))]
        if missing:
            raise MocapgraphError(f"MotionVAEPrior: body state {missing[0]} (root_key/pose_key) is not in the values")
        if self.shape_key is not None and not values.exists(self.shape_key):
            raise MocapgraphError("MotionVAEPrior: the shape key is not in the values")
        shape = self.fixed_shape if self.shape_key is None else values.atVector(self.shape_key)
        roots = self._ground_roots(values, states)
        poses = np.stack([values.atVector(pose_key(i)) for i in states]).reshape(len(states), NUM_JOINTS - 1, 3)
        row = {i: n for n, i in enumerate(states)}
        features = motion_features(self.body, roots, poses, [row[s] for s in self.starts], shape)
        return self.vae.encode(features)[0]

    def add_to(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
        """Add the ground prior and every window's latent prior, tie factor and 25 frame factors
        to ``graph``; insert the ground at the world's ``z = 0`` plane (unless ``values`` hold one),
        each latent at the encoder's μ of the current estimate's window and each canonical frame
        at its first root's (the body states and the shape must already be in ``values``)."""
        if not values.exists(ground_key()):
            missing = [s for s in self.starts if not values.exists(root_key(s))]
            if missing:
                raise MocapgraphError(f"MotionVAEPrior: body state {missing[0]} (root_key) is not in the values")
            self.ground_pivot = np.mean([values.atPose3(root_key(s)).translation()[:2] for s in self.starts], axis=0)
            values.insert(ground_key(), np.zeros(3))
        graph.add(self.ground_prior_factor())
        latents = self.initial_latents(values)
        frames = self.initial_frames(values)
        for w, z in enumerate(latents):
            values.insert(self.latent_keys[w], z)
            values.insert(self.frame_keys[w], frames[w])
            graph.add(latent_prior_factor(self.latent_keys[w], self.vae.latent_dim))
            graph.add(self.tie_factor(w))
            for t in range(WINDOW):
                graph.add(self.frame_factor(w, t))
