"""SmartMocap's motion prior in a GTSAM graph, in latent-variable form.

Window ``w`` covers the body states ``i0 … i0+24`` (30 Hz states, ``i0 = window_starts[w]``).
It gets a latent variable ``z_w = motion_latent_key(w)`` (``Vector(L)``) with the unit Gaussian
prior :func:`~mocapgraph.priors.latent.latent_prior_factor`, and one factor per frame ``t`` of
the window tying that frame's 22 joint positions to the decoder's (66 rows):

    r_t = (C(root_i0)⁻¹ · p_t − dec_pos(z_w)_t) / σ_t,

where ``p_t (22, 3)`` are the world joint positions from forward kinematics of ``root_key(i0+t)``,
``pose_key(i0+t)`` and the shape, ``C(root_i0)`` the window's canonical frame
(:mod:`mocapgraph.priors.motion_windows`: ground projection of the first root, yaw turning its
forward direction onto +Y), ``dec_pos(z_w)_t`` the decoded positions of frame ``t`` (canonical
frame, metres) and ``σ_t (66,)`` the model's decoder σ of that frame. So the factors add
``½‖z_w‖² + Σ_t ½‖r_t‖²``, the negative log joint density ``−log p(z_w) p(positions | z_w)``
of the VAE up to a constant (the positions' part of it: the 6D orientation channels are not tied).

Keys of the frame-``t`` factor: ``(z_w, root_i0, root_t, pose_t, shape)``; for ``t = 0`` the
frame's root *is* ``root_i0`` and the factor has ``(z_w, root_i0, pose_i0, shape)``, its root
Jacobian the sum of both contributions. Without a shape key the shape is held fixed. A dense
factor over the 25 states would make GTSAM eliminate a dense 25-state clique per window (10×
slower solves, ``../shared/notes/gtsam_performance.md`` §4); this form keeps the graph sparse.

**Elimination order.** Every frame factor ties its state to the window's first root and latent,
so those two must be eliminated *after* the window's other states: eliminated first, either one
joins all 25 states in one dense clique. Measured on a 60 s chain (1801 states with unary priors
and between factors on consecutive roots and poses, 73 windows of which the last overlaps,
W = 128, L = 64; the chain alone solves in 0.38 s in time order): COLAMD 0.92 s per solve;
per window its states 1–24, then its first state and ``z_w``: 1.22 s; states in time order with
each ``z_w`` after its window's last state (the first state eliminated in its turn): 12.0 s.

The decoder outputs and their Jacobians ``(25·66, L)`` of every window come from one
:class:`~mocapgraph.priors.latent.BatchedDecoder`: the first factor of a linearisation triggers
one batched run (forward-mode over the L latent columns) for all windows, the others read it.

Jacobians (Pose3 tangent, rotation first, right perturbation: ``R ← R Exp(ω)``, ``t ← t + R v``
at first order, which is GTSAM's retract for both of its Pose3 charts). With ``q = Rz(γ)ᵀ(p − o)``:

- the frame's own variables: ``∂q/∂x = Rz(γ)ᵀ ∂p/∂x`` (native forward kinematics);
- ``root_i0``'s rotation, through the yaw ``γ = atan2(−f_x, f_y)`` of its forward axis
  ``f = R0 e_z``: ``∂f/∂ω = R0 [[0, 1, 0], [−1, 0, 0], [0, 0, 0]]`` (``δf = R0 (ω × e_z)``),
  ``∂γ = (f_x ∂f_y − f_y ∂f_x) / (f_x² + f_y²)``, and ``∂q/∂γ = (q_y, −q_x, 0)``;
- ``root_i0``'s translation, through the origin ``o = P t0`` (``P = diag(1, 1, 0)``):
  ``∂q/∂v = −Rz(γ)ᵀ P R0``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import gtsam
import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.reprojection import ShapeTableCache
from mocapgraph.graphs.keys import motion_latent_key, pose_key, root_key
from mocapgraph.priors.latent import BatchedDecoder, latent_prior_factor
from mocapgraph.priors.motion_vae import MotionVAE
from mocapgraph.priors.motion_windows import POSITION_CHANNELS, WINDOW, canonical_frame, motion_features, rot_z

POSE_DIM = 3 * (NUM_JOINTS - 1)
_D_FORWARD_D_OMEGA = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
"""``δf = R0 (ω × e_z) = R0 · this · ω``."""
_GROUND = np.diag([1.0, 1.0, 0.0])
JACOBIAN_CHUNK = 8
"""Windows per vectorised Jacobian pass: 8 keeps a pass's tangents in cache (W = 128, L = 64, 72
windows, 1 thread: 14.6 ms per window against 26.8 ms in one pass; chunks of 2 or 24: 15.8, 15.9 ms)."""


def _d_canonical_d_root0(R0: np.ndarray, Rt: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``(P·3, 6)``: derivative of canonical points ``q (P, 3)`` (held fixed in the world) with
    respect to the Pose3 tangent (rotation first) of the window's first root, whose rotation is
    ``R0`` and whose canonical frame has ``Rt = Rz(γ)ᵀ``."""
    f = R0[:, 2]
    df = R0 @ _D_FORWARD_D_OMEGA
    d_yaw = (f[0] * df[1] - f[1] * df[0]) / (f[0] ** 2 + f[1] ** 2)
    J = np.zeros((len(q), 3, 6))
    J[:, 0, :3] = q[:, 1:2] * d_yaw
    J[:, 1, :3] = -q[:, 0:1] * d_yaw
    J[:, :, 3:] = -Rt @ _GROUND @ R0
    return J.reshape(-1, 6)


class _FrameError:
    """The error function of the frame-``t`` factor of one window (see the module docstring)."""

    def __init__(self, prior: MotionVAEPrior, t: int, keys: list[int], fixed_shape):
        from mocapgraph.body.native import native_module

        self.decoder, self.cache, self.t = prior.decoder, prior.cache, t
        self.keys, self.fixed_shape = keys, fixed_shape
        self.sigma = prior.vae.position_sigma[t]
        self.rows = slice(t * POSITION_CHANNELS, (t + 1) * POSITION_CHANNELS)
        self.fk = native_module().fk

    def __call__(self, this, values: gtsam.Values, H) -> np.ndarray:
        first = self.t == 0
        latent, root0_key = self.keys[:2]
        state_root_key, state_pose_key = (root0_key, self.keys[2]) if first else self.keys[2:4]
        shape = self.fixed_shape if self.fixed_shape is not None else values.atVector(self.keys[-1])
        root0 = values.atPose3(root0_key).matrix()
        root = root0 if first else values.atPose3(state_root_key).matrix()
        pose = values.atVector(state_pose_key).reshape(1, NUM_JOINTS - 1, 3)
        arrays = self.cache.entry(shape).arrays
        joints, _, _, d_joints, _ = self.fk(*arrays, np.ascontiguousarray(root)[None], pose, H is not None)
        yaw, origin = canonical_frame(root0)
        Rt = rot_z(yaw).T
        q = (joints[0] - origin) @ Rt.T
        decoded, d_decoded = self.decoder(values, latent, H is not None)
        residual = (q.ravel() - decoded[self.rows]) / self.sigma
        if H is not None:
            scale = 1.0 / self.sigma[:, None]
            d_state = np.matmul(Rt, d_joints[0]).reshape(POSITION_CHANNELS, -1) * scale
            d_root0 = _d_canonical_d_root0(root0[:3, :3], Rt, q) * scale
            H[0] = -d_decoded[self.rows] * scale
            if first:
                H[1] = d_root0 + d_state[:, :6]
                H[2] = d_state[:, 6 : 6 + POSE_DIM]
            else:
                H[1] = d_root0
                H[2] = d_state[:, :6]
                H[3] = d_state[:, 6 : 6 + POSE_DIM]
            if self.fixed_shape is None:
                H[len(self.keys) - 1] = d_state[:, 6 + POSE_DIM :]
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

    Attributes:
        decoder: the :class:`~mocapgraph.priors.latent.BatchedDecoder` of all windows.
    """

    def __init__(
        self,
        vae: MotionVAE,
        body: BodyModel,
        window_starts: Sequence[int],
        shape_key: int | None = None,
        fixed_shape=None,
        table_cache: ShapeTableCache | None = None,
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
        self.vae, self.body, self.starts = vae, body, [int(s) for s in starts]
        self.shape_key = None if shape_key is None else int(shape_key)
        self.fixed_shape = None if fixed_shape is None else body.check_shape(fixed_shape)
        self.cache = table_cache if table_cache is not None else ShapeTableCache(body, "body")
        self.latent_keys = [motion_latent_key(w) for w in range(len(self.starts))]
        self.decoder = BatchedDecoder(vae.decode_positions, self.latent_keys, vae.latent_dim, chunk_size=JACOBIAN_CHUNK)

    def frame_factor(self, w: int, t: int) -> gtsam.CustomFactor:
        """The factor tying frame ``t`` (0–24) of window ``w`` to the decoder (66 rows, unit noise)."""
        i0 = self.starts[w]
        keys = [self.latent_keys[w], root_key(i0)]
        keys += [pose_key(i0)] if t == 0 else [root_key(i0 + t), pose_key(i0 + t)]
        keys += [] if self.shape_key is None else [self.shape_key]
        error = _FrameError(self, t, keys, self.fixed_shape)
        return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(POSITION_CHANNELS), keys, error)

    def initial_latents(self, values: gtsam.Values) -> np.ndarray:
        """``(W, L)``: the encoder's μ of each window of the body states in ``values``."""
        states = sorted({s + t for s in self.starts for t in range(WINDOW)})
        missing = [i for i in states if not (values.exists(root_key(i)) and values.exists(pose_key(i)))]
        if missing:
            raise MocapgraphError(f"MotionVAEPrior: body state {missing[0]} (root_key/pose_key) is not in the values")
        if self.shape_key is not None and not values.exists(self.shape_key):
            raise MocapgraphError("MotionVAEPrior: the shape key is not in the values")
        shape = self.fixed_shape if self.shape_key is None else values.atVector(self.shape_key)
        roots = np.stack([values.atPose3(root_key(i)).matrix() for i in states])
        poses = np.stack([values.atVector(pose_key(i)) for i in states]).reshape(len(states), NUM_JOINTS - 1, 3)
        row = {i: n for n, i in enumerate(states)}
        features = motion_features(self.body, roots, poses, [row[s] for s in self.starts], shape)
        return self.vae.encode(features)[0]

    def add_to(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
        """Add every window's latent prior and 25 frame factors to ``graph``, and insert each
        latent into ``values`` at the encoder's μ of the current estimate's window (the body
        states and the shape must already be in ``values``)."""
        for w, z in enumerate(self.initial_latents(values)):
            values.insert(self.latent_keys[w], z)
            graph.add(latent_prior_factor(self.latent_keys[w], self.vae.latent_dim))
            for t in range(WINDOW):
                graph.add(self.frame_factor(w, t))



def decoder_jacobian_ms(vae: MotionVAE, windows: int = 72, repeats: int = 3, seed: int = 0) -> float:
    """Milliseconds per window of one linearisation's decoder run (outputs and Jacobians of
    ``windows`` latents in one :class:`~mocapgraph.priors.latent.BatchedDecoder` batch, as
    :class:`MotionVAEPrior` does), the median of ``repeats``, with torch's current thread count.

    72 windows are a 60 s sequence at 30 Hz with windows side by side.
    """
    keys = [motion_latent_key(w) for w in range(windows)]
    values = gtsam.Values()
    for key, z in zip(keys, np.random.default_rng(seed).standard_normal((windows, vae.latent_dim))):
        values.insert(key, z)
    seconds = []
    for _ in range(repeats):
        decoder = BatchedDecoder(vae.decode_positions, keys, vae.latent_dim, chunk_size=JACOBIAN_CHUNK)
        start = time.perf_counter()
        decoder(values, keys[0], jacobian=True)
        seconds.append(time.perf_counter() - start)
    return 1000.0 * float(np.median(seconds)) / windows
