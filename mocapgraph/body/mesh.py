"""A body's skinned mesh for one shape, posed by the 22 joints' forward kinematics.

A backend's mesh is skinned to its own bone rig (Anny: 104 bones), whose bones all move
rigidly with one of the 22 joints. That is what makes the posed mesh exact with only the
joints' forward kinematics: bone ``b`` turns with the world rotation of its *driver* joint
about a *pivot* point rigidly attached to its *anchor* joint,

    M_b = [ G_d , J_a + G_a (h_b⁰ − J_a⁰) − G_d h_b⁰ ]        W_b = M_b · W_b⁰

(``J⁰`` the joints at the neutral pose, ``W_b⁰`` the bone's pose there). For an ordinary bone of
joint ``c`` the driver is ``c``, the anchor its parent and the pivot ``J_c⁰``, so ``M_b`` is the
joint's own motion; Anny's toe bones turn with the foot joint about their own heads, which hang
from the ankle. The vertices are plain linear blend skinning against the bind pose,
``x = Σ_b w_vb · W_b · (B_b)⁻¹ · x_bind`` — the same formula glTF uses, so an export is exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapgraph.body.kinematics import FKResult
from mocapgraph.body.skeleton import NUM_JOINTS


@dataclass(frozen=True)
class SkinnedMesh:
    """A mesh, its bone rig and its skin, for one body shape; body frame (SMPL axes), metres.

    Attributes:
        bind_vertices: ``(V, 3)`` the mesh in the rig's bind pose.
        faces: ``(F, 3)`` int vertex indices of the triangles.
        bone_names: ``B`` names of the rig's bones.
        bone_parents: ``(B,)`` parent bone index, -1 for the root bone; parents precede children.
        bind_poses: ``(B, 4, 4)`` each bone's pose in the frame of ``bind_vertices``.
        neutral_poses: ``(B, 4, 4)`` each bone's pose at the neutral pose (root at identity,
            all 21 rotations zero).
        skin_indices: ``(V, K)`` int bone indices per vertex; ``skin_weights (V, K)`` their
            weights (rows sum to 1, unused slots 0).
        bone_driver, bone_anchor: ``(B,)`` joint indices (see the module docstring).
        bone_pivot: ``(B, 3)`` pivot at the neutral pose.
        neutral_joints: ``(22, 3)`` the joints at the neutral pose.
        joint_bones: for each of the 22 joints, the bones whose heads it is the mean of.
    """

    bind_vertices: np.ndarray
    faces: np.ndarray
    bone_names: tuple[str, ...]
    bone_parents: np.ndarray
    bind_poses: np.ndarray
    neutral_poses: np.ndarray
    skin_indices: np.ndarray
    skin_weights: np.ndarray
    bone_driver: np.ndarray
    bone_anchor: np.ndarray
    bone_pivot: np.ndarray
    neutral_joints: np.ndarray
    joint_bones: tuple[tuple[int, ...], ...]

    @property
    def num_vertices(self) -> int:
        return len(self.bind_vertices)

    def bone_poses(self, fk: FKResult) -> np.ndarray:
        """``(T, B, 4, 4)`` world poses of the bones for the posed joints of ``fk``."""
        G, J = fk.rotations, fk.joints
        d, a, h = self.bone_driver, self.bone_anchor, self.bone_pivot
        motion = np.zeros((len(J), len(d), 4, 4))
        motion[..., 3, 3] = 1.0
        motion[..., :3, :3] = G[:, d]
        pivot = J[:, a] + np.einsum("tbxy,by->tbx", G[:, a], h - self.neutral_joints[a])
        motion[..., :3, 3] = pivot - np.einsum("tbxy,by->tbx", G[:, d], h)
        return motion @ self.neutral_poses

    def skinning_matrices(self, bone_poses: np.ndarray) -> np.ndarray:
        """``(T, B, 3, 4)`` each bone's ``W_b · B_b⁻¹`` (what glTF calls joint matrices)."""
        return (bone_poses @ np.linalg.inv(self.bind_poses))[..., :3, :]

    def vertices(self, bone_poses: np.ndarray) -> np.ndarray:
        """``(T, V, 3)`` the skinned mesh for ``bone_poses (T, B, 4, 4)`` (world frame if they are)."""
        skin = self.skinning_matrices(bone_poses)  # (T, B, 3, 4)
        out = np.zeros((len(skin), self.num_vertices, 3))
        for k in range(self.skin_indices.shape[1]):  # K ≤ 9 passes over (T, V), no (T, V, K, 3, 4) temporary
            M = skin[:, self.skin_indices[:, k]]  # (T, V, 3, 4)
            moved = np.einsum("tvxy,vy->tvx", M[..., :3], self.bind_vertices) + M[..., 3]
            out += self.skin_weights[None, :, k, None] * moved
        return out

    def joints(self, bone_poses: np.ndarray) -> np.ndarray:
        """``(T, 22, 3)`` the joints read back from the bones' heads."""
        heads = bone_poses[..., :3, 3]
        return np.stack([heads[:, list(bones)].mean(axis=1) for bones in self.joint_bones], axis=1)

    def __post_init__(self):
        B = len(self.bone_names)
        if len(self.joint_bones) != NUM_JOINTS:
            raise ValueError(f"SkinnedMesh.joint_bones needs {NUM_JOINTS} entries, got {len(self.joint_bones)}")
        for field in ("bone_parents", "bind_poses", "neutral_poses", "bone_driver", "bone_anchor", "bone_pivot"):
            if len(getattr(self, field)) != B:
                raise ValueError(f"SkinnedMesh.{field} has {len(getattr(self, field))} rows, expected {B} (one per bone)")
