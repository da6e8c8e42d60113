"""The result format: round trip, optional parts, one clear error per bad field."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import random_root

from mocapgraph.data_tools.io.result import CameraTrack, Result, ResultError, load_result, write_result


def make_result(with_body: bool = True) -> Result:
    rng = np.random.default_rng(0)
    T = 4
    joints = rng.normal(size=(T, 22, 3))
    joints[2] = np.nan  # a frame the pipeline could not estimate
    res = Result(
        pipeline="unit", capture="captures/demo", world_frame="capture", timestamps=np.arange(T) / 30.0,
        joints=joints, keypoints=rng.normal(size=(T, 17, 3)), keypoint_format="coco",
        cameras={"cam0": CameraTrack(np.arange(3) / 30.0, random_root(rng, 3))},
        covariances={"joints": np.tile(np.eye(3), (T, 22, 1, 1)) * 1e-4},
        flags={"num_detections": np.array([17, 12, 0, 17])},
        log=[{"iteration": 0, "cost": 10.0}, {"iteration": 1, "cost": 2.5}],
        parameters={"gm_sigma_px": 40.0, "mode": "sequence"},
    )  # fmt: skip
    if with_body:
        res.body_model, res.root, res.pose, res.shape = "anny", random_root(rng, T), rng.normal(size=(T, 21, 3)), np.full(6, 0.5)
    return res


@pytest.mark.parametrize("with_body", [True, False])
def test_round_trip(tmp_path, with_body):
    original = make_result(with_body)
    loaded = load_result(write_result(original, tmp_path / "res"))
    assert (loaded.pipeline, loaded.capture, loaded.world_frame) == ("unit", "captures/demo", "capture")
    np.testing.assert_array_equal(loaded.joints, original.joints)
    assert loaded.keypoint_format == "coco17"
    np.testing.assert_allclose(loaded.cameras["cam0"].world_T_camera, original.cameras["cam0"].world_T_camera, atol=1e-12)
    np.testing.assert_array_equal(loaded.flags["num_detections"], [17, 12, 0, 17])
    assert loaded.log[1]["cost"] == 2.5 and loaded.parameters == {"gm_sigma_px": 40.0, "mode": "sequence"}
    assert loaded.has_body_parameters == with_body
    if with_body:
        np.testing.assert_allclose(loaded.root, original.root, atol=1e-12)


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda p: (p / "result.toml").write_text('format = "mocapgraph-capture"'), "result.toml: format: expected 'mocapgraph-result'"),
        (lambda p: np.savez(p / "body.npz", timestamps=np.arange(4.0), joints=np.zeros((4, 21, 3))), r"body.npz: joints: expected shape \(4, 22, 3\)"),
        (lambda p: np.savez(p / "body.npz", timestamps=np.arange(4.0), joints=np.zeros((4, 22, 3)), pose=np.zeros((4, 21, 3))), "body.npz: R: missing"),
        (lambda p: np.savez(p / "flags.npz", num_detections=np.zeros(3)), r"flags.npz: num_detections: per-frame flags need 4 rows"),
        (lambda p: np.savez(p / "cameras.npz", **{"cam0.timestamps": np.arange(3.0), "cam0.R": np.zeros((3, 3, 3)), "cam0.t": np.zeros((3, 3))}), "cameras.npz: cam0.R: not a rotation matrix"),
        (lambda p: (p / "log.json").write_text("{"), "log.json: not valid JSON"),
    ],
)
def test_bad_fields_are_one_clear_error(tmp_path, mutate, message):
    path = write_result(make_result(), tmp_path / "res")
    mutate(path)
    with pytest.raises(ResultError, match=message):
        load_result(path)
