"""Training the pose GMM on CMU takes retargeted onto the body, with a validation split by subject.

Frames come from every ``cmu_SS_TT[...].npz`` of the motion directory (``SS`` is the CMU
subject), retargeted by :func:`mocapgraph.data_tools.sim.cmu_motion.retarget` and thinned to every
``stride``-th frame (the takes are 30 fps resampled from 24 fps, so neighbours are nearly
copies). Whole subjects are held out, so the validation numbers measure poses of people the
mixture never saw.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import relative_angle, rotvec_to_matrix
from mocapgraph.body.skeleton import JOINT_NAMES
from mocapgraph.errors import MocapgraphError
from mocapgraph.priors.pose_gmm import PoseGMM, fit_pose_gmm

_TAKE_NAME = re.compile(r"cmu_(\d+)_\d+.*\.npz")


@dataclass
class PoseFrames:
    """``poses (N, 63)`` axis-angle (radians, the body's joint frames) and ``subjects (N,)`` CMU ids."""

    poses: np.ndarray
    subjects: np.ndarray


def take_files(motion_dir: str | Path) -> list[Path]:
    """The ``cmu_SS_TT[...].npz`` takes of ``motion_dir``, sorted; a MocapgraphError naming the
    directory when it does not exist or holds none."""
    directory = Path(motion_dir)
    if not directory.is_dir():
        raise MocapgraphError(f"{directory}: motion directory not found")
    files = sorted(p for p in directory.iterdir() if _TAKE_NAME.fullmatch(p.name))
    if not files:
        raise MocapgraphError(f"{directory}: no CMU takes (cmu_SS_TT.npz files) in the motion directory")
    return files


def take_subject(path: Path) -> int:
    """The CMU subject of a take file (``cmu_SS_…`` → ``SS``)."""
    return int(_TAKE_NAME.fullmatch(path.name).group(1))


def load_pose_frames(motion_dir: str | Path, body: BodyModel, stride: int = 4, progress=None) -> PoseFrames:
    """Every ``stride``-th frame of every take in ``motion_dir``, retargeted onto ``body``.

    ``progress(message)`` is called every 100 takes. Raises a MocapgraphError naming the
    directory when it does not exist or holds no ``cmu_*.npz`` take.
    """
    from mocapgraph.data_tools.sim.cmu_motion import load_cmu_take, retarget

    files = take_files(motion_dir)
    poses, subjects = [], []
    for i, path in enumerate(files):
        _, pose = retarget(load_cmu_take(path), body)
        poses.append(pose[::stride].reshape(-1, 63))
        subjects.append(np.full(len(poses[-1]), take_subject(path)))
        if progress is not None and ((i + 1) % 100 == 0 or i + 1 == len(files)):
            progress(f"loaded {i + 1}/{len(files)} takes")
    return PoseFrames(np.concatenate(poses), np.concatenate(subjects))


def moving_joints(poses: np.ndarray, tol_rad: float = 1e-3) -> np.ndarray:
    """Indices (into the 21 joints) of the joints whose rotation varies in ``poses (N, 63)``.

    A joint counts as moving when some axis-angle component has a standard deviation above
    ``tol_rad``. The retargeted CMU takes never move spine3, the feet or the collars (the takes
    animate no collars and no toes, and spine3 follows the chest); a prior fitted on them would pin
    those joints to the retargeting's constants, so the learned priors model only the others.
    """
    std = np.asarray(poses, dtype=float).reshape(len(poses), -1, 3).std(axis=0)
    return np.flatnonzero(std.max(axis=1) > tol_rad)


def split_by_subject(subjects: np.ndarray, val_fraction: float, seed: int) -> np.ndarray:
    """``(N,)`` bool, True for validation: a seeded ``val_fraction`` of the subjects (at least one)."""
    unique = np.unique(subjects)
    if len(unique) < 2:
        raise MocapgraphError(f"a split by subject needs at least 2 subjects, got {len(unique)}")
    count = min(len(unique) - 1, max(1, round(val_fraction * len(unique))))
    held_out = np.random.default_rng(seed).choice(unique, size=count, replace=False)
    return np.isin(subjects, held_out)


def held_out_split(subjects: np.ndarray, val_fraction: float, seed: int, noun: str, progress=None) -> tuple[np.ndarray, list[int]]:
    """:func:`split_by_subject` for a trainer: the ``(N,)`` validation mask and the held-out
    subjects, reported to ``progress`` as ``"<n> training <noun>, <m> held-out <noun> (subjects …)"``."""
    val = split_by_subject(subjects, val_fraction, seed)
    held_out = [int(s) for s in np.unique(subjects[val])]
    if progress is not None:
        progress(f"{int((~val).sum())} training {noun}, {int(val.sum())} held-out {noun} (subjects {', '.join(map(str, held_out))})")
    return val, held_out


def nearest_mean_geodesic(gmm: PoseGMM, poses: np.ndarray) -> np.ndarray:
    """``(N,)`` radians: per pose, the smallest over components of the mean over the modelled joints
    of the rotation angle between the pose's and the component mean's joint rotation."""
    poses = gmm.select(poses)
    R = rotvec_to_matrix(poses.reshape(len(poses), -1, 3))
    per_component = [relative_angle(R, rotvec_to_matrix(mean.reshape(-1, 3))).mean(axis=1) for mean in gmm.means]
    return np.min(per_component, axis=0)


def train_pose_prior(
    motion_dir: str | Path,
    body: BodyModel,
    components: int = 8,
    seed: int = 0,
    stride: int = 4,
    val_fraction: float = 0.2,
    progress: Callable[[str], None] | None = None,
) -> PoseGMM:
    """Load, split by subject, fit on the training subjects, score the held-out ones.

    Returns the mixture; its ``info`` records the data, the split and the measured numbers
    (``val_mean_log_likelihood`` nats per pose, ``val_nearest_mean_geodesic_rad``, seconds).
    """
    start = time.perf_counter()
    frames = load_pose_frames(motion_dir, body, stride, progress)
    load_s = time.perf_counter() - start
    val, held_out = held_out_split(frames.subjects, val_fraction, seed, "poses", progress)
    train_poses, val_poses = frames.poses[~val], frames.poses[val]
    joints = moving_joints(train_poses)

    def em_progress(iteration: int, mean_ll: float) -> None:
        if progress is not None and iteration % 10 == 0:
            progress(f"EM iteration {iteration}: mean log-likelihood {mean_ll:.2f}")

    start = time.perf_counter()
    gmm = fit_pose_gmm(train_poses, components, seed, body_model=body.name, progress=em_progress, joints=joints)
    fit_s = time.perf_counter() - start
    info = {
        "data": Path(motion_dir).name, "stride": stride, "seed": seed, "components": components,
        "train_poses": len(train_poses), "val_poses": len(val_poses),
        "modelled_joints": [JOINT_NAMES[1 + j] for j in joints],
        "val_subjects": held_out,
        "train_mean_log_likelihood": float(gmm.log_likelihood(train_poses).mean()),
        "val_mean_log_likelihood": float(gmm.log_likelihood(val_poses).mean()),
        "val_nearest_mean_geodesic_rad": float(nearest_mean_geodesic(gmm, val_poses).mean()),
        "load_seconds": round(load_s, 2), "fit_seconds": round(fit_s, 2),
    }  # fmt: skip
    return replace(gmm, info=info)
