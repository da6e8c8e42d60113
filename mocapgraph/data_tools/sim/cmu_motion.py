"""CMU motion takes (``../shared/motion/cmu_train``) retargeted onto the 22-joint body.

A take stores local joint rotations of a 21-joint skeleton whose rest pose (identity) is a
T-pose in SMPL's axes (Y up, facing +Z, left on +X), the same axes and neutral pose as our body.
The rest poses still differ bone by bone (segment directions), so each mapped joint gets a
constant alignment ``A_c`` turning our rest bone onto the take's rest bone; the posed world frame
is then ``G_c = W_m · A_c`` with ``W_m`` the take's world rotation of the mapped joint, and every
mapped bone points exactly where the take's bone points.

**The pelvis is anatomical, not the take's root.** The take's root (``hip``) rotation carries a
per-subject calibration tilt (median over a subject's frames up to 25°, subject 05), and the rig
bends the abdomen and chest back and flexes the hips to put the joints where they were. Copied,
it made ground truth with the pelvis pitched tens of degrees and the spine and hips bent to
match. The pelvis's world frame is therefore built from the take's joint positions
(:func:`pelvis_frames`): x along the hip line (right thigh → left thigh), y along root → neck
made orthogonal to it, and the same construction on our rest joints is the identity. The
pelvis's children (hips, spine1) keep their world rotations; only their local rotations change.
On the training takes the root's rotation and the new frame share the hip line (the take's
buttock joints carry no animation), so the change is a pitch about it.

The spine's top was chosen by measurement, on the first ordinary walking take of each of 30
subjects (``tests/test_cmu_motion.py`` picks them), as the median over frames of the pelvis's
up axis against vertical:

==========================================  =====  ======  =====
pelvis from                                  min    median  max
==========================================  =====  ======  =====
the take's root rotation (before)            1.9°   5.4°    15.2°
hip → chest, our pelvis → spine3             2.7°   8.3°    13.5°
hip → chest, our pelvis → neck               2.0°   5.1°    9.8°
**hip → neck, our pelvis → neck**            1.9°   4.3°    7.4°
hip → head, our pelvis → head                1.9°   4.5°    6.8°
==========================================  =====  ======  =====

Hip → neck and hip → head remove the tilt equally well (subject 46: 15.2° → 4.2°); the neck is
used because the head point also moves with nodding. The pelvis follows the trunk: where the
trunk leans on purpose it pitches with it (subject 74's "stiff walk" 12.4°, subject 77's
creeping walks 23°–39°), so there the hips flex less, and the spine bends less, than an
anatomical pelvis tilt would have them do.

The root translation is the one that keeps the 22 joints nearest, in the least-squares sense,
to where the take's root rotation put them (:func:`root_shift`). Our pelvis → spine1 lever is
rigid in the pelvis, so a pitch swings spine1 against the hips and no translation keeps both.
Over every training take the joints moved by a median of 3.3 mm, 99th percentile 20 mm, at most
46 mm (``cmu_77_18``, getting up from lying on the back, where the pitch is largest); over the
walks above by a median of 2.1 mm, at most 11.9 mm.

**Joints the source never moves** are constants of this retargeting, and the learned priors do
not model them (``priors.training.moving_joints``):

- spine3: the take has two spine bones above the hip (abdomen → chest, chest → neck) for our
  three; spine1 follows the abdomen, and spine2 and spine3 both follow the chest (the take has no
  chest/neck split to share between them);
- the feet (SMPL's toe joints): the take has no toe joints (``lToeEnd``/``rToeEnd`` are end
  sites of the ankle's bone, which drives our ankle);
- the collars: the take's collar joints carry no animation; the take's shoulder joints sit at
  fixed places on the chest and carry all of the arm's motion.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import axis_rotation, matrix_to_rotvec, minimal_rotation
from mocapgraph.body.skeleton import JOINT_NAMES, NUM_JOINTS, PARENTS, descendants_mask
from mocapgraph.errors import MocapgraphError

log = logging.getLogger(__name__)

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

# The pelvis frame (module docstring): the hip line between the take's thigh joints and our hip
# joints, and the spine line from the root to the neck in both (take joint, our joint).
PELVIS_HIP_LINE = (("lThigh", "left_hip"), ("rThigh", "right_hip"))
PELVIS_SPINE_TOP = ("neck", "neck")


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


def take_joint_positions(take: CMUTake, names) -> dict[str, np.ndarray]:
    """``{name: (T, 3)}`` positions of take joints relative to the root, in the take's axes."""
    wanted = set(names)
    positions: dict[str, np.ndarray] = {}
    for j, (name, parent) in enumerate(zip(take.joint_names, take.parents)):
        if parent < 0:
            positions[name] = np.zeros_like(take.root_translation)
        else:
            up = take.joint_names[parent]
            positions[name] = positions[up] + take.world_rotations[:, parent] @ take.offsets[j]
    missing = wanted - positions.keys()
    if missing:
        raise MocapgraphError(f"take {take.name}: no joint {sorted(missing)[0]!r}")
    return {n: positions[n] for n in names}


def hip_spine_frame(left: np.ndarray, right: np.ndarray, top: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotations ``(..., 3, 3)`` with columns: the hip line ``left − right``, the root → ``top`` line
    made orthogonal to it, their cross product (forward); and ``(...)`` the length of that
    orthogonal part (the frame is undefined where it is zero)."""
    x = left - right
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    y = top - np.sum(top * x, axis=-1, keepdims=True) * x
    length = np.linalg.norm(y, axis=-1)
    y = y / np.maximum(length, 1e-300)[..., None]
    return np.stack([x, y, np.cross(x, y)], axis=-1), length


def pelvis_frames(take: CMUTake, rest: np.ndarray) -> np.ndarray:
    """``(T, 3, 3)`` world rotations of our pelvis in the take's axes, from the take's anatomy
    (module docstring); ``rest (22, 3)`` are our rest joints, whose own frame maps to identity."""
    (left_take, left_ours), (right_take, right_ours) = PELVIS_HIP_LINE
    top_take, top_ours = PELVIS_SPINE_TOP
    index = JOINT_NAMES.index
    ours, _ = hip_spine_frame(
        rest[index(left_ours)], rest[index(right_ours)], rest[index(top_ours)] - rest[index("pelvis")]
    )
    p = take_joint_positions(take, (left_take, right_take, top_take))
    theirs, length = hip_spine_frame(p[left_take], p[right_take], p[top_take])
    frames = theirs @ ours.T
    # A spine lying along the hip line (a 90° side bend) leaves the pitch undefined; no take comes
    # near it (the spine is 0.55 m long), so those frames simply keep the take's root rotation.
    bad = length < 1e-3
    if np.any(bad):
        log.warning("%s: %d frames with the spine along the hip line keep the root's rotation", take.name, int(bad.sum()))
        frames[bad] = take.world_rotations[bad, take.joint_names.index(RETARGET_MAP["pelvis"][0])]
    return frames


def retarget(take: CMUTake, body: BodyModel, shape=None) -> tuple[np.ndarray, np.ndarray]:
    """The take on our body: ``world_T_root (T, 4, 4)`` in a Z-up world and ``pose (T, 21, 3)``.

    The pelvis's rotation is :func:`pelvis_frames`; every other mapped joint's world rotation is
    the take's (times its rest alignment). The root position is the take's hip position moved by
    the least-squares shift that keeps the 22 joints nearest to where they would be with the take's
    root rotation on the pelvis (module docstring); heights are not adapted to the body.
    """
    shape = body.default_shape if shape is None else shape
    rest = body.rest_joints(shape)
    T = take.world_rotations.shape[0]
    G = np.empty((T, NUM_JOINTS, 3, 3))
    for c, name in enumerate(JOINT_NAMES):
        if c == 0:
            G[:, 0] = pelvis_frames(take, rest)
            continue
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
    root[:, :3, 3] = (take.root_translation + root_shift(take, rest, G[:, 0])) @ Y_UP_TO_Z_UP.T
    return root, pose


def root_shift(take: CMUTake, rest: np.ndarray, pelvis: np.ndarray) -> np.ndarray:
    """``(T, 3)`` take axes: the root translation's change that keeps the 22 joints, in the least-
    squares sense, where they are with the take's root rotation on the pelvis instead of ``pelvis``.

    Turning the pelvis moves the subtree of each pelvis child ``c`` rigidly by
    ``δ_c = (R_new − R_old) · rest_c``; with a shift ``s`` the pelvis moves by ``s`` and the ``n_c``
    joints of that subtree by ``s + δ_c``, so the sum of squares is least at
    ``s = −Σ n_c δ_c / (1 + Σ n_c)``.
    """
    old = take.world_rotations[:, take.joint_names.index(RETARGET_MAP["pelvis"][0])]
    children = np.flatnonzero(PARENTS == 0)
    sizes = descendants_mask(PARENTS).sum(axis=1)[children]
    moved = (pelvis - old) @ (rest[children] - rest[0]).T  # (T, 3, children)
    return -(moved @ sizes) / (1 + sizes.sum())
