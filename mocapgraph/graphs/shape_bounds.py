"""The body shape kept inside its model's bounds during a solve (the body table is undefined
outside them): a projection for :func:`mocapgraph.graphs.solver.solve_staged`."""

from __future__ import annotations

from typing import Callable

import gtsam
import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.factors.keys import shape_key


def shape_projection(body: BodyModel) -> Callable[[gtsam.Values], gtsam.Values]:
    """A function that clamps ``shape_key()`` into ``body.shape_bounds`` (a hair inside, so the
    table's bound checks pass), returning the same ``Values`` when nothing moved."""
    lo, hi = body.shape_bounds.T

    def project(values: gtsam.Values) -> gtsam.Values:
        shape = values.atVector(shape_key())
        clamped = np.clip(shape, lo + 1e-9, hi - 1e-9)
        if np.array_equal(clamped, shape):
            return values
        out = gtsam.Values(values)
        out.update(shape_key(), clamped)
        return out

    return project
