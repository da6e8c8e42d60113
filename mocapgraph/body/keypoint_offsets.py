"""Keypoint-definition offsets: where a detector format puts a point relative to the body's.

A detector's hip, shoulder or ankle is not the body model's joint centre: annotators and the
networks trained on them place it a few centimetres off, consistently for a format (Needham et
al. 2021 measured 30–50 mm at hips and knees). Seen from different sides, such an offset moves
the point differently in each view, so it cannot be absorbed by the pose.

An offset is a vector in the frame of the segment that carries the point (its *carrier*: the
joint whose bone-attached marker vector is the point's largest, e.g. the pelvis for a hip point,
the shank for an ankle point). In the table form of :mod:`mocapgraph.body.table` it is one more
marker on that joint, ``ℓ_k,carrier += δ_k``, so forward kinematics and its Jacobians need no
change. Offsets are in the body frame of the rest pose: +x the body's left, +y up, +z forward;
a right point's offset is its left partner's mirrored (x negated).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mocapgraph.body.table import BodyTable
from mocapgraph.errors import MocapgraphError

MIRROR = np.array([-1.0, 1.0, 1.0])
"""The body's left-right mirror in its rest frame (x is lateral)."""


def carrier_joints(table: BodyTable) -> np.ndarray:
    """``(K,)`` per keypoint, the joint whose frame carries its offset (largest marker vector)."""
    return np.argmax(np.linalg.norm(table.markers, axis=-1), axis=1)


def with_offsets(table: BodyTable, offsets) -> BodyTable:
    """``table`` with ``offsets (K, 3)`` (metres, carrier frames) added to its mapped points."""
    offsets = np.asarray(offsets, dtype=float)
    if offsets.shape != (len(table.keypoint_names), 3) or not np.all(np.isfinite(offsets)):
        raise MocapgraphError(f"keypoint offsets: ({len(table.keypoint_names)}, 3) finite metres, got shape {offsets.shape}")
    markers = table.markers.copy()
    k = np.flatnonzero(table.mapped)
    markers[k, carrier_joints(table)[k]] += offsets[k]
    return replace(table, markers=markers)


__all__ = ["MIRROR", "carrier_joints", "with_offsets"]
