"""Gaussian priors on the body's variables: the shape and one state's joint rotations.

:func:`pose_regularizer_factor` is the built-in ``PriorFactorVector`` (~7 µs for 63-d; its
Jacobian is a fixed identity); :func:`shape_prior_factor` a linear factor with a constant
Jacobian. Learned pose priors (:mod:`mocapgraph.priors`) come as further factors on the same
``pose_key``.
"""

from __future__ import annotations

import gtsam
import numpy as np

from mocapgraph.errors import MocapgraphError, as_checked_array
from mocapgraph.factors.linear import DiagonalLinear
from mocapgraph.factors.noise import positive
from mocapgraph.factors.reprojection import POSE_DIM


def shape_prior_factor(key: int, mean, sigma) -> gtsam.CustomFactor:
    """Gaussian prior on the shape vector: residual ``(β − mean) / sigma`` (S,).

    Args:
        mean: ``(S,)``, e.g. ``body.default_shape``.
        sigma: scalar or ``(S,)``, in the shape's own units.
    """
    mean = as_checked_array(mean, "mean (shape)", (None,))
    inv = 1.0 / positive(sigma, "sigma (shape)", mean.shape)
    return DiagonalLinear([key], [inv], mean * inv).factor()


def pose_regularizer_factor(key: int, sigma_rad, mean=None) -> gtsam.PriorFactorVector:
    """Gaussian prior on one state's joint rotations: whitened residual ``(θ − mean) / sigma_rad`` (63,).

    A built-in ``PriorFactorVector`` with a diagonal noise model (exact: identity Jacobian).

    Args:
        sigma_rad: scalar or ``(63,)`` standard deviation, radians.
        mean: ``(63,)`` or ``(21, 3)`` axis-angle; default the neutral T-pose (zeros).
    """
    mean = np.zeros(POSE_DIM) if mean is None else as_checked_array(mean, "mean (pose)", (None,) * np.ndim(mean))
    if mean.size != POSE_DIM:
        raise MocapgraphError(f"mean (pose): expected 63 values ((63,) or (21, 3)), got shape {mean.shape}")
    sigma = positive(sigma_rad, "sigma_rad", (POSE_DIM,))
    return gtsam.PriorFactorVector(key, mean.reshape(POSE_DIM), gtsam.noiseModel.Diagonal.Sigmas(sigma))
