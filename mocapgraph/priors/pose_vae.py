"""Pose VAE prior: a variational autoencoder over the moving joints' rotations, its file format and training.

A pose is the ``(63,)`` vector of :mod:`mocapgraph.priors.pose_gmm` (21 local axis-angle rotations,
SMPL joint order, radians). The VAE models only the ``J`` joints that move in its training data
(``moving_joints``: 16 of 21 on CMU, where spine3, the feet and the collars are retargeting
constants); their ``3J`` axis-angle entries are the *modelled dimensions*. The other joints are
decoded as their training constants, so a decoded pose is a full pose.

Model (VPoser-like, Pavlakos et al. 2019):

- **Input.** Each modelled joint's rotation in the continuous 6D representation of Zhou et al.
  2019: the first two columns of its rotation matrix, ``[R[:, 0]; R[:, 1]]``, so ``6J`` numbers.
- **Encoder.** An MLP (two hidden layers of ``width``, GELU) to the mean ``μ`` and log variance
  of ``q(z | θ)``, ``z ∈ R^L``.
- **Decoder.** An MLP of the same shape from ``z`` to 6D per joint, Gram-Schmidt to a rotation
  matrix, then the log map to axis-angle: ``a(z) ∈ R^{3J}``.
- **Density.** ``z ~ N(0, I_L)`` and ``θ_m | z ~ N(a(z), diag σ²)`` with ``θ_m`` the modelled
  dimensions and ``σ`` (rad, ``(3J,)``) the decoder's residual measured on held-out poses after
  training. This is exactly what :mod:`mocapgraph.priors.pose_vae_factor` puts in the graph.

Training maximises the ELBO with a rotation-aware reconstruction term: per joint the chordal
distance ``‖R̂ − R‖²_F = 4(1 − cos φ) ≈ 2φ²`` (``φ`` the angle between the rotations) divided by
``4 s²``, i.e. a Gaussian of ``s = recon_sigma`` rad per tangent dimension for small ``φ``; the
KL term's weight rises linearly from 0 to 1 over the first epochs (KL annealing).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import relative_angle, rotvec_to_matrix
from mocapgraph.errors import MocapgraphError
from mocapgraph.priors.model_file import load_weights, read_model_file, weight_arrays, write_model_file
from mocapgraph.priors.pose_gmm import _as_poses
from mocapgraph.priors.training import held_out_split, load_pose_frames, moving_joints

FORMAT_VERSION = 1
_KEYS = ("format_version", "body_model", "joints", "static_pose", "sigma", "config", "info")
DEFAULT_POSE_VAE = Path(__file__).parent / "data" / "pose_vae.npz"


def rotmat_to_sixd(R: torch.Tensor) -> torch.Tensor:
    """``(..., 3, 3)`` rotation matrices → ``(..., 6)``: first column, then second column."""
    return torch.cat([R[..., :, 0], R[..., :, 1]], dim=-1)


def sixd_to_rotmat(x: torch.Tensor) -> torch.Tensor:
    """``(..., 6)`` → ``(..., 3, 3)`` by Gram-Schmidt: column 1 is ``x[:3]`` normalised, column 2
    is ``x[3:]`` minus its component along column 1, normalised, column 3 their cross product."""
    a1, a2 = x[..., :3], x[..., 3:]
    b1 = torch.nn.functional.normalize(a1, dim=-1)
    b2 = torch.nn.functional.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1)
    return torch.stack([b1, b2, torch.linalg.cross(b1, b2, dim=-1)], dim=-1)


def rotmat_to_rotvec(R: torch.Tensor) -> torch.Tensor:
    """Log map ``(..., 3, 3)`` → ``(..., 3)`` axis-angle, angle in [0, π], differentiable everywhere.

    With ``s = vee(R − Rᵀ)/2 = sin φ · axis`` and ``c = (trace R − 1)/2 = cos φ``:

    - ``φ ≤ 2π/3`` (``c ≥ −½``): ``s · φ/sin φ`` with ``φ = atan2(|s|, c)``; the ratio switches
      to its series ``1 + |s|²/6 + 3|s|⁴/40`` for ``|s| < 1e-4``, so the value and its first
      derivatives stay finite at the identity.
    - ``φ > 2π/3``: ``sin φ`` goes to 0 at π and ``s`` no longer fixes the axis well, so the axis
      comes from the symmetric part ``(R + Rᵀ)/2 − c I = (1 − c) axis axisᵀ`` (its column with
      the largest diagonal, never below ``(1 − c)/3 ≥ ½`` there), signed to agree with ``s``,
      and ``φ = atan2(axis · s, c)``.

    Both branches are evaluated everywhere with guarded divisions, so neither reverse- nor
    forward-mode derivatives see a NaN from the branch that is not selected.
    """
    s = 0.5 * torch.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    c = 0.5 * (R.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0)
    sin2 = (s * s).sum(-1)
    tiny = sin2 < 1e-8
    n = torch.sqrt(torch.where(tiny, torch.ones_like(sin2), sin2))
    ratio = torch.where(tiny, 1.0 + sin2 / 6.0 + 0.075 * sin2 * sin2, torch.atan2(n, c) / n)
    small_angle = s * ratio[..., None]

    B = 0.5 * (R + R.transpose(-1, -2)) - c[..., None, None] * torch.eye(3, dtype=R.dtype)
    diag = B.diagonal(dim1=-2, dim2=-1)
    k = diag.argmax(-1, keepdim=True)
    column = torch.take_along_dim(B, k[..., None, :], dim=-1)[..., 0]
    axis = column / torch.sqrt(torch.clamp(torch.take_along_dim(diag, k, dim=-1) * (1.0 - c[..., None]), min=1e-12))
    axis = torch.where((axis * s).sum(-1, keepdim=True) < 0, -axis, axis)
    large_angle = axis * torch.atan2((axis * s).sum(-1), c)[..., None]
    return torch.where((c < -0.5)[..., None], large_angle, small_angle)


def _sixd_to_rotvec(x: torch.Tensor) -> torch.Tensor:
    """``(..., 6)`` → ``(..., 3)``: Gram-Schmidt, then the log map."""
    return rotmat_to_rotvec(sixd_to_rotmat(x))


def _sixd_to_rotvec_jacobian(x: torch.Tensor) -> torch.Tensor:
    """``(..., 3, 6)``: the Jacobian of :func:`_sixd_to_rotvec` at each ``(..., 6)``."""
    # Rows stay (1, 6), not (6,): forward mode in torch 2.13 turns the tangent of a 0-d float32
    # result scaled by a Python float into float64.
    rows = x.reshape(-1, 1, 6)
    jac = torch.func.vmap(torch.func.jacfwd(lambda row: _sixd_to_rotvec(row)[0]))(rows)
    return jac.reshape(x.shape[:-1] + (3, 6))


class _SixdToRotvec(torch.autograd.Function):
    """:func:`_sixd_to_rotvec` with both derivatives taken through each joint's ``3×6`` Jacobian.

    Plain forward mode through the decoder pushes all ``L`` tangents through every elementwise op
    of Gram-Schmidt and the log map; here each joint's Jacobian is built once from 6 tangents and
    the ``L`` tangents only meet a ``3×6`` product. That halves the decoder's batched Jacobian
    (latent 32, width 512, 300 states, 1 thread: 1421 → 726 µs per state, measured).
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(x):
        return _sixd_to_rotvec(x)

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(inputs[0])
        ctx.save_for_forward(inputs[0])

    @staticmethod
    def jvp(ctx, tangent):
        (x,) = ctx.saved_tensors
        return (_sixd_to_rotvec_jacobian(x) @ tangent[..., None])[..., 0]

    @staticmethod
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        return (grad[..., None, :] @ _sixd_to_rotvec_jacobian(x))[..., 0, :]


def _mlp(inputs: int, width: int, outputs: int) -> torch.nn.Sequential:
    return torch.nn.Sequential(
        torch.nn.Linear(inputs, width), torch.nn.GELU(),
        torch.nn.Linear(width, width), torch.nn.GELU(),
        torch.nn.Linear(width, outputs),
    )  # fmt: skip


class PoseVAE(torch.nn.Module):
    """A VAE over the rotations of the joints ``joints`` (see the module docstring).

    Args:
        joints: ``(J,)`` indices into the 21 pose joints (SMPL order minus the pelvis) it models.
        static_pose: ``(63,)`` the training mean pose; its unmodelled joints fill decoded poses.
        latent: ``L``, the latent size.
        width: hidden width of the encoder's and the decoder's MLPs.
        sigma: ``(3J,)`` residual σ (rad) of ``θ_m | z``; None means "not measured yet" (ones).
        body_model: the body model whose joint frames the poses are in (e.g. ``"anny"``).
        info: free-form training record (data, seed, held-out numbers), saved with the file.

    The network runs in its parameters' dtype (float32 as trained; ``.double()`` for float64).
    """

    def __init__(
        self,
        joints,
        static_pose,
        latent: int = 32,
        width: int = 512,
        sigma=None,
        body_model: str = "anny",
        info: dict | None = None,
    ):
        super().__init__()
        joints = np.asarray(joints, dtype=np.int64)
        distinct = joints.ndim == 1 and len(joints) > 0 and len(np.unique(joints)) == len(joints)
        if not (distinct and np.all((joints >= 0) & (joints < 21))):
            raise MocapgraphError(f"PoseVAE: joints must be distinct indices in [0, 21), got {joints.tolist()}")
        if latent < 1 or width < 1:
            raise MocapgraphError(f"PoseVAE: latent and width must be >= 1, got {latent}, {width}")
        self.joints = np.sort(joints)
        self.static_pose = _as_poses(np.reshape(static_pose, (1, -1)), 63)[0]
        self.dims = (3 * self.joints[:, None] + np.arange(3)).ravel()
        """``(3J,)`` the modelled dimensions: indices into the 63 pose entries."""
        self.sigma = np.ones(len(self.dims)) if sigma is None else np.asarray(sigma, dtype=float)
        if self.sigma.shape != self.dims.shape or not np.all(self.sigma > 0):
            raise MocapgraphError(
                f"PoseVAE: sigma must be ({len(self.dims)},) and positive, got shape {self.sigma.shape}"
            )
        self.latent, self.width, self.body_model = int(latent), int(width), body_model
        self.info = dict(info or {})
        self.encoder = _mlp(6 * len(self.joints), self.width, 2 * self.latent)
        self.decoder = _mlp(self.latent, self.width, 6 * len(self.joints))

    @property
    def dtype(self) -> torch.dtype:
        return self.decoder[0].weight.dtype

    def _sixd(self, poses: np.ndarray) -> torch.Tensor:
        """``(N, 6J)`` encoder input of poses ``(N, 63)``."""
        R = rotvec_to_matrix(poses[:, self.dims].reshape(len(poses), -1, 3))
        return rotmat_to_sixd(torch.as_tensor(R, dtype=self.dtype)).reshape(len(poses), -1)

    def encode_torch(self, sixd: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``μ`` and ``log σ²`` ``(B, L)`` of ``q(z | θ)`` from ``(B, 6J)`` 6D rotations."""
        mu, log_var = self.encoder(sixd).chunk(2, dim=-1)
        return mu, log_var

    def decode_rotmat_torch(self, z: torch.Tensor) -> torch.Tensor:
        """``(B, L)`` latents → ``(B, J, 3, 3)`` the modelled joints' rotation matrices."""
        return sixd_to_rotmat(self.decoder(z.to(self.dtype)).reshape(len(z), -1, 6))

    def decode_rotvec_torch(self, z: torch.Tensor) -> torch.Tensor:
        """``a(z)``: ``(B, L)`` latents → ``(B, 3J)`` modelled dimensions (axis-angle, radians).

        Acts row by row and is differentiable in reverse and forward mode (``torch.func.jacfwd``),
        which is how :class:`mocapgraph.priors.latent.BatchedDecoder` takes its Jacobian.
        """
        return _SixdToRotvec.apply(self.decoder(z.to(self.dtype)).reshape(len(z), -1, 6)).reshape(len(z), -1)

    def encode(self, poses) -> np.ndarray:
        """``(N, L)``: the encoder's mean ``μ`` for poses ``(N, 63)`` (or ``(N, 21, 3)``)."""
        x = _as_poses(poses, 63)
        with torch.no_grad():
            return self.encode_torch(self._sixd(x))[0].double().numpy()

    def decode(self, z) -> np.ndarray:
        """``(N, 63)`` full poses for latents ``(N, L)``: ``a(z)`` on the modelled dimensions, the
        training constants on the others."""
        z = np.asarray(z, dtype=float).reshape(-1, self.latent)
        with torch.no_grad():
            a = self.decode_rotvec_torch(torch.as_tensor(z, dtype=self.dtype)).double().numpy()
        out = np.tile(self.static_pose, (len(z), 1))
        out[:, self.dims] = a
        return out

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``(n, 63)`` poses decoded from ``z ~ N(0, I)`` drawn with ``rng`` (the decoder's mean, no σ noise)."""
        return self.decode(rng.standard_normal((n, self.latent)))

    def geodesic_error(self, poses) -> np.ndarray:
        """``(N,)`` radians: per pose, the mean over the modelled joints of the rotation angle
        between the pose and its reconstruction ``decode(encode(pose))``."""
        x = _as_poses(poses, 63)
        with torch.no_grad():
            R = self.decode_rotmat_torch(self.encode_torch(self._sixd(x))[0]).double().numpy()
        return relative_angle(R, rotvec_to_matrix(x[:, self.dims].reshape(len(x), -1, 3))).mean(axis=1)

    def elbo(self, poses, samples: int = 16, seed: int = 0) -> np.ndarray:
        """``(N,)`` nats: the evidence lower bound ``E_q[log p(θ_m | z)] − KL(q(z | θ) ‖ N(0, I))``
        on ``log p(θ_m)``, the density of the modelled dimensions, with ``samples`` seeded draws of
        ``z`` per pose."""
        x = _as_poses(poses, 63)
        generator = torch.Generator().manual_seed(seed)
        sigma = torch.as_tensor(self.sigma, dtype=torch.float64)
        theta = torch.as_tensor(x[:, self.dims])
        with torch.no_grad():
            mu, log_var = self.encode_torch(self._sixd(x))
            log_lik = torch.zeros(len(x), dtype=torch.float64)
            for _ in range(samples):
                z = mu + torch.exp(0.5 * log_var) * torch.randn(mu.shape, generator=generator, dtype=mu.dtype)
                r = (theta - self.decode_rotvec_torch(z).double()) / sigma
                log_lik += -0.5 * (r * r).sum(-1)
            log_lik = log_lik / samples - torch.log(sigma).sum() - 0.5 * len(self.dims) * np.log(2 * np.pi)
            return (log_lik - _kl(mu, log_var).double()).numpy()

    def save(self, path: str | Path, float16: bool = False) -> Path:
        """Write one ``.npz`` (no pickle, :mod:`~mocapgraph.priors.model_file`): format version,
        body model, joints, static pose, σ, the config and info as JSON, and every weight as
        ``state/<name>`` (float16 when asked, which halves the file); atomic rename."""
        return write_model_file(
            path, format_version=FORMAT_VERSION, body_model=self.body_model, joints=self.joints,
            static_pose=self.static_pose, sigma=self.sigma,
            config=json.dumps({"latent": self.latent, "width": self.width}), info=json.dumps(self.info),
            **weight_arrays(self, np.float16 if float16 else np.float32),
        )  # fmt: skip

    @classmethod
    def load(cls, path: str | Path) -> PoseVAE:
        """Read a file written by :meth:`save` (weights as float32); errors name the file and the key."""
        d = read_model_file(path, "pose VAE", _KEYS, FORMAT_VERSION)
        try:
            config = json.loads(str(d["config"]))
            vae = cls(
                d["joints"], d["static_pose"], latent=config["latent"], width=config["width"], sigma=d["sigma"],
                body_model=str(d["body_model"]), info=json.loads(str(d["info"])),
            )  # fmt: skip
        except (MocapgraphError, ValueError) as exc:
            raise MocapgraphError(f"{path}: {exc}") from None
        except KeyError as exc:
            raise MocapgraphError(f"{path}: config has no {exc.args[0]!r}") from None
        load_weights(path, vae, d)
        return vae


def load_default_pose_vae() -> PoseVAE:
    """The shipped pose VAE (latent 32, Anny body, trained on CMU subjects 01–79 minus a held-out fifth)."""
    return PoseVAE.load(DEFAULT_POSE_VAE)


def _kl(mu: torch.Tensor, log_var: torch.Tensor) -> torch.Tensor:
    """``(B,)`` ``KL(N(μ, diag e^{log_var}) ‖ N(0, I))``."""
    return 0.5 * (mu * mu + torch.exp(log_var) - 1.0 - log_var).sum(-1)


def fit_pose_vae(
    train_poses,
    val_poses,
    joints=None,
    latent: int = 32,
    width: int = 512,
    epochs: int = 40,
    batch: int = 512,
    lr: float = 1e-3,
    recon_sigma: float = 0.1,
    kl_anneal_epochs: int | None = None,
    sigma_floor: float = 0.02,
    seed: int = 0,
    body_model: str = "anny",
    progress: Callable[[str], None] | None = None,
) -> PoseVAE:
    """Train a :class:`PoseVAE` on in-memory poses with Adam, then measure σ on the held-out ones.

    Args:
        train_poses: ``(N, 63)`` training poses (``(N, 21, 3)`` is flattened).
        val_poses: ``(M, 63)`` held-out poses: the per-epoch validation number and ``σ``.
        joints: indices of the modelled joints; default ``moving_joints(train_poses)``.
        latent, width: the network's size (see :class:`PoseVAE`).
        epochs, batch, lr: Adam over shuffled mini-batches, the rate decayed to 0 by a cosine.
        recon_sigma: ``s`` (rad) of the reconstruction term (module docstring); smaller trades a
            less Gaussian latent for sharper reconstructions.
        kl_anneal_epochs: the KL weight rises linearly to 1 over this many epochs (default a
            quarter of ``epochs``).
        sigma_floor: lower bound of every ``σ`` entry (rad), so the factor never trusts the
            decoder more than this even on dimensions it reconstructs almost exactly.
        seed: seeds the initial weights, the shuffling and the latent noise: the same seed (and
            torch thread count) gives the same model.
        progress: called with one line per epoch.

    Returns:
        the trained model; its ``info`` has ``train_poses``, ``val_poses``,
        ``val_geodesic_err_rad`` (mean over held-out poses and modelled joints of the angle between
        a pose and ``decode(encode(pose))``), ``val_elbo`` (nats per pose) and ``fit_seconds``.
    """
    start = time.perf_counter()
    x_train, x_val = _as_poses(train_poses, 63), _as_poses(val_poses, 63)
    if len(x_train) == 0 or len(x_val) == 0:
        raise MocapgraphError(f"fit_pose_vae: needs training and held-out poses, got {len(x_train)} and {len(x_val)}")
    joints = moving_joints(x_train) if joints is None else np.asarray(joints)
    kl_anneal_epochs = max(1, epochs // 4) if kl_anneal_epochs is None else max(1, kl_anneal_epochs)
    torch.manual_seed(seed)
    generator = torch.Generator().manual_seed(seed)
    vae = PoseVAE(joints, x_train.mean(axis=0), latent, width, body_model=body_model)
    inputs = vae._sixd(x_train)
    targets = sixd_to_rotmat(inputs.reshape(len(x_train), -1, 6))  # exact: the inputs are rotations
    steps = epochs * -(-len(x_train) // batch)
    optimiser = torch.optim.Adam(vae.parameters(), lr=lr)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, max(1, steps))
    for epoch in range(epochs):
        kl_weight = min(1.0, (epoch + 1) / kl_anneal_epochs)
        totals = np.zeros(2)
        for idx in torch.randperm(len(x_train), generator=generator).split(batch):
            mu, log_var = vae.encode_torch(inputs[idx])
            z = mu + torch.exp(0.5 * log_var) * torch.randn(mu.shape, generator=generator)
            recon = torch.square(vae.decode_rotmat_torch(z) - targets[idx]).sum((1, 2, 3)) / (4 * recon_sigma**2)
            kl = _kl(mu, log_var)
            loss = (recon + kl_weight * kl).mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            totals += [recon.sum().item(), kl.sum().item()]
        if progress is not None:
            recon_mean, kl_mean = totals / len(x_train)
            progress(
                f"epoch {epoch + 1}/{epochs}: loss {recon_mean + kl_weight * kl_mean:.3f} (reconstruction "
                f"{recon_mean:.3f}, KL {kl_mean:.3f} × {kl_weight:.2f}), "
                f"val geodesic {vae.geodesic_error(x_val).mean():.4f} rad"
            )
    vae.sigma = _residual_sigma(vae, x_val, sigma_floor)
    vae.info = {
        "latent": latent, "width": width, "epochs": epochs, "batch": batch, "lr": lr, "recon_sigma": recon_sigma,
        "kl_anneal_epochs": kl_anneal_epochs, "sigma_floor": sigma_floor, "seed": seed,
        "joints": [int(j) for j in vae.joints], "train_poses": len(x_train), "val_poses": len(x_val),
        "val_geodesic_err_rad": float(vae.geodesic_error(x_val).mean()),
        "val_elbo": float(vae.elbo(x_val).mean()),
        "fit_seconds": round(time.perf_counter() - start, 2),
    }  # fmt: skip
    return vae


def _residual_sigma(vae: PoseVAE, poses: np.ndarray, floor: float) -> np.ndarray:
    """``(3J,)`` root mean square of ``θ_m − a(μ(θ))`` over ``poses``, at least ``floor``.

    The root mean square rather than the standard deviation, because the factor's Gaussian is
    centred on ``a(z)`` with no bias term. Near π the same rotation has two axis-angle vectors
    (``θ`` and ``θ − 2π θ/|θ|``); each residual uses the one nearer the decoded vector, so σ
    measures the decoder's rotation error rather than the representation's wrap.
    """
    with torch.no_grad():
        a = vae.decode_rotvec_torch(torch.as_tensor(vae.encode(poses), dtype=vae.dtype)).double().numpy()
    theta = poses[:, vae.dims].reshape(len(poses), -1, 3)
    angle = np.linalg.norm(theta, axis=-1, keepdims=True)
    wrapped = theta - 2 * np.pi * theta / np.maximum(angle, 1e-12)
    a = a.reshape(theta.shape)
    wrap_is_nearer = np.linalg.norm(wrapped - a, axis=-1, keepdims=True) < np.linalg.norm(theta - a, axis=-1, keepdims=True)
    nearer = np.where(wrap_is_nearer, wrapped, theta)
    return np.maximum(np.sqrt(np.square(nearer - a).reshape(len(poses), -1).mean(axis=0)), floor)


def train_pose_vae(
    motion_dir: str | Path,
    body: BodyModel,
    latent: int = 32,
    width: int = 512,
    epochs: int = 40,
    batch: int = 512,
    seed: int = 0,
    stride: int = 4,
    val_fraction: float = 0.2,
    progress: Callable[[str], None] | None = None,
) -> PoseVAE:
    """Load CMU takes, split by subject (the pose GMM's split), fit with :func:`fit_pose_vae`.

    Returns the model; its ``info`` adds the data directory, stride, held-out subjects and
    loading time to :func:`fit_pose_vae`'s record.
    """
    start = time.perf_counter()
    frames = load_pose_frames(motion_dir, body, stride, progress)
    load_s = time.perf_counter() - start
    val, val_subjects = held_out_split(frames.subjects, val_fraction, seed, "poses", progress)
    vae = fit_pose_vae(
        frames.poses[~val], frames.poses[val], latent=latent, width=width, epochs=epochs, batch=batch,
        seed=seed, body_model=body.name, progress=progress,
    )  # fmt: skip
    vae.info = {"data": Path(motion_dir).name, "stride": stride, "val_subjects": val_subjects,
                **vae.info, "load_seconds": round(load_s, 2)}  # fmt: skip
    return vae
