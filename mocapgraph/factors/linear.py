"""Linear factors on vector variables with constant Jacobians, built once.

GTSAM's ``BetweenFactorVector`` on a 63-vector costs ~95 µs per linearisation (dynamic-size Lie
Jacobians, see the GTSAM performance notes); a linear ``CustomFactor`` whose Jacobians are
precomputed costs ~38 µs for three 63×63 blocks, most of it GTSAM copying them.
"""

from __future__ import annotations

import gtsam
import numpy as np

from mocapgraph.errors import MocapgraphError


class DiagonalLinear:
    """Residual ``Σ_i a_i ⊙ x_i − b`` of vector variables; Jacobians ``diag(a_i)``.

    The factor carries a unit noise model (the coefficients whiten it), so
    ``factor.error(v) = ½‖residual‖²``.
    """

    def __init__(self, keys, diagonals, offset):
        self.keys = [int(k) for k in keys]
        self.diagonals = [np.asarray(a, dtype=float) for a in diagonals]
        self.offset = np.asarray(offset, dtype=float)
        # Column-major: GTSAM copies them into Eigen matrices as they are.
        self.jacobians = [np.asfortranarray(np.diag(a)) for a in self.diagonals]
        if len(set(self.keys)) != len(self.keys):
            raise MocapgraphError("the keys of a linear factor must all differ")

    def __call__(self, this, values: gtsam.Values, H) -> np.ndarray:
        r = -self.offset
        for key, a in zip(self.keys, self.diagonals):
            r = r + a * values.atVector(key)
        if H is not None:
            for i, J in enumerate(self.jacobians):
                H[i] = J
        return r

    def factor(self) -> gtsam.CustomFactor:
        return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(len(self.offset)), self.keys, self)
