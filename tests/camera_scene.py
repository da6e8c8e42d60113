"""A small scene for the drawing and viewing tests: a standing body 4 m in front of one camera
with lens distortion (320 × 240), 3 frames, a simulated COCO detector, written as a capture
(with ground truth) and the body's own motion as a result."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from mocapgraph.body import load_body_model
from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import axis_rotation
from mocapgraph.data_tools.io.capture import Camera, Capture, Detector, GroundTruth, write_capture
from mocapgraph.data_tools.io.result import CameraTrack, Result, write_result

IMAGE = (320, 240)


def opencv_pixels(points: np.ndarray, world_T_camera: np.ndarray, K, distortion) -> np.ndarray:
    """``(N, 2)`` pixels of world ``points (N, 3)`` by ``cv2.projectPoints`` (the reference projection)."""
    R, t = world_T_camera[:3, :3], world_T_camera[:3, 3]
    return cv2.projectPoints(np.asarray(points, dtype=float), cv2.Rodrigues(R.T)[0], -R.T @ t, K, distortion)[0][:, 0]


@dataclass
class CameraScene:
    body: BodyModel
    camera: Camera
    capture: Capture
    result: Result
    result_path: Path
    world_T_camera: np.ndarray


def camera_scene(root_dir: Path) -> CameraScene:
    body = load_body_model("anny")
    T = 3
    root = np.tile(np.eye(4), (T, 1, 1))
    root[:, :3, :3] = axis_rotation("x", np.pi / 2)  # body up = world Z, facing −Y (the camera)
    root[:, :3, 3] = [[0.0, 0.0, 1.0], [0.05, 0.0, 1.0], [0.1, 0.0, 1.0]]
    pose = np.zeros((T, 21, 3))
    pose[:, 15] = [[0, 0, -0.5 * t] for t in range(T)]  # the left shoulder lowers the arm
    shape = body.default_shape
    fk = body.forward(shape, root, pose)
    world_T_camera = np.eye(4)
    world_T_camera[:3, :3] = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # x right = +X, y down = −Z, z forward = +Y
    world_T_camera[:3, 3] = [0.0, -4.0, 1.0]
    K = np.array([[280.0, 0, 160.0], [0, 280.0, 120.0], [0, 0, 1]])
    distortion = np.array([-0.05, 0.01, 0.001, -0.001, 0.0])
    times = np.arange(T) / 10.0
    detections = np.full((T, 17, 3), 0.9)
    detections[..., :2] = opencv_pixels(fk.keypoints[:, :17].reshape(-1, 3), world_T_camera, K, distortion).reshape(T, 17, 2) + 3.0
    detections[1, 4] = np.nan  # an ear the detector missed
    camera = Camera("cam", K, distortion, IMAGE, False, times, 10.0, {"sim": Detector("sim", "coco17", detections)})
    truth = GroundTruth("anny", times, root, pose, shape, fk.joints, cameras={"cam": np.tile(world_T_camera, (T, 1, 1))})
    capture = Capture("unit", [camera], world_frame="test", ground_truth=truth)
    capture_path = write_capture(capture, root_dir / "capture")
    result = Result(
        pipeline="unit", capture=str(capture_path), world_frame="capture", timestamps=times, joints=fk.joints,
        body_model="anny", root=root, pose=pose, shape=shape, keypoints=fk.keypoints[:, :17], keypoint_format="coco17",
        cameras={"cam": CameraTrack(times, np.tile(world_T_camera, (T, 1, 1)))},
        covariances={"joints": np.tile(np.diag([1e-4, 4e-4, 9e-4]), (T, 22, 1, 1))},
    )  # fmt: skip
    return CameraScene(body, camera, capture, result, write_result(result, root_dir / "result"), world_T_camera)


def with_video(scene: CameraScene, directory: Path, bgr=(30, 30, 200)) -> Capture:
    """The scene's capture with a video for its camera: one plain ``bgr`` frame per camera frame."""
    from dataclasses import replace

    writer = cv2.VideoWriter(str(directory / "cam.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), scene.camera.frame_rate, IMAGE)
    for _ in range(scene.camera.num_frames):
        writer.write(np.full((IMAGE[1], IMAGE[0], 3), bgr, np.uint8))
    writer.release()
    return replace(scene.capture, cameras=[replace(scene.camera, video="cam.mp4")], path=directory)
