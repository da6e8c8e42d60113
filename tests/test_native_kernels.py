"""The native kernels against their numpy references, and the references against finite differences."""

from __future__ import annotations

import dataclasses
import zlib

import numpy as np
import pytest
from conftest import LinearShapeTable, random_root

from mocapgraph.body.kinematics import forward_kinematics_numpy
from mocapgraph.body.native import forward_kinematics, native_module, table_arrays
from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.body.skeleton import NUM_JOINTS, PARENTS
from mocapgraph.body.table import BodyTable
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.reprojection_kernel import reproject, reproject_numpy

FK_FIELDS = ("joints", "keypoints", "rotations", "d_joints", "d_keypoints")


def max_rel_diff(got: np.ndarray, want: np.ndarray) -> float:
    """Max abs difference over ``max(1, max |want|)``: absolute for O(1) data, relative for pixels."""
    assert got.shape == want.shape
    if want.size == 0:
        return 0.0
    return float(np.abs(got - want).max() / max(1.0, np.abs(want).max()))


# ---------------------------------------------------------------------------------------------
# Forward kinematics


def table_without_shape(table: BodyTable) -> BodyTable:
    return dataclasses.replace(table, d_offsets=table.d_offsets[..., :0], d_markers=table.d_markers[..., :0])


def table_without_keypoints(table: BodyTable) -> BodyTable:
    S = table.shape_dim
    return dataclasses.replace(
        table,
        weights=np.zeros((0, NUM_JOINTS)),
        markers=np.zeros((0, NUM_JOINTS, 3)),
        d_markers=np.zeros((0, NUM_JOINTS, 3, S)),
        keypoint_names=(),
        mapped=np.zeros(0, dtype=bool),
    )


def make_table(kind: str) -> BodyTable:
    rng = np.random.default_rng(11)
    specs = {"k9_s4": (0, 9, 4), "k23_s6": (1, 23, 6), "k1_s1": (2, 1, 1), "k30_s10": (3, 30, 10)}
    if kind in specs:
        seed, K, S = specs[kind]
        return LinearShapeTable(seed=seed, num_keypoints=K, shape_dim=S)(rng.normal(size=S))
    if kind == "s0":
        return table_without_shape(LinearShapeTable(seed=4, num_keypoints=7, shape_dim=2)(rng.normal(size=2)))
    if kind == "k0":
        return table_without_keypoints(LinearShapeTable(seed=5, num_keypoints=3, shape_dim=3)(rng.normal(size=3)))
    if kind == "k0_s0":
        return table_without_shape(table_without_keypoints(LinearShapeTable(seed=6)(np.zeros(4))))
    raise ValueError(kind)


def random_axes(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    v = rng.normal(size=shape + (3,))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def make_pose(kind: str, rng: np.random.Generator, frames: int) -> np.ndarray:
    shape = (frames, NUM_JOINTS - 1)
    angles = {
        "zero": np.zeros(shape),
        "tiny": np.full(shape, 1e-9),
        "small": np.full(shape, 1e-5),
        # Both sides of the switch between the Taylor series and the closed forms.
        "threshold": 1e-4 * (1.0 + rng.uniform(-1e-3, 1e-3, shape)),
        "near_pi": np.full(shape, np.pi - 1e-6),
        "random": rng.uniform(0.0, 2.5, shape),
    }
    if kind == "mixed":
        choices = np.stack([angles[k] for k in ("zero", "tiny", "small", "near_pi", "random")])
        pick = rng.integers(0, len(choices), shape)
        magnitude = np.take_along_axis(choices, pick[None], axis=0)[0]
    else:
        magnitude = angles[kind]
    return random_axes(rng, shape) * magnitude[..., None]


@pytest.mark.parametrize("table_kind", ["k9_s4", "k23_s6", "k1_s1", "k30_s10", "s0", "k0", "k0_s0"])
@pytest.mark.parametrize("pose_kind", ["random", "zero", "tiny", "small", "threshold", "near_pi", "mixed"])
def test_native_fk_matches_numpy(table_kind, pose_kind):
    table = make_table(table_kind)
    rng = np.random.default_rng(zlib.crc32(f"{table_kind}/{pose_kind}".encode()))
    frames = 4
    root, pose = random_root(rng, frames), make_pose(pose_kind, rng, frames)
    want = forward_kinematics_numpy(table, root, pose, jacobians=True)
    got = forward_kinematics(table, root, pose, jacobians=True)
    P = 6 + 3 * (NUM_JOINTS - 1) + table.shape_dim
    assert got.d_keypoints.shape == (frames, table.num_keypoints, 3, P)
    for field in FK_FIELDS:
        assert max_rel_diff(getattr(got, field), getattr(want, field)) < 1e-9, field


def test_native_fk_without_jacobians():
    table = make_table("k9_s4")
    rng = np.random.default_rng(0)
    root, pose = random_root(rng, 3), make_pose("random", rng, 3)
    got = forward_kinematics(table, root, pose, jacobians=False)
    want = forward_kinematics_numpy(table, root, pose)
    assert got.d_joints is None and got.d_keypoints is None
    for field in FK_FIELDS[:3]:
        assert max_rel_diff(getattr(got, field), getattr(want, field)) < 1e-9


def test_native_fk_zero_frames():
    table = make_table("k9_s4")
    got = forward_kinematics(table, np.zeros((0, 4, 4)), np.zeros((0, NUM_JOINTS - 1, 3)), jacobians=True)
    assert got.keypoints.shape == (0, 9, 3) and got.d_joints.shape == (0, NUM_JOINTS, 3, 6 + 63 + 4)


def test_native_outputs_are_not_recycled_while_alive():
    # The binding recycles freed output buffers; live results must never be overwritten.
    table = make_table("k23_s6")
    rng = np.random.default_rng(1)
    frames = 64  # large enough for the Jacobians to go through the buffer pool
    first_in = random_root(rng, frames), make_pose("random", rng, frames)
    first = forward_kinematics(table, *first_in, jacobians=True)
    kept = {f: getattr(first, f).copy() for f in FK_FIELDS}
    for _ in range(3):
        del first
        first = forward_kinematics(table, *first_in, jacobians=True)
        forward_kinematics(table, random_root(rng, frames), make_pose("random", rng, frames), jacobians=True)
        for f in FK_FIELDS:
            np.testing.assert_array_equal(getattr(first, f), kept[f])


def test_native_fk_converts_layout_and_dtype():
    table = make_table("k9_s4")
    rng = np.random.default_rng(2)
    root, pose = random_root(rng, 3), make_pose("random", rng, 3)
    want = native_module().fk(*table_arrays(table), root, pose, True)
    strided_pose = np.asfortranarray(pose)
    got = native_module().fk(*table_arrays(table), root, strided_pose, True)
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)


def test_native_fk_rejects_bad_shapes_with_value_error():
    table = make_table("k9_s4")
    rng = np.random.default_rng(3)
    args = list(table_arrays(table)) + [random_root(rng, 2), make_pose("random", rng, 2), True]
    names = ["parents", "offsets", "d_offsets", "weights", "markers", "d_markers", "root", "pose"]
    fk = native_module().fk
    bad_cases = {
        "offsets": np.zeros((NUM_JOINTS - 1, 3)),
        "d_offsets": np.zeros((NUM_JOINTS, 3)),
        "weights": np.zeros((9, NUM_JOINTS + 1)),
        "markers": np.zeros((8, NUM_JOINTS, 3)),
        "d_markers": np.zeros((9, NUM_JOINTS, 3, 5)),
        "root": np.zeros((2, 3, 4)),
        "pose": np.zeros((3, NUM_JOINTS - 1, 3)),
    }
    for name, bad in bad_cases.items():
        call = list(args)
        call[names.index(name)] = bad
        with pytest.raises(ValueError, match=name):
            fk(*call)
    for bad_parents in (PARENTS[:0], np.where(np.arange(NUM_JOINTS) == 5, 7, PARENTS), np.r_[0, PARENTS[1:]]):
        call = list(args)
        call[0] = np.ascontiguousarray(bad_parents, dtype=np.int64)
        with pytest.raises(ValueError, match="parents"):
            fk(*call)


# ---------------------------------------------------------------------------------------------
# Reprojection


def look_at(position: np.ndarray, target: np.ndarray) -> np.ndarray:
    """world_T_camera ``(4, 4)`` of an OpenCV camera at ``position`` looking at ``target``, +Y up."""
    z = target - position
    z /= np.linalg.norm(z)
    y = np.array([0.0, -1.0, 0.0])
    y -= (y @ z) * z
    y /= np.linalg.norm(y)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([np.cross(y, z), y, z])
    pose[:3, 3] = position
    return pose


def project(cameras, intrinsics, points) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(C, K, 2)`` and depths ``(C, K)`` of world points, one camera at a time."""
    pixels, depths = [], []
    for T, (fx, fy, cx, cy) in zip(cameras, intrinsics):
        p = (points - T[:3, 3]) @ T[:3, :3]
        pixels.append(np.column_stack([fx * p[:, 0] / p[:, 2] + cx, fy * p[:, 1] / p[:, 2] + cy]))
        depths.append(p[:, 2])
    return np.array(pixels), np.array(depths)


@dataclasses.dataclass
class Scene:
    shape_table: LinearShapeTable
    beta: np.ndarray
    root: np.ndarray
    pose: np.ndarray
    cameras: np.ndarray
    intrinsics: np.ndarray
    observed: np.ndarray
    obs_weights: np.ndarray

    @property
    def table(self) -> BodyTable:
        return self.shape_table(self.beta)

    def args(self):
        return (self.table, self.root, self.pose, self.cameras, self.intrinsics, self.observed, self.obs_weights)

    def keypoints(self) -> np.ndarray:
        return forward_kinematics_numpy(self.table, self.root[None], self.pose[None]).keypoints[0]


def make_scene(seed: int = 0, K: int = 10, S: int = 3, C: int = 3, pose_kind: str = "random") -> Scene:
    rng = np.random.default_rng(seed)
    shape_table = LinearShapeTable(seed=seed, num_keypoints=K, shape_dim=S)
    root = random_root(rng, 1)[0]
    root[:3, 3] = rng.normal(scale=0.2, size=3)
    pose = make_pose(pose_kind, rng, 1)[0] * (0.4 if pose_kind == "random" else 1.0)
    headings = np.linspace(0, 2 * np.pi, C, endpoint=False) + rng.uniform(0, 0.5)
    cameras = np.stack(
        [
            look_at(np.array([4.5 * np.sin(h), rng.uniform(0.5, 1.5), 4.5 * np.cos(h)]), rng.normal(scale=0.2, size=3))
            for h in headings
        ]
    )
    intrinsics = np.column_stack(
        [rng.uniform(800, 1000, C), rng.uniform(800, 1000, C), rng.uniform(600, 680, C), rng.uniform(340, 380, C)]
    )
    scene = Scene(shape_table, rng.normal(size=S), root, pose, cameras, intrinsics, None, rng.uniform(0.3, 1.0, (C, K)))
    pixels, _ = project(cameras, intrinsics, scene.keypoints())
    # Errors of the order of sigma keep the Geman-McClure weighting in its nonlinear range.
    scene.observed = pixels + rng.normal(scale=12.0, size=pixels.shape)
    return scene


def finite_difference_jacobian(scene: Scene, gm_sigma_px: float, h: float = 1e-6) -> np.ndarray:
    """Central differences of ``reproject_numpy`` in the documented column layout."""
    C, S = scene.cameras.shape[0], scene.beta.size
    P = 6 + 3 * (NUM_JOINTS - 1) + S

    def perturbed(col: int, step: float) -> Scene:
        s = dataclasses.replace(
            scene, root=scene.root.copy(), pose=scene.pose.copy(), beta=scene.beta.copy(), cameras=scene.cameras.copy()
        )
        delta = np.zeros(3)
        if col < 3:
            delta[col] = step
            s.root[:3, :3] = s.root[:3, :3] @ rotvec_to_matrix(delta)
        elif col < 6:
            delta[col - 3] = step
            s.root[:3, 3] += s.root[:3, :3] @ delta
        elif col < P - S:
            s.pose.reshape(-1)[col - 6] += step
        elif col < P:
            s.beta[col - (P - S)] += step
        else:
            c, i = divmod(col - P, 6)
            delta[i % 3] = step
            if i < 3:
                s.cameras[c, :3, :3] = s.cameras[c, :3, :3] @ rotvec_to_matrix(delta)
            else:
                s.cameras[c, :3, 3] += s.cameras[c, :3, :3] @ delta
        return s

    columns = []
    for col in range(P + 6 * C):
        plus = reproject_numpy(*perturbed(col, h).args(), gm_sigma_px, jacobians=False).residual
        minus = reproject_numpy(*perturbed(col, -h).args(), gm_sigma_px, jacobians=False).residual
        columns.append((plus - minus) / (2 * h))
    return np.column_stack(columns)


@pytest.mark.parametrize("gm_sigma_px", [10.0, np.inf])
def test_reprojection_jacobian_matches_finite_differences(gm_sigma_px):
    scene = make_scene(seed=1, K=8, S=3, C=3)
    scene.observed[0, 2] = np.nan
    scene.obs_weights[1, 4] = 0.0
    result = reproject_numpy(*scene.args(), gm_sigma_px)
    assert result.valid.sum() == 3 * 8 - 2
    numeric = finite_difference_jacobian(scene, gm_sigma_px)
    # Pixel Jacobians are O(100); with h = 1e-6 round-off and truncation stay near 1e-9 of that.
    assert max_rel_diff(result.jacobian, numeric) < 1e-6


@pytest.mark.parametrize("pose_kind", ["random", "tiny", "near_pi", "mixed"])
@pytest.mark.parametrize("gm_sigma_px", [10.0, np.inf, 0.0])
def test_native_reprojection_matches_numpy(pose_kind, gm_sigma_px):
    scene = make_scene(seed=2, K=23, S=6, C=4, pose_kind=pose_kind)
    scene.observed[1, 3, 0] = np.nan
    scene.obs_weights[2, 7] = 0.0
    want = reproject_numpy(*scene.args(), gm_sigma_px)
    got = reproject(*scene.args(), gm_sigma_px)
    np.testing.assert_array_equal(got.valid, want.valid)
    assert got.valid.dtype == bool and got.jacobian.shape == (4 * 23 * 2, 6 + 63 + 6 + 24)
    assert max_rel_diff(got.residual, want.residual) < 1e-9
    assert max_rel_diff(got.jacobian, want.jacobian) < 1e-9
    no_jac = reproject(*scene.args(), gm_sigma_px, jacobians=False)
    assert no_jac.jacobian is None
    np.testing.assert_array_equal(no_jac.residual, got.residual)


@pytest.mark.parametrize("table_kind", ["s0", "k0", "k0_s0"])
def test_native_reprojection_degenerate_tables(table_kind):
    scene = make_scene(seed=3, C=2)
    table = make_table(table_kind)
    K = table.num_keypoints
    args = (table, scene.root, scene.pose, scene.cameras, scene.intrinsics)
    rng = np.random.default_rng(0)
    observed, weights = rng.uniform(300, 600, (2, K, 2)), np.ones((2, K))
    want = reproject_numpy(*args, observed, weights, 10.0)
    got = reproject(*args, observed, weights, 10.0)
    assert got.jacobian.shape == (2 * K * 2, 6 + 63 + table.shape_dim + 12)
    assert max_rel_diff(got.residual, want.residual) < 1e-9
    assert max_rel_diff(got.jacobian, want.jacobian) < 1e-9


def test_huge_sigma_gives_the_plain_weighted_error():
    scene = make_scene(seed=4)
    pixels, _ = project(scene.cameras, scene.intrinsics, scene.keypoints())
    plain = (scene.obs_weights[..., None] * (pixels - scene.observed)).reshape(-1)
    for fn in (reproject, reproject_numpy):
        np.testing.assert_allclose(fn(*scene.args(), 1e12).residual, plain, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(fn(*scene.args(), np.inf).residual, plain, rtol=1e-12, atol=1e-12)


def test_half_squared_residual_is_the_geman_mcclure_cost():
    scene = make_scene(seed=5)
    sigma = 7.5
    pixels, _ = project(scene.cameras, scene.intrinsics, scene.keypoints())
    err2 = np.sum((pixels - scene.observed) ** 2, axis=-1)
    cost = 0.5 * scene.obs_weights**2 * sigma**2 * err2 / (sigma**2 + err2)
    for fn in (reproject, reproject_numpy):
        r = fn(*scene.args(), sigma).residual.reshape(cost.shape + (2,))
        np.testing.assert_allclose(0.5 * np.sum(r**2, axis=-1), cost, rtol=1e-10)


def test_invalid_keypoints_have_zero_rows():
    scene = make_scene(seed=6, K=9, C=3)
    # A fourth camera inside the scene looking away from the body sees everything behind it.
    away = look_at(np.array([0.0, 1.0, 3.0]), np.array([0.0, 1.0, 10.0]))
    scene.cameras = np.concatenate([scene.cameras, away[None]])
    scene.intrinsics = np.concatenate([scene.intrinsics, scene.intrinsics[:1]])
    scene.observed = np.concatenate([scene.observed, scene.observed[:1]])
    scene.obs_weights = np.concatenate([scene.obs_weights, scene.obs_weights[:1]])
    scene.observed[0, 1] = np.nan
    scene.observed[1, 2, 1] = np.nan  # one coordinate missing is a missing detection
    scene.obs_weights[2, 3] = 0.0
    _, depths = project(scene.cameras, scene.intrinsics, scene.keypoints())
    assert np.all(depths[3] < 0) and np.all(depths[:3] > 1.0)
    # Also a depth threshold that cuts through camera 0's points (it applies to every camera).
    min_depth = float(np.median(depths[0]))
    expected = np.ones((4, 9), dtype=bool)
    expected[0, 1] = expected[1, 2] = expected[2, 3] = False
    expected[3] = False
    expected &= depths >= min_depth
    assert 0 < expected[:3].sum() < expected[:3].size - 3
    for fn in (reproject, reproject_numpy):
        result = fn(*scene.args(), 10.0, min_depth=min_depth)
        np.testing.assert_array_equal(result.valid, expected)
        rows = np.repeat(~expected.reshape(-1), 2)
        assert np.all(result.residual[rows] == 0.0) and np.all(result.jacobian[rows] == 0.0)
        assert np.all(np.abs(result.residual[~rows]) > 0)
        assert np.isfinite(result.jacobian).all()


def test_unmapped_keypoints_never_pull():
    """A point the body cannot provide (e.g. a BlazePose finger tip) is invalid even if observed."""
    scene = make_scene(seed=8, K=9, C=2)
    table = scene.table
    mapped = np.ones(9, dtype=bool)
    mapped[[2, 5]] = False
    table = dataclasses.replace(table, mapped=mapped)
    args = (table, *scene.args()[1:])
    for fn in (reproject, reproject_numpy):
        result = fn(*args, 10.0)
        assert not result.valid[:, [2, 5]].any() and result.valid[:, mapped].all()
        rows = np.repeat(~result.valid.reshape(-1), 2)
        assert np.all(result.residual[rows] == 0.0) and np.all(result.jacobian[rows] == 0.0)


def test_camera_columns_only_touch_their_camera():
    scene = make_scene(seed=7, K=5, C=3)
    result = reproject(*scene.args(), 10.0)
    P = 6 + 63 + scene.beta.size
    J = result.jacobian.reshape(3, 5, 2, -1)
    for c in range(3):
        for other in range(3):
            block = J[c, :, :, P + 6 * other : P + 6 * other + 6]
            assert (np.abs(block).max() > 0) == (c == other)


def good_reproject_args(scene: Scene) -> dict:
    return dict(
        table=scene.table,
        root=scene.root,
        pose=scene.pose,
        cameras=scene.cameras,
        intrinsics=scene.intrinsics,
        observed=scene.observed,
        obs_weights=scene.obs_weights,
        gm_sigma_px=10.0,
        min_depth=0.05,
    )


@pytest.mark.parametrize(
    "name, bad",
    [
        ("root", np.eye(4)[:3]),
        ("root", np.diag([2.0, 1.0, 1.0, 1.0])),
        ("root", "not an array"),
        ("pose", np.zeros((20, 3))),
        ("pose", np.full((21, 3), np.nan)),
        ("cameras", np.zeros((3, 3, 4))),
        ("cameras", np.tile(np.diag([1.0, 1.0, -1.0, 1.0]), (3, 1, 1))),
        ("intrinsics", np.ones((3, 3))),
        ("intrinsics", np.ones((2, 4))),
        ("intrinsics", np.tile([-900.0, 900.0, 640.0, 360.0], (3, 1))),
        ("observed", np.zeros((3, 11, 2))),
        ("observed", np.zeros((3, 10))),
        ("observed", np.full((3, 10, 2), np.inf)),
        ("obs_weights", np.ones((3, 9))),
        ("obs_weights", -np.ones((3, 10))),
        ("obs_weights", np.full((3, 10), np.nan)),
        ("gm_sigma_px", np.nan),
        ("gm_sigma_px", "wide"),
        ("min_depth", 0.0),
        ("min_depth", np.inf),
    ],
)
def test_reproject_rejects_bad_input_naming_the_argument(name, bad):
    args = good_reproject_args(make_scene(seed=8))
    args[name] = bad
    with pytest.raises(MocapgraphError, match=name):
        reproject(**args)


def test_native_reproject_rejects_bad_shapes_with_value_error():
    scene = make_scene(seed=9)
    C, K = scene.obs_weights.shape
    good = good_reproject_args(scene)
    for scalar in ("table", "gm_sigma_px", "min_depth"):
        del good[scalar]
    bad_cases = {
        "root": np.eye(3),
        "pose": np.zeros((NUM_JOINTS, 3)),
        "cameras": np.zeros((C, 4)),
        "intrinsics": np.ones((C + 1, 4)),
        "observed": np.zeros((C, K - 1, 2)),
        "obs_weights": np.ones((C, K, 1)),
    }
    fn = native_module().reproject
    for name, bad in bad_cases.items():
        args = dict(good, **{name: bad})
        with pytest.raises(ValueError, match=name):
            fn(*table_arrays(scene.table), *args.values(), 10.0, 0.05, True)
    with pytest.raises(ValueError, match="obs_weights"):
        fn(*table_arrays(scene.table), *dict(good, obs_weights=-scene.obs_weights).values(), 10.0, 0.05, True)
    with pytest.raises(ValueError, match="min_depth"):
        fn(*table_arrays(scene.table), *good.values(), 10.0, -1.0, True)


# ---------------------------------------------------------------------------------------------
# The prepared body (mocapgraph._native.Body)


def test_prepared_body_poses_as_the_table_functions():
    """``Body(*table_arrays(table)).fk`` returns exactly what ``fk`` on the arrays returns."""
    table = make_table("k23_s6")
    rng = np.random.default_rng(11)
    root, pose = random_root(rng, 3), make_pose("random", rng, 3)
    body = native_module().Body(*table_arrays(table))
    assert body.num_keypoints == table.num_keypoints and body.num_params == 6 + 3 * (NUM_JOINTS - 1) + table.shape_dim
    for jacobians in (False, True):
        want = native_module().fk(*table_arrays(table), root, pose, jacobians)
        got = body.fk(root, pose, jacobians)
        for w, g in zip(want, got):
            assert (w is None and g is None) or np.array_equal(w, g)


def factor_args(scene: Scene) -> dict:
    C, K = scene.obs_weights.shape
    return dict(
        root=scene.root, pose=scene.pose, cameras=scene.cameras, intrinsics=scene.intrinsics, observed=scene.observed,
        obs_weights=scene.obs_weights, mapped=np.ones(K), gm_sigma_px=10.0, min_depth=0.05, jacobians=True,
        permutations=np.stack([np.arange(K), np.arange(K)[::-1]]), allowed=np.ones((C, 2), dtype=bool), relabel_cost=1.0,
        relabel=True, cost_row=True, focal_columns=np.full(C, -1), num_focal=0,
    )  # fmt: skip


def test_prepared_body_factor_rows_are_the_kernels_usable_rows():
    """As detected (one hypothesis, no relabelling), the factor entry's rows are ``reproject``'s
    rows of finite, weighted detections, and its last row the relabelling cost (0 here)."""
    scene = make_scene(seed=12)
    scene.observed[1, 2] = np.nan
    scene.obs_weights[2, 5] = 0.0
    body = native_module().Body(*table_arrays(scene.table))
    args = dict(factor_args(scene), permutations=np.arange(scene.obs_weights.shape[1])[None], allowed=np.ones((3, 1), dtype=bool))
    residual, jacobian, choice = body.reproject_factor(**args)
    full = reproject(*scene.args(), 10.0)
    usable = np.repeat((np.isfinite(scene.observed).all(-1) & (scene.obs_weights > 0)).ravel(), 2)
    assert choice.tolist() == [0, 0, 0]
    assert np.array_equal(residual, np.append(full.residual[usable], 0.0))
    assert np.array_equal(jacobian[:-1], full.jacobian[usable]) and not jacobian[-1].any()


@pytest.mark.parametrize(
    "name, bad, match",
    [
        ("mapped", np.ones(3), "mapped"),
        ("permutations", np.full((2, 10), 10), "permutations"),
        ("permutations", np.zeros((2, 9), dtype=np.int64), "permutations"),
        ("allowed", np.ones((3, 3), dtype=bool), "allowed"),
        ("relabel_cost", -1.0, "relabel_cost"),
        ("focal_columns", np.zeros(3, dtype=np.int64), "focal_columns"),
        ("cameras", np.eye(4)[None].repeat(3, 0) * 2, "cameras"),
    ],
)
def test_prepared_body_factor_rejects_bad_input_naming_it(name, bad, match):
    scene = make_scene(seed=13)
    body = native_module().Body(*table_arrays(scene.table))
    with pytest.raises(ValueError, match=match):
        body.reproject_factor(**dict(factor_args(scene), **{name: bad}))
