"""A result in the rerun viewer (``rerun-sdk``, the optional ``[viz]`` extra), on the capture's time line.

Entities (world Z up, metres; timeline ``time`` = the capture's seconds):

- ``world/estimate/{mesh, skeleton, joints, joint_covariance}``: the body per state (the mesh
  when the body model has one; 1-σ ellipsoids when the result has joint covariances);
- ``world/cameras/<name>``: each camera's pose per frame, with its lens (a frustum) when the
  capture is known; under it, in image space, ``detected`` and ``reprojected`` keypoints and the
  ``video`` frames when the capture has a video; ``world/trajectories/<name>``: its path;
- ``world/truth/{skeleton, joints}`` and ``world/truth/trajectories/<name>`` for a capture with
  ground truth. The estimate is then moved into the capture's world as ``mocapgraph eval``
  aligns it (``notes`` says how).
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from mocapgraph.body.skeleton import PARENTS
from mocapgraph.data_tools.evaluation.evaluate import aligned
from mocapgraph.data_tools.evaluation.overlay import overlay_scene, video_frames
from mocapgraph.data_tools.geometry.camera_model import project_points
from mocapgraph.errors import MocapgraphError
from mocapgraph.progress import progress_bar

log = logging.getLogger(__name__)

INSTALL_HINT = "the viewer needs rerun-sdk: pip install 'mocapgraph[viz]'"
APPLICATION_ID = "mocapgraph"
ESTIMATE_RGB, TRUTH_RGB, DETECTED_RGB, REPROJECTED_RGB = (40, 200, 60), (230, 80, 60), (0, 120, 255), (40, 200, 60)
MESH_RGBA = (230, 170, 150, 255)
BONES = [(int(p), c) for c, p in enumerate(PARENTS) if p >= 0]


def _rerun():
    try:
        import rerun as rr
    except ImportError:
        raise MocapgraphError(INSTALL_HINT) from None
    return rr


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(V, 3)`` unit normals: the area-weighted mean of the adjacent triangles' normals."""
    tri = vertices[faces]
    face = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, faces[:, k], face)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)


def _bones(joints: np.ndarray) -> np.ndarray:
    """``(21, 2, 3)`` the skeleton's segments of ``joints (22, 3)``."""
    return np.stack([joints[[p, c]] for p, c in BONES])


def _log_body(rec, rr, path: str, joints: np.ndarray, rgb) -> None:
    ok = np.all(np.isfinite(joints), axis=1)
    segments = [s for s, (p, c) in zip(_bones(joints), BONES) if ok[p] and ok[c]]
    rec.log(f"{path}/skeleton", rr.LineStrips3D(segments, colors=rgb, radii=0.01))
    rec.log(f"{path}/joints", rr.Points3D(joints[ok], colors=rgb, radii=0.02))


def _log_covariances(rec, rr, joints: np.ndarray, covariance: np.ndarray) -> None:
    ok = np.all(np.isfinite(covariance), axis=(1, 2)) & np.all(np.isfinite(joints), axis=1)
    if not ok.any():
        return
    values, vectors = np.linalg.eigh(covariance[ok])
    vectors[np.linalg.det(vectors) < 0, :, 2] *= -1  # a proper rotation for the quaternion
    rec.log(
        "world/estimate/joint_covariance",
        rr.Ellipsoids3D(centers=joints[ok], half_sizes=np.sqrt(np.maximum(values, 0.0)), quaternions=Rotation.from_matrix(vectors).as_quat(), colors=ESTIMATE_RGB),
    )  # fmt: skip


def log_result(rec, result, capture=None, body=None, video: bool = True, mesh_every: int = 1) -> list[str]:
    """Log ``result`` (and what ``capture`` adds: lenses, detections, video, ground truth) into the
    rerun recording ``rec``; ``body`` gives the mesh, logged at every ``mesh_every``-th body state
    (about 330 kB a state). Returns notes on what was left out or moved."""
    rr = _rerun()
    notes = []
    covariance = result.covariances.get("joints")
    if capture is not None and capture.ground_truth is not None:
        moved, how = aligned(result, capture)
        notes.append(f"ground truth beside the estimate; alignment of the estimate: {how}")
        if covariance is not None and not how.startswith("none"):
            covariance = None
            notes.append("joint covariances are not drawn: they are in the result's own frame")
        result = moved
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    mesh = None
    if body is not None and result.has_body_parameters:
        try:
            mesh = body.mesh(result.shape)
        except MocapgraphError as exc:
            notes.append(f"no mesh: {exc}")
        else:
            rec.log("world/estimate/mesh", rr.Mesh3D.from_fields(triangle_indices=mesh.faces, albedo_factor=MESH_RGBA), static=True)
    for t, stamp in enumerate(progress_bar(result.timestamps, desc="viewer: body", unit="state")):
        rec.set_time("time", duration=float(stamp))
        _log_body(rec, rr, "world/estimate", result.joints[t], ESTIMATE_RGB)
        if mesh is not None and t % mesh_every == 0:
            vertices = mesh.vertices(mesh.bone_poses(body.forward(result.shape, result.root[t : t + 1], result.pose[t : t + 1])))[0]
            rec.log("world/estimate/mesh", rr.Mesh3D.from_fields(vertex_positions=vertices, vertex_normals=vertex_normals(vertices, mesh.faces)))
        if covariance is not None:
            _log_covariances(rec, rr, result.joints[t], covariance[t])

    truth = capture.ground_truth if capture is not None else None
    if truth is not None:
        for t, stamp in enumerate(truth.timestamps):
            rec.set_time("time", duration=float(stamp))
            _log_body(rec, rr, "world/truth", truth.joints[t], TRUTH_RGB)
        for name, poses in truth.cameras.items():
            rec.log(f"world/truth/trajectories/{name}", rr.LineStrips3D([poses[:, :3, 3]], colors=TRUTH_RGB, radii=0.01), static=True)

    lenses = {cam.name: cam for cam in capture.cameras} if capture is not None else {}
    for name, track in result.cameras.items():
        path = f"world/cameras/{name}"
        poses = np.asarray(track.world_T_camera)
        rec.log(f"world/trajectories/{name}", rr.LineStrips3D([poses[:, :3, 3]], colors=ESTIMATE_RGB, radii=0.01), static=True)
        for stamp, pose in zip(track.timestamps, poses):
            rec.set_time("time", duration=float(stamp))
            rec.log(path, rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
        if name in lenses:
            _log_camera_images(rec, rr, result, capture, lenses[name], path, video)
    missing = sorted(set(lenses) - set(result.cameras))
    if missing:
        notes.append(f"cameras without an estimated track are not drawn: {', '.join(missing)}")
    if notes:
        rec.log("notes", rr.TextDocument("\n\n".join(notes), media_type="text/markdown"), static=True)
    return notes


def _log_camera_images(rec, rr, result, capture, camera, path: str, video: bool) -> None:
    """The camera's lens, and per frame its detections, the result's reprojected keypoints (or
    joints) and its video frame."""
    width, height = camera.image_size
    rec.log(path, rr.Pinhole(image_from_camera=camera.K, resolution=[width, height], camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.4), static=True)
    scene = overlay_scene(result, camera)
    points = scene.keypoints if scene.keypoints is not None else scene.joints
    pixels = project_points(points, np.nan_to_num(scene.world_T_camera), camera.K, camera.distortion)[0]
    pixels[~np.all(np.isfinite(scene.world_T_camera), axis=(1, 2))] = np.nan
    images = video_frames(capture, camera) if video and camera.video is not None else None
    for frame, stamp in enumerate(camera.timestamps):
        rec.set_time("time", duration=float(stamp))
        if scene.detections is not None:
            seen = scene.detections[frame]
            seen = seen[np.all(np.isfinite(seen), axis=1) & (seen[:, 2] > 0)]
            rec.log(f"{path}/detected", rr.Points2D(seen[:, :2], colors=DETECTED_RGB, radii=4.0))
        shown = pixels[frame][np.all(np.isfinite(pixels[frame]), axis=1)]
        rec.log(f"{path}/reprojected", rr.Points2D(shown, colors=REPROJECTED_RGB, radii=3.0))
        image = next(images, None) if images is not None else None
        if image is not None:
            ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])
            rec.log(f"{path}/video", rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg"))


def view_result(
    result, capture=None, body=None, save: str | Path | None = None, video: bool = True, mesh_every: int = 1, overwrite: bool = False
) -> Path | None:
    """Open ``result`` in the rerun viewer, or save it as a recording (``.rrd``) when ``save`` is
    given; returns the recording's path (None when a viewer was opened). ``video`` and
    ``mesh_every`` as :func:`log_result` takes them."""
    if mesh_every < 1:
        raise MocapgraphError(f"mesh_every must be a positive number of body states, got {mesh_every}")
    rr = _rerun()
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=f"{result.pipeline}:{result.path or 'result'}")
    if save is None:
        rec.spawn()
        notes = log_result(rec, result, capture, body, video, mesh_every)
        rec.flush()
        for note in notes:
            log.info("viewer: %s", note)
        return None
    save = Path(save)
    if save.suffix != ".rrd":
        raise MocapgraphError(f"{save}: a rerun recording is an .rrd file; name it {save.with_suffix('.rrd').name}")
    from mocapgraph.data_tools.io.files import write_file_atomically

    def write(tmp: Path) -> None:
        rec.save(str(tmp))
        notes = log_result(rec, result, capture, body, video, mesh_every)
        rec.flush()
        rec.disconnect()  # closes the file with its footer
        for note in notes:
            log.info("viewer: %s", note)

    return write_file_atomically(save, overwrite, write)
