"""Overlays: the rasteriser against an independent point-in-polygon test, the drawn skeleton
against OpenCV's own projection, and the video read back."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from camera_scene import IMAGE, camera_scene, opencv_pixels, with_video
from matplotlib.path import Path as PolygonPath

from mocapgraph.data_tools.evaluation.overlay import (
    BACKGROUND_GREY,
    DETECTION_BGR,
    JOINT_BGR,
    draw_mesh,
    mesh_views,
    overlay_frame,
    overlay_scene,
    rasterize,
    write_overlay,
)
from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.errors import MocapgraphError

SIZE = (160, 120)


def test_rasterize_covers_the_pixels_inside_each_triangle():
    tri = np.array([[10.3, 12.7], [140.6, 30.2], [55.1, 101.4]])
    seen = rasterize(tri, np.full(3, 2.0), np.array([[0, 1, 2]]), SIZE)
    u, v = np.meshgrid(np.arange(SIZE[0]), np.arange(SIZE[1]))
    inside = PolygonPath(tri).contains_points(np.stack([u.ravel(), v.ravel()], axis=1)).reshape(v.shape)
    np.testing.assert_array_equal(seen >= 0, inside)
    assert inside.sum() > 4000  # large triangles take the widest windows of the batching


def test_rasterize_keeps_the_nearest_triangle_per_pixel():
    # Two triangles crossing in depth: the first is tilted (depth 1 m at the left, 5 m at the right),
    # the second stands at 3 m; left of the crossing the first is nearer, right of it the second.
    pixels = np.array([[0.2, 0.3], [159.6, 0.4], [0.5, 119.7], [159.8, 119.6], [0.3, 60.1], [159.7, 0.2], [159.4, 119.8]])
    depth = np.array([1.0, 5.0, 1.0, 5.0, 3.0, 3.0, 3.0])
    faces = np.array([[0, 1, 2], [2, 1, 3], [4, 5, 6]])
    seen = rasterize(pixels, depth, faces, SIZE)
    # Depth on the tilted quad is 1/z-affine: 1/z = 1 - (u / 159.6 …) * (1 - 1/5); it equals 3 m where 1/z = 1/3.
    u_cross = (1 - 1 / 3) / (1 - 1 / 5) * 159.6
    row = seen[60]
    assert np.all(row[5 : int(u_cross) - 2] != 2) and np.all(np.isin(row[int(u_cross) + 3 : 155], [2]))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return camera_scene(tmp_path_factory.mktemp("overlay"))


def test_skeleton_is_drawn_where_opencv_projects_the_joints(scene):
    body, camera, result, world_T_camera = scene.body, scene.camera, scene.result, scene.world_T_camera
    K, distortion = camera.K, camera.distortion
    drawn = overlay_scene(result, camera, body)
    drawn.detections = None  # their rings would cover some joints
    for frame in range(3):
        image = overlay_frame(np.full((IMAGE[1], IMAGE[0], 3), BACKGROUND_GREY, np.uint8), drawn, frame, camera)
        pixels = opencv_pixels(result.joints[frame], world_T_camera, K, distortion)
        inside = np.all((pixels > 2) & (pixels < np.array(IMAGE) - 3), axis=1)
        assert inside.sum() >= 20
        at = np.round(pixels[inside]).astype(int)
        np.testing.assert_array_equal(image[at[:, 1], at[:, 0]], np.tile(JOINT_BGR, (len(at), 1)))
        # The mesh is drawn where OpenCV projects its vertices, and nowhere else.
        vertices = drawn.vertices(frame)
        image = draw_mesh(np.full_like(image, BACKGROUND_GREY), vertices, drawn.mesh.faces, world_T_camera, K, distortion)
        at = np.round(opencv_pixels(vertices, world_T_camera, K, distortion)).astype(int)
        changed = np.any(image != BACKGROUND_GREY, axis=2)
        # (within a pixel: thin parts such as fingers cover no pixel centre at this size)
        assert cv2.dilate(changed.astype(np.uint8), np.ones((3, 3), np.uint8))[at[:, 1], at[:, 0]].mean() > 0.99
        near = np.zeros_like(changed, dtype=np.uint8)
        near[at[:, 1], at[:, 0]] = 1
        near = cv2.dilate(near, np.ones((5, 5), np.uint8)).astype(bool)
        assert np.sum(changed & ~near) < 0.01 * changed.sum()


def test_overlay_video_reads_back(scene, tmp_path):
    body, camera, result = scene.body, scene.camera, scene.result
    capture = Capture("unit", [camera], world_frame="test")
    path = write_overlay(result, capture, "cam", tmp_path / "cam.mp4", body=body)
    reader = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, image = reader.read()
        if not ok:
            break
        frames.append(image)
    assert len(frames) == 3 and frames[0].shape == (IMAGE[1], IMAGE[0], 3)
    expected = overlay_frame(np.full((IMAGE[1], IMAGE[0], 3), BACKGROUND_GREY, np.uint8), overlay_scene(result, camera, body), 1, camera)
    assert np.mean(np.abs(frames[1].astype(float) - expected)) < 8.0  # MPEG-4 compression
    ring = camera.detectors["sim"].keypoints[1, 0, :2] + [6, 0]  # on the nose's detection ring
    assert np.all(expected[int(round(ring[1])), int(round(ring[0]))] == DETECTION_BGR)
    with pytest.raises(MocapgraphError, match="already exists"):
        write_overlay(result, capture, "cam", path, body=body)
    with pytest.raises(MocapgraphError, match="has no camera 'other'"):
        write_overlay(result, capture, "other", tmp_path / "other.mp4", body=body)
    with pytest.raises(MocapgraphError, match="name it cam.mp4"):
        write_overlay(result, capture, "cam", tmp_path / "cam.avi", body=body)


def test_overlay_draws_over_the_cameras_video(scene, tmp_path):
    capture = with_video(scene, tmp_path)
    path = write_overlay(scene.result, capture, "cam", tmp_path / "over.mp4", body=scene.body)
    ok, image = cv2.VideoCapture(str(path)).read()
    assert ok
    corner = image[:20, :20].reshape(-1, 3).mean(axis=0)  # no body there: the video's own colour
    np.testing.assert_allclose(corner, (30, 30, 200), atol=12)
    middle = opencv_pixels(scene.result.joints[0, 3:4], scene.world_T_camera, scene.camera.K, scene.camera.distortion)[0]
    assert np.abs(image[int(middle[1]), int(middle[0])].astype(float) - (30, 30, 200)).max() > 40  # the body drawn over it


def test_mesh_views_show_the_body_from_the_front_and_the_side(scene):
    result, drawn = scene.result, overlay_scene(scene.result, scene.camera, scene.body)
    facing = result.root[0, :3, :3] @ [0.0, 0.0, 1.0]
    image = mesh_views(drawn.vertices(0), drawn.mesh.faces, result.joints[0], facing, size=(300, 400))
    assert image.shape == (400, 600, 3)
    extents = []
    for view in (image[:, :300], image[:, 300:]):
        rows, cols = np.nonzero(np.any(view != 235, axis=2))
        # 85 % of the height at the body's centre; its near side is ~0.15 m closer than the 4 m, so up to ~4 % more
        assert 0.85 <= (rows.max() - rows.min()) / 400 <= 0.89
        assert abs((cols.min() + cols.max()) / 2 - 150) < 15  # centred
        extents.append(cols.max() - cols.min())
    assert extents[0] > 1.5 * extents[1]  # arms spread (T-pose at frame 0): wide from the front, narrow from the side


def test_overlay_command(scene, tmp_path, capsys):
    from mocapgraph.cli.main import main

    result_path = scene.result_path
    out = tmp_path / "o.mp4"
    assert main(["overlay", str(result_path), "--camera", "cam", "--out", str(out), "--max-frames", "2"]) == 0
    assert capsys.readouterr().out.strip() == f"wrote {out.resolve()}"
    assert int(cv2.VideoCapture(str(out)).get(cv2.CAP_PROP_FRAME_COUNT)) == 2
    assert main(["overlay", str(tmp_path / "nothing"), "--camera", "cam", "--out", str(out), "--overwrite"]) == 2
    assert "nothing: directory not found" in capsys.readouterr().err
