"""SMPL / SMPL-X backend against an independent plain-LBS implementation, on synthetic stand-ins.

No real SMPL file is used (they are licensed): the fixtures write random-but-plausible files in
the distributed layouts (.npz and the authors' chumpy .pkl), with SMPL's real kinematic trees.
"""

from __future__ import annotations

import pickle
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse
from conftest import random_root
from scipy.spatial.transform import Rotation

from mocapgraph.body import load_body_model
from mocapgraph.body.kinematics import SHAPE_START, forward_kinematics_numpy
from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES, JOINT_NAMES, NUM_JOINTS, PARENTS
from mocapgraph.body.smpl_backend import SMPLBody
from mocapgraph.errors import MocapgraphError

# The test's own copy of the keypoint vertex ids (smplx package, vertex_ids.py: "smplh" / "smplx").
SMPL_VERTICES = {
    "nose": 332, "right_eye": 6260, "left_eye": 2800, "right_ear": 4071, "left_ear": 583,
    "left_big_toe": 3216, "left_small_toe": 3226, "left_heel": 3387,
    "right_big_toe": 6617, "right_small_toe": 6624, "right_heel": 6787,
}  # fmt: skip
SMPLX_VERTICES = {
    "nose": 9120, "right_eye": 9929, "left_eye": 9448, "right_ear": 616, "left_ear": 6,
    "left_big_toe": 5770, "left_small_toe": 5780, "left_heel": 8846,
    "right_big_toe": 8463, "right_small_toe": 8474, "right_heel": 8635,
}  # fmt: skip

UINT32_ROOT = 4294967295

# Rough SMPL rest joints (metres; +X left, +Y up, +Z forward).
SMPL_JOINTS = np.array([
    [0.00, -0.22, 0.02], [0.06, -0.31, 0.01], [-0.06, -0.31, 0.01], [0.00, -0.11, -0.01],
    [0.10, -0.69, 0.02], [-0.10, -0.69, 0.02], [0.00, 0.03, 0.01], [0.09, -1.09, -0.02],
    [-0.09, -1.09, -0.02], [0.00, 0.09, 0.03], [0.11, -1.15, 0.10], [-0.11, -1.15, 0.10],
    [0.00, 0.29, -0.01], [0.08, 0.20, 0.00], [-0.08, 0.20, 0.00], [0.00, 0.36, 0.04],
    [0.17, 0.23, -0.01], [-0.17, 0.23, -0.01], [0.43, 0.21, -0.03], [-0.43, 0.21, -0.03],
    [0.69, 0.22, -0.01], [-0.69, 0.22, -0.01], [0.77, 0.21, -0.02], [-0.77, 0.21, -0.02],
])  # fmt: skip
SMPL_PARENTS = np.concatenate([PARENTS, [20, 21]])


def smplx_skeleton() -> tuple[np.ndarray, np.ndarray]:
    """SMPL-X's 55 joints: the body 22, jaw and eyes below the head, 5 three-joint fingers per hand."""
    joints = list(SMPL_JOINTS[:22])
    parents = list(PARENTS)
    joints += [[0.0, 0.33, 0.08], [0.03, 0.42, 0.09], [-0.03, 0.42, 0.09]]
    parents += [15, 15, 15]
    for wrist, side in ((20, 1.0), (21, -1.0)):
        for finger in range(5):  # index, middle, pinky, ring, thumb
            spread = (finger - 2) * 0.015
            for seg in range(3):
                joints.append(SMPL_JOINTS[wrist] + [side * (0.08 + 0.025 * seg), 0.0, spread])
                parents.append(wrist if seg == 0 else len(parents) - 1)
    return np.array(joints), np.array(parents)


def keypoint_anchor(name: str, centres: np.ndarray) -> tuple[np.ndarray, dict[int, float]]:
    """Where a keypoint vertex sits and its skinning weights (frozen joints included on purpose)."""
    side = 1.0 if name.startswith("left") else -1.0
    # Joints 22 and 23 are frozen in both layouts (SMPL: hands; SMPL-X: jaw, left eye).
    if name == "nose":
        return centres[15] + [0.0, 0.05, 0.11], {15: 0.6, 12: 0.25, 22: 0.15}
    if name.endswith("eye"):
        return centres[15] + [side * 0.03, 0.08, 0.09], {15: 0.8, 9: 0.1, 22: 0.1}
    if name.endswith("ear"):
        return centres[15] + [side * 0.07, 0.05, -0.01], {15: 0.7, 12: 0.2, 23: 0.1}
    ankle, foot = (7, 10) if side > 0 else (8, 11)
    if name.endswith("heel"):
        return centres[ankle] + [0.0, -0.07, -0.05], {ankle: 0.9, foot: 0.1}
    lateral = 0.0 if "big" in name else 0.04
    knee = 4 if side > 0 else 5
    return centres[foot] + [side * (lateral - 0.02), -0.05, 0.09], {foot: 0.75, ankle: 0.2, knee: 0.05}


def make_model_arrays(
    num_vertices: int, centres: np.ndarray, parents: np.ndarray, vertex_ids: dict, *, seed: int,
    num_shape: int = 10, pose_dims: int = 207, num_faces: int = 13776,
) -> dict[str, np.ndarray]:
    """Arrays in the distributed layout: a noisy point cloud around the stick figure."""
    rng = np.random.default_rng(seed)
    J = len(centres)
    bone = rng.integers(1, J, num_vertices)
    u = rng.random(num_vertices)
    v = (1 - u)[:, None] * centres[parents[bone]] + u[:, None] * centres[bone]
    v += rng.normal(scale=0.03, size=v.shape)
    weights = np.zeros((num_vertices, J))
    rows = np.arange(num_vertices)
    weights[rows, parents[bone]] += 1 - u
    weights[rows, bone] += u
    weights[rows, rng.integers(0, J, num_vertices)] += 0.2 * rng.random(num_vertices)
    for name, vid in vertex_ids.items():
        v[vid], w = keypoint_anchor(name, centres)
        weights[vid] = 0.0
        for j, wj in w.items():
            weights[vid, j] += wj
    weights /= weights.sum(axis=1, keepdims=True)

    regressor = np.zeros((J, num_vertices))
    for j in range(J):
        near = np.argpartition(np.linalg.norm(v - centres[j], axis=1), 8)[:8]
        w = rng.random(8) + 0.1
        regressor[j, near] = w / w.sum()

    shapedirs = np.zeros((num_vertices, 3, num_shape))
    basis = rng.normal(scale=0.01, size=(num_vertices, 3, min(num_shape, 20)))
    shapedirs[:, :, : basis.shape[2]] = basis
    kintree = np.stack([parents, np.arange(J)]).astype(np.int64)
    kintree[0, 0] = UINT32_ROOT
    return {
        "v_template": v,
        "shapedirs": shapedirs,
        "J_regressor": regressor,
        "weights": weights,
        "kintree_table": kintree,
        "posedirs": np.zeros((num_vertices, 3, pose_dims), dtype=np.float32),
        "f": rng.integers(0, num_vertices, (num_faces, 3)).astype(np.uint32),
    }


def write_chumpy_pickle(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """The authors' .pkl layout: chumpy ``Ch`` arrays, a scipy.sparse J_regressor, protocol 2.

    A fake ``chumpy.ch`` module exists only while pickling; old module paths are written so the
    file looks like the Python 2 era originals.
    """
    pkg, sub = types.ModuleType("chumpy"), types.ModuleType("chumpy.ch")

    class Ch:
        pass

    Ch.__module__, Ch.__qualname__, Ch.__name__ = "chumpy.ch", "Ch", "Ch"
    sub.Ch, pkg.ch = Ch, sub

    def ch(array, key="x"):
        obj = Ch()
        obj.__dict__.update({"_dirty_vars": set(), "_itr": None, "_cache": {"drs": {}}, key: array})
        return obj

    saved = {name: sys.modules.get(name) for name in ("chumpy", "chumpy.ch")}
    sys.modules["chumpy"], sys.modules["chumpy.ch"] = pkg, sub
    try:
        content = {
            "v_template": ch(arrays["v_template"], key="a"),  # no "x": first array entry is used
            "shapedirs": ch(arrays["shapedirs"]),
            "weights": ch(arrays["weights"]),
            "posedirs": ch(arrays["posedirs"]),
            "J_regressor": scipy.sparse.csc_matrix(arrays["J_regressor"]),
            "J_regressor_prior": scipy.sparse.csc_matrix(arrays["J_regressor"]),
            "kintree_table": arrays["kintree_table"],
            "f": arrays["f"],
            "bs_style": "lbs",
            "bs_type": "lrotmin",
        }
        blob = pickle.dumps(content, protocol=2)
    finally:
        for name, module in saved.items():
            if module is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = module
    blob = blob.replace(b"numpy._core.multiarray\n", b"numpy.core.multiarray\n")
    blob = blob.replace(b"scipy.sparse._csc\n", b"scipy.sparse.csc\n")
    assert b"chumpy.ch\nCh\n" in blob and b"scipy.sparse.csc\n" in blob
    path.write_bytes(blob)


@pytest.fixture(scope="module")
def smpl_arrays():
    return make_model_arrays(6890, SMPL_JOINTS, SMPL_PARENTS, SMPL_VERTICES, seed=1)


@pytest.fixture(scope="module")
def smplx_arrays():
    centres, parents = smplx_skeleton()
    arrays = make_model_arrays(
        10475, centres, parents, SMPLX_VERTICES, seed=2, num_shape=400, pose_dims=486, num_faces=20908
    )
    arrays["shapedirs"] = arrays["shapedirs"].astype(np.float32)
    arrays["shapedirs"][:, :, 300:] = 50.0  # expression directions: must never be used
    arrays["kintree_table"][0, 0] = -1
    return arrays


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("smpl_models")


@pytest.fixture(scope="module")
def smpl_npz(model_dir, smpl_arrays):
    path = model_dir / "SMPL_NEUTRAL.npz"
    np.savez(path, **smpl_arrays)
    return path


@pytest.fixture(scope="module")
def smpl_pkl(model_dir, smpl_arrays):
    path = model_dir / "basicModel_neutral_lbs_10_207_0_v1.0.0.pkl"
    write_chumpy_pickle(path, smpl_arrays)
    return path


@pytest.fixture(scope="module")
def smplx_npz(model_dir, smplx_arrays):
    path = model_dir / "SMPLX_NEUTRAL.npz"
    np.savez(path, **smplx_arrays)
    return path


def required_only(arrays: dict) -> dict:
    return {k: arrays[k] for k in ("v_template", "shapedirs", "J_regressor", "weights", "kintree_table")}


# --------------------------------------------------------------------------------------------
# Independent reference: classic SMPL linear blend skinning over all joints


def reference_posed(arrays, beta, root, pose):
    """Posed joints (22, 3) and vertices (V, 3) by plain SMPL LBS over all joints, without pose correctives."""
    S = len(beta)
    v = arrays["v_template"] + np.asarray(arrays["shapedirs"][:, :, :S], dtype=float) @ beta
    J = arrays["J_regressor"] @ v
    parents = arrays["kintree_table"][0].astype(np.int64).copy()
    parents[0] = -1
    nj = len(parents)
    frozen = [np.eye(3)] * (nj - NUM_JOINTS)
    rotations = [root[:3, :3]] + [Rotation.from_rotvec(p).as_matrix() for p in pose] + frozen
    world = np.zeros((nj, 4, 4))
    for c in range(nj):
        local = np.eye(4)
        local[:3, :3] = rotations[c]
        local[:3, 3] = J[c] - (J[parents[c]] if c > 0 else 0.0)
        world[c] = local if c == 0 else world[parents[c]] @ local
    skin = world.copy()
    skin[:, :3, 3] -= np.einsum("cxy,cy->cx", world[:, :3, :3], J)
    per_vertex = np.einsum("vc,cxy->vxy", arrays["weights"], skin)
    posed = np.einsum("vxy,vy->vx", per_vertex[:, :3, :3], v) + per_vertex[:, :3, 3]
    shift = root[:3, 3] - J[0]  # our root translation is the pelvis position
    return world[:NUM_JOINTS, :3, 3] + shift, posed + shift


def reference_lbs(arrays, beta, root, pose, vertex_ids):
    """Posed joints (22, 3) and body keypoints (23, 3) by plain SMPL LBS (:func:`reference_posed`)."""
    joints, posed = reference_posed(arrays, beta, root, pose)
    keypoints = np.array(
        [
            joints[JOINT_NAMES.index(k)] if k in JOINT_NAMES else posed[vertex_ids[k]]
            for k in BODY_KEYPOINT_NAMES
        ]
    )
    return joints, keypoints


def check_against_reference(model, arrays, vertex_ids, seed, frames=3):
    rng = np.random.default_rng(seed)
    beta = rng.uniform(-2, 2, model.shape_dim)
    root = random_root(rng, frames)
    pose = rng.normal(scale=0.6, size=(frames, NUM_JOINTS - 1, 3))
    res = forward_kinematics_numpy(model.table(beta), root, pose)
    for t in range(frames):
        joints, keypoints = reference_lbs(arrays, beta, root[t], pose[t], vertex_ids)
        assert np.abs(res.joints[t] - joints).max() < 1e-9
        assert np.abs(res.keypoints[t] - keypoints).max() < 1e-9
    return beta, root, pose, res


def test_smpl_npz_matches_plain_lbs(smpl_npz, smpl_arrays):
    model = SMPLBody(smpl_npz)
    assert model.name == "smpl" and model.shape_dim == 10
    assert model.num_source_joints == 24
    check_against_reference(model, smpl_arrays, SMPL_VERTICES, seed=10)


def test_smpl_pkl_without_chumpy_matches_plain_lbs(smpl_pkl, smpl_arrays):
    assert "chumpy" not in sys.modules
    model = SMPLBody(smpl_pkl, kind="smpl")
    assert "chumpy" not in sys.modules
    check_against_reference(model, smpl_arrays, SMPL_VERTICES, seed=11)


def test_pkl_and_npz_give_the_same_table(smpl_npz, smpl_pkl):
    beta = np.linspace(-1, 1, 10)
    a, b = SMPLBody(smpl_npz).table(beta), SMPLBody(smpl_pkl).table(beta)
    for field in ("offsets", "d_offsets", "weights", "markers", "d_markers"):
        np.testing.assert_allclose(getattr(a, field), getattr(b, field), rtol=0, atol=1e-14)


def test_smplx_matches_plain_lbs_and_ignores_expression(smplx_npz, smplx_arrays):
    model = load_body_model("smplx", model_path=smplx_npz)
    assert isinstance(model, SMPLBody) and model.name == "smplx"
    assert model.num_source_joints == 55 and model.num_shape_components == 300
    check_against_reference(model, smplx_arrays, SMPLX_VERTICES, seed=12)
    wide = SMPLBody(smplx_npz, kind="smplx", num_betas=300)
    assert wide.shape_dim == 300
    with pytest.raises(MocapgraphError, match="num_betas = 301"):
        SMPLBody(smplx_npz, kind="smplx", num_betas=301)


def test_native_forward_agrees(smpl_npz, smpl_arrays):
    pytest.importorskip("mocapgraph._native")
    model = load_body_model("smpl", model_path=smpl_npz)
    beta, root, pose, ref = check_against_reference(model, smpl_arrays, SMPL_VERTICES, seed=13, frames=2)
    res = model.forward(beta, root, pose, jacobians=True)
    np.testing.assert_allclose(res.joints, ref.joints, atol=1e-12)
    np.testing.assert_allclose(res.keypoints, ref.keypoints, atol=1e-12)
    rest = model.rest_joints(model.default_shape)
    np.testing.assert_allclose(rest[0], 0.0, atol=1e-12)


def test_shape_interface(smpl_npz):
    model = SMPLBody(smpl_npz, num_betas=4)
    assert model.shape_names == ("beta0", "beta1", "beta2", "beta3")
    np.testing.assert_array_equal(model.shape_bounds, [[-5.0, 5.0]] * 4)
    np.testing.assert_array_equal(model.default_shape, np.zeros(4))
    with pytest.raises(MocapgraphError, match="beta2"):
        model.table([0, 0, 5.5, 0])
    info = model.describe()
    assert info["backend"] == "smpl" and info["model_file"] == str(smpl_npz)
    table = model.table(model.default_shape)
    assert table.mapped.all() and table.shape_dim == 4
    np.testing.assert_allclose(table.weights.sum(axis=1), 1.0, atol=1e-12)


# --------------------------------------------------------------------------------------------
# Jacobians through the numpy reference FK


def test_jacobians_match_finite_differences(smpl_npz):
    model = SMPLBody(smpl_npz)
    rng = np.random.default_rng(20)
    beta = rng.uniform(-1, 1, 10)
    root = random_root(rng, 1)
    pose = rng.normal(scale=0.5, size=(1, NUM_JOINTS - 1, 3))
    res = forward_kinematics_numpy(model.table(beta), root, pose, jacobians=True)

    def evaluate(beta, root, pose):
        out = forward_kinematics_numpy(model.table(beta), root, pose)
        return np.concatenate([out.joints[0], out.keypoints[0]])

    P = SHAPE_START + 10
    numeric = np.zeros((NUM_JOINTS + len(BODY_KEYPOINT_NAMES), 3, P))
    h = 1e-6
    for col in range(P):
        values = []
        for sign in (1.0, -1.0):
            b, r, p = beta.copy(), root.copy(), pose.copy()
            if col < 3:
                r[0, :3, :3] = r[0, :3, :3] @ rotvec_to_matrix(sign * h * np.eye(3)[col])
            elif col < 6:
                r[0, :3, 3] += sign * h * r[0, :3, :3][:, col - 3]
            elif col < SHAPE_START:
                p[0].reshape(-1)[col - 6] += sign * h
            else:
                b[col - SHAPE_START] += sign * h
            values.append(evaluate(b, r, p))
        numeric[..., col] = (values[0] - values[1]) / (2 * h)
    analytic = np.concatenate([res.d_joints[0], res.d_keypoints[0]])
    rel = np.abs(analytic - numeric).max() / np.abs(analytic).max()
    assert rel < 1e-6
    shape_cols = analytic[..., SHAPE_START:]
    assert np.abs(shape_cols).max() > 1e-3  # shape really moves the body


# --------------------------------------------------------------------------------------------
# Bad input: one MocapgraphError naming the file (and field)


def expect_error(path, *fragments, **kwargs):
    with pytest.raises(MocapgraphError) as info:
        SMPLBody(path, **kwargs)
    message = str(info.value)
    assert Path(path).name in message
    for fragment in fragments:
        assert fragment in message, message
    assert info.value.__cause__ is None
    return message


def test_missing_file(tmp_path):
    expect_error(tmp_path / "SMPL_MISSING.npz", "does not exist")


def test_directory_and_bad_num_betas(tmp_path, smpl_npz):
    expect_error(tmp_path, "is a directory")
    expect_error(smpl_npz, "num_betas", num_betas=0)


def test_corrupt_files(tmp_path):
    noise = np.random.default_rng(5).bytes(4096)
    for name in ("corrupt.npz", "corrupt.pkl"):
        (tmp_path / name).write_bytes(noise)
        expect_error(tmp_path / name, "cannot read")
    truncated = tmp_path / "truncated.npz"
    np.savez(truncated, v_template=np.zeros((6890, 3)))
    truncated.write_bytes(truncated.read_bytes()[:5000])
    expect_error(truncated, "cannot read")


def test_unknown_extension(tmp_path):
    path = tmp_path / "model.obj"
    path.write_text("v 0 0 0\n")
    expect_error(path, ".obj")


def test_pickle_with_code_is_refused(tmp_path):
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.pkl"
    path.write_bytes(b"cos\nsystem\n(S'touch " + str(marker).encode() + b"'\ntR.")
    expect_error(path, "os.system")
    assert not marker.exists()


def test_pickle_not_a_dict(tmp_path):
    path = tmp_path / "list.pkl"
    path.write_bytes(pickle.dumps([1, 2, 3], protocol=2))
    expect_error(path, "dict")


@pytest.mark.parametrize(
    "field, change, fragment",
    [
        ("J_regressor", None, "missing field 'J_regressor'"),
        ("shapedirs", lambda a: a.transpose(0, 2, 1), "'shapedirs'"),
        ("v_template", lambda a: np.where(np.arange(len(a))[:, None] == 7, np.nan, a), "NaN"),
        ("J_regressor", lambda a: a[:, :-1], "'J_regressor'"),
        ("weights", lambda a: a[:, :-1], "'weights'"),
        ("weights", lambda a: np.where(a == a.max(), np.inf, a), "'weights'"),
        ("kintree_table", lambda a: a[:, :20], "'kintree_table'"),
        ("kintree_table", lambda a: np.where(np.arange(24) == 15, [[9], [15]], a), "differ from SMPL"),
        ("v_template", lambda a: a[:100], "100 vertices"),
    ],
)
def test_bad_arrays(tmp_path, smpl_arrays, field, change, fragment):
    arrays = required_only(smpl_arrays)
    if change is None:
        del arrays[field]
    else:
        arrays[field] = change(arrays[field])
    path = tmp_path / f"bad_{field}.npz"
    np.savez(path, **arrays)
    message = expect_error(path, fragment)
    assert field in message


def test_too_many_betas_and_wrong_kind(smpl_npz, smplx_npz):
    expect_error(smpl_npz, "shapedirs", "num_betas = 11", num_betas=11)
    expect_error(smpl_npz, "6890", "smpl backend", kind="smplx")
    expect_error(smplx_npz, "10475", "smplx backend", kind="smpl")


def test_object_array_in_npz_is_refused(tmp_path, smpl_arrays):
    arrays = required_only(smpl_arrays)
    arrays["J_regressor"] = np.array([scipy.sparse.csc_matrix(arrays["J_regressor"])], dtype=object)
    path = tmp_path / "object.npz"
    np.savez(path, **arrays)
    expect_error(path, "'J_regressor'", "pickled")
