"""Every factor of mocapgraph.factors: Jacobians against central differences, errors against
independent formulas, the annealed robust scale, the shape-table cache and a tiny Gauss-Newton fit."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.body import load_body_model
from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.keypoint_offsets import offset_basis
from mocapgraph.body.labelling import SWAP_KINDS, swap_permutation
from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.body_priors import pose_regularizer_factor, shape_prior_factor
from mocapgraph.factors.camera_priors import camera_prior_factor
from mocapgraph.factors.keys import camera_key, pose_key, root_key, shape_key
from mocapgraph.factors.reprojection import Labelling, ShapeTableCache, reprojection_factor
from mocapgraph.factors.reprojection_kernel import reproject_numpy
from mocapgraph.factors.robust import RobustScale
from mocapgraph.factors.smoothness import camera_acceleration_factor, camera_smoothness_factor, pose_smoothness_factor, pose_velocity_factor, root_smoothness_factor, rotation_acceleration_factor

FORMAT = "coco17"
INTRINSICS = np.array([1000.0, 980.0, 640.0, 360.0])


@pytest.fixture(scope="module")
def body():
    return load_body_model()


# ---------------------------------------------------------------------------------------------
# Helpers


def look_at_body(angle: float, distance: float = 3.5, height: float = 1.2) -> np.ndarray:
    """world_T_camera of an OpenCV camera on a circle around the origin, looking at (0, 0, 1), Z up."""
    centre = np.array([distance * math.cos(angle), distance * math.sin(angle), height])
    z = np.array([0.0, 0.0, 1.0]) - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = centre
    return T


def standing_root(rng: np.random.Generator) -> np.ndarray:
    """An upright world_T_root (body +Y along world +Z) near the origin, randomly turned."""
    T = np.eye(4)
    T[:3, :3] = rotvec_to_matrix(np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)])) @ rotvec_to_matrix(
        np.array([np.pi / 2, 0.0, 0.0])
    )
    T[:3, 3] = [rng.normal(scale=0.1), rng.normal(scale=0.1), 1.0]
    return T


def random_shape(body, rng: np.random.Generator) -> np.ndarray:
    """Inside the phenotype box and away from its edges (Anny's shape map has kinks at anchors)."""
    lo, hi = body.shape_bounds.T
    return lo + (hi - lo) * rng.uniform(0.1, 0.9, size=body.shape_dim)


def is_pose3(values: gtsam.Values, key: int) -> bool:
    try:
        values.atPose3(key)
    except RuntimeError:
        return False
    return True


def perturbed(values: gtsam.Values, key: int, delta: np.ndarray) -> gtsam.Values:
    """A copy of ``values`` with ``key`` moved along its retraction (Pose3.retract or +delta)."""
    out = gtsam.Values(values)
    if is_pose3(values, key):
        out.update(key, values.atPose3(key).retract(delta))
    else:
        out.update(key, values.atVector(key) + delta)
    return out


def variable_dim(values: gtsam.Values, key: int) -> int:
    return 6 if is_pose3(values, key) else len(values.atVector(key))


def numerical_jacobian(residual, factor, values: gtsam.Values, h: float = 1e-6) -> np.ndarray:
    """Central differences of ``residual(values)`` through each key's retraction, in key order."""
    columns = []
    for key in factor.keys():
        for j in range(variable_dim(values, key)):
            step = np.zeros(variable_dim(values, key))
            step[j] = h
            plus = residual(perturbed(values, key, step))
            minus = residual(perturbed(values, key, -step))
            columns.append((plus - minus) / (2 * h))
    return np.stack(columns, axis=1)


def max_rel_diff(got: np.ndarray, want: np.ndarray) -> float:
    """Max abs difference over ``max(1, max |want|)``: absolute for O(1) data, relative for pixels."""
    assert got.shape == want.shape
    return float(np.abs(got - want).max() / max(1.0, np.abs(want).max()))


def assert_jacobians(factor, values: gtsam.Values):
    """A Gaussian-noise factor: its linearisation equals central differences of its whitened residual."""
    A, b = factor.linearize(values).jacobian()
    np.testing.assert_allclose(b, -factor.whitenedError(values), atol=1e-12)
    numeric = numerical_jacobian(factor.whitenedError, factor, values)
    assert max_rel_diff(A, numeric) < 1e-6


def random_pose3(rng: np.random.Generator, scale: float = 1.0) -> gtsam.Pose3:
    return gtsam.Pose3.Expmap(rng.normal(scale=scale, size=6))


# ---------------------------------------------------------------------------------------------
# Reprojection scene: 2 refined cameras + 1 fixed camera, NaN observations, outliers


class Scene:
    """One body state seen by three cameras; camera 1 is fixed, cameras 0 and 2 are refined."""

    def __init__(self, body, seed: int = 0, gm_sigma_px: float = 8.0, noise_px: float = 1.5):
        rng = np.random.default_rng(seed)
        self.body = body
        self.root = standing_root(rng)
        self.pose = rng.normal(scale=0.3, size=63)
        self.shape = random_shape(body, rng)
        self.cameras = np.stack([look_at_body(a) for a in (0.3, 2.4, 4.4)])
        self.intrinsics = np.tile(INTRINSICS, (3, 1))
        truth = body.forward(self.shape, self.root[None], self.pose.reshape(1, 21, 3), keypoints=FORMAT).keypoints[0]
        p = np.einsum("cyx,cky->ckx", self.cameras[:, :3, :3], truth[None] - self.cameras[:, None, :3, 3])
        uv = p[..., :2] / p[..., 2:] * self.intrinsics[:, None, :2] + self.intrinsics[:, None, 2:]
        self.observed = uv + rng.normal(scale=3.0, size=uv.shape)
        self.observed[0, 4] += [60.0, -45.0]  # outliers
        self.observed[2, 9] += [-80.0, 20.0]
        self.observed[0, 2] = np.nan  # missed detections
        self.observed[1, 11] = np.nan
        self.observed[2, 0] = np.nan
        self.weights = rng.uniform(0.3, 1.0, size=(3, 17))
        self.weights[1, 5] = 0.0
        self.scale = RobustScale(gm_sigma_px)
        self.noise_px = noise_px
        self.cache = ShapeTableCache(body, FORMAT)
        self.camera_keys = [camera_key(0, 7), None, camera_key(2, 7)]
        self.factor = reprojection_factor(
            body,
            self.cache,
            root_key(7),
            pose_key(7),
            shape_key(),
            self.camera_keys,
            [None, self.cameras[1], None],
            self.intrinsics,
            self.observed,
            self.weights,
            FORMAT,
            self.scale,
            noise_px=noise_px,
        )
        self.values = gtsam.Values()
        # Evaluate away from the truth, so that the Jacobian of the robust weight matters too.
        self.values.insert(root_key(7), gtsam.Pose3(self.root).retract(rng.normal(scale=0.02, size=6)))
        self.values.insert(pose_key(7), self.pose + rng.normal(scale=0.05, size=63))
        self.values.insert(shape_key(), self.shape)
        for c in (0, 2):
            self.values.insert(camera_key(c, 7), gtsam.Pose3(self.cameras[c]).retract(rng.normal(scale=0.01, size=6)))

    @property
    def usable_rows(self) -> np.ndarray:
        """``(2·3·17,)`` bool: the kernel's rows of observations with finite pixels and weight > 0."""
        return np.repeat((np.isfinite(self.observed).all(-1) & (self.weights > 0)).ravel(), 2)

    def independent_residual(self, values: gtsam.Values) -> np.ndarray:
        """The numpy reference kernel with a freshly built table (no cache, no native code), on
        the usable rows."""
        cameras = self.cameras.copy()
        for c in (0, 2):
            cameras[c] = values.atPose3(camera_key(c, 7)).matrix()
        result = reproject_numpy(
            self.body.table(values.atVector(shape_key()), keypoints=FORMAT),
            values.atPose3(root_key(7)).matrix(),
            values.atVector(pose_key(7)).reshape(21, 3),
            cameras,
            self.intrinsics,
            self.observed,
            self.weights,
            self.scale.sigma_px,
            jacobians=False,
        )
        return result.residual[self.usable_rows] / self.noise_px


@pytest.fixture(scope="module", params=[0, 1])
def scene(body, request):
    return Scene(body, seed=request.param)


# ---------------------------------------------------------------------------------------------
# Reprojection factor


def test_reprojection_keys_and_dimension(scene):
    """Keys are [root, pose, shape, refined cameras]; the fixed camera has none; two rows per
    usable observation (3 cameras × 17 points, less 3 NaN and 1 zero weight)."""
    assert list(scene.factor.keys()) == [root_key(7), pose_key(7), shape_key(), camera_key(0, 7), camera_key(2, 7)]
    assert scene.factor.dim() == 2 * (3 * 17 - 4)


@pytest.mark.parametrize("gm_sigma_px", [8.0, math.inf])
def test_reprojection_jacobian(scene, gm_sigma_px):
    """Robust and L2 Jacobians equal central differences through Pose3.retract and vector +delta."""
    scene.scale.sigma_px = gm_sigma_px
    assert_jacobians(scene.factor, scene.values)


def test_reprojection_error_is_half_squared_whitened_residual(scene):
    """error = ½‖residual / noise_px‖², the residual from the numpy reference kernel."""
    for sigma in (8.0, math.inf):
        scene.scale.sigma_px = sigma
        want = scene.independent_residual(scene.values)
        np.testing.assert_allclose(scene.factor.whitenedError(scene.values), want, rtol=1e-9, atol=1e-9)
        assert scene.factor.error(scene.values) == pytest.approx(0.5 * want @ want, rel=1e-10)


def test_reprojection_missing_points_have_no_rows(scene):
    """A NaN pixel and a zero weight both drop the point's rows: the same factor results when the
    NaN points get arbitrary pixels and weight 0; a factor with nothing usable is refused."""
    observed, weights = scene.observed.copy(), scene.weights.copy()
    missing = ~np.isfinite(observed).all(-1)
    observed[missing] = [5000.0, -700.0]
    weights[missing] = 0.0
    args = (root_key(7), pose_key(7), shape_key(), scene.camera_keys, [None, scene.cameras[1], None], scene.intrinsics)
    zeroed = reprojection_factor(scene.body, scene.cache, *args, observed, weights, FORMAT, scene.scale, noise_px=scene.noise_px)
    assert zeroed.dim() == scene.factor.dim()
    A, b = scene.factor.linearize(scene.values).jacobian()
    A2, b2 = zeroed.linearize(scene.values).jacobian()
    np.testing.assert_array_equal(A, A2)
    np.testing.assert_array_equal(b, b2)
    with pytest.raises(MocapgraphError, match="no usable observation"):
        reprojection_factor(scene.body, scene.cache, *args, observed, np.zeros_like(weights), FORMAT, scene.scale)


def test_reprojection_with_a_fixed_shape(scene):
    """Holding the shape fixed drops its key and Jacobian and leaves residual and other blocks equal."""
    fixed = reprojection_factor(
        scene.body, scene.cache, root_key(7), pose_key(7), None, scene.camera_keys, [None, scene.cameras[1], None],
        scene.intrinsics, scene.observed, scene.weights, FORMAT, scene.scale, noise_px=scene.noise_px,
        fixed_shape=scene.shape,
    )  # fmt: skip
    assert list(fixed.keys()) == [root_key(7), pose_key(7), camera_key(0, 7), camera_key(2, 7)]
    np.testing.assert_array_equal(fixed.whitenedError(scene.values), scene.factor.whitenedError(scene.values))
    full, _ = scene.factor.linearize(scene.values).jacobian()
    held, _ = fixed.linearize(scene.values).jacobian()
    S = scene.body.shape_dim
    np.testing.assert_array_equal(held, np.delete(full, np.s_[69 : 69 + S], axis=1))
    assert_jacobians(fixed, scene.values)
    with pytest.raises(MocapgraphError, match="exactly one of shape_key and fixed_shape"):
        reprojection_factor(
            scene.body, scene.cache, root_key(7), pose_key(7), shape_key(), scene.camera_keys, [None, scene.cameras[1], None],
            scene.intrinsics, scene.observed, scene.weights, FORMAT, scene.scale, fixed_shape=scene.shape,
        )  # fmt: skip


def test_labelling_keeps_the_dimension_with_unmapped_points(body):
    """BlazePose's finger points have no body point (unmapped): a labelled factor keeps one row
    pair per detected point, whatever labelling each camera takes, like the unlabelled one."""
    rng = np.random.default_rng(5)
    fmt = get_format("blazepose33")
    cache = ShapeTableCache(body, fmt.name)
    root, pose, shape = standing_root(rng), rng.normal(scale=0.2, size=63), body.default_shape
    cameras = np.stack([look_at_body(a) for a in (0.2, 2.0)])
    truth = body.forward(shape, root[None], pose.reshape(1, 21, 3), keypoints=fmt.name).keypoints[0]
    p = np.einsum("cyx,cky->ckx", cameras[:, :3, :3], truth[None] - cameras[:, None, :3, 3])
    observed = p[..., :2] / p[..., 2:] * INTRINSICS[:2] + INTRINSICS[2:] + rng.normal(scale=2.0, size=(2, 33, 2))
    observed[1] = observed[1, swap_permutation(fmt.names, "body")]
    weights = np.ones((2, 33))
    values = gtsam.Values()
    values.insert(root_key(0), gtsam.Pose3(root))
    values.insert(pose_key(0), pose)
    scale = RobustScale(8.0)
    args = (body, cache, root_key(0), pose_key(0), None, [None, None], list(cameras), np.tile(INTRINSICS, (2, 1)), observed, weights, fmt.name, scale)
    plain = reprojection_factor(*args, fixed_shape=shape)
    perms = np.stack([swap_permutation(fmt.names, k) for k in SWAP_KINDS])
    labelling = Labelling(perms, cost=2.0)
    factor = reprojection_factor(*args, fixed_shape=shape, labelling=labelling)
    assert factor.dim() == plain.dim() + 1 == 2 * 2 * 33 + 1
    assert len(factor.whitenedError(values)) == factor.dim()
    assert labelling.choice.tolist() == [0, 1]
    assert factor.error(values) < plain.error(values)
    assert_jacobians(factor, values)


def labelled_factor(scene, observed, labelling):
    return reprojection_factor(
        scene.body, scene.cache, root_key(7), pose_key(7), shape_key(), scene.camera_keys, [None, scene.cameras[1], None],
        scene.intrinsics, observed, scene.weights, FORMAT, scene.scale, noise_px=scene.noise_px, labelling=labelling,
    )  # fmt: skip


PERMUTATIONS = np.stack([swap_permutation(get_format(FORMAT).names, k) for k in SWAP_KINDS])


def test_labelled_reprojection_undoes_swaps(scene):
    """Camera 0's whole body and camera 2's legs swapped: the max-mixture takes "body" and
    "legs" there and "none" for camera 1; its error equals the unswapped factor's plus the two
    relabellings' cost; its Jacobians equal central differences. Under L2 (the scale at
    infinity) it keeps the points as detected."""
    scene.scale.sigma_px = 8.0
    observed = scene.observed.copy()
    observed[0] = observed[0, PERMUTATIONS[1]]
    observed[2] = observed[2, PERMUTATIONS[3]]
    # the weights stay with their points under a swap, as a detector's confidences do
    labelling = Labelling(PERMUTATIONS, cost=2.0)
    weights = scene.weights.copy()
    weights[0], weights[2] = weights[0, PERMUTATIONS[1]], weights[2, PERMUTATIONS[3]]
    factor = reprojection_factor(
        scene.body, scene.cache, root_key(7), pose_key(7), shape_key(), scene.camera_keys, [None, scene.cameras[1], None],
        scene.intrinsics, observed, weights, FORMAT, scene.scale, noise_px=scene.noise_px, labelling=labelling,
    )  # fmt: skip
    assert factor.dim() == scene.factor.dim() + 1
    error = factor.error(scene.values)
    assert labelling.choice.tolist() == [1, 0, 3]
    assert error == pytest.approx(scene.factor.error(scene.values) + 2 * 2.0, rel=1e-9)
    assert_jacobians(factor, scene.values)
    scene.scale.sigma_px = math.inf
    as_detected = reprojection_factor(
        scene.body, scene.cache, root_key(7), pose_key(7), shape_key(), scene.camera_keys, [None, scene.cameras[1], None],
        scene.intrinsics, observed, weights, FORMAT, scene.scale, noise_px=scene.noise_px,
    )  # fmt: skip
    assert factor.error(scene.values) == pytest.approx(as_detected.error(scene.values), rel=1e-12)
    assert labelling.choice.tolist() == [0, 0, 0]
    assert_jacobians(factor, scene.values)


def test_labelling_is_the_cheapest_hypothesis(scene):
    """The factor's error is the minimum over every camera's hypotheses of the factors built with
    that relabelling applied (each hypothesis not the identity costing ``cost``): 4³ combinations."""
    scene.scale.sigma_px = 8.0
    labelling = Labelling(PERMUTATIONS, cost=0.5)
    error = labelled_factor(scene, scene.observed, labelling).error(scene.values)
    best = np.inf
    for combo in np.ndindex(4, 4, 4):
        observed = np.stack([scene.observed[c, PERMUTATIONS[h]] for c, h in enumerate(combo)])
        weights = np.stack([scene.weights[c, PERMUTATIONS[h]] for c, h in enumerate(combo)])
        plain = reprojection_factor(
            scene.body, scene.cache, root_key(7), pose_key(7), shape_key(), scene.camera_keys, [None, scene.cameras[1], None],
            scene.intrinsics, observed, weights, FORMAT, scene.scale, noise_px=scene.noise_px,
        )  # fmt: skip
        best = min(best, plain.error(scene.values) + 0.5 * np.count_nonzero(combo))
    assert error == pytest.approx(best, rel=1e-9)


def numpy_factor(body, fmt, values, cameras, camera_keys, intrinsics, observed, weights, noise_px, sigma, permutations, cost, allowed):
    """The labelled reprojection factor written with the numpy reference kernel, camera by
    camera: each hypothesis' robust cost ``½|r|²`` (plus ``cost`` if not the identity, ``inf``
    if not allowed), the cheapest's residual on the usable rows, the cost row. Returns the
    residual, the Jacobian in key order and the choice."""
    table = body.table(values.atVector(shape_key()), keypoints=fmt)
    root, pose = values.atPose3(root_key(0)).matrix(), values.atVector(pose_key(0)).reshape(21, 3)
    P = 6 + 63 + body.shape_dim
    residual, jacobian, choice = [], [], []
    refined = [c for c, key in enumerate(camera_keys) if key is not None]
    for c, key in enumerate(camera_keys):
        camera = cameras[c] if key is None else values.atPose3(key).matrix()
        runs = []
        for h, perm in enumerate(permutations):
            run = reproject_numpy(table, root, pose, camera[None], intrinsics[c : c + 1], observed[c : c + 1, perm], weights[c : c + 1, perm] / noise_px, sigma)
            runs.append((0.5 * run.residual @ run.residual + (cost if h else 0.0) if allowed[c, h] else np.inf, run))
        h = int(np.argmin([cost_h for cost_h, _ in runs])) if np.isfinite(sigma) else 0
        run, perm = runs[h][1], permutations[h]
        usable = np.repeat((np.isfinite(observed[c, perm]).all(-1) & (weights[c, perm] > 0)), 2)
        block = np.zeros((usable.sum(), P + 6 * len(refined)))
        block[:, :P] = run.jacobian[usable, :P]
        if key is not None:
            j = P + 6 * refined.index(c)
            block[:, j : j + 6] = run.jacobian[usable, P : P + 6]
        residual.append(run.residual[usable])
        jacobian.append(block)
        choice.append(h)
    residual.append([math.sqrt(2 * cost * np.count_nonzero(choice))])
    jacobian.append(np.zeros((1, jacobian[0].shape[1])))
    return np.concatenate(residual), np.concatenate(jacobian), choice


@pytest.mark.parametrize("seed", range(6))
def test_reprojection_equals_the_numpy_reference(body, seed):
    """On random states, detections (swapped, missing, zero-weight, outlying), cameras (fixed or
    refined) and allowed hypotheses, in L2 and Geman-McClure: the factor's residual, Jacobian and
    labelling choice equal the numpy reference kernel's, hypothesis by hypothesis
    (:func:`numpy_factor`)."""
    rng = np.random.default_rng(seed)
    fmt = ("coco17", "blazepose33")[seed % 2]
    names = get_format(fmt).names
    C, K = 1 + seed % 4, len(names)
    root, pose, shape = standing_root(rng), rng.normal(scale=0.3, size=63), random_shape(body, rng)
    cameras = np.stack([look_at_body(a) for a in rng.uniform(0, 2 * np.pi, size=C)])
    intrinsics = np.column_stack([rng.uniform(800, 1200, size=(C, 2)), np.tile([640.0, 360.0], (C, 1))])
    truth = body.forward(shape, root[None], pose.reshape(1, 21, 3), keypoints=fmt).keypoints[0]
    p = np.einsum("cyx,cky->ckx", cameras[:, :3, :3], truth[None] - cameras[:, None, :3, 3])
    observed = p[..., :2] / p[..., 2:] * intrinsics[:, None, :2] + intrinsics[:, None, 2:] + rng.normal(scale=3.0, size=(C, K, 2))
    observed[rng.uniform(size=(C, K)) < 0.1] += 70.0
    observed[rng.uniform(size=(C, K)) < 0.1] = np.nan
    permutations = np.stack([swap_permutation(names, kind) for kind in SWAP_KINDS])
    for c in range(C):
        observed[c] = observed[c, permutations[rng.integers(0, 4)]]
    weights = rng.uniform(0.2, 1.0, size=(C, K)) * (rng.uniform(size=(C, K)) > 0.05)
    camera_keys = [camera_key(c, 0) if rng.uniform() < 0.7 else None for c in range(C)]
    allowed = rng.uniform(size=(C, 4)) < 0.8
    allowed[:, 0] = True
    cost, noise_px = 0.5 * rng.uniform(0, 3) ** 2, rng.uniform(0.5, 3.0)
    values = gtsam.Values()
    values.insert(root_key(0), gtsam.Pose3(root).retract(rng.normal(scale=0.03, size=6)))
    values.insert(pose_key(0), pose + rng.normal(scale=0.05, size=63))
    values.insert(shape_key(), shape)
    for c, key in enumerate(camera_keys):
        if key is not None:
            values.insert(key, gtsam.Pose3(cameras[c]).retract(rng.normal(scale=0.01, size=6)))
    scale = RobustScale()
    labelling = Labelling(permutations, cost, allowed=allowed)
    factor = reprojection_factor(
        body, ShapeTableCache(body, fmt), root_key(0), pose_key(0), shape_key(), camera_keys, [cameras[c] if key is None else None for c, key in enumerate(camera_keys)],
        intrinsics, observed, weights, fmt, scale, noise_px=noise_px, labelling=labelling,
    )  # fmt: skip
    for sigma in (math.inf, 10.0, 40.0):
        scale.sigma_px = sigma
        want_residual, want_jacobian, want_choice = numpy_factor(body, fmt, values, cameras, camera_keys, intrinsics, observed, weights, noise_px, sigma, permutations, cost, allowed)
        assert factor.error(values) == pytest.approx(0.5 * want_residual @ want_residual, rel=1e-12)
        assert labelling.choice.tolist() == want_choice
        A, b = factor.linearize(values).jacobian()
        assert max_rel_diff(-b, want_residual) < 1e-12
        assert max_rel_diff(A, want_jacobian) < 1e-10


def test_labelling_is_checked(scene):
    for bad in (PERMUTATIONS[::-1], PERMUTATIONS[:, :5], PERMUTATIONS.astype(float), np.stack([PERMUTATIONS[0], np.zeros(17, int)])):
        with pytest.raises(MocapgraphError, match="labelling.permutations"):
            labelled_factor(scene, scene.observed, Labelling(bad, cost=1.0))
    with pytest.raises(MocapgraphError, match="labelling.cost"):
        labelled_factor(scene, scene.observed, Labelling(PERMUTATIONS, cost=-1.0))


@pytest.mark.parametrize("gm_sigma_px", [8.0, math.inf])
@pytest.mark.parametrize("labelled", [False, True])
def test_reprojection_with_variable_focal_lengths(scene, gm_sigma_px, labelled):
    """Cameras 0 (refined) and 1 (fixed) with a focal log scale: at scale s the factor equals
    one built with the focal lengths multiplied by e^s; the Jacobians (the focal columns too)
    equal central differences, with and without labelling hypotheses."""
    scene.scale.sigma_px = gm_sigma_px
    focal_keys = [gtsam.symbol("f", 0), gtsam.symbol("f", 1), None]
    labelling = Labelling(PERMUTATIONS, cost=2.0) if labelled else None
    factor = reprojection_factor(
        scene.body, scene.cache, root_key(7), pose_key(7), shape_key(), scene.camera_keys, [None, scene.cameras[1], None],
        scene.intrinsics, scene.observed, scene.weights, FORMAT, scene.scale, noise_px=scene.noise_px, focal_keys=focal_keys,
        labelling=labelling,
    )  # fmt: skip
    assert list(factor.keys())[-2:] == focal_keys[:2]
    values = gtsam.Values(scene.values)
    log_scales = (0.12, -0.2)
    for key, s in zip(focal_keys, log_scales):
        values.insert(key, np.array([s]))
    scaled = scene.intrinsics.copy()
    scaled[0, :2] *= math.exp(log_scales[0])
    scaled[1, :2] *= math.exp(log_scales[1])
    plain = reprojection_factor(
        scene.body, scene.cache, root_key(7), pose_key(7), shape_key(), scene.camera_keys, [None, scene.cameras[1], None],
        scaled, scene.observed, scene.weights, FORMAT, scene.scale, noise_px=scene.noise_px, labelling=labelling,
    )  # fmt: skip
    assert factor.error(values) == pytest.approx(plain.error(values), rel=1e-12)
    assert_jacobians(factor, values)
    with pytest.raises(MocapgraphError, match="focal_keys"):
        reprojection_factor(
            scene.body, scene.cache, root_key(7), pose_key(7), shape_key(), scene.camera_keys, [None, scene.cameras[1], None],
            scene.intrinsics, scene.observed, scene.weights, FORMAT, scene.scale, focal_keys=focal_keys[:2],
        )  # fmt: skip


@pytest.mark.parametrize("gm_sigma_px", [8.0, math.inf])
@pytest.mark.parametrize("variant", ["plain", "labelled, focal", "interpolated, fixed shape"])
def test_reprojection_with_keypoint_offset_variables(scene, gm_sigma_px, variant):
    """The format's keypoint offsets as a variable: at parameters θ the factor equals one whose
    tables carry the offsets ``basis @ θ`` as constants; its Jacobians (the offsets' columns,
    through the shape table's extra columns) equal central differences, with labelling
    hypotheses, a focal length, an interpolated state and a fixed shape too."""
    scene.scale.sigma_px = gm_sigma_px
    basis = offset_basis(scene.body.table(scene.shape, keypoints=FORMAT))
    assert basis.shape == (17, 3, 2 + 3 * 8)  # the nose (up, forward) and eight left/right pairs
    theta = np.random.default_rng(5).normal(scale=0.03, size=basis.shape[-1])
    variable, constant = ShapeTableCache(scene.body, FORMAT, offset_basis=basis), ShapeTableCache(scene.body, FORMAT, offsets=basis @ theta)
    extra, values = {}, gtsam.Values(scene.values)
    if variant == "labelled, focal":
        extra = {"labelling": Labelling(PERMUTATIONS, cost=2.0), "focal_keys": [gtsam.symbol("f", 0), None, None]}
        values.insert(gtsam.symbol("f", 0), np.array([0.1]))
    if variant == "interpolated, fixed shape":
        extra = {"next_state": (root_key(8), pose_key(8)), "fraction": 0.3}
        values = two_states(scene)
    shape = {"shape_key": None, "fixed_shape": scene.shape} if "fixed shape" in variant else {"shape_key": shape_key()}

    def factor(cache, **more):
        return reprojection_factor(
            scene.body, cache, root_key(7), pose_key(7), camera_keys=scene.camera_keys, fixed_cameras=[None, scene.cameras[1], None],
            intrinsics=scene.intrinsics, observed=scene.observed, weights=scene.weights, keypoint_format=FORMAT, scale=scene.scale,
            noise_px=scene.noise_px, **shape, **extra, **more,
        )  # fmt: skip

    with_offsets = factor(variable, offset_key=gtsam.symbol("k", 0))
    assert list(with_offsets.keys())[-1] == gtsam.symbol("k", 0)
    values.insert(gtsam.symbol("k", 0), theta)
    assert with_offsets.error(values) == pytest.approx(factor(constant).error(values), rel=1e-10)
    assert with_offsets.error(values) != pytest.approx(factor(scene.cache).error(values), rel=1e-3)
    assert_jacobians(with_offsets, values)
    with pytest.raises(MocapgraphError, match="offset_basis"):
        factor(scene.cache, offset_key=gtsam.symbol("k", 0))


@pytest.mark.parametrize("gm_sigma_px", [8.0, math.inf])
def test_reprojection_with_a_shared_focal_length(scene, gm_sigma_px):
    """Cameras 0 and 2 on one focal key: the factor equals one with both their focal lengths
    scaled by e^s, has that key once, and its Jacobian (the one shared column) equals central differences."""
    scene.scale.sigma_px = gm_sigma_px
    shared = gtsam.symbol("f", 9)
    factor = reprojection_factor(
        scene.body, scene.cache, root_key(7), pose_key(7), shape_key(), scene.camera_keys, [None, scene.cameras[1], None],
        scene.intrinsics, scene.observed, scene.weights, FORMAT, scene.scale, noise_px=scene.noise_px, focal_keys=[shared, None, shared],
    )  # fmt: skip
    assert list(factor.keys()).count(shared) == 1
    values = gtsam.Values(scene.values)
    values.insert(shared, np.array([-0.15]))
    scaled = scene.intrinsics.copy()
    scaled[[0, 2], :2] *= math.exp(-0.15)
    plain = reprojection_factor(
        scene.body, scene.cache, root_key(7), pose_key(7), shape_key(), scene.camera_keys, [None, scene.cameras[1], None],
        scaled, scene.observed, scene.weights, FORMAT, scene.scale, noise_px=scene.noise_px,
    )  # fmt: skip
    assert factor.error(values) == pytest.approx(plain.error(values), rel=1e-12)
    assert_jacobians(factor, values)


def interpolated_factor(scene, fraction: float, shape=True):
    """The scene's observations explained by the state ``fraction`` of the way from state 7 to 8."""
    return reprojection_factor(
        scene.body, scene.cache, root_key(7), pose_key(7), shape_key() if shape else None, scene.camera_keys,
        [None, scene.cameras[1], None], scene.intrinsics, scene.observed, scene.weights, FORMAT, scene.scale,
        noise_px=scene.noise_px, fixed_shape=None if shape else scene.shape, next_state=(root_key(8), pose_key(8)),
        fraction=fraction,
    )  # fmt: skip


def two_states(scene, seed: int = 3) -> gtsam.Values:
    """The scene's values plus a next state 8 a few degrees and centimetres away from state 7."""
    rng = np.random.default_rng(seed)
    values = gtsam.Values(scene.values)
    values.insert(root_key(8), values.atPose3(root_key(7)).retract(rng.normal(scale=0.1, size=6)))
    values.insert(pose_key(8), values.atVector(pose_key(7)) + rng.normal(scale=0.1, size=63))
    return values


@pytest.mark.parametrize("gm_sigma_px", [8.0, math.inf])
def test_interpolated_reprojection_jacobian(scene, gm_sigma_px):
    """Between two grid states: Jacobians of both states (through the slerp) equal central differences."""
    scene.scale.sigma_px = gm_sigma_px
    factor = interpolated_factor(scene, 0.37)
    assert list(factor.keys()) == [root_key(7), pose_key(7), root_key(8), pose_key(8), shape_key(), camera_key(0, 7), camera_key(2, 7)]
    assert_jacobians(factor, two_states(scene))
    assert_jacobians(interpolated_factor(scene, 0.8, shape=False), two_states(scene, seed=4))


def test_interpolated_reprojection_equals_the_interpolated_state(scene):
    """The residual equals the single-state factor at an independently interpolated state
    (scipy's slerp of the root rotation, linear pelvis and joint rotation vectors), and the
    fraction's ends reproduce the two states."""
    from scipy.spatial.transform import Rotation, Slerp

    scene.scale.sigma_px = 8.0
    values = two_states(scene)
    r7, r8 = values.atPose3(root_key(7)), values.atPose3(root_key(8))
    q7, q8 = values.atVector(pose_key(7)), values.atVector(pose_key(8))
    for a in (1e-9, 0.25, 0.5, 1 - 1e-9):
        rotation = Slerp([0.0, 1.0], Rotation.from_matrix([r7.rotation().matrix(), r8.rotation().matrix()]))([a])
        middle = gtsam.Values(values)
        middle.update(root_key(7), gtsam.Pose3(gtsam.Rot3(rotation.as_matrix()[0]), (1 - a) * r7.translation() + a * r8.translation()))
        middle.update(pose_key(7), (1 - a) * q7 + a * q8)
        np.testing.assert_allclose(
            interpolated_factor(scene, a).whitenedError(values), scene.factor.whitenedError(middle), rtol=1e-9, atol=1e-9
        )


def test_interpolated_reprojection_rejects_bad_fractions(scene):
    for bad in (0.0, 1.0, -0.1, 1.5):
        with pytest.raises(MocapgraphError, match="fraction"):
            interpolated_factor(scene, bad)
    with pytest.raises(MocapgraphError, match="needs next_state"):
        reprojection_factor(
            scene.body, scene.cache, root_key(7), pose_key(7), shape_key(), scene.camera_keys, [None, scene.cameras[1], None],
            scene.intrinsics, scene.observed, scene.weights, FORMAT, scene.scale, fraction=0.5,
        )  # fmt: skip
    with pytest.raises(MocapgraphError, match="must all differ"):
        reprojection_factor(
            scene.body, scene.cache, root_key(7), pose_key(7), shape_key(), scene.camera_keys, [None, scene.cameras[1], None],
            scene.intrinsics, scene.observed, scene.weights, FORMAT, scene.scale, next_state=(root_key(7), pose_key(8)),
            fraction=0.5,
        )  # fmt: skip


def test_reprojection_annealing_changes_the_error(scene):
    """Changing scale.sigma_px between evaluations changes the cost, without a new factor."""
    scene.scale.sigma_px = math.inf
    l2 = scene.factor.error(scene.values)
    scene.scale.sigma_px = 8.0
    gm = scene.factor.error(scene.values)
    scene.scale.sigma_px = 2.0
    tighter = scene.factor.error(scene.values)
    assert l2 > gm > tighter  # GM saturates the outliers, more so at a smaller scale
    e = scene.independent_residual(scene.values)
    assert tighter == pytest.approx(0.5 * e @ e, rel=1e-10)


def test_robust_scale_rejects_invalid_values():
    scale = RobustScale()
    assert not scale.is_robust
    scale.sigma_px = 5
    assert scale.is_robust and scale.sigma_px == 5.0
    for bad in (0.0, -1.0, float("nan"), "x"):
        with pytest.raises(MocapgraphError):
            scale.sigma_px = bad


def test_shape_table_cache_rebuilds_only_on_change(body):
    """Same shape: no build; new shape: one build; the previous shape is still cached (size 2)."""
    cache = ShapeTableCache(body, FORMAT)
    a = body.default_shape
    b = a.copy()
    b[2] += 0.01
    t = cache(a)
    assert cache.builds == 1
    assert cache(a.copy()) is t and cache.builds == 1
    assert cache(b) is not t and cache.builds == 2
    assert cache(a) is t and cache.builds == 2
    c = b.copy()
    c[0] += 0.01
    cache(c)  # evicts b, the least recently used
    assert cache.builds == 3
    cache(b)
    assert cache.builds == 4
    one = ShapeTableCache(body, FORMAT, size=1)
    for shape in (a, b, a):
        one(shape)
    assert one.builds == 3


def test_factors_sharing_a_cache_build_one_table(scene):
    """Re-evaluating and linearising at one shape builds no new table."""
    scene.factor.error(scene.values)
    before = scene.cache.builds
    for _ in range(3):
        scene.factor.error(scene.values)
        scene.factor.linearize(scene.values)
    assert scene.cache.builds == before


def test_reprojection_shape_outside_bounds_is_an_error(scene):
    """A shape outside the body's box fails loudly, naming the parameter (no silent clamping)."""
    values = gtsam.Values(scene.values)
    shape = values.atVector(shape_key())
    shape[0] = 1.5
    values.update(shape_key(), shape)
    with pytest.raises(MocapgraphError, match=scene.body.shape_names[0]):
        scene.factor.error(values)


def test_reprojection_rejects_inconsistent_cameras(body):
    cache = ShapeTableCache(body, FORMAT)
    args = dict(
        intrinsics=np.tile(INTRINSICS, (2, 1)),
        observed=np.zeros((2, 17, 2)),
        weights=np.ones((2, 17)),
        keypoint_format=FORMAT,
        scale=RobustScale(),
    )
    with pytest.raises(MocapgraphError, match="camera 1"):
        reprojection_factor(body, cache, 1, 2, 3, [10, 11], [None, np.eye(4)], **args)
    with pytest.raises(MocapgraphError, match="table_cache"):
        reprojection_factor(body, ShapeTableCache(body, "body"), 1, 2, 3, [10, 11], [None, None], **args)
    with pytest.raises(MocapgraphError, match="observed"):
        reprojection_factor(body, cache, 1, 2, 3, [10, 11], [None, None], **{**args, "observed": np.zeros((2, 23, 2))})


# ---------------------------------------------------------------------------------------------
# Pose3 priors and smoothness (built-in factors)


@pytest.mark.parametrize("kernel", ["huber", "cauchy", "gm"])
def test_camera_prior_error_and_jacobian(kernel):
    """error = the mEstimator's loss of the Mahalanobis distance; the linearisation is GTSAM's
    reweighting √w(d) of the exact Gaussian-whitened Jacobian, checked by central differences."""
    rng = np.random.default_rng(1)
    prior, x = random_pose3(rng), random_pose3(rng)
    L = rng.normal(scale=0.05, size=(6, 6))
    cov = L @ L.T + np.diag([1e-3] * 3 + [4e-3] * 3)
    factor = camera_prior_factor(5, prior.matrix(), cov, kernel=kernel, k=2.0)
    values = gtsam.Values()
    values.insert(5, x)

    info_sqrt = np.linalg.cholesky(np.linalg.inv(cov)).T  # Σ⁻¹ = RᵀR

    def whitened(v):
        return info_sqrt @ gtsam.Pose3.Logmap(prior.between(v.atPose3(5)))

    distance = np.linalg.norm(whitened(values))
    estimator = {
        "huber": gtsam.noiseModel.mEstimator.Huber,
        "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
        "gm": gtsam.noiseModel.mEstimator.GemanMcClure,
    }[kernel].Create(2.0)
    assert factor.error(values) == pytest.approx(estimator.loss(distance), rel=1e-9)
    A, b = factor.linearize(values).jacobian()
    root_w = math.sqrt(estimator.weight(distance))
    numeric = numerical_jacobian(whitened, factor, values)
    assert np.linalg.norm(b) == pytest.approx(root_w * distance, rel=1e-9)
    assert max_rel_diff(A, root_w * numeric) < 1e-6
    # Whitening is in the covariance's metric whatever the square root: compare AᵀA.
    np.testing.assert_allclose(A.T @ A, root_w**2 * numeric.T @ numeric, rtol=1e-6, atol=1e-8)


def test_camera_prior_with_sigmas_and_without_kernel():
    rng = np.random.default_rng(2)
    prior, x = random_pose3(rng, 0.3), random_pose3(rng, 0.3)
    values = gtsam.Values()
    values.insert(1, x)
    sigmas = np.array([0.01, 0.02, 0.03, 0.1, 0.2, 0.3])
    e = gtsam.Pose3.Logmap(prior.between(x)) / sigmas
    plain = camera_prior_factor(1, prior.matrix(), sigmas=sigmas, kernel="none")
    assert plain.error(values) == pytest.approx(0.5 * e @ e, rel=1e-9)
    huber = camera_prior_factor(1, prior.matrix(), sigmas=sigmas)
    assert huber.error(values) == pytest.approx(gtsam.noiseModel.mEstimator.Huber.Create(1.345).loss(np.linalg.norm(e)))
    with pytest.raises(MocapgraphError, match="exactly one"):
        camera_prior_factor(1, prior.matrix())
    with pytest.raises(MocapgraphError, match="kernel"):
        camera_prior_factor(1, prior.matrix(), sigmas=sigmas, kernel="tukey")


@pytest.mark.parametrize("which", ["root", "camera"])
def test_pose3_smoothness_error_and_jacobian(which):
    """½‖Log(T_a⁻¹T_b) / (σ·dt)‖²; Jacobians by central differences."""
    rng = np.random.default_rng(3)
    a, b = random_pose3(rng), random_pose3(rng)
    values = gtsam.Values()
    values.insert(1, a)
    values.insert(2, b)
    dt = 0.04
    if which == "root":
        factor = root_smoothness_factor(1, 2, dt, (0.5, 0.8))
    else:
        factor = camera_smoothness_factor(1, 2, dt, 0.5, 0.8)
    sigmas = np.array([0.5] * 3 + [0.8] * 3) * dt
    e = gtsam.Pose3.Logmap(a.between(b)) / sigmas
    assert factor.error(values) == pytest.approx(0.5 * e @ e, rel=1e-9)
    assert_jacobians(factor, values)


def test_camera_acceleration_error_and_jacobian():
    """The three-point second derivative of the centres over σ (uneven steps), against one
    computed from the velocities of the two steps; zero along a constant velocity whatever the
    rotations; Jacobians by central differences."""
    rng = np.random.default_rng(5)
    poses = [random_pose3(rng) for _ in range(3)]
    times = np.array([0.10, 0.14, 0.19])
    values = gtsam.Values()
    for k, pose in enumerate(poses, start=1):
        values.insert(k, pose)
    factor = camera_acceleration_factor([1, 2, 3], times, 3.0)
    p = [pose.translation() for pose in poses]
    v01, v12 = (p[1] - p[0]) / 0.04, (p[2] - p[1]) / 0.05
    acceleration = (v12 - v01) / ((times[2] - times[0]) / 2)
    assert factor.error(values) == pytest.approx(0.5 * np.sum((acceleration / 3.0) ** 2), rel=1e-9)
    assert_jacobians(factor, values)
    steady = gtsam.Values()
    for k, t in enumerate(times, start=1):
        steady.insert(k, gtsam.Pose3(random_pose3(rng).rotation(), np.array([1.0, -2.0, 0.5]) + t * np.array([0.7, 1.3, -0.2])))
    assert factor.error(steady) == pytest.approx(0.0, abs=1e-20)
    with pytest.raises(MocapgraphError, match="3 consecutive"):
        camera_acceleration_factor([1, 2], times[:2], 3.0)


def test_rotation_acceleration_factor_penalises_a_change_of_angular_velocity():
    rng = np.random.default_rng(11)
    times = np.array([0.0, 0.04, 0.09])
    poses = [random_pose3(rng, 0.3) for _ in times]
    values = gtsam.Values()
    for k, pose in enumerate(poses, start=1):
        values.insert(k, pose)
    factor = rotation_acceleration_factor([1, 2, 3], times, 2.0)
    # independent: scipy's rotation vectors of the two steps
    R = [Rotation.from_matrix(p.rotation().matrix()) for p in poses]
    w01, w12 = (R[0].inv() * R[1]).as_rotvec() / 0.04, (R[1].inv() * R[2]).as_rotvec() / 0.05
    acceleration = (w12 - w01) / ((times[2] - times[0]) / 2)
    assert factor.error(values) == pytest.approx(0.5 * np.sum((acceleration / 2.0) ** 2), rel=1e-9)
    assert_jacobians(factor, values)
    # turning at a constant body-frame rate, anywhere, with any translations: no cost
    start, omega = Rotation.from_rotvec(rng.normal(size=3)), np.array([0.8, -1.5, 2.0])
    steady = gtsam.Values()
    for k, t in enumerate(times, start=1):
        steady.insert(k, gtsam.Pose3(gtsam.Rot3((start * Rotation.from_rotvec(omega * t)).as_matrix()), rng.normal(size=3)))
    assert factor.error(steady) == pytest.approx(0.0, abs=1e-20)
    with pytest.raises(MocapgraphError, match="3 consecutive"):
        rotation_acceleration_factor([1, 2], times[:2], 2.0)


def test_root_smoothness_takes_six_sigmas():
    rng = np.random.default_rng(4)
    values = gtsam.Values()
    values.insert(1, random_pose3(rng, 0.2))
    values.insert(2, random_pose3(rng, 0.2))
    sigmas = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    e = gtsam.Pose3.Logmap(values.atPose3(1).between(values.atPose3(2))) / (sigmas * 0.5)
    assert root_smoothness_factor(1, 2, 0.5, sigmas).error(values) == pytest.approx(0.5 * e @ e, rel=1e-9)
    with pytest.raises(MocapgraphError, match="dt"):
        root_smoothness_factor(1, 2, 0.0, sigmas)


# ---------------------------------------------------------------------------------------------
# Linear vector factors


def vector_values(rng, keys, dim) -> gtsam.Values:
    values = gtsam.Values()
    for key in keys:
        values.insert(key, rng.normal(size=dim))
    return values


def test_pose_smoothness_is_the_second_derivative_for_uneven_steps():
    """On a quadratic θ(t) = a + b t + ½ c t², the residual is c / σ for any time steps."""
    rng = np.random.default_rng(5)
    a, b, c = rng.normal(size=(3, 63))
    sigma = rng.uniform(0.5, 2.0, size=63)
    times = np.array([0.1, 0.13, 0.21])  # steps of 30 ms and 80 ms
    keys = [pose_key(i) for i in range(3)]
    values = gtsam.Values()
    for key, t in zip(keys, times):
        values.insert(key, a + b * t + 0.5 * c * t * t)
    factor = pose_smoothness_factor(keys, times, sigma)
    np.testing.assert_allclose(factor.whitenedError(values), c / sigma, rtol=1e-7, atol=1e-7)
    assert factor.error(values) == pytest.approx(0.5 * np.sum((c / sigma) ** 2), rel=1e-7)
    assert_jacobians(factor, vector_values(rng, keys, 63))
    with pytest.raises(MocapgraphError, match="increase"):
        pose_smoothness_factor(keys, [0.0, 0.2, 0.1], 1.0)


def test_pose_velocity_factor():
    rng = np.random.default_rng(6)
    values = vector_values(rng, [pose_key(0), pose_key(1)], 63)
    factor = pose_velocity_factor(pose_key(0), pose_key(1), 0.05, 2.0)
    e = (values.atVector(pose_key(1)) - values.atVector(pose_key(0))) / (0.05 * 2.0)
    assert factor.error(values) == pytest.approx(0.5 * e @ e, rel=1e-12)
    assert_jacobians(factor, values)


def test_shape_prior_factor(body):
    rng = np.random.default_rng(7)
    values = vector_values(rng, [shape_key()], body.shape_dim)
    sigma = rng.uniform(0.1, 0.3, size=body.shape_dim)
    factor = shape_prior_factor(shape_key(), body.default_shape, sigma)
    e = (values.atVector(shape_key()) - body.default_shape) / sigma
    assert factor.error(values) == pytest.approx(0.5 * e @ e, rel=1e-12)
    assert_jacobians(factor, values)
    scalar = shape_prior_factor(shape_key(), body.default_shape, 0.2)
    e = (values.atVector(shape_key()) - body.default_shape) / 0.2
    assert scalar.error(values) == pytest.approx(0.5 * e @ e, rel=1e-12)


def test_pose_regularizer_factor():
    rng = np.random.default_rng(8)
    values = vector_values(rng, [pose_key(3)], 63)
    theta = values.atVector(pose_key(3))
    zero_mean = pose_regularizer_factor(pose_key(3), 0.5)
    assert zero_mean.error(values) == pytest.approx(0.5 * np.sum((theta / 0.5) ** 2), rel=1e-12)
    mean = rng.normal(size=(21, 3))
    sigma = rng.uniform(0.2, 1.0, size=63)
    factor = pose_regularizer_factor(pose_key(3), sigma, mean=mean)
    e = (theta - mean.reshape(63)) / sigma
    assert factor.error(values) == pytest.approx(0.5 * e @ e, rel=1e-12)
    assert_jacobians(factor, values)
    with pytest.raises(MocapgraphError, match="sigma"):
        pose_regularizer_factor(pose_key(3), -1.0)


# ---------------------------------------------------------------------------------------------
# End to end


def test_gauss_newton_recovers_a_known_body(body):
    """Noise-free observations from 3 fixed cameras: Gauss-Newton from a perturbed state converges.

    COCO-17 does not see every joint rotation (wrists, ankles and feet twist freely; the spine's
    bend splits among three joints), so a weak pose prior fixes those directions. It is centred
    on the truth, where the reprojection cost is zero as well, so it moves no optimum; likewise
    the shape prior. The root has no prior at all.
    """
    rng = np.random.default_rng(9)
    root = standing_root(rng)
    pose = rng.normal(scale=0.3, size=63)
    shape = random_shape(body, rng)
    cameras = np.stack([look_at_body(a) for a in (0.2, 2.3, 4.3)])
    intrinsics = np.tile(INTRINSICS, (3, 1))
    truth = body.forward(shape, root[None], pose.reshape(1, 21, 3), keypoints=FORMAT)
    p = np.einsum("cyx,cky->ckx", cameras[:, :3, :3], truth.keypoints[0][None] - cameras[:, None, :3, 3])
    observed = p[..., :2] / p[..., 2:] * intrinsics[:, None, :2] + intrinsics[:, None, 2:]

    scale = RobustScale()
    graph = gtsam.NonlinearFactorGraph()
    graph.add(
        reprojection_factor(
            body,
            ShapeTableCache(body, FORMAT),
            root_key(0),
            pose_key(0),
            shape_key(),
            [None] * 3,
            list(cameras),
            intrinsics,
            observed,
            np.ones((3, 17)),
            FORMAT,
            scale,
        )
    )
    graph.add(pose_regularizer_factor(pose_key(0), 1.0, mean=pose))
    graph.add(shape_prior_factor(shape_key(), shape, 0.05))

    values = gtsam.Values()
    values.insert(root_key(0), gtsam.Pose3(root).retract(rng.normal(scale=0.1, size=6)))  # ~6°, ~10 cm
    values.insert(pose_key(0), pose + rng.normal(scale=0.1, size=63))
    values.insert(shape_key(), shape + rng.uniform(-0.03, 0.03, size=body.shape_dim))
    start_error = graph.error(values)

    for iteration in range(8):
        if iteration == 5:
            scale.sigma_px = 10.0  # anneal to Geman-McClure for the last steps
        gfg = graph.linearize(values)
        values = values.retract(gfg.optimize())

    assert graph.error(values) < 1e-12 * max(1.0, start_error)
    got = body.forward(
        values.atVector(shape_key()),
        values.atPose3(root_key(0)).matrix()[None],
        values.atVector(pose_key(0)).reshape(1, 21, 3),
    )
    assert np.abs(got.joints[0] - truth.joints[0]).max() < 1e-3  # metres
    assert np.linalg.norm(gtsam.Pose3.Logmap(gtsam.Pose3(root).between(values.atPose3(root_key(0))))) < 1e-6


# ---------------------------------------------------------------------------------------------
# Interpolation between grid states


@pytest.mark.parametrize("angle", [0.0, 1e-7, 0.05, 1.0, 3.0, np.pi - 1e-6])
def test_native_interpolation_matches_the_gtsam_reference(angle):
    """The native slerp and its Jacobians equal the GTSAM-Rot3 reference at every angle up to π,
    and both equal central differences through Pose3.retract."""
    from mocapgraph.factors.interpolation import interpolate_root, interpolate_root_reference

    rng = np.random.default_rng(int(angle * 1000))
    axis = rng.normal(size=3)
    first = random_pose3(rng)
    second = first.compose(gtsam.Pose3(gtsam.Rot3.Expmap(angle * axis / np.linalg.norm(axis)), rng.normal(size=3)))
    for a in (0.0, 0.3, 0.5, 1.0):
        got = interpolate_root(first.matrix(), second.matrix(), a)
        want = interpolate_root_reference(first, second, a)
        for g, w in zip(got, want):
            np.testing.assert_allclose(g, w, rtol=0, atol=1e-9)
        if angle > np.pi - 1e-3:
            continue  # Log's branch flips under a 1e-6 perturbation at π: no derivative there
        middle = gtsam.Pose3(got[0])
        h = 1e-6
        for which, A in ((0, got[1]), (1, got[2])):
            numeric = np.zeros((6, 6))
            for k in range(6):
                step = np.zeros(6)
                step[k] = h
                ends = [[first, second], [first, second]]
                ends[0][which] = ends[0][which].retract(step)
                ends[1][which] = ends[1][which].retract(-step)
                plus, minus = (gtsam.Pose3(interpolate_root(e[0].matrix(), e[1].matrix(), a)[0]) for e in ends)
                numeric[:, k] = (middle.localCoordinates(plus) - middle.localCoordinates(minus)) / (2 * h)
            np.testing.assert_allclose(A, numeric, rtol=0, atol=1e-7)


def test_native_interpolation_rejects_bad_input():
    from mocapgraph.body.native import native_module

    with pytest.raises(ValueError, match="fraction"):
        native_module().interpolate_pose(np.eye(4), np.eye(4), 1.5)
    with pytest.raises(ValueError, match="not a rotation"):
        native_module().interpolate_pose(2 * np.eye(4), np.eye(4), 0.5)
