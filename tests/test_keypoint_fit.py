"""Keypoint-definition offsets and the reprojection report: the offset table against forward
kinematics done by hand, the offsets a solve shows against the ones that made the detections,
and the pixel medians against a direct projection."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mocapgraph.body import load_body_model
from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.keypoint_offsets import MIRROR, carrier_joints, drifted, offset_basis, offset_parameters, offset_shape_table, with_offsets
from mocapgraph.body.native import forward_kinematics
from mocapgraph.body.skeleton import JOINT_NAMES
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.keys import focal_key
from mocapgraph.graphs.body_graph import BodyGraph, GraphOptions
from mocapgraph.graphs.keypoint_fit import PRIOR_FRAMES, _samples, estimate_drift, estimate_offsets, offsets_from_table, outlier_views, refine_drift_in_images, reprojection_medians
from mocapgraph.graphs.solver import SolverOptions, held, levenberg_marquardt
from mocapgraph.graphs.state_model import CameraDetections, CameraInfo, Estimate, build_state_model

FMT = "coco17"


@pytest.fixture(scope="module")
def body():
    return load_body_model()


def known_offsets() -> np.ndarray:
    """Symmetric offsets of a few centimetres at the hips, shoulders and ankles (left points)."""
    names = get_format(FMT).names
    out = np.zeros((len(names), 3))
    for name, left in (("hip", (0.03, 0.0, 0.02)), ("shoulder", (0.01, 0.03, 0.0)), ("ankle", (0.01, 0.0, 0.0))):
        out[names.index(f"left_{name}")] = left
        out[names.index(f"right_{name}")] = MIRROR * left
    return out


def test_carriers_and_offsets_in_forward_kinematics(body):
    """Hip points ride on the pelvis, ankles on the shanks; a posed table with offsets puts each
    point at the plain table's point plus its carrier's world rotation times the offset."""
    table = body.table(body.default_shape, keypoints=FMT)
    names = get_format(FMT).names
    carriers = carrier_joints(table)
    assert JOINT_NAMES[carriers[names.index("left_hip")]] == "pelvis"
    assert JOINT_NAMES[carriers[names.index("left_ankle")]] == "left_knee"
    rng = np.random.default_rng(0)
    roots = np.tile(np.eye(4), (3, 1, 1))
    roots[:, :3, 3] = rng.normal(size=(3, 3))
    pose = rng.normal(scale=0.3, size=(3, 21, 3))
    plain = forward_kinematics(table, roots, pose)
    moved = forward_kinematics(with_offsets(table, known_offsets()), roots, pose)
    want = plain.keypoints + np.einsum("tkij,kj->tki", plain.rotations[:, carriers], known_offsets())
    np.testing.assert_allclose(moved.keypoints, want, atol=1e-12)
    np.testing.assert_array_equal(moved.joints, plain.joints)
    with pytest.raises(MocapgraphError, match="keypoint offsets"):
        with_offsets(table, np.zeros((5, 3)))


def scene(body, offsets, T=60, drift=None, miss=None):
    """Four static cameras around a person walking a circle, whose detector's points carry
    ``offsets`` (and per state ``drift (T, K, 3)`` on top); exact pixels but for ``miss = (camera,
    state, keypoint, pixels)``, one detection moved that far along the image's x. Returns the
    state model and the true estimate."""
    rng = np.random.default_rng(1)
    angle = np.linspace(0, 2 * np.pi, T)
    roots = np.tile(np.eye(4), (T, 1, 1))
    for t, a in enumerate(angle):
        c, s = np.cos(a), np.sin(a)
        Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        roots[t, :3, :3] = Rz @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])  # body +Y up, +Z forward
        roots[t, :3, 3] = [np.cos(a), np.sin(a), 0.95]
    poses = rng.normal(scale=0.1, size=(T, 21, 3))
    table = with_offsets(body.table(body.default_shape, keypoints=FMT), offsets)
    posed = forward_kinematics(table, roots, poses)
    points = posed.keypoints if drift is None else drifted(posed.keypoints, posed.rotations, table, drift)
    K = np.array([[1000.0, 0, 640], [0, 1000.0, 360], [0, 0, 1]])
    cams, dets, cameras = [], [], []
    times = np.arange(T) / 30.0
    for c, a in enumerate((0.3, 1.9, 3.5, 5.0)):
        centre = np.array([5 * np.cos(a), 5 * np.sin(a), 1.5])
        z = np.array([0.0, 0.0, 1.0]) - centre
        z /= np.linalg.norm(z)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        T_wc = np.eye(4)
        T_wc[:3, :3], T_wc[:3, 3] = np.column_stack([x, np.cross(z, x), z]), centre
        p = (points - centre) @ T_wc[:3, :3]
        uv = p[..., :2] / p[..., 2:] * 1000.0 + [640, 360]
        if miss is not None and miss[0] == c:
            uv[miss[1], miss[2], 0] += miss[3]
        cams.append(CameraInfo(f"cam{c}", K, False, times, 30.0))
        dets.append(CameraDetections(c, "sim", FMT, np.concatenate([uv, np.ones((T, 17, 1))], axis=-1)))
        cameras.append(np.tile(T_wc, (T, 1, 1)))
    model = build_state_model(cams, dets, "closest")
    return model, Estimate(roots, poses, body.default_shape.copy(), cameras)


def test_offset_basis_mirrors_pairs_and_skips_unmapped_points(body):
    """BlazePose: a parameter moves a left/right pair (mouth_left/mouth_right too) mirrored, a
    midline point (the nose) only up and forward, an unmapped point (a finger) never; the
    parameters of symmetric offsets give them back; the extended table's extra shape columns
    are the offset directions at the carriers."""
    table = body.table(body.default_shape, keypoints="blazepose33")
    names = get_format("blazepose33").names
    basis = offset_basis(table)
    moved = np.abs(basis).sum(axis=(1, 2)) > 0
    assert set(np.array(names)[moved]) == set(np.array(names)[table.mapped])
    assert basis.shape[-1] == 2 + 3 * (int(table.mapped.sum()) - 1) // 2
    nose, mouth_l, mouth_r = names.index("nose"), names.index("mouth_left"), names.index("mouth_right")
    assert not basis[nose, 0].any() and basis[nose, 1:].any()
    np.testing.assert_array_equal(basis[mouth_r], MIRROR[:, None] * basis[mouth_l])
    offsets = np.zeros((len(names), 3))
    for name, left in (("hip", (0.022, -0.015, 0.007)), ("shoulder", (0.015, 0.02, -0.01))):
        offsets[names.index(f"left_{name}")] = left
        offsets[names.index(f"right_{name}")] = MIRROR * left
    offsets[nose] = (0.0, 0.01, 0.02)
    np.testing.assert_allclose(basis @ offset_parameters(basis, offsets), offsets, atol=1e-12)
    extended = offset_shape_table(table, basis)
    S = table.d_markers.shape[-1]
    carriers = carrier_joints(table)
    np.testing.assert_array_equal(extended.d_markers[np.arange(len(names)), carriers, :, S:], basis)
    assert not extended.d_offsets[..., S:].any() and extended.d_markers.sum() == pytest.approx(table.d_markers.sum() + basis.sum())


def test_offsets_recovered_from_exact_views(body):
    """At the true body and cameras, the estimate is the offsets that made the detections,
    shrunk by n / (n + PRIOR_FRAMES) for the n = 2 × 60 pooled frames of each pair."""
    model, truth = scene(body, known_offsets())
    fit = estimate_offsets(body, model, truth, FMT)
    n = 2 * 60
    assert fit.frames[get_format(FMT).names.index("left_hip")] == n
    np.testing.assert_allclose(fit.offsets, known_offsets() * n / (n + PRIOR_FRAMES), atol=1e-6)
    assert fit.dropped == []
    assert set(fit.as_table()) == {f"{s}_{p}" for s in ("left", "right") for p in ("hip", "shoulder", "ankle")}
    # a result's table (as the online loop reads its bootstrap's) gives the offsets back, to its 0.1 mm rounding
    np.testing.assert_allclose(offsets_from_table(FMT, fit.as_table()), fit.offsets, atol=0.5e-4 + 1e-12)


def test_offsets_estimated_with_the_body(body):
    """Exact views of a body whose shoulders and hips carry offsets, the cameras and shape held
    at the truth: the graph's offset variables, started at zero, land within 2 mm of the truth,
    but for the hips' forward part: to first order it is the root moved forward and the spine
    and legs turned back, so only the prior decides it and shrinks it (a third here); the other
    points' offsets stay as given (none)."""
    truth = known_offsets()
    model, est = scene(body, truth, T=30)
    options = GraphOptions(offsets="estimate", offset_parts=("shoulder", "hip"), pose_prior="none", shape="hold", joint_sigma_m_s=None)
    bg = BodyGraph(model, body, options, fixed_cameras={c: est.cameras[c] for c in range(4)})
    graph, values = bg.sequence(est)
    solved = levenberg_marquardt(held(graph, values, bg.held_keys()), values, SolverOptions(max_iterations=40))
    got = bg.offsets(solved.values)[FMT]
    names = get_format(FMT).names
    free = [names.index(f"{side}_{part}") for side in ("left", "right") for part in ("shoulder", "hip")]
    hips = [names.index("left_hip"), names.index("right_hip")]
    forward = np.zeros((len(names), 3), dtype=bool)
    forward[hips, 2] = True
    np.testing.assert_allclose(got[free][~forward[free]], truth[free][~forward[free]], atol=0.002)
    assert np.all((got[hips, 2] > 0.3 * truth[hips, 2]) & (got[hips, 2] < truth[hips, 2]))
    others = np.setdiff1d(np.arange(len(names)), free)
    assert not got[others].any()
    assert np.abs(bg.offsets(values)[FMT]).max() == 0.0  # the start: the given offsets, none


def test_guessed_alike_cameras_share_a_focal_length(body):
    """Three cameras guessed with one K and a fourth with another: two focal variables (one per
    guess), each camera's focal length read from its group's; each its own without focal_shared."""
    model, est = scene(body, np.zeros((17, 3)), T=5)
    other = model.cameras[3].K.copy()
    other[:2, :2] *= 1.5
    model = replace(model, cameras=[replace(cam, focal_guessed=True, K=other if c == 3 else cam.K) for c, cam in enumerate(model.cameras)])
    bg = BodyGraph(model, body, GraphOptions(pose_prior="none"))
    assert bg.focal_leader == {0: 0, 1: 0, 2: 0, 3: 3}
    values = bg.values(est)
    assert [values.exists(focal_key(c)) for c in range(4)] == [True, False, False, True]
    values.update(focal_key(0), np.array([0.2]))
    out = bg.read(values, est)
    np.testing.assert_array_equal(out.focal_log, [0.2, 0.2, 0.2, 0.0])
    graph, _ = bg.sequence(est)
    keys = {k for i in range(graph.size()) for k in graph.at(i).keys()}
    assert {focal_key(c) for c in range(4)} & keys == {focal_key(0), focal_key(3)}
    alone = BodyGraph(model, body, GraphOptions(pose_prior="none", focal_shared=False))
    assert alone.focal_leader == {c: c for c in range(4)}


def test_implausible_offsets_are_dropped(body):
    big = known_offsets()
    big[[11, 12]] *= 5  # hips 18 cm off: not a definition
    model, truth = scene(body, big)
    fit = estimate_offsets(body, model, truth, FMT)
    assert sorted(fit.dropped) == ["left_hip", "right_hip"] and not fit.offsets[[11, 12]].any()


def test_reprojection_medians(body):
    """Zero at the truth with the true offsets; without them, the hips' median equals the
    median pixel shift the offsets cause, computed directly."""
    offsets = known_offsets()
    model, truth = scene(body, offsets)
    exact = reprojection_medians(body, model, truth, {FMT: offsets})
    assert exact["all"] < 1e-6 and set(exact["camera"]) == {"cam0", "cam1", "cam2", "cam3"}
    plain = reprojection_medians(body, model, truth)
    table = body.table(body.default_shape, keypoints=FMT)
    a = forward_kinematics(table, truth.roots, truth.poses).keypoints
    b = forward_kinematics(with_offsets(table, offsets), truth.roots, truth.poses).keypoints
    shifts = []
    for c in range(4):
        T_cw = np.linalg.inv(truth.cameras[c][0])
        pa, pb = a @ T_cw[:3, :3].T + T_cw[:3, 3], b @ T_cw[:3, :3].T + T_cw[:3, 3]
        shifts.append(np.linalg.norm(1000.0 * (pa[..., :2] / pa[..., 2:] - pb[..., :2] / pb[..., 2:]), axis=-1)[:, 11])
    assert plain["keypoint"][FMT]["left_hip"] == pytest.approx(np.median(np.concatenate(shifts)), abs=0.01)


def test_drift_of_the_definitions_recovered_and_smoothed(body):
    """A left hip whose definition drifts slowly (2 cm sideways, one period over the 60 states)
    on top of the constant offsets: at the true body and cameras, with a sample's σ far below the
    others the drift comes back to 0.1 mm; with (1, 1, 3) cm the smoothing shrinks a slow
    sinusoid by ``1 / (1 + 2(1 - cos ω) σ_obs²/σ_step² + σ_obs²/σ_prior²)`` (0.891 here) in the
    middle of the take, where the ends do not reach; every other point stays at zero, and the
    reprojection with the drift is exact where without it the hip is off."""
    T, names = 60, get_format(FMT).names
    hip = names.index("left_hip")
    omega = 2 * np.pi / T
    drift = np.zeros((T, len(names), 3))
    drift[:, hip, 0] = 0.02 * np.sin(omega * np.arange(T))
    model, truth = scene(body, known_offsets(), T, drift)
    exact = estimate_drift(body, model, truth, FMT, known_offsets(), (1e-5, 0.01, 0.03))
    np.testing.assert_allclose(exact, drift, atol=1e-4)
    smoothed = estimate_drift(body, model, truth, FMT, known_offsets(), (0.01, 0.01, 0.03))
    gain = 1.0 / (1.0 + 2.0 * (1.0 - np.cos(omega)) + (0.01 / 0.03) ** 2)
    middle = slice(15, 45)
    np.testing.assert_allclose(smoothed[middle, hip, 0], gain * drift[middle, hip, 0], atol=1.5e-3)
    others = np.ones(len(names), dtype=bool)
    others[hip] = False
    assert np.abs(smoothed[:, others]).max() < 1e-4 and np.abs(smoothed[:, hip, 1:]).max() < 1e-4
    with_drift = reprojection_medians(body, model, truth, {FMT: known_offsets()}, {FMT: exact})
    without = reprojection_medians(body, model, truth, {FMT: known_offsets()})
    assert with_drift["keypoint"][FMT]["left_hip"] < 0.05 < 1.0 < without["keypoint"][FMT]["left_hip"]


def test_drift_refined_in_the_images(body):
    """The same slowly drifting hip: from zero, the refinement against the views finds the drift
    (to 0.1 mm with a sample's σ far below the others, as the samples' smoothing does); one view's
    gross miss (cam1's hip 300 px off at state 20), which the samples' plain DLT follows by
    centimetres, moves it by less than 0.5 mm there; the other points stay at zero; a point whose
    views' median the refinement would raise keeps its start."""
    T, names = 60, get_format(FMT).names
    hip = names.index("left_hip")
    drift = np.zeros((T, len(names), 3))
    drift[:, hip, 0] = 0.02 * np.sin(2 * np.pi / T * np.arange(T))
    model, truth = scene(body, known_offsets(), T, drift)
    exact = refine_drift_in_images(body, model, truth, FMT, known_offsets(), (1e-5, 0.01, 0.03), np.zeros_like(drift))
    np.testing.assert_allclose(exact, drift, atol=1e-4)
    missed, _ = scene(body, known_offsets(), T, drift, miss=(1, 20, hip, 300.0))
    sigmas = (1e-3, 0.01, 0.03)
    refined = refine_drift_in_images(body, missed, truth, FMT, known_offsets(), sigmas, np.zeros_like(drift))
    assert np.linalg.norm(refined[20, hip] - drift[20, hip]) < 5e-4
    _, samples = _samples(body, missed, truth, FMT, known_offsets())
    assert np.linalg.norm(samples[20, hip] - drift[20, hip]) > 0.01  # what the plain DLT makes of it
    others = np.ones(len(names), dtype=bool)
    others[hip] = False
    assert np.abs(refined[:, others]).max() < 1e-4
    # a drift of 15 cm, which the prior (3 cm) would shrink: started at the truth, where the views
    # fit exactly, the refinement could only raise the hip's median, so the hip keeps its start
    large = np.zeros_like(drift)
    large[:, hip, 0] = 0.15
    model, truth = scene(body, known_offsets(), T, large)
    kept = refine_drift_in_images(body, model, truth, FMT, known_offsets(), (0.01, 0.01, 0.03), large)
    np.testing.assert_array_equal(kept[:, hip], large[:, hip])


def test_views_of_someone_else_are_outliers_and_left_out(body):
    """Three frames of one camera replaced by a body 40 cm to the side: exactly those views are
    outliers at the true solve, and the model without them has no observation there."""
    model, truth = scene(body, np.zeros((17, 3)))
    bad = [10, 11, 12]
    states = []
    for i, obs in enumerate(model.states):
        states.append([replace(o, observed=o.observed + 80.0) if (o.camera == 2 and o.frame in bad) else o for o in obs])
    model = replace(model, states=states)
    views = outlier_views(body, model, truth)
    assert list(views) == [2] and views[2].tolist() == bad
    kept = model.without(views)
    assert sum(len(obs) for obs in kept.states) == sum(len(obs) for obs in model.states) - 3
    assert not any(o.camera == 2 and o.frame in bad for obs in kept.states for o in obs)


def test_unmapped_points_are_not_reported(body):
    """BlazePose's finger and mouth points have no body counterpart: the report leaves them out."""
    model, truth = scene(body, np.zeros((17, 3)))
    blaze = get_format("blazepose33")
    states = []
    for obs in model.states:
        out = []
        for o in obs:
            observed = np.full((33, 2), 300.0)  # unmapped points anywhere
            weights = np.ones(33)
            for k, name in enumerate(get_format(FMT).names):
                observed[blaze.names.index(name)] = o.observed[k]
            out.append(replace(o, fmt=blaze.name, observed=observed, weights=weights))
        states.append(out)
    report = reprojection_medians(body, replace(model, states=states), truth)
    points = report["keypoint"]["blazepose33"]
    assert "left_pinky" not in points and "mouth_left" not in points
    assert points["left_hip"] < 1e-6 and points["nose"] < 1e-6


def test_the_hips_shift_is_held_at_the_prior(body):
    """With ``hold_root_shift`` the hips (the points the pelvis carries) keep the prior's up and
    forward parts and only their lateral part is measured; every other point is measured as
    without it. With the body's root 1 cm behind the truth in its own frame (the lean the rounds
    showed on ``rich``), the plain measure puts that centimetre into the hips' forward part and
    every other point's, while the held hips stay at the prior."""
    truth = known_offsets()
    names = get_format(FMT).names
    hips = [names.index("left_hip"), names.index("right_hip")]
    prior = np.zeros_like(truth)
    prior[hips] = [(0.02, -0.01, 0.005), (-0.02, -0.01, 0.005)]
    model, est = scene(body, truth)
    n = 2 * 60
    measured = prior + (truth - prior) * n / (n + PRIOR_FRAMES)
    plain = estimate_offsets(body, model, est, FMT, prior)
    held_fit = estimate_offsets(body, model, est, FMT, prior, hold_root_shift=True)
    others = np.setdiff1d(np.arange(len(names)), hips)
    np.testing.assert_allclose(plain.offsets, measured, atol=1e-6)
    np.testing.assert_allclose(held_fit.offsets[others], measured[others], atol=1e-6)
    np.testing.assert_allclose(held_fit.offsets[hips, 0], measured[hips, 0], atol=1e-6)
    np.testing.assert_array_equal(held_fit.offsets[hips, 1:], prior[hips, 1:])
    behind = replace(est, roots=est.roots.copy())
    behind.roots[:, :3, 3] -= 0.01 * est.roots[:, :3, 2]  # the root's +Z is the body's forward
    leaned = estimate_offsets(body, model, behind, FMT, prior, hold_root_shift=True)
    shift = (prior[hips] + (truth[hips] + [0.0, 0.0, 0.01] - prior[hips]) * n / (n + PRIOR_FRAMES))[:, 2]
    np.testing.assert_allclose(estimate_offsets(body, model, behind, FMT, prior).offsets[hips, 2], shift, atol=1e-6)
    np.testing.assert_array_equal(leaned.offsets[hips, 1:], prior[hips, 1:])


@pytest.mark.slow
def test_offsets_measured_again_each_round_come_nearer_the_truth(monkeypatch):
    """SmartMocap on ``rich`` (2 s, realistic faults but the literature's COCO-17 definitions,
    hips 30 mm lateral and 20 mm forward of the body's): rounds that measure the offsets again
    on the body the last one left find more of the hips' offset, in both parts, and put the
    pelvis nearer the truth (measured, one round against four: hips 13.4, -0.3, 3.5 -> 15.5,
    -0.7, 7.1 mm, MPE 2.43 -> 2.07 cm)."""
    from mocapgraph.data_tools.evaluation.evaluate import evaluate
    from mocapgraph.data_tools.sim import detectors
    from mocapgraph.data_tools.sim.synthetic import synthesize
    from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap

    literature = detectors.LITERATURE_DEFINITION_OFFSETS_M[FMT]
    preset = detectors.DETECTOR_PRESETS["coco_hrnet"]
    monkeypatch.setitem(detectors.DETECTOR_PRESETS, "coco_hrnet", replace(preset, faults=replace(preset.faults, keypoint_offsets_m=literature)))
    capture = synthesize("rich", seed=0, duration_s=2.0, detector_faults="realistic")
    hips, mpe = {}, {}
    for rounds in (1, 4):
        # the hips' forward part measured (hold_root_offsets off): the rounds' own behaviour
        options = SmartmocapOptions(covariances=False, motion_prior="none", workers=1, offset_rounds=rounds, hold_root_offsets=False)
        result = run_smartmocap(capture, options)
        hips[rounds] = np.array(result.parameters["keypoint_offsets_m"][FMT]["left_hip"])
        mpe[rounds] = evaluate(result, capture).metrics["mpe_m"]
    simulated = np.array(literature["hip"])
    lateral_forward = [0, 2]
    assert np.all(np.abs(hips[4] - simulated)[lateral_forward] < np.abs(hips[1] - simulated)[lateral_forward] - 0.001), hips
    assert np.all(hips[4][lateral_forward] < simulated[lateral_forward]), hips  # still short of it: the body's lean
    assert mpe[4] < mpe[1] - 0.001, mpe


def test_offsets_shrunk_towards_a_prior(body):
    """With a prior (a table fitted on real footage), each pair's median is shrunk towards it
    rather than towards zero: ``prior + (truth - prior) · n / (n + PRIOR_FRAMES)``; a point the
    views never saw, or one dropped as implausible, keeps the prior."""
    truth = known_offsets()
    names = get_format(FMT).names
    prior = np.zeros_like(truth)
    for name, left in (("hip", (0.02, -0.01, 0.0)), ("knee", (0.0, 0.0, 0.015))):
        prior[names.index(f"left_{name}")] = left
        prior[names.index(f"right_{name}")] = MIRROR * left
    model, est = scene(body, truth)
    fit = estimate_offsets(body, model, est, FMT, prior)
    n = 2 * 60
    np.testing.assert_allclose(fit.offsets, prior + (truth - prior) * n / (n + PRIOR_FRAMES), atol=1e-6)
    big = truth.copy()
    big[[11, 12]] *= 5
    model, est = scene(body, big)
    fit = estimate_offsets(body, model, est, FMT, prior)
    assert sorted(fit.dropped) == ["left_hip", "right_hip"]
    np.testing.assert_array_equal(fit.offsets[[11, 12]], prior[[11, 12]])


@pytest.mark.slow  # two SmartMocap runs on 2 s of rich: 1-2 min on two shared cores
def test_the_fitted_prior_moves_the_offsets_towards_the_truth(monkeypatch):
    """A capture whose simulated BlazePose points sit where the real clip's fit puts them
    (:data:`~mocapgraph.body.definition_priors.FITTED_OFFSETS_M`, realistic faults otherwise):
    started at and shrunk towards that table, SmartMocap's offsets land nearer the simulator's
    than from zero (the ``zero`` run's estimate is what the body did not take up), and the pelvis
    is no further off. With the simulator set to the table this is circular by design: it shows
    the prior is used as meant, not that the table is right (that is the real clip's test)."""
    from mocapgraph.body.definition_priors import FITTED_OFFSETS_M, prior_offsets
    from mocapgraph.body.labelling import part_name
    from mocapgraph.data_tools.evaluation.evaluate import evaluate
    from mocapgraph.data_tools.sim import detectors
    from mocapgraph.data_tools.sim.synthetic import synthesize
    from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap

    fmt = "blazepose33"
    fitted = {part_name(name): tuple(v) for name, v in FITTED_OFFSETS_M[fmt].items()}
    preset = detectors.DETECTOR_PRESETS["mediapipe"]
    monkeypatch.setitem(detectors.DETECTOR_PRESETS, "mediapipe", replace(preset, faults=replace(preset.faults, keypoint_offsets_m=fitted)))
    capture = synthesize("rich", seed=0, duration_s=2.0, detectors=("mediapipe",), detector_faults="realistic")
    truth = prior_offsets(fmt)
    errors, mpe = {}, {}
    for prior in ("zero", "fitted"):
        result = run_smartmocap(capture, SmartmocapOptions(covariances=False, motion_prior="none", workers=1, offset_prior=prior))
        got = offsets_from_table(fmt, result.parameters["keypoint_offsets_m"][fmt])
        mapped = np.any(truth != 0, axis=1)
        errors[prior] = float(np.median(np.linalg.norm(got[mapped] - truth[mapped], axis=1)))
        mpe[prior] = evaluate(result, capture).metrics["mpe_m"]
    assert errors["fitted"] < 0.5 * errors["zero"], errors
    assert mpe["fitted"] < mpe["zero"] + 0.002, mpe
