"""The interface every body-model backend implements, and the posing calls built on it."""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from mocapgraph.body.kinematics import FKResult
from mocapgraph.body.mesh import SkinnedMesh
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES, JOINT_NAMES, NUM_JOINTS, PARENTS
from mocapgraph.body.table import BodyTable
from mocapgraph.errors import MocapgraphError, as_checked_array


class BodyModel(ABC):
    """A body model reduced to SMPL's 22 joints and the 23 body keypoints.

    Subclasses give the shape parameterisation and :meth:`table`; posing is shared.
    Poses are ``world_T_root (T, 4, 4)`` and local axis-angle ``(T, 21, 3)`` in the body frame
    of :mod:`mocapgraph.body.skeleton` (SMPL axes, T-pose at zero).
    """

    name: str
    joint_names: tuple[str, ...] = JOINT_NAMES
    parents: np.ndarray = PARENTS
    keypoint_names: tuple[str, ...] = BODY_KEYPOINT_NAMES

    @property
    @abstractmethod
    def shape_names(self) -> tuple[str, ...]:
        """Names of the entries of the shape vector."""

    @property
    @abstractmethod
    def shape_bounds(self) -> np.ndarray:
        """``(S, 2)`` lower and upper bound of each shape entry (±inf when unbounded)."""

    @property
    @abstractmethod
    def default_shape(self) -> np.ndarray:
        """``(S,)`` the average body."""

    @abstractmethod
    def _table(self, shape: np.ndarray) -> BodyTable:
        """The table of the 23 body keypoints for a validated shape vector."""

    @property
    def shape_dim(self) -> int:
        return len(self.shape_names)

    def check_shape(self, shape) -> np.ndarray:
        """``shape`` as a validated ``(S,)`` float array; out-of-bounds values are an error."""
        shape = as_checked_array(shape, f"{self.name} shape vector", (self.shape_dim,))
        lo, hi = self.shape_bounds.T
        outside = (shape < lo - 1e-12) | (shape > hi + 1e-12)
        if np.any(outside):
            i = int(np.argmax(outside))
            raise MocapgraphError(
                f"{self.name} shape parameter {self.shape_names[i]!r} = {shape[i]:g} "
                f"is outside its range [{lo[i]:g}, {hi[i]:g}]"
            )
        return shape

    def table(self, shape, keypoints: str = "body") -> BodyTable:
        """Table for ``shape``; ``keypoints`` is ``"body"`` or a detector format of the registry."""
        table = self._table(self.check_shape(shape))
        if keypoints == "body":
            return table
        from mocapgraph.body.keypoint_formats import format_table

        return format_table(table, keypoints)

    def forward(
        self, shape, root, pose, *, keypoints: str = "body", jacobians: bool = False
    ) -> FKResult:
        """Joints and keypoints for ``root (T, 4, 4)`` and ``pose (T, 21, 3)``; see FKResult."""
        from mocapgraph.body.native import forward_kinematics

        return forward_kinematics(self.table(shape, keypoints), root, pose, jacobians=jacobians)

    def rest_joints(self, shape) -> np.ndarray:
        """``(22, 3)`` joints in the neutral pose, body frame, pelvis at the origin."""
        res = self.forward(shape, np.eye(4)[None], np.zeros((1, NUM_JOINTS - 1, 3)))
        return res.joints[0]

    def mesh(self, shape) -> SkinnedMesh:
        """The skinned mesh for ``shape`` (see :mod:`mocapgraph.body.mesh`); a backend without one
        raises a MocapgraphError."""
        raise MocapgraphError(f"the {self.name} body model has no mesh in mocapgraph (anny has one, and SMPL from a file with its triangles)")

    def describe(self) -> dict:
        """What ``mocapgraph body info`` prints."""
        return {
            "backend": self.name,
            "joints": list(self.joint_names),
            "parents": [int(p) for p in self.parents],
            "keypoints": list(self.keypoint_names),
            "shape": [
                {"name": n, "min": float(lo), "max": float(hi), "default": float(d)}
                for n, (lo, hi), d in zip(self.shape_names, self.shape_bounds, self.default_shape)
            ],
        }
