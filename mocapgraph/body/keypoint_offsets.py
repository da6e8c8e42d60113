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

To estimate offsets jointly with the body, :func:`offset_basis` parametrises a format's offsets
by ``D`` numbers (a 3-vector per left/right pair, mirrored onto the right point; the up and
forward parts of a midline point) and :func:`offset_shape_table` appends them to the table's
shape vector: the marker derivatives of those extra "shape" columns are the offset directions,
so the kernels' shape Jacobians carry the offsets' Jacobians without any new code.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mocapgraph.body.labelling import part_name, swap_permutation
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


def drifted(keypoints: np.ndarray, rotations: np.ndarray, table: BodyTable, drift) -> np.ndarray:
    """``(N, K, 3)`` world keypoints of a posed body moved by per-state offsets ``drift (N, K, 3)``
    (metres, carrier frames, on top of the table's own), ``rotations (N, J, 3, 3)`` the joints'
    world rotations of the same forward kinematics."""
    return keypoints + np.einsum("nkxy,nky->nkx", rotations[:, carrier_joints(table)], np.asarray(drift, dtype=float))


def offset_basis(table: BodyTable, parts: tuple[str, ...] | None = None) -> np.ndarray:
    """``(K, 3, D)``: the offsets ``basis @ θ`` (carrier frames, metres) of the table's points as
    a linear function of ``D`` parameters ``θ``: per mapped left/right pair three (the first
    point's offset, the partner's its mirror image), per mapped midline point two (up, forward;
    it has no side to be off towards); unmapped points, and with ``parts`` the points of other
    body parts (names without their side, e.g. ``"hip"``), have none."""
    K = len(table.keypoint_names)
    partner = swap_permutation(table.keypoint_names, "body")
    columns = []
    for k in range(K):
        j = partner[k]
        if j < k or not table.mapped[k] or not table.mapped[j] or (parts is not None and part_name(table.keypoint_names[k]) not in parts):
            continue
        for axis in (0, 1, 2) if j != k else (1, 2):
            column = np.zeros((K, 3))
            column[k, axis] = 1.0
            column[j, axis] = MIRROR[axis] if j != k else 1.0
            columns.append(column)
    return np.stack(columns, axis=-1) if columns else np.zeros((K, 3, 0))


def offset_parameters(basis: np.ndarray, offsets) -> np.ndarray:
    """``(D,)`` the parameters whose offsets ``basis @ θ`` are nearest ``offsets (K, 3)`` (least
    squares: a left/right pair's mean of the left and the mirrored right)."""
    A = basis.reshape(-1, basis.shape[-1])
    return np.linalg.lstsq(A, np.asarray(offsets, dtype=float).ravel(), rcond=None)[0] if A.shape[1] else np.zeros(0)


def offset_shape_table(table: BodyTable, basis: np.ndarray) -> BodyTable:
    """``table`` whose shape vector has ``D`` more entries, the offset parameters of ``basis``
    (:func:`offset_basis`): ``d_markers`` gains the offset directions at each point's carrier and
    ``d_offsets`` zeros. The markers stay as they are (the parameters at zero); a caller adds
    ``basis @ θ`` at the carriers (:func:`with_offsets`) for other values."""
    K, J, _, S = table.d_markers.shape
    D = basis.shape[-1]
    d_markers = np.concatenate([table.d_markers, np.zeros((K, J, 3, D))], axis=-1)
    d_markers[np.arange(K), carrier_joints(table), :, S:] = basis
    d_offsets = np.concatenate([table.d_offsets, np.zeros(table.d_offsets.shape[:2] + (D,))], axis=-1)
    return replace(table, d_markers=d_markers, d_offsets=d_offsets)


__all__ = ["MIRROR", "carrier_joints", "drifted", "offset_basis", "offset_parameters", "offset_shape_table", "with_offsets"]
