"""Keypoint format registry: mappings onto body keypoints, confidence conventions, errors."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import LinearShapeTable, random_root

from mocapgraph.body.keypoint_formats import FORMATS, format_for_points, format_table, formats_with_points, get_format
from mocapgraph.body.kinematics import forward_kinematics_numpy
from mocapgraph.body.labelling import swap_permutation
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES
from mocapgraph.errors import MocapgraphError


def test_formats_have_their_published_sizes():
    assert get_format("coco17").num_points == 17
    assert get_format("openpose25").num_points == 25
    assert get_format("openpose25b").num_points == 25
    assert get_format("halpe26").num_points == 26
    assert get_format("blazepose33").num_points == 33
    assert get_format("mediapipe") is get_format("BlazePose33") is FORMATS["blazepose33"]
    # Pose2Sim's spellings of its pose models
    assert get_format("BODY_25B") is FORMATS["openpose25b"] and get_format("HALPE_26") is FORMATS["halpe26"]
    assert get_format("BODY_25") is FORMATS["openpose25"] and get_format("COCO_17") is FORMATS["coco17"]


# Published indices (OpenPose poseParameters.cpp for BODY_25B; Halpe-FullBody for HALPE_26).
@pytest.mark.parametrize(
    "name, index, point",
    [
        ("openpose25b", 0, "nose"), ("openpose25b", 1, "left_eye"), ("openpose25b", 6, "right_shoulder"),
        ("openpose25b", 11, "left_hip"), ("openpose25b", 16, "right_ankle"), ("openpose25b", 17, "upper_neck"),
        ("openpose25b", 18, "head_top"), ("openpose25b", 19, "left_big_toe"), ("openpose25b", 21, "left_heel"),
        ("openpose25b", 22, "right_big_toe"), ("openpose25b", 24, "right_heel"),
        ("halpe26", 5, "left_shoulder"), ("halpe26", 12, "right_hip"), ("halpe26", 17, "head"), ("halpe26", 18, "neck"),
        ("halpe26", 19, "hip"), ("halpe26", 20, "left_big_toe"), ("halpe26", 21, "right_big_toe"),
        ("halpe26", 22, "left_small_toe"), ("halpe26", 24, "left_heel"), ("halpe26", 25, "right_heel"),
        ("openpose25", 1, "neck"), ("openpose25", 8, "mid_hip"), ("openpose25", 19, "left_big_toe"),
    ],
)  # fmt: skip
def test_layouts_follow_the_published_order(name, index, point):
    assert get_format(name).names[index] == point


@pytest.mark.parametrize("name", sorted(FORMATS))
def test_every_format_is_consistent(name):
    fmt = get_format(name)
    assert len(set(fmt.names)) == fmt.num_points, "names must be unique"
    mix = fmt.mix()
    mapped = np.array([m is not None for m in fmt.mapping])
    np.testing.assert_allclose(mix.sum(axis=1), mapped.astype(float), rtol=0, atol=1e-15)  # weights sum to 1
    assert np.all(mix >= 0)
    # A whole-body swap exchanges every left point with its right twin, and swaps the body
    # keypoints the format's points are made of in the same way.
    perm = swap_permutation(fmt.names, "body")
    assert np.array_equal(perm[perm], np.arange(fmt.num_points))
    for i, j in enumerate(perm):
        mirrored = fmt.names[i].replace("left", "@").replace("right", "left").replace("@", "right")
        assert fmt.names[j] == (mirrored if mirrored in fmt.names else fmt.names[i])
    body_perm = swap_permutation(BODY_KEYPOINT_NAMES, "body")
    np.testing.assert_array_equal(mix[perm], mix[:, body_perm])


def test_formats_by_point_count():
    assert formats_with_points(25) == ["openpose25", "openpose25b"]
    assert format_for_points(26).name == "halpe26" and format_for_points(33).name == "blazepose33"
    with pytest.raises(MocapgraphError, match="cam1/f.json: 25 points per person could be openpose25 or openpose25b"):
        format_for_points(25, source="cam1/f.json")
    with pytest.raises(MocapgraphError, match="18 points per person match no known format.*COCO-18"):
        format_for_points(18)


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
    halpe = forward_kinematics_numpy(format_table(table, "halpe26"), root, pose).keypoints
    assert np.allclose(halpe[:, 19], (body[:, k("left_hip")] + body[:, k("right_hip")]) / 2)
    assert np.allclose(halpe[:, 24], body[:, k("left_heel")]) and np.allclose(halpe[:, 21], body[:, k("right_big_toe")])
    assert [n for n, m in zip(format_table(table, "halpe26").keypoint_names, format_table(table, "halpe26").mapped) if not m] == ["head", "neck"]
    b25b = format_table(table, "openpose25b")
    assert [n for n, m in zip(b25b.keypoint_names, b25b.mapped) if not m] == ["upper_neck", "head_top"]
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
