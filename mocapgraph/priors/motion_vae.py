"""SmartMocap's motion prior: a VAE over 25-frame motion windows, its file format and training.

A window is ``(25, 198)``: 25 frames at 30 fps of the 22 joint positions (metres) and 6D joint
orientations in the window's canonical frame (:mod:`mocapgraph.priors.motion_windows`). The
network sees channels normalised by the training mean and standard deviation (stored with the
model) and is convolutional in time:

- encoder: Conv1d(198→W, k3) → N residual blocks (conv–GELU–conv + skip, width W) → GELU →
  mean over time → Linear(W→2L) = μ, log σ²_q;
- decoder: Linear(L→25·W) → reshape (W, 25) → N residual blocks → Conv1d(W→198, k3).

Every convolution pads by one frame ("same"), so the network acts on each window on its own (no
batch statistics), as :class:`~mocapgraph.priors.latent.BatchedDecoder` requires.

Density: ``z ~ N(0, I_L)`` and ``p(x | z) = N(dec(z), diag σ²)`` with ``σ (25, 198)`` in data
units, per frame and channel: the standard deviation of the held-out reconstruction residual
``x − dec(μ(x))`` measured after training, floored (1 cm for positions). The per-frame factor of
:mod:`mocapgraph.priors.motion_factor` uses the 66 position channels of it. Training minimises
``½‖x̂ − x‖² + β_t KL(q(z|x) ‖ N(0, I))`` per window in normalised units, where ``β_t`` follows a
cyclic schedule (a linear ramp from 0 to β over the first half of every ``cycle`` epochs, then
flat) so the decoder learns to use the latent before the KL term shapes it. β plays the part of
the normalised residual variance (a Gaussian likelihood of variance β in normalised units),
so ``β = 0.003`` asks for residuals of about 0.055 standard deviations of each channel.

File format (:mod:`mocapgraph.priors.model_file`): an ``.npz`` without pickles:
``format_version``, ``body_model``, ``config`` and ``info`` (JSON), ``mean``, ``std``, ``sigma``,
and one array ``state/<name>`` per entry of the network's ``state_dict`` (float16 by default: it
halves the file and changed the shipped model's held-out MPJPE by 0.002 mm).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable

import gtsam
import numpy as np
import torch
from torch import nn

from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.keys import motion_latent_key
from mocapgraph.priors.latent import BatchedDecoder
from mocapgraph.priors.model_file import load_weights, read_model_file, weight_arrays, write_model_file
from mocapgraph.priors.motion_windows import CHANNELS, POSITION_CHANNELS, WINDOW, feature_positions

DEFAULT_MOTION_VAE = Path(__file__).parent / "data" / "motion_vae.npz"
FORMAT_VERSION = 1
_KEYS = ("format_version", "body_model", "config", "info", "mean", "std", "sigma")
SIGMA_FLOOR = 0.01
"""Smallest decoder σ (metres for positions, unit-vector components for 6D): the first frame's
root x, y are 0 by construction and would otherwise get a σ of almost 0."""


@dataclass(frozen=True)
class MotionVAEConfig:
    """Network sizes: residual ``width`` W, ``latent`` L, ``blocks`` N per side."""

    width: int = 128
    latent: int = 64
    blocks: int = 2

    def __post_init__(self):
        for name in ("width", "latent", "blocks"):
            if int(getattr(self, name)) < 1:
                raise MocapgraphError(f"MotionVAEConfig: {name} must be >= 1, got {getattr(self, name)}")


class _ResidualBlock(nn.Module):
    def __init__(self, width: int):
        super().__init__()
        self.conv1 = nn.Conv1d(width, width, 3, padding=1)
        self.conv2 = nn.Conv1d(width, width, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv2(nn.functional.gelu(self.conv1(x)))


class MotionVAENet(nn.Module):
    """The torch network on normalised windows ``(B, 25, 198)``; see the module docstring."""

    def __init__(self, config: MotionVAEConfig):
        super().__init__()
        W, L, N = config.width, config.latent, config.blocks
        self.config = config
        self.encoder_in = nn.Conv1d(CHANNELS, W, 3, padding=1)
        self.encoder_blocks = nn.Sequential(*[_ResidualBlock(W) for _ in range(N)])
        self.encoder_out = nn.Linear(W, 2 * L)
        self.decoder_in = nn.Linear(L, W * WINDOW)
        self.decoder_blocks = nn.Sequential(*[_ResidualBlock(W) for _ in range(N)])
        self.decoder_out = nn.Conv1d(W, CHANNELS, 3, padding=1)

    def encode(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """μ and log σ²_q ``(B, L)`` of normalised windows ``(B, 25, 198)``."""
        h = self.encoder_blocks(self.encoder_in(x.transpose(1, 2)))
        out = self.encoder_out(nn.functional.gelu(h).mean(dim=2))
        return out.chunk(2, dim=1)

    def trunk(self, z: torch.Tensor) -> torch.Tensor:
        """The decoder up to its output convolution: ``(B, W, 25)``."""
        return self.decoder_blocks(self.decoder_in(z).view(len(z), self.config.width, WINDOW))

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """Normalised windows ``(B, 25, 198)`` of latents ``(B, L)``."""
        return self.decoder_out(self.trunk(z)).transpose(1, 2)

    def decode_channels(self, z: torch.Tensor, channels: slice) -> torch.Tensor:
        """``decode(z)[..., channels]`` ``(B, 25, C)``, computing only those output channels."""
        weight, bias = self.decoder_out.weight[channels], self.decoder_out.bias[channels]
        return nn.functional.conv1d(self.trunk(z), weight, bias, padding=1).transpose(1, 2)


@dataclass(frozen=True, eq=False)
class MotionVAE:
    """A trained motion VAE with its normalisation and decoder noise.

    Attributes:
        net: the network (float32; it has no dropout or batch statistics, so no train/eval modes).
        mean, std: ``(198,)`` channel normalisation (data units).
        sigma: ``(25, 198)`` decoder standard deviation per frame and channel (data units).
        body_model: the body model whose joints the windows hold (e.g. ``"anny"``).
        info: free-form training record (data, split, seconds, held-out numbers), saved with the file.
    """

    net: MotionVAENet
    mean: np.ndarray
    std: np.ndarray
    sigma: np.ndarray
    body_model: str = "anny"
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        mean, std, sigma = (np.asarray(a, dtype=float) for a in (self.mean, self.std, self.sigma))
        if mean.shape != (CHANNELS,) or std.shape != (CHANNELS,) or sigma.shape != (WINDOW, CHANNELS):
            raise MocapgraphError(
                f"MotionVAE: expected mean ({CHANNELS},), std ({CHANNELS},), sigma ({WINDOW}, {CHANNELS}), "
                f"got {mean.shape}, {std.shape}, {sigma.shape}"
            )
        if not (np.all(np.isfinite(mean)) and np.all(std > 0) and np.all(sigma > 0)):
            raise MocapgraphError("MotionVAE: mean must be finite, std and sigma positive")
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "std", std)
        object.__setattr__(self, "sigma", sigma)
        object.__setattr__(self, "_mean_t", torch.as_tensor(mean, dtype=torch.float32))
        object.__setattr__(self, "_std_t", torch.as_tensor(std, dtype=torch.float32))

    @property
    def config(self) -> MotionVAEConfig:
        return self.net.config

    @property
    def latent_dim(self) -> int:
        return self.config.latent

    @property
    def parameter_count(self) -> int:
        return sum(p.numel() for p in self.net.parameters())

    @property
    def position_sigma(self) -> np.ndarray:
        """``(25, 66)`` decoder σ of the joint positions, metres."""
        return self.sigma[:, :POSITION_CHANNELS]

    def _normalised(self, windows) -> torch.Tensor:
        x = np.asarray(windows, dtype=float)
        if x.ndim != 3 or x.shape[1:] != (WINDOW, CHANNELS) or not np.all(np.isfinite(x)):
            raise MocapgraphError(f"windows: expected finite (N, {WINDOW}, {CHANNELS}), got shape {x.shape}")
        return torch.as_tensor((x - self.mean) / self.std, dtype=torch.float32)

    def encode(self, windows) -> tuple[np.ndarray, np.ndarray]:
        """μ and log σ²_q ``(N, L)`` of windows ``(N, 25, 198)`` (canonical frame, data units)."""
        with torch.no_grad():
            mu, logvar = self.net.encode(self._normalised(windows))
        return mu.double().numpy(), logvar.double().numpy()

    def decode(self, z) -> np.ndarray:
        """Windows ``(N, 25, 198)`` (canonical frame, data units) of latents ``(N, L)``."""
        with torch.no_grad():
            out = self.net.decode(torch.as_tensor(np.asarray(z), dtype=torch.float32))
        return out.double().numpy() * self.std + self.mean

    def decode_positions(self, z: torch.Tensor) -> torch.Tensor:
        """Flattened joint positions ``(B, 25·66)`` (canonical frame, metres; frame-major, then
        joint, then x, y, z) of latents ``(B, L)`` float32, differentiable: the function of the
        :class:`~mocapgraph.priors.latent.BatchedDecoder` of the motion factor."""
        pos = slice(0, POSITION_CHANNELS)
        out = self.net.decode_channels(z, pos) * self._std_t[pos] + self._mean_t[pos]
        return out.reshape(len(z), WINDOW * POSITION_CHANNELS)

    def sample(self, n: int, seed: int = 0) -> np.ndarray:
        """``(n, 25, 198)`` windows decoded from ``z ~ N(0, I)`` drawn with ``seed`` (decoder means)."""
        return self.decode(np.random.default_rng(seed).standard_normal((n, self.latent_dim)))

    def reconstruction_mpjpe(self, windows) -> np.ndarray:
        """``(N,)`` metres: mean over frames and joints of ``|pos(dec(μ(x))) − pos(x)|`` per window."""
        recon = self.decode(self.encode(windows)[0])
        return np.linalg.norm(feature_positions(recon) - feature_positions(windows), axis=-1).mean(axis=(1, 2))

    def elbo(self, windows, samples: int = 8, seed: int = 0) -> np.ndarray:
        """``(N,)`` evidence lower bound ``E_q[log p(x|z)] − KL(q(z|x) ‖ N(0, I))`` of each window,
        nats (higher is more probable), with ``samples`` draws of ``z ~ q`` from ``seed``."""
        x = np.asarray(windows, dtype=float)
        mu, logvar = self.encode(x)
        rng = np.random.default_rng(seed)
        log_norm = -np.log(self.sigma).sum() - 0.5 * self.sigma.size * np.log(2 * np.pi)
        log_lik = np.zeros(len(x))
        for _ in range(samples):
            z = mu + np.exp(0.5 * logvar) * rng.standard_normal(mu.shape)
            log_lik += -0.5 * np.square((x - self.decode(z)) / self.sigma).sum(axis=(1, 2)) + log_norm
        kl = 0.5 * (np.exp(logvar) + np.square(mu) - 1.0 - logvar).sum(axis=1)
        return log_lik / samples - kl

    def save(self, path: str | Path, dtype=np.float16) -> Path:
        """Write an ``.npz`` (see the module docstring) with the weights as ``dtype``; atomic rename."""
        return write_model_file(
            path, compressed=True, format_version=FORMAT_VERSION, body_model=self.body_model,
            config=json.dumps(asdict(self.config)), info=json.dumps(self.info), mean=self.mean, std=self.std,
            sigma=self.sigma, **weight_arrays(self.net, dtype),
        )  # fmt: skip

    @classmethod
    def load(cls, path: str | Path) -> MotionVAE:
        """Read a file written by :meth:`save`; errors name the file and the key."""
        arrays = read_model_file(path, "motion VAE", _KEYS, FORMAT_VERSION)
        try:
            net = MotionVAENet(MotionVAEConfig(**json.loads(str(arrays["config"]))))
            info = json.loads(str(arrays["info"]))
        except (ValueError, TypeError) as exc:
            raise MocapgraphError(f"{path}: unreadable 'config' or 'info' ({exc})") from None
        load_weights(path, net, arrays)
        body_model = str(arrays["body_model"])
        arrays = {k: arrays[k].astype(float) for k in ("mean", "std", "sigma")}
        try:
            return cls(net, **arrays, body_model=body_model, info=info)
        except MocapgraphError as exc:
            raise MocapgraphError(f"{path}: {exc}") from None


JACOBIAN_CHUNK = 8
"""Windows per vectorised Jacobian pass: 8 keeps a pass's tangents in cache (W = 128, L = 64, 72
windows, 1 thread: 14.6 ms per window against 26.8 ms in one pass; chunks of 2 or 24: 15.8, 15.9 ms)."""


def load_default_motion_vae() -> MotionVAE:
    """The shipped motion VAE (:data:`DEFAULT_MOTION_VAE`; its ``info`` records sizes, data and held-out numbers)."""
    return MotionVAE.load(DEFAULT_MOTION_VAE)


def kl_weight(epoch_position: float, beta: float, cycle: int) -> float:
    """KL weight at ``epoch_position`` (epochs since the start, fractional): a linear ramp from 0
    to ``beta`` over the first half of each ``cycle`` epochs, then ``beta``."""
    phase = (epoch_position % cycle) / cycle
    return beta * min(1.0, 2.0 * phase)


def _check_windows(windows, name: str) -> np.ndarray:
    x = np.asarray(windows, dtype=np.float32)
    if x.ndim != 3 or x.shape[1:] != (WINDOW, CHANNELS) or len(x) == 0 or not np.all(np.isfinite(x)):
        raise MocapgraphError(f"{name}: expected finite (N ≥ 1, {WINDOW}, {CHANNELS}), got shape {x.shape}")
    return x


def measure_sigma(vae: MotionVAE, windows, floor: float = SIGMA_FLOOR) -> np.ndarray:
    """``(25, 198)`` root-mean-square reconstruction residual ``x − dec(μ(x))`` of ``windows``
    per frame and channel, at least ``floor``."""
    x = np.asarray(windows, dtype=float)
    residual = np.concatenate([x[i : i + 4096] - vae.decode(vae.encode(x[i : i + 4096])[0]) for i in range(0, len(x), 4096)])
    return np.maximum(np.sqrt(np.square(residual).mean(axis=0)), floor)


def fit_motion_vae(
    train_windows,
    val_windows,
    config: MotionVAEConfig = MotionVAEConfig(),
    epochs: int = 20,
    seed: int = 0,
    beta: float = 0.003,
    cycle: int = 20,
    batch_size: int = 64,
    learning_rate: float = 1e-3,
    body_model: str = "anny",
    progress: Callable[[str], None] | None = None,
) -> MotionVAE:
    """Train a :class:`MotionVAE` on windows in memory, then measure its σ on ``val_windows``.

    Args:
        train_windows, val_windows: ``(N, 25, 198)`` features (canonical frame, data units).
        config: network sizes.
        epochs: passes over ``train_windows``.
        seed: seeds the initial weights, the shuffling and the reparameterisation noise; the same
            seed (and torch thread count) gives the same model.
        beta: the KL weight reached in each cycle (see the module docstring).
        cycle: epochs per KL cycle.
        batch_size, learning_rate: Adam's mini-batches and step size (cosine-decayed to 5 %).
            Batches of 64 beat 256 for the same compute (held-out MPJPE 69 against 86 mm after two
            epochs on a third of the CMU windows, W = 128, L = 32; learning rate 3e-3 gave 74 mm).
        body_model: recorded in the model.
        progress: called with one line per epoch (``epoch 3/40: loss …, val mpjpe … mm``).

    Returns:
        the model; its ``info`` holds the window counts, ``val_mpjpe_m`` (mean over held-out
        windows, frames and joints of the reconstruction's position error, metres) and seconds.
    """
    train = _check_windows(train_windows, "train_windows")
    val = _check_windows(val_windows, "val_windows")
    if epochs < 1 or cycle < 1 or batch_size < 1 or not beta >= 0:
        raise MocapgraphError(
            f"fit_motion_vae: epochs, cycle, batch_size must be >= 1 and beta >= 0, got {epochs}, {cycle}, {batch_size}, {beta}"
        )
    start = time.perf_counter()
    mean = train.mean(axis=(0, 1), dtype=np.float64)
    # A floor keeps channels that never move (the first frame's root x, y are 0) finite.
    std = np.maximum(train.std(axis=(0, 1), dtype=np.float64), 1e-3)
    data = torch.as_tensor((train - mean.astype(np.float32)) / std.astype(np.float32))
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        net = MotionVAENet(config)
    generator = torch.Generator().manual_seed(seed)
    optimiser = torch.optim.Adam(net.parameters(), lr=learning_rate)
    batches = (len(data) + batch_size - 1) // batch_size
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=epochs * batches, eta_min=0.05 * learning_rate)
    # Progress lines score a fixed, evenly spaced subset of the held-out windows (cheap per epoch).
    monitor = val[np.linspace(0, len(val) - 1, min(len(val), 1024)).astype(int)]
    for epoch in range(epochs):
        order = torch.randperm(len(data), generator=generator)
        total = total_kl = 0.0
        for b in range(batches):
            x = data[order[b * batch_size : (b + 1) * batch_size]]
            mu, logvar = net.encode(x)
            z = mu + torch.exp(0.5 * logvar) * torch.randn(mu.shape, generator=generator)
            recon = 0.5 * torch.square(net.decode(z) - x).sum(dim=(1, 2)).mean()
            kl = 0.5 * (torch.exp(logvar) + torch.square(mu) - 1.0 - logvar).sum(dim=1).mean()
            loss = recon + kl_weight(epoch + b / batches, beta, cycle) * kl
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            total += float(loss.detach()) * len(x)
            total_kl += float(kl.detach()) * len(x)
        if progress is not None:
            vae = MotionVAE(net, mean, std, np.ones((WINDOW, CHANNELS)), body_model)
            progress(
                f"epoch {epoch + 1}/{epochs}: loss {total / len(data):.2f}, kl {total_kl / len(data):.1f}, "
                f"val mpjpe {1000 * vae.reconstruction_mpjpe(monitor).mean():.1f} mm ({time.perf_counter() - start:.0f} s)"
            )
    fit_s = time.perf_counter() - start
    vae = MotionVAE(net, mean, std, np.ones((WINDOW, CHANNELS)), body_model)
    val_mpjpe = np.concatenate([vae.reconstruction_mpjpe(val[i : i + 4096]) for i in range(0, len(val), 4096)])
    info = {
        "width": config.width, "latent": config.latent, "blocks": config.blocks, "parameters": vae.parameter_count,
        "epochs": epochs, "seed": seed, "beta": beta, "cycle": cycle, "batch_size": batch_size,
        "learning_rate": learning_rate, "train_windows": len(train), "val_windows": len(val),
        "val_mpjpe_m": float(val_mpjpe.mean()), "fit_seconds": round(fit_s, 1),
    }  # fmt: skip
    return replace(vae, sigma=measure_sigma(vae, val), info=info)


def train_motion_vae(
    motion_dir: str | Path,
    body,
    width: int = 128,
    latent: int = 64,
    epochs: int = 20,
    seed: int = 0,
    stride: int = 5,
    val_fraction: float = 0.2,
    progress: Callable[[str], None] | None = None,
    blocks: int = 2,
    beta: float = 0.003,
) -> MotionVAE:
    """Load the CMU takes of ``motion_dir`` as windows on ``body`` (default shape, one window every
    ``stride`` frames), hold out a seeded ``val_fraction`` of the subjects (the same subjects as
    the pose prior for the same seed), train on the rest, measure σ and the MPJPE on the held-out.

    Returns the model; its ``info`` adds the data, the stride, the held-out subjects, the loading
    time and the decoder Jacobian's cost (:func:`decoder_jacobian_ms`
    with the process's torch threads) to :func:`fit_motion_vae`'s record.
    """
    from mocapgraph.priors.motion_windows import load_motion_windows
    from mocapgraph.priors.training import held_out_split

    start = time.perf_counter()
    windows = load_motion_windows(motion_dir, body, stride, progress)
    load_s = time.perf_counter() - start
    val, held_out = held_out_split(windows.subjects, val_fraction, seed, "windows", progress)
    vae = fit_motion_vae(
        windows.features[~val], windows.features[val], MotionVAEConfig(width, latent, blocks), epochs, seed, beta,
        body_model=body.name, progress=progress,
    )  # fmt: skip
    info = {"data": Path(motion_dir).name, "stride": stride, "val_fraction": val_fraction,
            "val_subjects": held_out, "train_subjects": int(len(np.unique(windows.subjects[~val]))),
            "load_seconds": round(load_s, 1), **vae.info,
            "decoder_jacobian_ms_per_window": round(decoder_jacobian_ms(vae), 1),
            "decoder_jacobian_threads": torch.get_num_threads()}  # fmt: skip
    return replace(vae, info=info)


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

