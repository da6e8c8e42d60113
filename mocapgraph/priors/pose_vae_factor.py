"""The pose VAE prior as GTSAM factors in latent-variable form.

For each body state ``i`` the prior adds a latent variable ``z_i = pose_latent_key(i)``
(``Vector(L)``) and two factors:

- ``latent_prior_factor``: ``z_i ~ N(0, s² I)``, cost ``½‖z_i‖²/s²`` (``s`` = ``latent_sigma``);
- a ``CustomFactor`` on ``[pose_key(i), pose_latent_key(i)]`` with the ``3J`` residual rows

      r = (θ_i[m] − a(z_i)) / σ,     Jacobians  [ S / σ ,  −J_a(z_i) / σ ],

  where ``m`` are the VAE's modelled dimensions (its moving joints), ``S`` the ``(3J, 63)``
  selection of those dimensions, ``a`` the decoder (axis-angle out, :meth:`PoseVAE.decode_rotvec_torch`)
  and ``σ`` its residual measured on held-out poses.

With ``s = 1`` the two cost ``½‖z‖² + ½‖(θ_m − a(z))/σ‖² = −log p(θ_m, z) + const`` with
``const = (L + 3J)/2 log 2π + Σ log σ``: the VAE's joint density of the modelled rotations and the
latent. The solver minimises it over ``z`` along with everything else, and that minimum
approximates ``−log p(θ_m)`` (the MAP-latent approximation of the marginal).

**Why ``s`` = 3 by default.** That minimum over ``z`` pulls every pose toward the decoder's mode,
``a(0)``, and for a model of all of CMU that mode is a crouch (hips flexed 0.46 rad, knees 0.7,
spine1 0.4). Under heavy keypoint noise the fit followed it: spine1 bent, the root turned to
compensate and RA-MPJPE rose above the fit without the prior. A wider latent prior keeps the
pose near the decoder's manifold and weakens the pull to its mode. RA-MPJPE, mean of three
held-out CMU takes (walk, conversation, bending; 8 s each, keypoint noise ×3, not the benchmark's
take): 9.47 cm without a pose prior, 8.25 with ``s`` = 1, **6.34** with 3, 6.41 with 10,
6.43 with 100 (the GMM: 7.17).

The unmodelled
joints (spine3, feet, collars on CMU) get nothing from this prior; the graphs' weak regulariser on
every joint holds them.

The decoder runs once per linearisation for every state: all factors share one
:class:`~mocapgraph.priors.latent.BatchedDecoder`, whose first call at new latents evaluates the
network and its forward-mode Jacobian on the whole batch, and the other factors read its cache.
"""

from __future__ import annotations

from typing import Sequence

import gtsam
import numpy as np

from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.keys import pose_key, pose_latent_key
from mocapgraph.priors.latent import BatchedDecoder, latent_prior_factor
from mocapgraph.priors.pose_vae import PoseVAE

LATENT_SIGMA = 3.0
"""Default σ of the latent prior, chosen by measurement (module docstring)."""


class _LatentPose:
    """The ``(θ_i, z_i)`` factor's error function, shared by every state's factor."""

    def __init__(self, decoder: BatchedDecoder, dims: np.ndarray, sigma: np.ndarray):
        self.decoder, self.dims = decoder, dims
        self.inv_sigma = 1.0 / sigma
        # Column-major S/σ: GTSAM copies Fortran-ordered arrays as they are.
        select = np.zeros((len(dims), 63))
        select[np.arange(len(dims)), dims] = self.inv_sigma
        self.select = np.asfortranarray(select)

    def __call__(self, this, values: gtsam.Values, H) -> np.ndarray:
        theta_key, z_key = this.keys()
        decoded, jac = self.decoder(values, z_key, H is not None)
        if H is not None:
            H[0] = self.select
            H[1] = np.asfortranarray(jac * -self.inv_sigma[:, None])
        return (values.atVector(theta_key)[self.dims] - decoded) * self.inv_sigma


class PoseVAEPrior:
    """The pose VAE prior on the body states ``states`` of one graph, with one shared decoder.

    Args:
        vae: the model, e.g. :func:`mocapgraph.priors.pose_vae.load_default_pose_vae`.
        states: the body-state indices ``i`` that get a latent ``pose_latent_key(i)``.
        latent_sigma: σ of each latent's Gaussian prior (the model's own: 1; see the module docstring).

    Attributes:
        decoder: the shared :class:`BatchedDecoder` (its ``evaluations`` counts network runs).
    """

    def __init__(self, vae: PoseVAE, states: Sequence[int], latent_sigma: float = LATENT_SIGMA):
        self.vae, self.latent_sigma = vae, float(latent_sigma)
        self.states = [int(i) for i in states]
        self.decoder = BatchedDecoder(vae.decode_rotvec_torch, [pose_latent_key(i) for i in self.states], vae.latent)
        self._error = _LatentPose(self.decoder, vae.dims, vae.sigma)
        self._noise = gtsam.noiseModel.Unit.Create(len(vae.dims))
        self._known = set(self.states)

    def factors(self, i: int) -> list[gtsam.NonlinearFactor]:
        """State ``i``'s two factors: ``N(0, s² I)`` on ``z_i`` and the ``(θ_i, z_i)`` factor (``3J`` rows)."""
        if i not in self._known:
            raise MocapgraphError(f"PoseVAEPrior: state {i} is not one of the prior's {len(self.states)} states")
        return [
            latent_prior_factor(pose_latent_key(i), self.vae.latent, self.latent_sigma),
            gtsam.CustomFactor(self._noise, [pose_key(i), pose_latent_key(i)], self._error),
        ]

    def initial_latents(self, poses) -> np.ndarray:
        """``(N, L)``: the encoder's mean for each state's current pose ``(N, 63)``, in ``states`` order."""
        poses = np.asarray(poses, dtype=float)
        if len(poses) != len(self.states):
            raise MocapgraphError(f"PoseVAEPrior: {len(poses)} poses for {len(self.states)} states")
        return self.vae.encode(poses)

    def add_to(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, poses) -> None:
        """Add every state's factors to ``graph`` and insert its latent into ``values``.

        ``poses (N, 63)`` are the states' current joint rotations in ``states`` order; each latent
        starts at the encoder's mean of its pose, near where the solver will put it.
        """
        for i, z in zip(self.states, self.initial_latents(poses)):
            for factor in self.factors(i):
                graph.add(factor)
            values.insert(pose_latent_key(i), z)
