"""Calibrated covariances (graphs/uncertainty.py) against the truth of linear-Gaussian graphs:
Monte Carlo over the measurements' noise, every trial solved and compared as ``eval`` compares
(after a similarity over the points), and variance components recovered from residuals."""

from dataclasses import replace

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import C, X
from scipy.stats import chi2

from mocapgraph.data_tools.evaluation.alignment import umeyama
from mocapgraph.graphs.uncertainty import (
    SimilarityDatum,
    _information,
    factor_groups,
    linear_system,
    scaled_linear_graph,
    similarity_jacobian,
    variance_factors,
    window_misfit,
)

RNG = np.random.default_rng(7)
POINTS = RNG.uniform(-1.0, 1.0, (12, 3)) * [0.4, 0.3, 0.9]  # a body's size, metres
CAMERA = np.array([3.0, -1.5, 1.2])  # a static camera 3 m away
EDGES = [(i, i + 1) for i in range(len(POINTS) - 1)] + [(0, 5), (3, 9), (2, 11), (6, 10)]
LINKED = (0, 3, 6, 8, 11)  # the points the camera is measured from
CAMERA_LINKS = len(LINKED)
SIGMA = 0.01  # m, each relative measurement per axis
GAUGE = 1e-3  # m, the first point held stiffly (the world pinned to the first body state)


def point_graph(noise: np.ndarray | None = None, camera_sigma: float = SIGMA):
    """Points linked by noisy relative measurements, the camera by measurements to three of
    them; the first point pinned. ``noise (len(EDGES) + CAMERA_LINKS, 3)`` added to the true relations."""
    noise = np.zeros((len(EDGES) + CAMERA_LINKS, 3)) if noise is None else noise
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPoint3(X(0), POINTS[0], gtsam.noiseModel.Isotropic.Sigma(3, GAUGE)))
    for (i, j), n in zip(EDGES, noise):
        graph.add(gtsam.BetweenFactorPoint3(X(i), X(j), POINTS[j] - POINTS[i] + n, gtsam.noiseModel.Isotropic.Sigma(3, SIGMA)))
    for i, n in zip(LINKED, noise[len(EDGES) :]):
        graph.add(gtsam.BetweenFactorPoint3(X(i), C(0), CAMERA - POINTS[i] + n, gtsam.noiseModel.Isotropic.Sigma(3, camera_sigma)))
    values = gtsam.Values()
    for i, p in enumerate(POINTS):
        values.insert(X(i), p)
    values.insert(C(0), CAMERA)
    return graph, values


def solved(graph, values):
    return gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()


def datum_covariances(graph, values):
    """Raw marginals and those in the points' similarity datum, of every point and the camera."""
    system = linear_system(graph.linearize(values), values)
    _, lu = _information(system, np.ones(system.A.shape[0]))
    keys = [X(i) for i in range(len(POINTS))] + [C(0)]
    rows = np.zeros((3 * len(POINTS), system.n))
    for i in range(len(POINTS)):
        rows[3 * i : 3 * i + 3, system.cols(X(i))] = np.eye(3)
    datum = SimilarityDatum(lu, POINTS, rows)
    marginals = gtsam.Marginals(graph, values)
    raw = np.stack([marginals.marginalCovariance(k) for k in keys])
    G = similarity_jacobian(np.vstack([POINTS, CAMERA]) - datum.centroid).reshape(-1, 3, 7)
    rows_Z = np.stack([datum.Z[system.cols(k)] for k in keys])
    return raw, datum.apply(raw, rows_Z, G)


def aligned_errors(trials: int):
    """``(trials, P + 1, 3)`` errors of the points and the camera after the similarity that best
    maps the solved points onto the true ones (Umeyama with scale, as ``eval``)."""
    out = []
    for _ in range(trials):
        graph, values = point_graph(RNG.normal(0.0, SIGMA, (len(EDGES) + CAMERA_LINKS, 3)))
        result = solved(graph, values)
        est = np.array([result.atPoint3(X(i)) for i in range(len(POINTS))] + [result.atPoint3(C(0))])
        fit = umeyama(est[:-1], POINTS, with_scale=True)
        out.append(fit.apply(est) - np.vstack([POINTS, CAMERA]))
    return np.array(out)


@pytest.fixture(scope="module")
def monte_carlo():
    graph, values = point_graph()
    raw, datum = datum_covariances(graph, values)
    return raw, datum, aligned_errors(1500)


def coverage(errors, cov, level=0.95):
    d2 = np.einsum("tki,kij,tkj->tk", errors, np.linalg.inv(cov), errors)
    return (d2 <= chi2.ppf(level, 3)).mean(0)


def test_datum_covariance_is_the_aligned_errors_covariance(monte_carlo):
    """The S-transformed covariance matches the Monte Carlo covariance of the aligned errors
    (1500 trials: a covariance entry to about ±4 % of its diagonal's scale)."""
    _, datum, errors = monte_carlo
    empirical = np.einsum("tki,tkj->kij", errors, errors) / len(errors)
    scale = np.sqrt(np.einsum("kii->ki", empirical))
    rel = (datum - empirical) / (scale[:, :, None] * scale[:, None, :])
    assert np.abs(rel).max() < 0.12
    np.testing.assert_allclose(np.trace(datum, axis1=1, axis2=2), np.trace(empirical, axis1=1, axis2=2), rtol=0.1)


def test_raw_marginals_overcover_the_aligned_errors_and_the_datum_is_honest(monte_carlo):
    """The graph's own marginals are in the pinned first point's gauge: the other points' too
    large once the alignment absorbed the chain from that point (measured 0.997-1.0 inside the
    95 % ellipsoid), the pinned point's and the camera's 3 m away too small (0.03, 0.23: the
    alignment's rotation moves them, their marginals know nothing of it); in the datum, each
    about 95 % (binomial ±1.1 % at 1500 trials)."""
    raw, datum, errors = monte_carlo
    old, new = coverage(errors, raw), coverage(errors, datum)
    assert np.all(old[1:-1] > 0.99) and old[0] < 0.1 and old[-1] < 0.5
    assert np.all(np.abs(new - 0.95) < 0.03), new
    assert abs(new.mean() - 0.95) < 0.01


def test_variance_factors_recover_each_groups_true_noise():
    """Camera links 3x noisier than their noise models say (variance factor 9), point links as
    modelled (1), at the solution of the truly weighted graph: the variance components recover
    both (pooled over 40 graphs: the camera group's redundancy is about 12 each, its factor 9·χ²₁₂/12)."""
    n_edges = len(EDGES)
    factors = []
    for _ in range(40):
        noise = RNG.normal(0.0, SIGMA, (n_edges + CAMERA_LINKS, 3)) * np.r_[np.ones(n_edges), 3 * np.ones(CAMERA_LINKS)][:, None]
        result = solved(*point_graph(noise, camera_sigma=3 * SIGMA))
        stated, _ = point_graph(noise)
        system = linear_system(stated.linearize(result), result)
        groups = {"points": np.arange(1, n_edges + 1), "camera": np.arange(n_edges + 1, n_edges + 1 + CAMERA_LINKS)}
        factors.append(variance_factors(system, groups, iterations=3, samples=64, floor=0.0))
    assert abs(np.mean([f["points"] for f in factors]) - 1.0) < 0.25  # redundancy 12 each: ±0.07 pooled, and LM stops a little short
    assert abs(np.mean([f["camera"] for f in factors]) - 9.0) < 9.0 * 3 * np.sqrt(2 / 12 / 40)


def gm_between(i: int, j: int, z: np.ndarray, sigma: float, c: float) -> gtsam.CustomFactor:
    """A 2-D relative measurement with mocapgraph's per-point Geman-McClure inside (the
    reprojection kernel's form): residual ``c·u/√(c² + |u|²)``, ``u`` the whitened error."""

    def error(this, values, H):
        u = (values.atPoint2(X(j)) - values.atPoint2(X(i)) - z) / sigma
        d = c**2 + u @ u
        if H is not None:
            D = c / np.sqrt(d) * (np.eye(2) - np.outer(u, u) / d) / sigma
            H[0], H[1] = -D, D
        return c * u / np.sqrt(d)

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2), gtsam.KeyVector([X(i), X(j)]), error)


def faulty_chain_factors(rng: np.random.Generator) -> tuple[float, float, gtsam.NonlinearFactorGraph]:
    """One chain of 40 points with four two-row measurements per link, 2x noisier than modelled
    and 5 % of them gross faults (40σ), solved with the kernel: the links' variance factor
    measured as a robust group and as a plain sum, and the graph."""
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    truth = rng.uniform(-1, 1, (40, 2))
    for i, p in enumerate(truth):
        values.insert(X(i), gtsam.Point2(*p))
    graph.add(gtsam.PriorFactorPoint2(X(0), truth[0], gtsam.noiseModel.Isotropic.Sigma(2, 1e-3)))
    for _ in range(4):
        for i in range(len(truth) - 1):
            n = rng.normal(0.0, 2 * SIGMA, 2) + (rng.random() < 0.05) * rng.normal(0.0, 40 * SIGMA, 2)
            graph.add(gm_between(i, i + 1, truth[i + 1] - truth[i] + n, SIGMA, 10.0))
    result = solved(graph, values)
    system = linear_system(graph.linearize(result), result)
    between = {"between": np.arange(1, graph.size())}
    return variance_factors(system, between, robust={"between"})["between"], variance_factors(system, between)["between"], graph


ROBUST_MEAN, ROBUST_SD, RATIO_MEAN, RATIO_SD = 3.755, 0.45, 1.66, 0.09
"""The robust factor's sampling distribution on one such chain, measured over 400 fresh generators:
mean 3.755, standard deviation 0.45 (12 %: the median of 156 keypoints' residuals, whose own
relative spread is 1/(ln 2·√156) = 11.6 %); of 8 chains' means, plain over robust 1.66 ± 0.09.
The mean is 6 % under what the linearised graph's marginals need (3.98 by Monte Carlo of the
solution over 300 draws; 3.83 against 3.54 without faults): the kernel compresses the residuals a
little more than it weakens the information; with it, 0.943 of the solved points' errors lie
inside their 95 % ellipses (docs/uncertainty.md)."""


def test_robust_group_ignores_the_faults_a_kernel_sets_aside():
    """Measured as a robust group (median of the pairs) the factor is near 4, the noise's; as a
    plain sum the faults' saturated residuals dominate. Pooled over 8 chains of the test's own
    generator, each bound is 4 standard deviations of that pooled mean's sampling distribution
    (:data:`ROBUST_SD`, measured), not of a guess: one chain's factor alone spreads ±0.45."""
    rng = np.random.default_rng(11)
    draws = [faulty_chain_factors(rng) for _ in range(8)]
    robust, plain = np.mean([d[0] for d in draws]), np.mean([d[1] for d in draws])
    assert abs(robust - ROBUST_MEAN) < 4 * ROBUST_SD / np.sqrt(len(draws)), robust
    assert plain / robust > RATIO_MEAN - 4 * RATIO_SD, (plain, robust)
    assert set(factor_groups(draws[0][2])) == {"x"}  # one kind of variable: one group


def test_scaled_graph_scales_the_marginals():
    """Every factor's σ times 2: every marginal ×4 (a check of the re-linearisation)."""
    graph, values = point_graph()
    linear = graph.linearize(values)
    scaled = scaled_linear_graph(linear, values, np.full(graph.size(), 2.0))
    np.testing.assert_allclose(
        gtsam.Marginals(scaled, values).marginalCovariance(C(0)), 4 * gtsam.Marginals(linear, values).marginalCovariance(C(0)), rtol=1e-9
    )


def test_lever_covariances_are_a_small_world_rotations_first_order_effect():
    """SmartMocap's model error as a rotation about the joints' centroid: the covariances of
    points and of poses (GTSAM's tangent) under ``δθ ~ N(0, I)`` equal ``J Jᵀ`` with ``J`` the
    first-order effect of turning them about the pivot, measured by finite differences through
    GTSAM's ``Rot3.Expmap`` and ``Pose3.Logmap``."""
    from mocapgraph.pipelines.smartmocap import lever_covariance, pose_lever_covariance

    rng = np.random.default_rng(3)
    pivot = rng.normal(size=3)
    points = pivot + rng.normal(scale=4.0, size=(5, 3))
    poses = np.array([gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), p).matrix() for p in points])
    h = 1e-6
    turns = [gtsam.Rot3.Expmap(h * axis).matrix() for axis in np.eye(3)]
    for n, (p, T) in enumerate(zip(points, poses)):
        J = np.stack([(R @ (p - pivot) + pivot - p) / h for R in turns], axis=1)
        assert np.allclose(lever_covariance(p - pivot), J @ J.T, atol=1e-4 * np.abs(J).max() ** 2)
        moved = [np.block([[R, (pivot - R @ pivot)[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]]) @ T for R in turns]
        G = np.stack([gtsam.Pose3.Logmap(gtsam.Pose3(T).between(gtsam.Pose3(M))) / h for M in moved], axis=1)
        assert np.allclose(pose_lever_covariance(T[None], pivot)[0], G @ G.T, atol=1e-4 * np.abs(G).max() ** 2)
    # the rotation about the point itself moves it nowhere, and turns a pose only
    assert np.allclose(lever_covariance(np.zeros(3)), 0.0)
    at_pivot = pose_lever_covariance(np.array([np.eye(4)]), np.zeros(3))[0]
    assert np.allclose(at_pivot[:3, :3], np.eye(3)) and np.allclose(at_pivot[3:], 0.0)


def test_window_misfit_is_each_windows_chi2_per_row():
    """The motion prior's misfit per state: the squared whitened residuals over the rows of the
    factors on each window's latent (symbol ``m``), at the values; a state in two windows takes
    the larger, a state in none 0, a factor on no latent counts nowhere."""
    m0, m1 = gtsam.symbol("m", 0), gtsam.symbol("m", 1)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorVector(m0, np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, 0.5)))
    graph.add(gtsam.PriorFactorVector(m1, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 2.0)))
    graph.add(gtsam.PriorFactorVector(m1, np.ones(3), gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    graph.add(gtsam.PriorFactorPoint3(X(0), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)))
    values = gtsam.Values()
    values.insert(m0, np.array([1.0, -0.5]))
    values.insert(m1, np.array([0.2, 0.4, 1.0]))
    values.insert(X(0), np.array([1.0, 0.0, 0.0]))
    system = linear_system(graph.linearize(values), values)
    w0 = (1.0**2 + 0.5**2) / 0.5**2 / 2
    w1 = ((0.2**2 + 0.4**2 + 1.0**2) / 2.0**2 + (0.8**2 + 0.6**2 + 0.0**2) / 0.1**2) / 6
    misfit = window_misfit(system, graph, "m", [0, 3], 4, 8)
    np.testing.assert_allclose(misfit, [w0, w0, w0, max(w0, w1), w1, w1, w1, 0.0], rtol=1e-9)


def test_model_error_scales_each_states_joints_by_the_motion_priors_misfit():
    """SmartMocap's model error of state ``i``'s joints and root: the variance factor times
    ``1 + gain·μ_i`` (``μ`` the result's ``motion_prior_misfit`` flag), the rotation about the
    centroid added as it was; no flag: the factor alone."""
    from mocapgraph.data_tools.io.result import Result
    from mocapgraph.pipelines.smartmocap import lever_covariance, pose_lever_covariance, with_model_error

    rng = np.random.default_rng(5)
    joints = rng.normal(size=(3, 22, 3))
    root = np.repeat(np.eye(4)[None], 3, axis=0)
    root[:, :3, 3] = joints[:, 0]
    A, B = rng.normal(size=(3, 22, 3, 3)), rng.normal(size=(3, 6, 6))
    covariances = {"joints": A @ np.swapaxes(A, -1, -2), "root": B @ np.swapaxes(B, -1, -2)}
    result = Result("smartmocap", "toy", "ground_plane", np.arange(3) / 30, joints, root=root, flags={"motion_prior_misfit": np.array([0.0, 0.5, 2.0])})
    out = with_model_error(covariances, result, None, (2.0, 1.0, 1.0), (0.01, 0.0, 0.0), misfit_gain=1.5)
    factor = 2.0 * (1.0 + 1.5 * np.array([0.0, 0.5, 2.0]))
    centroid = joints.reshape(-1, 3).mean(0)
    np.testing.assert_allclose(out["joints"], factor[:, None, None, None] * covariances["joints"] + 1e-4 * lever_covariance(joints - centroid), rtol=1e-12)
    np.testing.assert_allclose(out["root"], factor[:, None, None] * covariances["root"] + 1e-4 * pose_lever_covariance(root, centroid), rtol=1e-12)
    result.flags = {}
    np.testing.assert_allclose(with_model_error(covariances, result, None, (2.0, 1.0, 1.0), (0.0, 0.0, 0.0), misfit_gain=1.5)["joints"], 2.0 * covariances["joints"])


@pytest.mark.slow
def test_smartmocap_coverage_on_a_held_out_phones_capture():
    """SmartMocap's covariances on a ``phones`` capture none of their model error was fitted on
    (the synthesiser's procedural walk, seed 5, 3 s; the fit used CMU takes of other subjects):
    the share of the joints' and of the camera centres' errors inside their 95 % ellipsoids, after
    the evaluation's alignment, with the model error as the options give it (factors, the
    rotation about the joints' centroid and the motion prior's misfit) and with the old factors
    alone (3.7, 22.5, 13), both from the same solve's graph covariances. Measured: joints 0.969
    against 0.812, cameras 1.0 and 1.0. The motion prior misfits this walk (χ² per row 1.1-1.5,
    0.2-0.7 on the training takes) and the joints' errors are as much larger, the pelvis's most
    (0.48 inside without the misfit's term; docs/uncertainty.md); a take's cameras may reach 1.0
    (a static camera's one pose is in or out)."""
    from mocapgraph.data_tools.evaluation.evaluate import coverage
    from mocapgraph.data_tools.sim.synthetic import synthesize
    from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap, with_model_error

    capture = synthesize("phones", seed=5, duration_s=3.0)
    defaults = SmartmocapOptions()
    graph_only = run_smartmocap(
        capture, SmartmocapOptions(keypoint_offsets=False, covariance_model_error=(1.0, 1.0, 1.0), covariance_lever_error_rad=(0.0, 0.0, 0.0), covariance_misfit_gain=0.0)
    )
    shares = {}
    models = (
        ("new", defaults.covariance_model_error, defaults.covariance_lever_error_rad, defaults.covariance_misfit_gain),
        ("old", (3.7, 22.5, 13.0), (0.0, 0.0, 0.0), 0.0),
    )
    for name, factors, lever, gain in models:
        result = replace(graph_only, covariances={**graph_only.covariances, **with_model_error(graph_only.covariances, graph_only, capture, factors, lever, gain)})
        shares[name] = coverage(result, capture)
    assert 0.85 <= shares["new"]["joints"] <= 0.99 and 0.85 <= shares["new"]["cameras"] <= 1.0
    assert shares["new"]["joints"] >= shares["old"]["joints"] and shares["new"]["cameras"] >= shares["old"]["cameras"]
