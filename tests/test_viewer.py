"""The rerun recording, read back with rerun's own .rrd reader: what each entity holds per time
against the result, OpenCV's projection and the ground truth (float32 in the recording)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from camera_scene import camera_scene, opencv_pixels, with_video

from mocapgraph.errors import MocapgraphError

rr = pytest.importorskip("rerun")


def read_rrd(path) -> dict[str, dict[str, dict[float, object]]]:
    """``{entity: {column: {time (s, to the µs; -1 when static): value}}}`` of every logged component."""
    from rerun.chunk import RrdReader

    out: dict = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        names = batch.schema.names
        times = [round(t.total_seconds(), 6) for t in batch.column(names.index("time")).to_pylist()] if "time" in names else [-1.0] * batch.num_rows
        for name in names:
            if ":" in name:
                values = batch.column(names.index(name)).to_pylist()
                out.setdefault(chunk.entity_path, {}).setdefault(name, {}).update(zip(times, values))
    return out


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    pytest.importorskip("torch")
    from mocapgraph.data_tools.evaluation.viewer import view_result

    root = tmp_path_factory.mktemp("viewer")
    scene = camera_scene(root)
    path = view_result(scene.result, with_video(scene, root), scene.body, save=root / "result.rrd")
    return scene, read_rrd(path)


def test_body_mesh_and_covariances_per_state(recording):
    scene, rrd = recording
    result, body = scene.result, scene.body
    joints = rrd["/world/estimate/joints"]["Points3D:positions"]
    for t, stamp in enumerate(result.timestamps):
        np.testing.assert_allclose(joints[round(stamp, 6)], result.joints[t], atol=1e-6)
    mesh = body.mesh(result.shape)
    assert len(rrd["/world/estimate/mesh"]["Mesh3D:triangle_indices"][-1.0]) == len(mesh.faces)
    vertices = np.array(rrd["/world/estimate/mesh"]["Mesh3D:vertex_positions"][round(result.timestamps[2], 6)])
    expected = mesh.vertices(mesh.bone_poses(body.forward(result.shape, result.root[2:], result.pose[2:])))[0]
    np.testing.assert_allclose(vertices, expected, atol=1e-5)
    half = np.array(rrd["/world/estimate/joint_covariance"]["Ellipsoids3D:half_sizes"][0.0])
    np.testing.assert_allclose(np.sort(half, axis=1), np.tile([0.01, 0.02, 0.03], (22, 1)), rtol=1e-5)


def test_cameras_detections_and_reprojections(recording):
    scene, rrd = recording
    camera, pose = scene.camera, scene.world_T_camera
    cam = rrd["/world/cameras/cam"]
    np.testing.assert_allclose(np.array(cam["Pinhole:image_from_camera"][-1.0]).reshape(3, 3).T, camera.K, atol=1e-9)
    for stamp in camera.timestamps:
        np.testing.assert_allclose(cam["Transform3D:translation"][round(stamp, 6)][0], pose[:3, 3], atol=1e-6)
    np.testing.assert_allclose(np.array(cam["Transform3D:mat3x3"][0.0]).reshape(3, 3).T, pose[:3, :3], atol=1e-6)
    for frame, stamp in enumerate(camera.timestamps):
        key = round(stamp, 6)
        shown = np.array(rrd["/world/cameras/cam/reprojected"]["Points2D:positions"][key])
        np.testing.assert_allclose(shown, opencv_pixels(scene.result.keypoints[frame], pose, camera.K, camera.distortion), atol=1e-3)
        detected = camera.detectors["sim"].keypoints[frame]
        seen = np.array(rrd["/world/cameras/cam/detected"]["Points2D:positions"][key])
        np.testing.assert_allclose(seen, detected[np.isfinite(detected[:, 0]), :2], atol=1e-3)
    assert len(rrd["/world/trajectories/cam"]["LineStrips3D:strips"][-1.0][0]) == 3

    frames = rrd["/world/cameras/cam/video"]["EncodedImage:blob"]
    assert sorted(frames) == [round(s, 6) for s in camera.timestamps]
    (jpeg,) = frames[0.1]  # one blob: a list of its bytes
    image = cv2.imdecode(np.array(jpeg, dtype=np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (240, 320, 3)
    np.testing.assert_allclose(image.reshape(-1, 3).mean(axis=0), (30, 30, 200), atol=12)


def test_ground_truth_beside_the_estimate(recording):
    scene, rrd = recording
    truth = scene.capture.ground_truth
    for t, stamp in enumerate(truth.timestamps):
        np.testing.assert_allclose(rrd["/world/truth/joints"]["Points3D:positions"][round(stamp, 6)], truth.joints[t], atol=1e-6)
    (notes,) = rrd["/notes"]["TextDocument:text"][-1.0]
    assert notes == "ground truth beside the estimate; alignment of the estimate: none (result is in the capture's world frame)"


def test_view_command_saves_a_recording(tmp_path, capsys):
    from mocapgraph.cli.main import main

    scene = camera_scene(tmp_path)
    out = tmp_path / "r.rrd"
    assert main(["view", str(scene.result_path), "--save", str(out), "--mesh-every", "2"]) == 0
    assert capsys.readouterr().out.strip() == f"wrote {out.resolve()} (open it with: rerun {out})"
    rrd = read_rrd(out)
    assert "/world/cameras/cam/reprojected" in rrd
    assert sorted(rrd["/world/estimate/mesh"]["Mesh3D:vertex_positions"]) == [0.0, 0.2]  # every 2nd of the 3 states
    assert main(["view", str(scene.result_path), "--save", str(tmp_path / "r.txt")]) == 2
    assert "name it r.rrd" in capsys.readouterr().err
    with pytest.raises(MocapgraphError, match="already exists"):
        from mocapgraph.data_tools.evaluation.viewer import view_result

        view_result(scene.result, save=out)
