"""A learned decoder evaluated for every latent variable of a graph at once.

A learned prior enters the graphs in latent-variable form (``../shared/notes/gtsam_performance.md``
§4): a latent variable ``z`` per frame or window with a unit Gaussian prior, and factors that tie
the body's variables to the decoder's output ``f(z)``. GTSAM calls each factor's error function
on its own, while a network is only fast on a batch. :class:`BatchedDecoder` bridges the two:
the first factor that asks for ``f(z_k)`` at a new value of ``z_k`` triggers one batched
evaluation over every latent variable present in the ``gtsam.Values``, together with the
Jacobians when they were asked for, and the other factors of the same linearisation read the
cache. ``f`` acts row by row (no batch statistics), so a cached row stays valid as long as its own
``z_k`` is unchanged, which is the cache's only test.
"""

from __future__ import annotations

from typing import Callable

import gtsam
import numpy as np
import torch

from mocapgraph.errors import MocapgraphError


class BatchedDecoder:
    """``f: (B, L) → (B, R)`` and its Jacobian ``(B, R, L)`` for the latent variables ``keys``.

    Args:
        fn: a torch function acting independently on each row of a ``(B, L)`` float32 batch.
        keys: the GTSAM keys of the latent variables (``Vector(L)`` each).
        dim: ``L``.
        chunk_size: rows per vectorised Jacobian pass (None: the whole batch in one pass).

    The Jacobian comes from forward-mode differentiation (``L`` JVPs per row, vectorised over the
    batch), cheaper than reverse mode because ``L`` is smaller than ``R`` for every prior here.
    A pass holds ``L`` tangents of every hidden activation of its rows; for a large network,
    chunks keep them in cache (the motion VAE, W = 128, L = 64, 72 windows: 14.6 ms per window
    in chunks of 8 against 26.8 ms in one pass, 1 thread).
    """

    def __init__(
        self, fn: Callable[[torch.Tensor], torch.Tensor], keys: list[int], dim: int, chunk_size: int | None = None
    ):
        self.fn, self.keys, self.dim = fn, [int(k) for k in keys], int(dim)
        self.chunk_size = chunk_size
        self.row = {k: i for i, k in enumerate(self.keys)}
        self._z = np.full((len(self.keys), self.dim), np.nan)
        self._out: np.ndarray | None = None
        self._jac: np.ndarray | None = None
        self._has_jac = np.zeros(len(self.keys), dtype=bool)
        self.evaluations = 0  # batched network runs, for tests and benchmarks

    def __call__(self, values: gtsam.Values, key: int, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """``f(z_key)`` ``(R,)`` and, when ``jacobian``, ``∂f/∂z_key`` ``(R, L)``, at ``values``.

        The output is a copy; the Jacobian is a read-only view of the cache (slice it, don't keep it).
        """
        i = self.row[key]
        if not (np.array_equal(self._z[i], values.atVector(key)) and (self._has_jac[i] or not jacobian)):
            self._evaluate(values, jacobian)
        return self._out[i].copy(), (self._jac[i] if jacobian else None)

    def _evaluate(self, values: gtsam.Values, jacobian: bool) -> None:
        present = np.array([values.exists(k) for k in self.keys])
        Z = np.full((len(self.keys), self.dim), np.nan)
        Z[present] = np.stack([values.atVector(k) for k, p in zip(self.keys, present) if p])
        batch = torch.as_tensor(Z[present], dtype=torch.float32)
        with torch.no_grad():
            out = self.fn(batch).double().numpy()
        if self._out is None:
            self._out = np.zeros((len(self.keys), out.shape[1]))
            self._jac = np.zeros((len(self.keys), out.shape[1], self.dim))
        self._out[present] = out
        if jacobian:
            single = lambda z: self.fn(z[None])[0]  # noqa: E731 (torch.func wants a per-row function)
            with torch.no_grad():
                rows_jacobian = torch.func.vmap(torch.func.jacfwd(single), chunk_size=self.chunk_size)
                self._jac[present] = rows_jacobian(batch).double().numpy()
        self._has_jac = present & jacobian
        self._z = Z
        self.evaluations += 1


def latent_prior_factor(key: int, dim: int, sigma: float = 1.0) -> gtsam.NonlinearFactor:
    """``z ~ N(0, σ² I)`` on one latent variable, cost ``½‖z‖²/σ²``: the VAE's own prior with
    ``σ = 1``; a wider ``σ`` tempers its pull toward the decoder's mode at ``z = 0``."""
    if not (np.isfinite(sigma) and sigma > 0):
        raise MocapgraphError(f"latent prior: sigma must be finite and > 0, got {sigma}")
    return gtsam.PriorFactorVector(int(key), np.zeros(dim), gtsam.noiseModel.Isotropic.Sigma(dim, float(sigma)))
