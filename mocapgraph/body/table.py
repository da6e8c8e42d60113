"""The table form every backend reduces to for one body shape.

With world-aligned joint frames ``G_c`` (``G_0`` = root rotation, ``G_c = G_p · Exp(θ_c)``) and
joint positions ``J_0`` = root translation, ``J_c = J_p + G_p · o_c(β)``, each keypoint is an
exact weighted sum of bone-attached markers::

    k = Σ_c ( a_kc · J_c + G_c · ℓ_kc(β) )

``a`` does not depend on shape; ``o`` and ``ℓ`` do, and the table carries their derivatives with
respect to the shape vector β so that forward kinematics can give exact shape Jacobians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapgraph.body.skeleton import NUM_JOINTS, PARENTS


@dataclass(frozen=True)
class BodyTable:
    """Shape-specific constants of forward kinematics, in the body frame (metres).

    Attributes:
        parents: ``(22,)`` parent index per joint, -1 for the root.
        offsets: ``(22, 3)`` joint offset from its parent, in the parent's world-aligned frame;
            row 0 is unused (the root position is a variable) and zero.
        d_offsets: ``(22, 3, S)`` derivative of ``offsets`` with respect to the shape vector.
        weights: ``(K, 22)`` joint-position weights ``a`` of each keypoint.
        markers: ``(K, 22, 3)`` bone-attached marker vectors ``ℓ``.
        d_markers: ``(K, 22, 3, S)`` derivative of ``markers`` with respect to shape.
        keypoint_names: ``K`` names.
        mapped: ``(K,)`` bool, False for keypoints a backend cannot provide (rows are zero).
    """

    parents: np.ndarray
    offsets: np.ndarray
    d_offsets: np.ndarray
    weights: np.ndarray
    markers: np.ndarray
    d_markers: np.ndarray
    keypoint_names: tuple[str, ...]
    mapped: np.ndarray

    def __post_init__(self):
        K = len(self.keypoint_names)
        S = self.d_offsets.shape[-1]
        expected = {
            "parents": (NUM_JOINTS,),
            "offsets": (NUM_JOINTS, 3),
            "d_offsets": (NUM_JOINTS, 3, S),
            "weights": (K, NUM_JOINTS),
            "markers": (K, NUM_JOINTS, 3),
            "d_markers": (K, NUM_JOINTS, 3, S),
            "mapped": (K,),
        }
        for field, shape in expected.items():
            got = np.shape(getattr(self, field))
            if got != shape:
                raise ValueError(f"BodyTable.{field} has shape {got}, expected {shape}")
        if not np.array_equal(self.parents, PARENTS):
            raise ValueError("BodyTable.parents differs from the SMPL-22 kinematic tree")

    @property
    def shape_dim(self) -> int:
        return self.d_offsets.shape[-1]

    @property
    def num_keypoints(self) -> int:
        return len(self.keypoint_names)

    def combine(self, mix: np.ndarray, names: tuple[str, ...]) -> BodyTable:
        """Another point set: point ``i`` is ``Σ_k mix[i, k] · keypoint k`` of this table.

        Keypoints are linear in ``(a, ℓ)``, so any fixed blend of body keypoints (a detector's
        mid-hip as the mean of both hips) is again a table row. ``mix`` is ``(K', K)``; a row of
        zeros marks a point this body cannot provide (``mapped`` False).
        """
        mix = np.asarray(mix, dtype=float)
        used = mix != 0
        return BodyTable(
            parents=self.parents,
            offsets=self.offsets,
            d_offsets=self.d_offsets,
            weights=mix @ self.weights,
            markers=np.einsum("ik,kcx->icx", mix, self.markers),
            d_markers=np.einsum("ik,kcxs->icxs", mix, self.d_markers),
            keypoint_names=tuple(names),
            mapped=used.any(axis=1) & ~(used & ~self.mapped[None]).any(axis=1),
        )
