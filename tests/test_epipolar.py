"""Two-view geometry of body keypoints (``data_tools.geometry.epipolar``) against known cameras.

The rig: four cameras around a person walking a circle (the body model's ``turn`` motion, COCO-17
keypoints), projected exactly and with Gaussian pixel noise; left/right swaps injected in runs.
"""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest

from mocapgraph.body import load_body_model
from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import SWAP_KINDS, swap_permutation
from mocapgraph.data_tools.geometry import epipolar as E
from mocapgraph.data_tools.geometry.camera_model import project_points
from mocapgraph.data_tools.sim.motion_sources import procedural_motion
from mocapgraph.data_tools.sim.scenarios import look_at
from mocapgraph.errors import MocapgraphError

NAMES = get_format("coco17").names
NOISE_PX = 2.0


def rotation_error_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1.0) / 2.0, -1.0, 1.0))))


def relative(world_T_a: np.ndarray, world_T_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` with ``X_b = R X_a + t``, ``‖t‖ = 1``."""
    b_T_a = np.linalg.inv(world_T_b) @ world_T_a
    return b_T_a[:3, :3], b_T_a[:3, 3] / np.linalg.norm(b_T_a[:3, 3])


@pytest.fixture(scope="module")
def scene():
    """Keypoints ``(N, 17, 3)`` of 150 frames, four cameras, exact and noisy pixels."""
    body = load_body_model()
    motion = procedural_motion("turn", 5.5, seed=3, body=body)
    times = np.arange(150) / 30.0
    root, pose = motion.sample(times)
    points = body.forward(motion.shape, root, pose, keypoints="coco17").keypoints
    centre = points[..., :2].reshape(-1, 2).mean(axis=0)
    angles = np.radians([10.0, 95.0, 190.0, 280.0])
    poses = np.stack(
        [look_at([centre[0] + 5.5 * np.cos(a), centre[1] + 5.5 * np.sin(a), 1.8 + 0.2 * k], [centre[0], centre[1], 0.9]) for k, a in enumerate(angles)]
    )
    K = np.array([[1000.0, 0.0, 960.0], [0.0, 1000.0, 540.0], [0.0, 0.0, 1.0]])
    Ks = np.stack([K] * 4)
    exact = np.stack([project_points(points, T, K)[0] for T in poses])
    rng = np.random.default_rng(0)
    noisy = exact + rng.normal(0.0, NOISE_PX, exact.shape)
    return {"points": points, "poses": poses, "Ks": Ks, "exact": exact, "noisy": noisy, "w": np.ones(exact.shape[:3])}


def test_normalised_inverts_the_intrinsics():
    K = np.array([[900.0, 1.5, 640.0], [0.0, 950.0, 360.0], [0.0, 0.0, 1.0]])
    rays = np.random.default_rng(1).normal(size=(20, 2))
    pixels = (np.column_stack([rays, np.ones(20)]) @ K.T)[:, :2]
    np.testing.assert_allclose(E.normalised(pixels, K), rays, atol=1e-12)


def test_sampson_distance_matches_the_optimal_correction(scene):
    """For small errors the Sampson distance is the total image displacement of the optimal
    correction (Hartley–Sturm, ``cv2.correctMatches``), and zero for exact correspondences."""
    R, t = relative(scene["poses"][0], scene["poses"][1])
    F = E.fundamental_matrix(E._skew(t) @ R, scene["Ks"][0], scene["Ks"][1])
    xa, xb = scene["exact"][0].reshape(-1, 2), scene["exact"][1].reshape(-1, 2)
    assert np.nanmax(E.sampson_px(F, xa, xb)) < 1e-6
    xa, xb = scene["noisy"][0].reshape(-1, 2), scene["noisy"][1].reshape(-1, 2)
    ca, cb = cv2.correctMatches(F, xa[None], xb[None])
    optimal = np.sqrt(np.sum((ca[0] - xa) ** 2 + (cb[0] - xb) ** 2, axis=1))
    np.testing.assert_allclose(E.sampson_px(F, xa, xb), optimal, rtol=1e-3, atol=1e-6)


@pytest.mark.parametrize("a, b", [(0, 1), (0, 2), (1, 3)])  # (0, 2) and (1, 3) face each other across the person
def test_relative_pose_of_each_pair(scene, a, b):
    both = np.ones(scene["noisy"].shape[1:3], dtype=bool)
    g = E.relative_pose(scene["noisy"][a][both], scene["noisy"][b][both], scene["Ks"][a], scene["Ks"][b], threshold_px=15.0, a=a, b=b)
    R, t = relative(scene["poses"][a], scene["poses"][b])
    assert rotation_error_deg(g.R, R) < 0.3
    assert np.degrees(np.arccos(np.clip(g.t @ t, -1, 1))) < 0.5
    assert g.inliers > 0.97 * g.correspondences and g.median_angle_deg > 30
    np.testing.assert_allclose(np.linalg.norm(g.t), 1.0)
    # E is the essential matrix of (R, t), F its pixel version.
    np.testing.assert_allclose(g.E, E._skew(g.t) @ g.R, atol=1e-12)
    np.testing.assert_allclose(g.F, np.linalg.inv(scene["Ks"][b]).T @ g.E @ np.linalg.inv(scene["Ks"][a]), atol=1e-15)


def test_refine_pose_returns_to_the_truth_from_a_degree_off(scene):
    R, t = relative(scene["poses"][0], scene["poses"][1])
    xa, xb = scene["exact"][0].reshape(-1, 2), scene["exact"][1].reshape(-1, 2)
    turned = cv2.Rodrigues(np.radians([0.7, -0.5, 0.4]))[0] @ R
    R2, t2 = E.refine_pose(turned, t + [0.01, -0.02, 0.0], xa, xb, scene["Ks"][0], scene["Ks"][1], scale_px=3.0)
    assert rotation_error_deg(R2, R) < 1e-4 and np.linalg.norm(t2 - t) < 1e-5


def test_too_few_correspondences_give_no_geometry(scene):
    x = scene["exact"][0].reshape(-1, 2)[: E.MIN_CORRESPONDENCES - 1]
    assert E.relative_pose(x, x + 5.0, scene["Ks"][0], scene["Ks"][1], threshold_px=15.0) is None


def test_triangulate_pair_matches_opencv(scene):
    g = E.relative_pose(scene["noisy"][0].reshape(-1, 2), scene["noisy"][1].reshape(-1, 2), scene["Ks"][0], scene["Ks"][1], threshold_px=15.0)
    xa, xb = scene["noisy"][0][:5], scene["noisy"][1][:5]
    mine = E.triangulate_pair(g, xa, xb, scene["Ks"][0], scene["Ks"][1]).reshape(-1, 3)
    na, nb = E.normalised(xa, scene["Ks"][0]).reshape(-1, 2), E.normalised(xb, scene["Ks"][1]).reshape(-1, 2)
    h = cv2.triangulatePoints(np.hstack([np.eye(3), np.zeros((3, 1))]), np.hstack([g.R, g.t[:, None]]), na.T, nb.T)
    # Midpoint and DLT agree to well under the noise (the baseline is 1 here, the person ~0.8 away).
    np.testing.assert_allclose(mine, (h[:3] / h[3]).T, atol=2e-3)
    assert np.isnan(E.triangulate_pair(g, np.full((1, 2), np.nan), xb[0, :1], scene["Ks"][0], scene["Ks"][1])).all()


def test_apply_labels_swaps_and_restores():
    values = np.arange(2 * 3 * 17 * 2, dtype=float).reshape(2, 3, 17, 2)
    labels = np.array([[0, 1, 2], [3, 0, 1]])
    out = E.apply_labels(values, labels, NAMES)
    np.testing.assert_array_equal(out[0, 0], values[0, 0])
    np.testing.assert_array_equal(out[0, 1], values[0, 1][swap_permutation(NAMES, "body")])
    np.testing.assert_array_equal(out[1, 0], values[1, 0][swap_permutation(NAMES, "legs")])
    np.testing.assert_array_equal(E.apply_labels(out, labels, NAMES), values)


def test_decide_labels_is_the_optimal_path():
    """Viterbi against every path of a small problem, with the costs the docstring states."""
    rng = np.random.default_rng(5)
    nats = rng.normal(0.0, 4.0, (6, len(SWAP_KINDS)))
    nats[2] = np.nan
    got = E.decide_labels(nats)

    def cost(path):
        unary = sum(np.nan_to_num(nats[n, k]) + (E.SWAP_NATS if k else 0.0) for n, k in enumerate(path))
        padded = (0, *path, 0)  # unswapped before the first frame and after the last
        return unary + E.SWITCH_NATS * sum(p != q for p, q in zip(padded, padded[1:]))

    best = min(itertools.product(range(len(SWAP_KINDS)), repeat=len(nats)), key=cost)
    np.testing.assert_array_equal(got, best)
    # Only the kinds asked for.
    assert set(E.decide_labels(nats, kinds=("legs",))) <= {0, SWAP_KINDS.index("legs")}


def inject(noisy: np.ndarray, runs: dict[int, list[tuple[int, int, str]]]) -> tuple[np.ndarray, np.ndarray]:
    """Detections with swaps in ``runs`` (camera → (start, length, kind)) and the truth ``(C, N)``."""
    truth = np.zeros(noisy.shape[:2], dtype=int)
    for c, spans in runs.items():
        for start, length, kind in spans:
            truth[c, start : start + length] = SWAP_KINDS.index(kind)
    return E.apply_labels(noisy, truth, NAMES), truth


def test_swap_costs_prefer_the_labels_that_undo_a_swap(scene):
    x, truth = inject(scene["noisy"], {2: [(20, 10, "body"), (60, 8, "legs"), (100, 6, "arms")]})
    pairs = E.pair_geometries(scene["noisy"], scene["w"], scene["Ks"], threshold_px=15.0)
    tables = E.pair_tables(x, scene["w"], scene["Ks"], pairs, NAMES, cap_px=15.0)
    nats = E.swap_costs(tables, np.zeros_like(truth))
    best = np.argmin(nats[2], axis=-1)
    np.testing.assert_array_equal(best, truth[2])
    # Clean cameras prefer their labels as detected where every other camera is right too (where
    # one camera is swapped, it can pull another: resolve_swaps takes the strongest evidence first).
    clean = truth[2] == 0
    assert np.all(np.argmin(nats[[0, 1, 3]][:, clean], axis=-1) == 0)
    # The objective: the truth costs less than the labels as detected by the swap's evidence
    # less the priors (every frame relabelled costs SWAP_NATS, each run two changes).
    undone = E.labelling_cost(tables, truth)
    assert undone < E.labelling_cost(tables, np.zeros_like(truth)) - 24 * E.SWAP_NATS - 6 * E.SWITCH_NATS
    # A camera's costs are the pairs' misfits under its labels and the others' current ones.
    frames = np.arange(truth.shape[1])
    np.testing.assert_allclose(nats[2, :, 1], tables[(0, 2)][frames, 0, 1] + tables[(1, 2)][frames, 0, 1] + tables[(2, 3)][frames, 1, 0])


def test_best_frames_is_exact_per_frame(scene):
    """After the move, every odd frame's labels (decided last, against their final neighbours)
    are the best of all 4⁴ joint labellings, by :func:`labelling_cost` of the whole sequence."""
    x, truth = inject(scene["noisy"], {0: [(50, 4, "body")], 1: [(51, 3, "legs")], 2: [(52, 2, "arms")]})
    pairs = E.pair_geometries(scene["noisy"], scene["w"], scene["Ks"], threshold_px=15.0)
    tables = {k: t[48:58] for k, t in E.pair_tables(x, scene["w"], scene["Ks"], pairs, NAMES, cap_px=15.0).items()}
    start = np.random.default_rng(2).integers(0, len(SWAP_KINDS), (4, 10))
    out = E.best_frames(tables, start)
    assert E.labelling_cost(tables, out) < E.labelling_cost(tables, start)
    for n in range(1, 10, 2):
        costs = []
        for state in itertools.product(range(len(SWAP_KINDS)), repeat=4):
            trial = out.copy()
            trial[:, n] = state
            costs.append(E.labelling_cost(tables, trial))
        assert E.labelling_cost(tables, out) <= min(costs) + 1e-9
    np.testing.assert_array_equal(out[:, 1::2], truth[:, 48:58][:, 1::2])


def test_resolve_swaps_finds_sustained_runs(scene):
    x, truth = inject(scene["noisy"], {1: [(5, 20, "body"), (70, 12, "legs")], 3: [(40, 15, "body"), (120, 9, "arms")]})
    check = E.resolve_swaps(x, scene["w"], scene["Ks"], NAMES, threshold_px=15.0)
    found, true = check.labels > 0, truth > 0
    precision, recall = (found & true).sum() / found.sum(), (found & true).sum() / true.sum()
    assert precision >= 0.95 and recall >= 0.95, (precision, recall)
    assert np.mean(check.labels[true] == truth[true]) >= 0.95  # and of the right kind
    R, t = relative(scene["poses"][1], scene["poses"][3])
    assert rotation_error_deg(check.pairs[(1, 3)].R, R) < 0.3


def test_anatomy_scores_tell_a_person_from_their_mirror_labels(scene):
    points = scene["points"]
    right = E.anatomy_scores(points, NAMES)
    assert np.all(right["body"] > 0.7) and np.all(right["legs"] > 0.1) and np.all(right["arms"] > 0.1)
    for kind in ("body", "legs", "arms"):
        swapped = E.anatomy_scores(points[:, swap_permutation(NAMES, kind)], NAMES)
        assert np.all(swapped[kind] < -0.1 if kind != "body" else swapped[kind] < -0.7)
    # Any right-handed frame and scale: the scores do not change.
    turn = cv2.Rodrigues(np.array([0.3, -1.0, 2.0]))[0]
    moved = E.anatomy_scores(3.0 * points @ turn.T + 1.0, NAMES)
    np.testing.assert_allclose(moved["body"], right["body"], atol=1e-9)
    # A missing point leaves the other cues.
    partial = points.copy()
    partial[:, NAMES.index("left_ear")] = np.nan
    assert np.all(E.anatomy_scores(partial, NAMES)["body"] > 0.5)


def test_absolute_labels_undo_a_swap_every_camera_shares(scene):
    """A frame swapped in every camera fits the epipolar geometry as well as the truth does; the
    body's handedness finds it."""
    x, truth = inject(scene["noisy"], {c: [(30, 10, "body")] for c in range(4)})
    pairs = E.pair_geometries(scene["noisy"], scene["w"], scene["Ks"], threshold_px=15.0)
    labels = np.zeros_like(truth)
    scores, decided = E.pair_anatomy(x, scene["w"], scene["Ks"], pairs, NAMES, labels)
    assert decided["body"].all() and np.all((scores["body"] < 0) == (truth[0] > 0))
    np.testing.assert_array_equal(E.absolute_labels(labels, np.ones_like(truth, dtype=bool), scores, decided), truth)
    # Undecided frames keep the labelling with fewer swaps.
    undecided = {k: np.zeros_like(v) for k, v in decided.items()}
    mostly = np.zeros_like(truth)
    mostly[:3, :5] = 1
    expected = np.zeros_like(truth)
    expected[3, :5] = 1
    np.testing.assert_array_equal(E.absolute_labels(mostly, np.ones_like(truth, dtype=bool), scores, undecided), expected)


def test_bad_input_is_one_clear_error(scene):
    with pytest.raises(MocapgraphError, match=r"w \(C, N, K\): expected shape"):
        E.pair_geometries(scene["noisy"], scene["w"][:, :3], scene["Ks"], threshold_px=15.0)
    with pytest.raises(MocapgraphError, match="confidences must be >= 0"):
        E.pair_geometries(scene["noisy"], -scene["w"], scene["Ks"], threshold_px=15.0)
    with pytest.raises(MocapgraphError, match="swap kinds: choose among"):
        E.decide_labels(np.zeros((3, 4)), kinds=("mirror",))
    with pytest.raises(MocapgraphError, match="names: 5 point names for 17 keypoints"):
        E.pair_tables(scene["noisy"], scene["w"], scene["Ks"], {}, NAMES[:5], cap_px=15.0)
    with pytest.raises(MocapgraphError, match="max_rounds"):
        E.resolve_swaps(scene["noisy"], scene["w"], scene["Ks"], NAMES, threshold_px=15.0, max_rounds=0)


def test_pair_from_poses_fits_exact_projections():
    """Known poses give a geometry whose Sampson distances of exact projections are zero, and
    whose relative pose maps camera a's coordinates to b's."""
    from mocapgraph.data_tools.geometry.epipolar import pair_from_poses, sampson_px

    rng = np.random.default_rng(3)
    K = np.array([[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]])

    def look(centre):
        z = -centre / np.linalg.norm(centre)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = np.column_stack([x, np.cross(z, x), z]), centre
        return T

    Ta, Tb = look(np.array([4.0, 0.5, 1.5])), look(np.array([-1.0, 3.8, 1.2]))
    X = rng.normal(scale=0.5, size=(50, 3))
    pix = []
    for T in (Ta, Tb):
        p = (X - T[:3, 3]) @ T[:3, :3]
        pix.append(p[:, :2] / p[:, 2:] @ K[:2, :2].T + K[:2, 2])
    pair = pair_from_poses(0, 1, Ta, Tb, K, K)
    assert np.max(sampson_px(pair.F, pix[0], pix[1])) < 1e-6
    Xa = (X - Ta[:3, 3]) @ Ta[:3, :3]
    Xb = (X - Tb[:3, 3]) @ Tb[:3, :3]
    scale = np.linalg.norm(Tb[:3, 3] - Ta[:3, 3])
    np.testing.assert_allclose(Xa @ pair.R.T + scale * pair.t, Xb, atol=1e-9)


def test_per_frame_geometry_of_moving_cameras(scene):
    """Poses ``(N, 4, 4)`` give one geometry per frame, each equal to the single-pose geometry of
    that frame; its triangulation too. With two cameras circling the person (no single essential
    matrix), :func:`resolve_swaps` given their poses per frame finds the runs injected into one."""
    N = scene["exact"].shape[1]
    cx, cy = scene["points"][..., :2].reshape(-1, 2).mean(axis=0)
    orbit = np.radians(np.linspace(0.0, 120.0, N))
    walkers = [
        np.stack([look_at([cx + 4.5 * np.cos(a), cy + 4.5 * np.sin(a), 1.5], [cx, cy, 0.9]) for a in orbit]),
        np.stack([look_at([cx - 4.0 * np.sin(a), cy + 4.0 * np.cos(a), 1.6], [cx, cy, 0.9]) for a in orbit]),
    ]
    poses = np.stack([np.repeat(scene["poses"][c][None], N, axis=0) for c in (0, 2)] + walkers)
    K = scene["Ks"][0]
    exact = np.stack([np.stack([project_points(scene["points"][n], poses[c, n], K)[0] for n in range(N)]) for c in range(4)])
    noisy = exact + np.random.default_rng(1).normal(0.0, NOISE_PX, exact.shape)
    pair = E.pair_from_poses(1, 2, poses[1], poses[2], K, K)
    assert pair.F.shape == (N, 3, 3) and pair.t.shape == (N, 3)
    for n in (0, N // 2, N - 1):
        single = E.pair_from_poses(1, 2, poses[1, n], poses[2, n], K, K)
        np.testing.assert_allclose(pair.F[n], single.F, atol=1e-12)
        np.testing.assert_allclose(E.triangulate_pair(pair, exact[1], exact[2], K, K)[n], E.triangulate_pair(single, exact[1, n], exact[2, n], K, K), atol=1e-9)
    assert np.max(E.sampson_px(pair.F, exact[1], exact[2])) < 1e-6
    x, truth = inject(noisy, {2: [(10, 25, "body"), (90, 8, "legs")], 3: [(50, 20, "body")]})
    labels = E.resolve_swaps(x, scene["w"], np.stack([K] * 4), NAMES, threshold_px=15.0, poses=poses).labels
    found, true = labels > 0, truth > 0
    assert (found & true).sum() / found.sum() >= 0.95 and (found & true).sum() / true.sum() >= 0.95
    assert np.mean(labels[true] == truth[true]) >= 0.95


def test_joint_labels_is_the_least_cost_labelling():
    """Over every labelling of two cameras' three frames (4⁶), none costs less than
    :func:`joint_labels`' by :func:`labelling_cost`."""
    rng = np.random.default_rng(5)
    S = len(SWAP_KINDS)
    tables = {(0, 1): rng.uniform(0.0, 12.0, (3, S, S))}
    best = E.joint_labels(tables, (2, 3))
    costs = [E.labelling_cost(tables, np.reshape(flat, (2, 3))) for flat in itertools.product(range(S), repeat=6)]
    assert E.labelling_cost(tables, best) <= min(costs) + 1e-9


def test_track_tables_tell_where_a_cameras_swap_starts_and_ends(scene):
    """One camera's own track, with a whole-body run in frames 30-49 and the person missed at 40:
    the labels as detected jump where the run starts and ends, relabelled they go on; the frame
    after the miss is compared with the one before it. The Viterbi on the tracks finds the run
    with a weak swap prior (0.5 nats a frame); at the pairs' prior of 2 nats its two jumps (20
    nats each here, 17 points) do not pay for 20 frames: the tracks tell where a camera's labels
    change, the other cameras that they are wrong."""
    x, truth = inject(scene["noisy"], {2: [(30, 20, "body")]})
    x[2, 40] = np.nan
    w = np.where(np.isfinite(x).all(-1), 1.0, 0.0)
    tracks = E.track_tables(x, w, NAMES, cap_px=15.0)
    assert tracks.shape == (4, 150, len(SWAP_KINDS), len(SWAP_KINDS))
    # only the change counts: every labelling kept, and a swap or its undoing, cost alike
    np.testing.assert_allclose(np.einsum("cnii->cni", tracks), np.repeat(tracks[:, :, :1, 0], len(SWAP_KINDS), axis=2))
    np.testing.assert_allclose(tracks[..., 0, 1], tracks[..., 1, 0])
    # an entry computed anew: each point's move less the mean move, truncated, in the log of its mean square
    move = x[2, 31] - x[2, 30]
    d = np.minimum(np.linalg.norm(move - move.mean(axis=0), axis=-1), 15.0)
    np.testing.assert_allclose(tracks[2, 31, 0, 0], 0.5 * len(NAMES) * np.log(np.mean(d**2) + 0.25))
    body = SWAP_KINDS.index("body")
    jumps = tracks[2, :, 0, body] < tracks[2, :, 0, 0]
    assert set(np.flatnonzero(jumps)) == {30, 50}
    assert np.all(tracks[2, 40] == 0) and tracks[2, 41, 0, 0] < tracks[2, 41, 0, body]  # bridged from 39
    none = np.zeros((150, len(SWAP_KINDS)))
    np.testing.assert_array_equal(E.decide_labels(none, tracks=tracks[2], swap_nats=0.5), truth[2])
    assert not np.any(E.decide_labels(none, tracks=tracks[2]))
    assert not np.any(E.decide_labels(none, tracks=tracks[0], swap_nats=0.5))  # a clean camera stays as detected
    assert np.all(E.track_tables(x, w, NAMES, cap_px=15.0, max_gap=0)[2, 41] == 0)


def test_labelling_with_tracks_is_the_least_cost():
    """With each camera's track (:func:`track_tables`) in the objective, :func:`joint_labels` is
    still the least-cost labelling over every one of two cameras' three frames (4⁶),
    :func:`best_frames` leaves the middle frame at its best labelling given the others, and
    :func:`decide_labels` finds the least-cost path of one camera."""
    rng = np.random.default_rng(6)
    S = len(SWAP_KINDS)
    tables = {(0, 1): rng.uniform(0.0, 12.0, (3, S, S))}
    tracks = rng.uniform(0.0, 12.0, (2, 3, S, S))
    best = E.joint_labels(tables, (2, 3), tracks=tracks)
    costs = [E.labelling_cost(tables, np.reshape(flat, (2, 3)), tracks=tracks) for flat in itertools.product(range(S), repeat=6)]
    assert E.labelling_cost(tables, best, tracks=tracks) <= min(costs) + 1e-9
    moved = E.best_frames(tables, rng.integers(0, S, (2, 3)), tracks=tracks)
    trials = [np.column_stack([moved[:, 0], state, moved[:, 2]]) for state in itertools.product(range(S), repeat=2)]
    assert E.labelling_cost(tables, moved, tracks=tracks) <= min(E.labelling_cost(tables, t, tracks=tracks) for t in trials) + 1e-9
    nats = rng.normal(0.0, 4.0, (4, S))
    got = E.decide_labels(nats, tracks=np.concatenate([tracks[0], tracks[1, :1]]))

    def cost(path):
        padded = (0, *path, 0)
        moves = sum(np.concatenate([tracks[0], tracks[1, :1]])[n, path[n - 1], path[n]] for n in range(1, len(path)))
        return sum(nats[n, k] + (E.SWAP_NATS if k else 0.0) for n, k in enumerate(path)) + moves + E.SWITCH_NATS * sum(p != q for p, q in zip(padded, padded[1:]))

    np.testing.assert_array_equal(got, min(itertools.product(range(S), repeat=4), key=cost))
