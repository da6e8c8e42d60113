"""SMPL/AMASS-style parameters (``.npz``) of a result solved with the SMPL or SMPL-X backend.

The keys follow AMASS: ``poses (T, 3·J)`` (root orientation, the 21 body joints, then zeros for
the joints we do not estimate: SMPL's hands, SMPL-X's jaw, eyes and fingers), ``root_orient
(T, 3)``, ``pose_body (T, 63)``, ``trans (T, 3)``, ``betas (S,)``, ``gender``,
``mocap_framerate``, ``surface_model_type``; plus ``timestamps (T,)`` seconds. AMASS's world is
Z up like ours, so ``root_orient`` is the root's world rotation as it is. SMPL turns the root
about its unposed pelvis ``J0(β)``, so ``trans`` = our root translation − ``J0(β)``.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from mocapgraph.body.rotations import matrix_to_rotvec
from mocapgraph.data_tools.io.exporters import frame_time


def model_gender(model_file: str) -> str:
    """``female``, ``male`` or ``neutral`` from the model file's name (SMPL's files are named so)."""
    name = Path(model_file).stem.lower()
    return "female" if "female" in name else "male" if "male" in name else "neutral"


def smpl_bytes(result, body) -> bytes:
    """The ``.npz`` file of the result's SMPL parameters (see the module docstring)."""
    T = len(result.timestamps)
    root_orient = matrix_to_rotvec(result.root[:, :3, :3])
    pose_body = result.pose.reshape(T, -1)
    poses = np.zeros((T, 3 * body.num_source_joints))
    poses[:, :3], poses[:, 3 : 3 + pose_body.shape[1]] = root_orient, pose_body
    f = io.BytesIO()
    np.savez(
        f, poses=poses, root_orient=root_orient, pose_body=pose_body,
        trans=result.root[:, :3, 3] - body.rest_pelvis(result.shape), betas=result.shape,
        gender=np.array(model_gender(body.source)), mocap_framerate=np.array(1.0 / frame_time(result.timestamps)),
        surface_model_type=np.array(body.name), timestamps=result.timestamps,
    )  # fmt: skip
    return f.getvalue()
