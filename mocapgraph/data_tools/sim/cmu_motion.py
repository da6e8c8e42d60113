"""CMU motion takes (``../shared/motion/cmu_train``) retargeted onto the 22-joint body.

A take stores local joint rotations of a 21-joint skeleton whose rest pose (identity) is a
T-pose in SMPL's axes (Y up, facing +Z, left on +X), the same axes and neutral pose as our body.
The rest poses still differ bone by bone (segment directions), so each mapped joint gets a
constant alignment ``A_c`` turning our rest bone onto the take's rest bone; the posed world frame
is then ``G_c = W_m · A_c`` with ``W_m`` the take's world rotation of the mapped joint, and every
mapped bone points exactly where the take's bone points.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import axis_rotation, matrix_to_rotvec, minimal_rotation
from mocapgraph.body.skeleton import JOINT_NAMES, NUM_JOINTS, PARENTS
from mocapgraph.errors import MocapgraphError

DEFAULT_MOTION_DIR = Path(__file__).resolve().parents[3] / ".." / "shared" / "motion" / "cmu_train"

# Our joint → (take joint that drives it, our child joint, take joint or end site at that child).
# Joints absent here keep their parent's world frame (zero local rotation).
RETARGET_MAP: dict[str, tuple[str, str | None, str | None]] = {
    "pelvis": ("hip", None, None),
    "left_hip": ("lThigh", "left_knee", "lShin"),
    "right_hip": ("rThigh", "right_knee", "rShin"),
    "spine1": ("abdomen", "spine2", "chest"),
    "left_knee": ("lShin", "left_ankle", "lFoot"),
    "right_knee": ("rShin", "right_ankle", "rFoot"),
    "spine2": ("chest", "spine3", "neck"),
    "left_ankle": ("lFoot", "left_foot", "lToeEnd"),
    "right_ankle": ("rFoot", "right_foot", "rToeEnd"),
    "spine3": ("chest", "neck", "neck"),
    "neck": ("neck", "head", "head"),
    "left_collar": ("lCollar", "left_shoulder", "lShldr"),
    "right_collar": ("rCollar", "right_shoulder", "rShldr"),
    "head": ("head", None, None),
    "left_shoulder": ("lShldr", "left_elbow", "lForeArm"),
    "right_shoulder": ("rShldr", "right_elbow", "rForeArm"),
    "left_elbow": ("lForeArm", "left_wrist", "lHand"),
    "right_elbow": ("rForeArm", "right_wrist", "rHand"),
    "left_wrist": ("lHand", None, None),
    "right_wrist": ("rHand", None, None),
}

# The take's Y-up axes into our Z-up world: (x, y, z) → (x, −z, y).
Y_UP_TO_Z_UP = axis_rotation("x", np.pi / 2)


def motion_dir() -> Path:
    """The CMU training directory: ``$MOCAPGRAPH_MOTION_DIR`` or ``../shared/motion/cmu_train``."""
    return Path(os.environ.get("MOCAPGRAPH_MOTION_DIR", DEFAULT_MOTION_DIR)).resolve()


@dataclass
class CMUTake:
    """One take: ``world_rotations (T, 21, 3, 3)`` rest→posed in the take's Y-up axes,
    ``root_translation (T, 3)`` metres, rest ``offsets (21, 3)``, end sites, 30 fps."""

    name: str
    joint_names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    end_sites: dict[str, tuple[int, np.ndarray]]
    world_rotations: np.ndarray
    root_translation: np.ndarray
    fps: float

    def rest_vector(self, parent_joint: str, child: str) -> np.ndarray:
        """Rest-pose vector from ``parent_joint`` to a child joint or end site (take axes)."""
        if child in self.end_sites:
            return self.end_sites[child][1]
        return self.offsets[self.joint_names.index(child)]


def load_cmu_take(path: str | Path) -> CMUTake:
    """Read one ``.npz`` take (format: ``shared/motion/README.md``); errors name the file and key."""
    path = Path(path)
    if not path.exists():
        raise MocapgraphError(f"{path}: motion file not found")
    required = ("joint_names", "parents", "rotations", "offsets", "root_translation", "fps",
                "end_site_names", "end_site_parents", "end_site_offsets")  # fmt: skip
    try:
        with np.load(path, allow_pickle=False) as d:
            missing = [k for k in required if k not in d.files]
            if missing:
                raise MocapgraphError(f"{path}: missing key {missing[0]!r}")
            names = [str(n) for n in d["joint_names"]]
            parents = d["parents"].astype(int)
            quats = d["rotations"].astype(float)
            offsets = d["offsets"].astype(float)
            root_t = d["root_translation"].astype(float)
            fps = float(d["fps"])
            ends = {
                str(n): (int(p), o.astype(float))
                for n, p, o in zip(d["end_site_names"], d["end_site_parents"], d["end_site_offsets"])
            }
    except (OSError, ValueError) as exc:
        raise MocapgraphError(f"{path}: not a readable motion .npz ({exc})") from None
    if quats.ndim != 3 or quats.shape[1:] != (len(names), 4) or not np.all(np.isfinite(quats)):
        raise MocapgraphError(f"{path}: 'rotations' must be finite (T, {len(names)}, 4), got {quats.shape}")
    from scipy.spatial.transform import Rotation

    local = Rotation.from_quat(quats.reshape(-1, 4), scalar_first=True).as_matrix().reshape(quats.shape[:2] + (3, 3))
    world = np.empty_like(local)
    for j, p in enumerate(parents):
        world[:, j] = local[:, j] if p < 0 else world[:, p] @ local[:, j]
    return CMUTake(path.stem, names, parents, offsets, ends, world, root_t, fps)


def retarget(take: CMUTake, body: BodyModel, shape=None) -> tuple[np.ndarray, np.ndarray]:
    """The take on our body: ``world_T_root (T, 4, 4)`` in a Z-up world and ``pose (T, 21, 3)``.

    The root position is the take's hip position (its height is not adapted to the body).
    """
    shape = body.default_shape if shape is None else shape
    rest = body.rest_joints(shape)
    T = take.world_rotations.shape[0]
    G = np.empty((T, NUM_JOINTS, 3, 3))
    for c, name in enumerate(JOINT_NAMES):
        if name not in RETARGET_MAP:
            G[:, c] = G[:, PARENTS[c]]
            continue
        source, child, source_child = RETARGET_MAP[name]
        align = np.eye(3)
        if child is not None:
            ours = rest[JOINT_NAMES.index(child)] - rest[c]
            theirs = take.rest_vector(source, source_child)
            align = minimal_rotation(ours, theirs)
        G[:, c] = take.world_rotations[:, take.joint_names.index(source)] @ align
    pose = matrix_to_rotvec(np.swapaxes(G[:, PARENTS[1:]], -1, -2) @ G[:, 1:])
    root = np.tile(np.eye(4), (T, 1, 1))
    root[:, :3, :3] = Y_UP_TO_Z_UP @ G[:, 0]
    root[:, :3, 3] = take.root_translation @ Y_UP_TO_Z_UP.T
    return root, pose
