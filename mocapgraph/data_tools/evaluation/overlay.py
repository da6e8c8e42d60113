"""A result drawn over one camera's images: the body's mesh (shaded, semi-transparent), its
skeleton, and the camera's detections; on the camera's video when the capture has one, else on a
plain background.

The mesh goes through :func:`rasterize`, a z-buffer in numpy: every triangle's candidate pixels
(its bounding box, in batches of triangles of similar size) are tested by their barycentric
coordinates at once, and the nearest triangle per pixel wins. The lens distortion is applied to
the vertices (straight edges between them stay straight: at the mesh's ~2 cm triangles the error
is sub-pixel for ordinary lenses).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from mocapgraph.body.mesh import SkinnedMesh
from mocapgraph.body.skeleton import PARENTS
from mocapgraph.data_tools.geometry.camera_model import project_points
from mocapgraph.data_tools.geometry.raster import rasterize
from mocapgraph.data_tools.io.files import refuse_existing, write_file_atomically
from mocapgraph.errors import MocapgraphError
from mocapgraph.progress import progress_bar

log = logging.getLogger(__name__)

MESH_BGR = (150, 170, 230)
SKELETON_BGR = (40, 220, 40)
JOINT_BGR = (0, 90, 255)
DETECTION_BGR = (255, 80, 0)
BACKGROUND_GREY = 60
def face_shading(camera_points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(F,)`` in [0, 1]: |cos| of the angle between each triangle's normal and its line of sight
    (a headlight at the camera; two-sided, so the inside of an open mesh is lit too)."""
    tri = camera_points[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    sight = tri.mean(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cos = np.abs(np.sum(normal * sight, axis=1)) / (np.linalg.norm(normal, axis=1) * np.linalg.norm(sight, axis=1))
    return np.nan_to_num(cos)


def draw_mesh(image: np.ndarray, vertices: np.ndarray, faces: np.ndarray, world_T_camera, K, distortion, alpha: float = 0.6) -> np.ndarray:
    """``image (H, W, 3)`` BGR uint8 with the mesh ``vertices (V, 3)`` world drawn over it, shaded, blended by ``alpha``."""
    pixels, depth = project_points(vertices, world_T_camera, K, distortion)
    R, t = world_T_camera[:3, :3], world_T_camera[:3, 3]
    seen = rasterize(pixels, depth, faces, (image.shape[1], image.shape[0]))
    mask = seen >= 0
    shade = 0.3 + 0.7 * face_shading((vertices - t) @ R, faces)
    colour = shade[seen[mask], None] * np.array(MESH_BGR, dtype=float)
    out = image.copy()
    out[mask] = np.clip((1 - alpha) * image[mask] + alpha * colour, 0, 255).astype(np.uint8)
    return out


def draw_skeleton(image: np.ndarray, joint_pixels: np.ndarray, radius: int = 4) -> np.ndarray:
    """``image`` with the 22 joints ``(22, 2)`` pixels drawn: bones as lines, joints as dots of
    ``radius`` pixels (NaN: skipped)."""
    out = image.copy()
    ok = np.all(np.isfinite(joint_pixels), axis=1) & np.all(np.abs(joint_pixels) < 1e6, axis=1)
    ij = np.round(np.where(ok[:, None], joint_pixels, 0)).astype(int)
    for c, p in enumerate(PARENTS):
        if p >= 0 and ok[c] and ok[p]:
            cv2.line(out, tuple(ij[p]), tuple(ij[c]), SKELETON_BGR, max(1, radius // 2), cv2.LINE_AA)
    for j in np.flatnonzero(ok):
        cv2.circle(out, tuple(ij[j]), radius, JOINT_BGR, -1, cv2.LINE_AA)
    return out


def draw_detections(image: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """``image`` with detected keypoints ``(K, 3)`` (x, y, confidence; NaN = missing) as rings."""
    out = image.copy()
    for x, y, conf in keypoints:
        if np.isfinite(x) and np.isfinite(y) and conf > 0:
            cv2.circle(out, (int(round(x)), int(round(y))), 6, DETECTION_BGR, 2, cv2.LINE_AA)
    return out


def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``(4, 4)`` world_T_camera of an OpenCV camera at ``eye`` looking at ``target``, world ``up`` up in the image."""
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, np.cross(forward, right), forward], axis=1)
    pose[:3, 3] = eye
    return pose


def mesh_views(vertices: np.ndarray, faces: np.ndarray, joints: np.ndarray, facing: np.ndarray, size: tuple[int, int] = (360, 480)) -> np.ndarray:
    """The posed mesh from the front and from its left side, side by side: ``(H, 2W, 3)`` BGR uint8.

    Args:
        vertices: ``(V, 3)`` world metres (Z up); ``joints (22, 3)`` drawn over it.
        facing: ``(3,)`` the body's forward direction in the world (its horizontal part is used).
        size: ``(width, height)`` of each view; the body fills 85 % of the height, seen from 4 m.
    """
    width, height = size
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    tall = np.ptp(vertices[:, 2])
    distance = 4.0
    f = 0.85 * height * distance / max(tall, 1e-6)
    K = np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
    front = np.array([facing[0], facing[1], 0.0]) / max(np.hypot(facing[0], facing[1]), 1e-9)
    left = np.cross([0.0, 0.0, 1.0], front)
    views = []
    for direction in (front, left):
        pose = look_at(centre + distance * direction, centre)
        image = np.full((height, width, 3), 235, np.uint8)
        image = draw_mesh(image, vertices, faces, pose, K, None, alpha=1.0)
        views.append(draw_skeleton(image, project_points(joints, pose, K)[0], radius=max(2, height // 160)))
    return np.concatenate(views, axis=1)


def nearest_frames(times: np.ndarray, reference: np.ndarray, tolerance: float) -> np.ndarray:
    """``(len(times),)`` index of the nearest ``reference`` time to each of ``times``, -1 when it is farther than ``tolerance``."""
    if len(reference) == 0:
        return np.full(len(times), -1)
    right = np.clip(np.searchsorted(reference, times), 0, len(reference) - 1)
    left = np.maximum(right - 1, 0)
    pick = np.where(np.abs(reference[left] - times) < np.abs(reference[right] - times), left, right)
    return np.where(np.abs(reference[pick] - times) <= tolerance, pick, -1)


@dataclass
class OverlayScene:
    """What one camera sees of a result, per camera frame.

    Attributes:
        world_T_camera: ``(T_c, 4, 4)`` the result's camera pose (NaN where it has none near the frame).
        state: ``(T_c,)`` the body state nearest each frame, -1 where none is near.
        joints: ``(T_c, 22, 3)`` world metres (NaN where no body state is near the frame).
        keypoints: ``(T_c, K, 3)`` the result's keypoints likewise, or None (it has none).
        detections: ``(T_c, K, 3)`` the camera's first detector's keypoints, or None.
        result, body, mesh: what :meth:`vertices` poses (mesh None: no mesh for this result).
    """

    world_T_camera: np.ndarray
    state: np.ndarray
    joints: np.ndarray
    keypoints: np.ndarray | None
    detections: np.ndarray | None
    result: object
    body: object = None
    mesh: SkinnedMesh | None = None

    def vertices(self, frame: int) -> np.ndarray | None:
        """``(V, 3)`` the posed mesh at camera frame ``frame``, world metres, or None."""
        t = int(self.state[frame])
        if self.mesh is None or t < 0:
            return None
        res = self.result
        return self.mesh.vertices(self.mesh.bone_poses(self.body.forward(res.shape, res.root[t : t + 1], res.pose[t : t + 1])))[0]


def overlay_scene(result, camera, body=None) -> OverlayScene:
    """The result as seen by ``camera`` (a capture's :class:`Camera`) at each of its frames.

    A frame takes the nearest body state and camera pose within half a frame period; ``body``
    (the model the result was solved with) gives the mesh, when the result has body parameters
    and the backend a mesh.
    """
    if camera.name not in result.cameras:
        raise MocapgraphError(f"the result has no track of camera {camera.name!r} (it has: {', '.join(result.cameras) or 'none'})")
    track = result.cameras[camera.name]
    half = 0.5 / camera.frame_rate
    pose_at = nearest_frames(camera.timestamps, track.timestamps, half)
    state = nearest_frames(camera.timestamps, result.timestamps, half)
    world_T_camera = np.where((pose_at >= 0)[:, None, None], np.asarray(track.world_T_camera)[np.maximum(pose_at, 0)], np.nan)

    def at_states(points: np.ndarray) -> np.ndarray:
        return np.where((state >= 0)[:, None, None], points[np.maximum(state, 0)], np.nan)

    mesh = None
    if body is not None and result.has_body_parameters:
        try:
            mesh = body.mesh(result.shape)
        except MocapgraphError as exc:
            log.warning("drawing the skeleton only: %s", exc)
    detections = next(iter(camera.detectors.values())).keypoints if camera.detectors else None
    keypoints = None if result.keypoints is None else at_states(result.keypoints)
    return OverlayScene(world_T_camera, state, at_states(result.joints), keypoints, detections, result, body, mesh)


def overlay_frame(image: np.ndarray, scene: OverlayScene, frame: int, camera) -> np.ndarray:
    """One camera frame ``image (H, W, 3)`` BGR uint8 with the mesh, skeleton and detections of ``frame`` drawn."""
    out = image
    pose = scene.world_T_camera[frame]
    if np.all(np.isfinite(pose)):
        vertices = scene.vertices(frame)
        if vertices is not None:
            out = draw_mesh(out, vertices, scene.mesh.faces, pose, camera.K, camera.distortion)
        out = draw_skeleton(out, project_points(scene.joints[frame], pose, camera.K, camera.distortion)[0])
    if scene.detections is not None:
        out = draw_detections(out, scene.detections[frame])
    return out


def video_frames(capture, camera):
    """The camera's video frames (BGR uint8) in order, or plain grey frames when it has no video."""
    width, height = camera.image_size
    if camera.video is None:
        for _ in range(camera.num_frames):
            yield np.full((height, width, 3), BACKGROUND_GREY, dtype=np.uint8)
        return
    path = Path(capture.path or ".") / camera.video
    reader = cv2.VideoCapture(str(path))
    if not reader.isOpened():
        raise MocapgraphError(f"{path}: OpenCV cannot open the video of camera {camera.name}")
    try:
        for _ in range(camera.num_frames):
            ok, image = reader.read()
            if not ok:
                log.warning("%s: the video ends before the camera's %d frames", path, camera.num_frames)
                return
            yield image
    finally:
        reader.release()


def write_overlay(result, capture, camera_name: str, out: str | Path, *, body=None, overwrite: bool = False, max_frames: int | None = None) -> Path:
    """Write an MP4 of ``result`` drawn over camera ``camera_name`` of ``capture`` (see the module docstring).

    Returns the path written. ``max_frames`` limits the video to the first frames.
    """
    out = Path(out)
    if out.suffix.lower() != ".mp4":
        raise MocapgraphError(f"{out}: the overlay is an MP4 video; name it {out.with_suffix('.mp4').name}")
    refuse_existing(out, overwrite)  # before building the mesh, not after
    camera = capture.camera(camera_name)
    scene = overlay_scene(result, camera, body)
    frames = camera.num_frames if max_frames is None else min(camera.num_frames, max_frames)

    def write(tmp: Path) -> None:
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(camera.frame_rate), tuple(camera.image_size))
        if not writer.isOpened():
            raise MocapgraphError(f"{out}: OpenCV cannot write an MP4 video here")
        try:
            images = video_frames(capture, camera)
            for frame in progress_bar(range(frames), desc=f"overlay {camera_name}", unit="frame"):
                image = next(images, None)
                if image is None:
                    break
                writer.write(overlay_frame(image, scene, frame, camera))
        finally:
            writer.release()

    return write_file_atomically(out, overwrite, write)
