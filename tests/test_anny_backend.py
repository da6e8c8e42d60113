"""The Anny backend against the anny package's own forward pass, and its shape derivatives."""

from __future__ import annotations

import itertools
import logging

import numpy as np
import pytest
from conftest import random_root

from mocapgraph.body import anny_backend, load_body_model
from mocapgraph.body.anny_export import SMPL_TO_ANNY
from mocapgraph.body.kinematics import SHAPE_START, forward_kinematics_numpy
from mocapgraph.body.skeleton import JOINT_NAMES
from mocapgraph.errors import MocapgraphError

torch = pytest.importorskip("torch")
anny = pytest.importorskip("anny")


@pytest.fixture(scope="module")
def body():
    return load_body_model("anny")


@pytest.fixture(scope="module")
def anny_model():
    return anny.Anny()


def anny_forward(model, body, shapes, root, pose):
    """Joints (T, 22, 3) and keypoints (T, 23, 3) from the anny package itself."""
    deltas = {k: torch.from_numpy(v) for k, v in body.anny_pose(root, pose).items()}
    phen = {n: torch.from_numpy(np.ascontiguousarray(shapes[:, i])) for i, n in enumerate(body.shape_names)}
    out = model(pose_parameters=deltas, phenotype_kwargs=phen)
    keypoints = anny.KeypointsRegressor.coco(model)(out).numpy()
    heads = out["bone_poses"].numpy()[:, :, :3, 3]
    labels = list(model.bone_labels)
    joints = np.stack(
        [np.mean([heads[:, labels.index(b)] for b in SMPL_TO_ANNY[n]], axis=0) for n in JOINT_NAMES], axis=1
    )
    return joints, keypoints


def table_fk(body, shapes, root, pose):
    out = [forward_kinematics_numpy(body.table(s), root[i : i + 1], pose[i : i + 1]) for i, s in enumerate(shapes)]
    return np.concatenate([o.joints for o in out]), np.concatenate([o.keypoints for o in out])


def test_posed_joints_and_keypoints_match_anny(body, anny_model):
    """Random phenotypes and poses: the reduced table reproduces Anny to round-off."""
    rng = np.random.default_rng(0)
    lo, hi = body.shape_bounds.T
    n = 12
    shapes = lo + (hi - lo) * rng.random((n, 6))
    root = random_root(rng, n)
    pose = rng.normal(scale=0.7, size=(n, 21, 3))
    pose[0] = 0.0
    pose[1] = rng.normal(size=(21, 3)) * 1e-9  # near-zero rotations
    axes = rng.normal(size=(21, 3))
    pose[2] = (np.pi - 1e-6) * axes / np.linalg.norm(axes, axis=1, keepdims=True)  # near π
    joints, keypoints = anny_forward(anny_model, body, shapes, root, pose)
    ours_j, ours_k = table_fk(body, shapes, root, pose)
    assert np.abs(ours_j - joints).max() < 1e-6
    assert np.abs(ours_k - keypoints).max() < 1e-6


def test_skeleton_exact_over_phenotype_ranges(body, anny_model):
    """Rest skeleton at every anchor-grid corner and random phenotypes: exact (< 1 µm)."""
    lo, hi = body.shape_bounds.T
    corners = np.array(list(itertools.product(*zip(lo, hi))))
    rng = np.random.default_rng(1)
    shapes = np.concatenate([corners, lo + (hi - lo) * rng.random((32, 6))])
    n = len(shapes)
    root = np.tile(np.eye(4), (n, 1, 1))
    pose = np.zeros((n, 21, 3))
    joints, keypoints = anny_forward(anny_model, body, shapes, root, pose)
    ours_j, ours_k = table_fk(body, shapes, root, pose)
    assert np.abs(ours_j - joints).max() < 1e-6
    assert np.abs(ours_k - keypoints).max() < 1e-6


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_shape_jacobian_matches_finite_differences(body, seed):
    rng = np.random.default_rng(seed)
    lo, hi = body.shape_bounds.T
    shape = lo + (hi - lo) * (0.05 + 0.9 * rng.random(6))
    # Stay clear of the anchors, where the phenotype map has kinks.
    anchors = [body._data["anchors"][f, : body._data["anchor_counts"][f]] for f in range(6)]
    for f in range(6):
        while np.min(np.abs(anchors[f] - shape[f])) < 1e-3:
            shape[f] += 2e-3
    root = random_root(rng, 2)
    pose = rng.normal(scale=0.5, size=(2, 21, 3))
    res = forward_kinematics_numpy(body.table(shape), root, pose, jacobians=True)
    h = 1e-6
    for s in range(6):
        step = np.eye(6)[s] * h
        plus = forward_kinematics_numpy(body.table(shape + step), root, pose)
        minus = forward_kinematics_numpy(body.table(shape - step), root, pose)
        for got, p, m in ((res.d_joints, plus.joints, minus.joints), (res.d_keypoints, plus.keypoints, minus.keypoints)):
            numeric = (p - m) / (2 * h)
            scale = max(np.abs(numeric).max(), 1e-3)
            assert np.abs(got[..., SHAPE_START + s] - numeric).max() / scale < 1e-6


def test_neutral_pose_is_a_t_pose_in_smpl_axes(body):
    joints = body.rest_joints(body.default_shape)
    j = JOINT_NAMES.index
    for side, sign in (("left", 1), ("right", -1)):
        arm = joints[[j(f"{side}_shoulder"), j(f"{side}_elbow"), j(f"{side}_wrist")]]
        assert np.ptp(arm[:, 1]) < 1e-9  # horizontal
        assert np.ptp(arm[:, 2]) < 1e-9  # straight, in the frontal plane
        assert sign * (arm[2, 0] - arm[0, 0]) > 0.4  # pointing to its own side
        assert sign * joints[j(f"{side}_hip"), 0] > 0.05  # body's left on +X
    assert joints[j("head"), 1] > 0.5 > -0.7 > joints[j("left_ankle"), 1]  # Y up
    nose = body.forward(body.default_shape, np.eye(4), np.zeros((21, 3))).keypoints[0, 0]
    assert nose[2] > joints[j("head"), 2] + 0.05  # facing +Z


def test_default_body_height(body):
    """The all-0.5 default body is 1.63 m tall (Anny's measured stature, sole to crown)."""
    kps = body.forward(body.default_shape, np.eye(4), np.zeros((21, 3))).keypoints[0]
    # Keypoints stop at the eyes and heels, so the span is a little under the stature.
    assert 1.45 < kps[:, 1].max() - kps[:, 1].min() < 1.63


def test_out_of_range_and_nan_shapes_are_clear_errors(body):
    with pytest.raises(MocapgraphError, match="'height' = 1.5 is outside"):
        body.table([0.5, 0.5, 0.5, 0.5, 1.5, 0.5])
    with pytest.raises(MocapgraphError, match="NaN"):
        body.table([0.5, np.nan, 0.5, 0.5, 0.5, 0.5])
    with pytest.raises(MocapgraphError, match=r"expected shape \(6\)"):
        body.table([0.5, 0.5])


def test_stale_or_corrupt_cache_is_rebuilt(tmp_path, monkeypatch):
    """A cache file of another export format, or garbage, triggers one re-export; a fresh one none."""
    monkeypatch.setenv("MOCAPGRAPH_CACHE_DIR", str(tmp_path))
    calls = []

    def fake_export():
        calls.append(1)
        return {"export_format": np.array(anny_backend.EXPORT_FORMAT)}

    monkeypatch.setattr("mocapgraph.body.anny_export.export_anny_table", fake_export)
    path = anny_backend.anny_table_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"not an npz")
    assert anny_backend.ensure_anny_table() == path and len(calls) == 1
    assert anny_backend.ensure_anny_table() == path and len(calls) == 1
    np.savez(path, export_format=np.array(anny_backend.EXPORT_FORMAT - 1))
    anny_backend.ensure_anny_table()
    assert len(calls) == 2
    assert not list(tmp_path.glob("*.tmp*"))


def test_unreadable_table_file_names_the_file(tmp_path):
    bad = tmp_path / "broken.npz"
    bad.write_bytes(b"\x00garbage")
    with pytest.raises(MocapgraphError, match="broken.npz"):
        load_body_model("anny", bad)


def test_export_chatter_stays_off_stdout(tmp_path, monkeypatch, capsys, caplog):
    """Anny's warp backend prints banners; a first-use export must not corrupt `--json` output."""
    monkeypatch.setenv("MOCAPGRAPH_CACHE_DIR", str(tmp_path))

    def chatty_export():
        print("Warp 1.19.0 initialized:")
        return {"export_format": np.array(anny_backend.EXPORT_FORMAT)}

    monkeypatch.setattr("mocapgraph.body.anny_export.export_anny_table", chatty_export)
    caplog.set_level(logging.INFO, logger="mocapgraph")
    anny_backend.ensure_anny_table()
    out = capsys.readouterr()
    assert out.out == "" and "Warp 1.19.0 initialized" in out.err and "Anny table written" in caplog.text
