"""The Gaussian-mixture pose prior as a GTSAM factor (SMPLify's max-mixture approximation).

A mixture's ``−log Σ_k w_k N_k(θ)`` is not a sum of squares, so, as SMPLify does, the factor
uses the single best component at the current θ:

    k* = argmax_k w_k N(θ; μ_k, Σ_k) = argmin_k ½‖P_kᵀ(θ − μ_k)‖² + c_k,
    c_k = −log w_k + ½ log det Σ_k,

and the residual ``(D + 1,)``

    r(θ) = [ P_k*ᵀ(θ − μ_k*) ;  sqrt(2 (c_k* − c_min)) ],   c_min = min_k c_k.

Then ``½‖r‖² = −log(w_k* N_k*(θ)) − (D/2 log 2π + c_min)``: the max-component negative log
density up to a constant. The constant row is why the cost is continuous: where the best
component switches from j to k the two component costs ``½‖P_jᵀ(θ−μ_j)‖² + c_j`` and
``½‖P_kᵀ(θ−μ_k)‖² + c_k`` are equal, so the factor's cost is ``min_k`` of continuous
functions. Without the row it would jump by ``c_k − c_j`` there, and Levenberg-Marquardt's
cost comparisons would reward or punish crossing a switch for no reason. ``c_min`` is subtracted
so the square root is real; the row does not depend on θ, so its Jacobian row is zero.

Within a component the Jacobian ``[P_k*ᵀ; 0]`` is exact; at a switch the cost has a kink (as
any max-mixture has), which Gauss-Newton handles by re-choosing ``k*`` at every linearisation.
"""

from __future__ import annotations

import gtsam
import numpy as np

from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.errors import MocapgraphError
from mocapgraph.priors.pose_gmm import PoseGMM


class _MaxMixture:
    """The factor's error function: best component, whitened residual, constant row."""

    def __init__(self, gmm: PoseGMM, pose_dim: int):
        self.gmm = gmm
        self.costs = gmm.component_costs()
        self.offsets = np.sqrt(2.0 * (self.costs - self.costs.min()))
        # P_kᵀ in the modelled columns of the whole pose, a zero last row; column-major because
        # GTSAM copies Fortran-ordered arrays as they are.
        self.jacobians = []
        for P in gmm.precisions_cholesky:
            J = np.zeros((gmm.dim + 1, pose_dim), order="F")
            J[:-1, gmm.dims] = P.T
            self.jacobians.append(J)

    def __call__(self, this, values: gtsam.Values, H) -> np.ndarray:
        whitened = self.gmm.whitened(values.atVector(this.keys()[0])[self.gmm.dims])
        k = int(np.argmin(0.5 * np.square(whitened).sum(axis=1) + self.costs))
        if H is not None:
            H[0] = self.jacobians[k]
        return np.append(whitened[k], self.offsets[k])


def pose_gmm_factor(pose_key: int, gmm: PoseGMM, pose_dim: int | None = None) -> gtsam.CustomFactor:
    """Max-mixture Gaussian-mixture prior on one state's joint rotations.

    Args:
        pose_key: the state's pose key (``mocapgraph.factors.keys.pose_key``, ``Vector(63)``).
        gmm: the mixture, e.g. :func:`mocapgraph.priors.load_default_pose_gmm`; when it models
            some joints only (``gmm.joints``), the factor touches only their dimensions.
        pose_dim: length of the pose variable; default 63 for a mixture over some joints, else
            the mixture's dimension.

    Returns:
        a ``CustomFactor`` with a unit noise model and ``D + 1`` residual rows (see the module
        docstring), so ``factor.error(values) = −log max_k w_k N_k(θ) − D/2 log 2π − min_k c_k``.
    """
    if pose_dim is None:
        pose_dim = 3 * (NUM_JOINTS - 1) if gmm.joints is not None else gmm.dim
    if pose_dim <= gmm.dims.max():
        raise MocapgraphError(f"pose_gmm_factor: a pose of {pose_dim} values has no dimension {gmm.dims.max()}")
    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(gmm.dim + 1), [int(pose_key)], _MaxMixture(gmm, pose_dim))
