"""Moving cameras' tracks from a reference reconstruction (``run smartmocap --cameras-from colmap``).

A reference (:mod:`~mocapgraph.data_tools.evaluation.colmap_reference`) has each registered frame's
camera pose in COLMAP's world: arbitrary origin, orientation and scale, one world per COLMAP model.
Into the pipeline's world (the ground plane's, metres) it goes in three steps:

1. each model's world is mapped onto the pipeline's first solution by one similarity
   (:func:`reference_similarities`: SmartMocap's normalised Procrustes over the positions and
   orientations of every frame of every camera of that model, static ones too), which scales,
   levels and places it;
2. a moving camera's registered frames start the next solve at their mapped poses, its other
   frames moved along with the nearest registered one (:meth:`ReferenceTracks.started`);
3. the motion between its consecutive registered frames becomes a prior
   (:func:`~mocapgraph.factors.camera_priors.camera_motion_prior_factor`). That motion depends on
   the similarity's scale alone: the first solution's errors of orientation and position do not
   enter it, so the track's shape comes from COLMAP and its placement still from the body.

Frames COLMAP did not register (or did not sample) keep the pipeline's own terms only.

A moving camera's IMU log has its own clock; with a reference, its offset is found against the
reference's rotations (:func:`reference_clock_offsets`), which need no similarity.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from mocapgraph.data_tools.evaluation.alignment import Similarity, procrustes_trajectory
from mocapgraph.data_tools.evaluation.colmap_reference import ColmapReference, ReferenceError, load_reference
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.camera_priors import camera_motion_prior_factor, camera_prior_factor
from mocapgraph.factors.keys import camera_key
from mocapgraph.factors.navigation import FusionNoise
from mocapgraph.graphs.camera_imu import PHONE_GYRO_NOISE, CameraImu, add_gyro_chain, frames_inside, grid_minimum, offset_grid
from mocapgraph.graphs.state_model import Estimate, StateModel

SOURCES = ("colmap",)
"""Where ``cameras_from`` may take camera tracks from."""
MIN_SPREAD_M = 0.2
"""A model's frames in the first solution must spread this far (RMS distance from their mean) for
its scale: below it, the scale is mostly the solution's own noise (a static camera alone has none)."""


def load_camera_reference(capture, source: str, name: str) -> ColmapReference:
    """The reference ``name`` of ``capture`` (written by ``mocapgraph colmap``), checked against
    the capture: every camera it names is one of the capture's, with as many frames.

    Raises:
        ReferenceError: an unknown ``source``; a capture not read from a directory; no such
            reference; a camera the capture does not have, or a different number of frames.
    """
    if source not in SOURCES:
        raise ReferenceError(f"cameras_from {source!r}: choose one of {', '.join(SOURCES)}")
    if capture.path is None:
        raise ReferenceError(f"capture {capture.name!r} was not read from a directory: it has no references/{name}")
    reference = load_reference(capture.path, name)
    names = {c.name: c for c in capture.cameras}
    unknown = [c for c in reference.cameras if c not in names]
    if unknown:
        raise ReferenceError(
            f"{capture.path}/references/{name}: cameras {', '.join(unknown)} are not in the capture (it has {', '.join(names)}); "
            "was the reference made from another capture?"
        )
    for c, poses in reference.cameras.items():
        if len(poses) != names[c].num_frames:
            raise ReferenceError(f"{capture.path}/references/{name}: camera {c} has {len(poses)} frames, the capture {names[c].num_frames}")
    return reference


def _finite(poses: np.ndarray) -> np.ndarray:
    return np.all(np.isfinite(poses), axis=(1, 2))


def reference_similarities(reference: dict[str, np.ndarray], solved: dict[str, np.ndarray], groups: dict[str, int]) -> dict[int, Similarity]:
    """Per COLMAP model, the similarity mapping its world onto the solution's.

    Args:
        reference: per camera, ``(T_c, 4, 4)`` world_T_camera in its model's world, NaN where none.
        solved: per camera, ``(T_c, 4, 4)`` world_T_camera of a solution, NaN where none.
        groups: per camera, its model (cameras of different models share no world; -1: none).

    Returns:
        Per model whose frames in ``solved`` spread by :data:`MIN_SPREAD_M`, the
        :class:`~mocapgraph.data_tools.evaluation.alignment.Similarity` with
        ``apply_pose(reference) ≈ solved``, fitted over all its cameras' frames at once
        (:func:`~mocapgraph.data_tools.evaluation.alignment.procrustes_trajectory`).
    """
    out = {}
    for g in sorted({groups.get(c, 0) for c in reference} - {-1}):
        ref, est = [], []
        for c in reference:
            if groups.get(c, 0) == g and c in solved:
                both = _finite(reference[c]) & _finite(solved[c])
                ref.append(reference[c][both])
                est.append(solved[c][both])
        if not ref:
            continue
        ref, est = np.concatenate(ref), np.concatenate(est)
        if len(est) < 2 or np.sqrt(np.mean(np.sum((est[:, :3, 3] - est[:, :3, 3].mean(0)) ** 2, axis=1))) < MIN_SPREAD_M:
            continue
        try:
            out[g] = procrustes_trajectory(ref[:, :3, 3], est[:, :3, 3], ref[:, :3, :3], est[:, :3, :3])
        except MocapgraphError:
            continue  # the reference's positions coincide (one still camera): they fix no scale
    return out


@dataclass
class ReferenceTracks:
    """A reference's moving-camera tracks in the pipeline's world.

    Attributes:
        name: the reference's name.
        frames: per model camera index, ``(M_c,)`` its frames that COLMAP registered and that
            belong to a body state.
        poses: per camera, ``(M_c, 4, 4)`` world_T_camera at those frames, the pipeline's world (metres).
        sigmas: ``(rad, m)`` of each prior on the motion between consecutive registered frames.
    """

    name: str
    frames: dict[int, np.ndarray]
    poses: dict[int, np.ndarray]
    sigmas: tuple[float, float]

    def add_to(self, graph: gtsam.NonlinearFactorGraph, model: StateModel) -> int:
        """The motion priors between consecutive registered frames of every camera; how many."""
        added = 0
        for c, frames in self.frames.items():
            poses = self.poses[c]
            for a in range(len(frames) - 1):
                a_T_b = np.linalg.inv(poses[a]) @ poses[a + 1]
                graph.add(camera_motion_prior_factor(model.camera_var(c, frames[a]), model.camera_var(c, frames[a + 1]), a_T_b, sigmas=self.sigmas))
                added += 1
        return added

    def started(self, estimate: Estimate, model: StateModel) -> Estimate:
        """``estimate`` with each camera's registered frames at the reference's poses and its
        other frames moved as the nearest registered one was (the rigid correction it got)."""
        cameras = [c.copy() for c in estimate.cameras]
        for c, frames in self.frames.items():
            own = model.camera_frames(c)
            nearest = frames[np.argmin(np.abs(own[:, None] - frames[None, :]), axis=1)]
            index = {int(j): k for k, j in enumerate(frames)}
            correction = {int(j): self.poses[c][k] @ np.linalg.inv(estimate.cameras[c][j]) for k, j in enumerate(frames)}
            for j, n in zip(own, nearest):
                cameras[c][j] = self.poses[c][index[int(j)]] if int(j) in index else correction[int(n)] @ estimate.cameras[c][j]
        return Estimate(estimate.roots.copy(), estimate.poses.copy(), estimate.shape.copy(), cameras, list(estimate.log), estimate.focal_log.copy())


def reference_tracks(reference: ColmapReference, model: StateModel, estimate: Estimate, sigmas: tuple[float, float]) -> tuple[ReferenceTracks, list[str]]:
    """The reference's moving-camera tracks mapped into the world of ``estimate`` (the first
    solution; the module docstring's step 1), and per moving camera a note on how many of its
    frames use the reference, or why none do."""
    solved = {}
    for c, name in enumerate(model.names):
        frames = model.camera_frames(c)
        if len(frames):
            track = estimate.cameras[c].copy()
            if model.cameras[c].moving:  # only the frames the solve estimated: the others kept their start
                track[np.setdiff1d(np.arange(len(track)), frames)] = np.nan
            solved[name] = track
    groups = reference.groups()
    similarities = reference_similarities(reference.cameras, solved, groups)
    frames_out, poses_out, notes = {}, {}, []
    for c, name in enumerate(model.names):
        if not model.cameras[c].moving or not len(model.camera_frames(c)):
            continue
        if name not in reference.cameras:
            notes.append(f"camera {name}: not in the reference {reference.name!r}; its poses rest on the pipeline's own terms")
            continue
        g = groups.get(name, 0)
        own = model.camera_frames(c)
        registered = own[_finite(reference.cameras[name][own])]
        if g not in similarities or len(registered) < 2:
            why = (f"{len(registered)} of its frames registered in the reference {reference.name!r}" if len(registered) < 2 else
                   f"its COLMAP model ({g}) spreads less than {MIN_SPREAD_M} m in the first solution, too little for a scale")  # fmt: skip
            notes.append(f"camera {name}: {why}; its poses rest on the pipeline's own terms")
            continue
        S = similarities[g]
        frames_out[c] = registered
        poses_out[c] = S.apply_pose(reference.cameras[name][registered])
        notes.append(
            f"camera {name}: {len(registered)} of its {len(own)} frames from the reference {reference.name!r} (COLMAP model {g}, "
            f"scaled by {S.scale:.4g} onto the first solution), {len(registered) - 1} motion priors; the other frames as before"
        )
    return ReferenceTracks(reference.name, frames_out, poses_out, tuple(sigmas)), notes


CLOCK_STEP_S = 0.005
"""The grid of :func:`reference_clock_offsets` (refined by a parabola), as the views' estimate's."""


def reference_rotation_cost(imu: CameraImu, offset_s: float, times: np.ndarray, poses: np.ndarray, sigma_rad: float, noise: FusionNoise = PHONE_GYRO_NOISE) -> float:
    """How far the gyroscope of ``imu``, its log shifted by ``offset_s`` (``imu.shifted``), turns
    the camera between its frames at ``times (M,)`` from the reference's turns between them
    (``poses (M, 4, 4)`` world_T_camera in the reference's world): the cost of those poses held
    by priors there (σ ``sigma_rad``; their positions free, 1 m, since only rotations meet the
    gyroscope) and the gyroscope between them, its bias a state (:func:`~mocapgraph.graphs.camera_imu.add_gyro_chain`)."""
    shifted = imu.shifted(offset_s)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    keys = [camera_key(0, j) for j in range(len(times))]
    for key, pose in zip(keys, poses):
        values.insert(key, gtsam.Pose3(pose))
        graph.add(camera_prior_factor(key, pose, sigmas=(sigma_rad, 1.0), kernel="none"))
    add_gyro_chain(graph, values, shifted, times, keys, noise)
    return float(graph.error(gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()))


def reference_clock_offsets(
    reference: ColmapReference, model: StateModel, imus: dict[int, CameraImu], max_offset_s: float, sigma_rad: float, noise: FusionNoise = PHONE_GYRO_NOISE,
) -> dict[int, float]:  # fmt: skip
    """Per camera of ``imus`` (model index → log) whose frames the reference registered, the
    offset of its log's clock from the camera's (``log t = camera t + offset``), seconds: the
    minimum of :func:`reference_rotation_cost` over ``[-max_offset_s, max_offset_s]`` on its
    registered frames inside the log at both ends (:func:`~mocapgraph.graphs.camera_imu.grid_minimum`).

    The turns between two of a camera's frames are in its own axes, whatever the similarity of the
    reference's world, and COLMAP's are within a few hundredths of a degree; the views of a solved
    body (:func:`~mocapgraph.graphs.camera_imu.estimated_clock_offsets`) see them far less well:
    on 2 s of ``phones`` with one static phone beside the walking one they gave -0.7 ms where the
    log was 18.5 ms off, and the gyroscope then turned the track 0.4° per 0.1 s away from COLMAP's
    (measured). A camera with fewer than three registered frames inside the log is left out.
    """
    grid = offset_grid(max_offset_s, CLOCK_STEP_S)
    out = {}
    for c, imu in imus.items():
        name = model.names[c]
        if name not in reference.cameras:
            continue
        frames = model.camera_frames(c)
        frames = frames[_finite(reference.cameras[name][frames])]
        times = model.cameras[c].timestamps[frames]
        keep = frames_inside(imu, times, grid) if len(frames) else np.zeros(0, dtype=int)
        if len(keep) < 3:
            continue
        poses = reference.cameras[name][frames[keep]]
        out[c] = grid_minimum(lambda o: reference_rotation_cost(imu, o, times[keep], poses, sigma_rad, noise), grid)[0]
    return out
