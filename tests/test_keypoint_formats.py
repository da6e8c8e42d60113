"""Keypoint format registry: mappings onto body keypoints, confidence conventions, errors."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import LinearShapeTable, random_root

from mocapgraph.body.keypoint_formats import FORMATS, format_table, get_format
from mocapgraph.body.kinematics import forward_kinematics_numpy
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES
from mocapgraph.errors import MocapgraphError


def test_formats_have_their_published_sizes():
    assert get_format("coco17").num_points == 17
    assert get_format("openpose25").num_points == 25
    assert get_format("blazepose33").num_points == 33
    assert get_format("mediapipe") is get_format("BlazePose33") is FORMATS["blazepose33"]


def test_unknown_format_is_a_clear_error():
    with pytest.raises(MocapgraphError, match="unknown keypoint format 'vitpose133'.*coco17"):
        get_format("vitpose133")


@pytest.mark.parametrize("name", ["coco17", "openpose25", "blazepose33"])
def test_left_right_pairs_are_mirror_names(name):
    fmt = get_format(name)
    pairs = fmt.left_right_pairs
    assert pairs, name
    for left, right in pairs:
        assert fmt.names[left].replace("left_", "") == fmt.names[right].replace("right_", "")


def test_format_points_are_blends_of_body_keypoints():
    """A format table posed by FK equals the same blend of the posed body keypoints."""
    rng = np.random.default_rng(0)
    table_fn = LinearShapeTable(seed=1, num_keypoints=len(BODY_KEYPOINT_NAMES), names=BODY_KEYPOINT_NAMES)
    table = table_fn(rng.normal(size=4))
    root, pose = random_root(rng, 2), rng.normal(size=(2, 21, 3))
    body = forward_kinematics_numpy(table, root, pose).keypoints
    k = BODY_KEYPOINT_NAMES.index
    op = forward_kinematics_numpy(format_table(table, "openpose25"), root, pose).keypoints
    fmt = get_format("openpose25")
    assert np.allclose(op[:, fmt.names.index("neck")], (body[:, k("left_shoulder")] + body[:, k("right_shoulder")]) / 2)
    assert np.allclose(op[:, fmt.names.index("mid_hip")], (body[:, k("left_hip")] + body[:, k("right_hip")]) / 2)
    assert np.allclose(op[:, fmt.names.index("left_heel")], body[:, k("left_heel")])
    bp = format_table(table, "blazepose33")
    unmapped = [n for n, m in zip(bp.keypoint_names, bp.mapped) if not m]
    assert "left_thumb" in unmapped and "nose" not in unmapped and len(unmapped) == 12
    assert np.all(bp.weights[~bp.mapped] == 0)


def test_openpose_zeros_become_nan_and_confidences_are_clipped():
    fmt = get_format("openpose25")
    raw = np.random.default_rng(0).random((4, 25, 3)) * [640, 480, 1.2]
    raw[0, 3] = 0.0
    raw[1, 5, 2] = 0.0
    out = fmt.normalise(raw)
    assert np.all(np.isnan(out[0, 3])) and np.all(np.isnan(out[1, 5]))
    ok = np.isfinite(out[..., 2])
    assert out[..., 2][ok].max() <= 1.0
    assert np.array_equal(out[2, :, :2], raw[2, :, :2])


def test_coco_keeps_a_point_at_the_image_origin():
    """Only OpenPose uses (0, 0, 0) for missing; for COCO a zero-confidence point is missing."""
    fmt = get_format("coco17")
    raw = np.ones((17, 3))
    raw[0] = [0.0, 0.0, 0.9]
    raw[1, 2] = 0.0
    out = fmt.normalise(raw)
    assert np.array_equal(out[0], [0.0, 0.0, 0.9])
    assert np.all(np.isnan(out[1]))


def test_bad_detections_name_the_source():
    fmt = get_format("coco17")
    with pytest.raises(MocapgraphError, match=r"cam0/keypoints.npy: coco17 keypoints must have shape \(\.\.\., 17, 3\)"):
        fmt.normalise(np.zeros((5, 25, 3)), source="cam0/keypoints.npy")
    bad = np.ones((17, 3))
    bad[2, 2] = -0.5
    with pytest.raises(MocapgraphError, match="negative confidence"):
        fmt.normalise(bad)
