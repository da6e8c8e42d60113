"""Gaussian-mixture pose prior: the mixture, its file format, and EM fitting in numpy.

A pose is the 21 local joint rotations of the body as axis-angle vectors, flattened to ``(63,)``
in SMPL joint order (``mocapgraph.body.skeleton``), each in its parent joint's frame, radians;
all zeros is the T-pose. It is exactly the ``pose_key`` variable of the factor graphs. The code
below works for any dimension ``D`` (tests use small ones). The shipped prior models the 16 joints
that move in its training data (``joints``), ``D = 48`` of the 63; it leaves the other joints'
dimensions to the graphs' weak regulariser (``docs/priors.md``).

Density: ``p(θ) = Σ_k w_k N(θ; μ_k, Σ_k)``. Each component is stored as its covariance and
used through ``P_k``, the upper-triangular Cholesky factor of its precision
(``Σ_k⁻¹ = P_k P_kᵀ``, sklearn's ``precisions_cholesky``), so ``‖P_kᵀ(θ − μ_k)‖²`` is the
Mahalanobis distance and ``P_kᵀ(θ − μ_k)`` the whitened residual of the factor.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.linalg import solve_triangular
from scipy.special import logsumexp

from mocapgraph.errors import MocapgraphError
from mocapgraph.priors.model_file import read_model_file, write_model_file

FORMAT_VERSION = 1
_KEYS = ("format_version", "body_model", "weights", "means", "covariances", "info")


@dataclass(frozen=True, eq=False)
class PoseGMM:
    """A Gaussian mixture over pose vectors.

    Attributes:
        weights: ``(M,)`` mixture weights, positive, summing to 1.
        means: ``(M, D)`` component means (axis-angle, radians).
        covariances: ``(M, D, D)`` symmetric positive definite (rad²).
        body_model: name of the body model whose joint frames the poses are in (e.g. ``"anny"``).
        info: free-form training record (data, seed, held-out numbers), saved with the file.
        joints: indices of the modelled joints (``D = 3·len(joints)``) when the mixture covers
            only part of a pose: then poses passed in are whole ``(N, 3·J)`` vectors and
            :meth:`select` picks the modelled dimensions; None when the mixture covers the whole
            vector.
    """

    weights: np.ndarray
    means: np.ndarray
    covariances: np.ndarray
    body_model: str = "anny"
    info: dict = field(default_factory=dict)
    joints: np.ndarray | None = None
    precisions_cholesky: np.ndarray = field(init=False, repr=False)
    """``(M, D, D)`` upper-triangular ``P_k`` with ``P_k P_kᵀ = Σ_k⁻¹``."""
    log_det_cov: np.ndarray = field(init=False, repr=False)
    """``(M,)`` ``log det Σ_k``."""
    _chol: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        w, mu, cov = (np.asarray(a, dtype=float) for a in (self.weights, self.means, self.covariances))
        M, D = mu.shape if mu.ndim == 2 else (0, 0)
        if M == 0 or w.shape != (M,) or cov.shape != (M, D, D):
            raise MocapgraphError(
                f"PoseGMM: expected weights (M,), means (M, D), covariances (M, D, D), "
                f"got {w.shape}, {mu.shape}, {cov.shape}"
            )
        if not all(np.all(np.isfinite(a)) for a in (w, mu, cov)):
            raise MocapgraphError("PoseGMM: weights, means and covariances must be finite")
        if self.joints is not None:
            joints = np.asarray(self.joints, dtype=int)
            if joints.ndim != 1 or 3 * len(joints) != D or len(np.unique(joints)) != len(joints) or np.any(joints < 0):
                raise MocapgraphError(f"PoseGMM: joints must be {D // 3} distinct indices >= 0 for D = {D}, got {self.joints!r}")
            object.__setattr__(self, "joints", joints)
        if not (np.all(w > 0) and abs(w.sum() - 1.0) < 1e-6):
            raise MocapgraphError("PoseGMM: weights must be positive and sum to 1")
        if not np.allclose(cov, np.swapaxes(cov, 1, 2), rtol=0.0, atol=1e-10 * np.abs(cov).max()):
            raise MocapgraphError("PoseGMM: every covariance must be symmetric")
        try:
            chol = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            raise MocapgraphError("PoseGMM: every covariance must be positive definite") from None
        # P_k = C_k⁻ᵀ with Σ_k = C_k C_kᵀ: then P_kᵀ d = C_k⁻¹ d and P_k P_kᵀ = Σ_k⁻¹.
        inv_chol = np.stack([solve_triangular(c, np.eye(D), lower=True) for c in chol])
        object.__setattr__(self, "weights", w)
        object.__setattr__(self, "means", mu)
        object.__setattr__(self, "covariances", cov)
        object.__setattr__(self, "precisions_cholesky", np.ascontiguousarray(np.swapaxes(inv_chol, 1, 2)))
        object.__setattr__(self, "_chol", chol)
        # log det Σ_k = 2 Σ log diag C_k.
        object.__setattr__(self, "log_det_cov", 2.0 * np.log(np.diagonal(chol, axis1=1, axis2=2)).sum(axis=1))

    @property
    def components(self) -> int:
        return len(self.weights)

    @property
    def dim(self) -> int:
        return self.means.shape[1]

    @property
    def dims(self) -> np.ndarray:
        """``(D,)`` indices of the modelled dimensions in a whole pose vector."""
        if self.joints is None:
            return np.arange(self.dim)
        return (3 * self.joints[:, None] + np.arange(3)).ravel()

    def select(self, poses) -> np.ndarray:
        """``(N, D)``: the modelled dimensions of ``poses`` (``(N, 3·J)`` or ``(N, J, 3)``)."""
        x = _as_poses(poses)
        if self.joints is None:
            return _as_poses(x, self.dim)
        if x.shape[1] <= self.dims.max():
            raise MocapgraphError(f"poses: the mixture models joints up to {self.joints.max()}, got shape {np.shape(poses)}")
        return x[:, self.dims]

    def whitened(self, pose: np.ndarray) -> np.ndarray:
        """``(M, D)``: ``P_kᵀ(θ − μ_k)`` of one pose ``(D,)`` for every component."""
        return np.einsum("kd,kde->ke", pose - self.means, self.precisions_cholesky)

    def component_costs(self) -> np.ndarray:
        """``(M,)`` ``c_k = −log w_k + ½ log det Σ_k``: ``−log(w_k N_k(θ)) = ½ mahalanobis + c_k + D/2 log 2π``."""
        return -np.log(self.weights) + 0.5 * self.log_det_cov

    def component_log_densities(self, poses: np.ndarray) -> np.ndarray:
        """``(N, M)``: ``log(w_k N(θ_n; μ_k, Σ_k))``."""
        # One component at a time: an (M, N, D) temporary would be ~300 MB for the CMU frames.
        maha = np.stack([np.square((poses - m) @ P).sum(axis=1) for m, P in zip(self.means, self.precisions_cholesky)], 1)
        return -0.5 * maha - self.component_costs() - 0.5 * self.dim * np.log(2 * np.pi)

    def log_likelihood(self, poses: np.ndarray) -> np.ndarray:
        """``(N,)`` log density of each pose under the mixture (nats); see :meth:`select`."""
        return logsumexp(self.component_log_densities(self.select(poses)), axis=1)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``(n, D)`` draws from the mixture with ``rng`` (the modelled dimensions only)."""
        k = rng.choice(self.components, size=n, p=self.weights)
        z = rng.standard_normal((n, self.dim))
        return self.means[k] + np.einsum("nde,ne->nd", self._chol[k], z)

    def save(self, path: str | Path) -> Path:
        """Write an ``.npz`` (format version, body model, arrays, info as JSON); atomic rename."""
        return write_model_file(
            path, format_version=FORMAT_VERSION, body_model=self.body_model, weights=self.weights,
            means=self.means, covariances=self.covariances, info=json.dumps(self.info),
            **({} if self.joints is None else {"joints": self.joints}),
        )  # fmt: skip

    @classmethod
    def load(cls, path: str | Path) -> PoseGMM:
        """Read a file written by :meth:`save`; errors name the file and the key."""
        d = read_model_file(path, "pose GMM", _KEYS, FORMAT_VERSION)
        try:
            return cls(
                **{k: d[k].astype(float) for k in ("weights", "means", "covariances")},
                body_model=str(d["body_model"]), info=json.loads(str(d["info"])),
                joints=d["joints"].astype(int) if "joints" in d else None,
            )  # fmt: skip
        except (MocapgraphError, ValueError) as exc:
            raise MocapgraphError(f"{path}: {exc}") from None


def _as_poses(poses, dim: int | None = None) -> np.ndarray:
    """``(N, D)`` finite float array from ``(N, D)`` or ``(N, J, 3)``, or a MocapgraphError."""
    x = np.asarray(poses, dtype=float)
    x = x.reshape(len(x), -1) if x.ndim > 2 else x
    if x.ndim != 2 or (dim is not None and x.shape[1] != dim) or not np.all(np.isfinite(x)):
        want = "D" if dim is None else dim
        raise MocapgraphError(f"poses: expected finite (N, {want}), got shape {np.shape(poses)}")
    return x


def _kmeans_plus_plus(x: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """``(k, D)`` seeds: the first uniformly, each next with probability ∝ squared distance."""
    centres = [x[rng.integers(len(x))]]
    d2 = np.square(x - centres[0]).sum(axis=1)
    for _ in range(1, k):
        centres.append(x[rng.choice(len(x), p=d2 / d2.sum())])
        d2 = np.minimum(d2, np.square(x - centres[-1]).sum(axis=1))
    return np.stack(centres)


def fit_pose_gmm(
    poses,
    components: int = 8,
    seed: int = 0,
    iterations: int = 30,
    reg: float = 1e-3,
    tol: float = 1e-3,
    body_model: str = "anny",
    progress: Callable[[int, float], None] | None = None,
    joints=None,
) -> PoseGMM:
    """Fit a full-covariance Gaussian mixture by EM.

    Args:
        poses: ``(N, D)`` training vectors (``(N, 21, 3)`` is flattened).
        components: number of components M.
        seed: seeds the k-means++ initialisation; the same seed gives the same mixture.
        iterations: at most this many EM steps.
        reg: added to every covariance's diagonal (rad²) so components stay positive definite
            even on dimensions the data never moves (e.g. the retargeted feet are always zero).
        tol: stop when the mean log-likelihood per sample improves by less than this (nats).
        body_model: recorded in the mixture (the joint frames the poses are in).
        progress: called as ``progress(iteration, mean_log_likelihood)`` after each E-step.
        joints: model only these joints of whole poses (``PoseGMM.joints``); None: every dimension.

    Returns:
        the fitted :class:`PoseGMM`.
    """
    x = _as_poses(poses)
    if joints is not None:
        joints = np.asarray(joints, dtype=int)
        x = x[:, (3 * joints[:, None] + np.arange(3)).ravel()]
    N, D = x.shape
    if components < 1:
        raise MocapgraphError(f"fit_pose_gmm: components must be >= 1, got {components}")
    if N < components:
        raise MocapgraphError(f"fit_pose_gmm: {N} samples for {components} components")
    if reg <= 0:
        raise MocapgraphError("fit_pose_gmm: reg must be > 0 (it keeps the covariances positive definite)")
    rng = np.random.default_rng(seed)
    # Hard assignment to the nearest k-means++ seed gives the first M-step's responsibilities.
    centres = _kmeans_plus_plus(x, components, rng)
    nearest = np.argmin(np.square(centres).sum(axis=1) - 2.0 * x @ centres.T, axis=1)
    resp = np.eye(components)[nearest]
    previous = -np.inf
    for it in range(iterations):
        gmm = _m_step(x, resp, reg, body_model, joints)
        log_dens = gmm.component_log_densities(x)
        log_lik = logsumexp(log_dens, axis=1)
        resp = np.exp(log_dens - log_lik[:, None])
        mean_ll = float(log_lik.mean())
        if progress is not None:
            progress(it, mean_ll)
        if mean_ll - previous < tol:
            break
        previous = mean_ll
    return _m_step(x, resp, reg, body_model, joints)


def _m_step(x: np.ndarray, resp: np.ndarray, reg: float, body_model: str, joints) -> PoseGMM:
    """Weights, means and regularised covariances from responsibilities ``(N, M)``."""
    # A tiny floor keeps a component that lost all its samples defined (mean 0, covariance
    # reg·I, weight ~1e-15) instead of dividing by zero.
    nk = resp.sum(axis=0) + 10 * np.finfo(float).eps
    means = (resp.T @ x) / nk[:, None]
    cov = np.empty((len(nk), x.shape[1], x.shape[1]))
    for k in range(len(nk)):
        d = x - means[k]
        cov[k] = (resp[:, k, None] * d).T @ d / nk[k]
    cov += reg * np.eye(x.shape[1])
    return PoseGMM(nk / nk.sum(), means, cov, body_model, joints=joints)
