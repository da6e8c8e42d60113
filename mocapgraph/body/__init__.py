"""Body models behind one interface: SMPL's 22 joints, 23 body keypoints, exact Jacobians.

``load_body_model()`` gives the default, license-free Anny body; ``load_body_model("smpl",
model_path=...)`` (or ``"smplx"``) reads a user's own licensed model file. Also forward
kinematics with Jacobians, the keypoint format registry and rotation helpers.

The bottom layer: it may import only ``errors`` and the native kernels.
"""

from __future__ import annotations

from pathlib import Path

from mocapgraph.body.kinematics import FKResult
from mocapgraph.body.model import BodyModel
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES, JOINT_NAMES, NUM_JOINTS, PARENTS
from mocapgraph.body.table import BodyTable
from mocapgraph.errors import MocapgraphError

BACKENDS = ("anny", "smpl", "smplx")


def load_body_model(backend: str = "anny", model_path: str | Path | None = None) -> BodyModel:
    """A body model by backend name; ``smpl``/``smplx`` need ``model_path`` to the user's file."""
    if backend == "anny":
        if model_path is not None:
            from mocapgraph.body.anny_backend import AnnyBody

            return AnnyBody(model_path)
        from mocapgraph.body.anny_backend import cached_anny_body

        return cached_anny_body()
    if backend in ("smpl", "smplx"):
        if model_path is None:
            raise MocapgraphError(
                f"the {backend} backend needs your own licensed model file: pass --model-path "
                "(mocapgraph never downloads SMPL/SMPL-X files)"
            )
        from mocapgraph.body.smpl_backend import SMPLBody

        return SMPLBody(model_path, kind=backend)
    raise MocapgraphError(f"unknown body backend {backend!r}; choose one of {', '.join(BACKENDS)}")


__all__ = [
    "BACKENDS",
    "BODY_KEYPOINT_NAMES",
    "BodyModel",
    "BodyTable",
    "FKResult",
    "JOINT_NAMES",
    "NUM_JOINTS",
    "PARENTS",
    "load_body_model",
]
