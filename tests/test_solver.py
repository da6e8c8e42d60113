"""The Python LM loop of mocapgraph.graphs.solver against GTSAM's own optimisers and known answers."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest

from mocapgraph.errors import MocapgraphError
from mocapgraph.graphs.solver import (
    CONVERGED_REASONS,
    SolveLog,
    SolverOptions,
    levenberg_marquardt,
    marginal_covariances,
    solve_staged,
)

POSE_SIGMAS = np.array([0.05] * 3 + [0.1] * 3)
TIGHT = dict(relative_tolerance=1e-12, absolute_tolerance=1e-12)


def _custom_between(key1: int, key2: int, measured: gtsam.Pose3, noise) -> gtsam.CustomFactor:
    """A CustomFactor with BetweenFactorPose3's residual ``Log(measured⁻¹ · p1⁻¹ · p2)``."""

    def error(this, values, jacobians):
        p1, p2 = values.atPose3(this.keys()[0]), values.atPose3(this.keys()[1])
        if jacobians is None:
            return measured.localCoordinates(p1.between(p2))
        d1, d2, dlocal = (np.zeros((6, 6), order="F") for _ in range(3))
        residual = measured.localCoordinates(p1.between(p2, d1, d2), None, dlocal)
        jacobians[0] = dlocal @ d1
        jacobians[1] = dlocal @ d2
        return residual

    return gtsam.CustomFactor(noise, [key1, key2], error)


def pose_chain(n=40, seed=0, start_noise=0.4, custom=False):
    """A noisy Pose3 chain with a prior on the first pose and two loop closures."""
    rng = np.random.default_rng(seed)
    truth = [gtsam.Pose3()]
    for _ in range(1, n):
        step = gtsam.Pose3(gtsam.Rot3.Rodrigues(*(0.2 * rng.normal(size=3))), rng.normal(size=3))
        truth.append(truth[-1].compose(step))
    noise = gtsam.noiseModel.Diagonal.Sigmas(POSE_SIGMAS)
    between = _custom_between if custom else gtsam.BetweenFactorPose3
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(0, truth[0], gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    pairs = [(i - 1, i) for i in range(1, n)] + [(0, n - 1), (5, n // 2)]
    for a, b in pairs:
        measured = truth[a].between(truth[b]).compose(gtsam.Pose3.Expmap(POSE_SIGMAS * rng.normal(size=6)))
        graph.add(between(a, b, measured, noise))
    initial = gtsam.Values()
    for i, pose in enumerate(truth):
        initial.insert(i, pose.compose(gtsam.Pose3.Expmap(start_noise * rng.normal(size=6))))
    return graph, initial


def max_pose_difference(a: gtsam.Values, b: gtsam.Values) -> float:
    return max(float(np.abs(a.atPose3(k).localCoordinates(b.atPose3(k))).max()) for k in a.keys())


def exp_fit_problem(outliers=False, seed=1):
    """``y = a·exp(b·x)`` fitted by one scalar CustomFactor per sample on a 2-vector [a, b].

    The factors read ``scale["c"]``: a Geman-McClure scale inside the residual (inf = plain L2).
    """
    truth = np.array([2.0, -0.7])
    x = np.linspace(0.0, 3.0, 25)
    y = truth[0] * np.exp(truth[1] * x)
    if outliers:
        rng = np.random.default_rng(seed)
        y = y + 0.01 * rng.normal(size=x.size)
        y[[3, 11, 19]] += np.array([1.5, -1.2, 1.0])
    scale = {"c": math.inf}
    key = gtsam.symbol("p", 0)
    noise = gtsam.noiseModel.Isotropic.Sigma(1, 0.01)

    def sample_factor(xi: float, yi: float) -> gtsam.CustomFactor:
        def error(this, values, jacobians):
            a, b = values.atVector(key)
            e = math.exp(min(b * xi, 50.0))  # far-off trial steps stay finite
            r = a * e - yi
            row = np.array([[e, a * xi * e]])
            c = scale["c"]
            if math.isfinite(c):
                rw = r / 0.01  # the kernel acts on the whitened residual
                s = c / math.sqrt(c * c + rw * rw)
                row = row * (s**3)
                r = r * s
            if jacobians is not None:
                jacobians[0] = row
            return np.array([r])

        return gtsam.CustomFactor(noise, [key], error)

    graph = gtsam.NonlinearFactorGraph()
    for xi, yi in zip(x, y):
        graph.add(sample_factor(float(xi), float(yi)))
    initial = gtsam.Values()
    initial.insert(key, np.array([0.5, 0.5]))
    return graph, initial, key, truth, scale


# (a) built-in factors: same answer as GTSAM's LevenbergMarquardtOptimizer
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pose_chain_matches_gtsam_lm(seed):
    graph, initial = pose_chain(seed=seed)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-12)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    expected = optimizer.optimize()

    result = levenberg_marquardt(graph, initial, SolverOptions(**TIGHT))

    assert result.converged and result.reason in CONVERGED_REASONS
    assert max_pose_difference(expected, result.values) < 1e-6
    assert result.error == pytest.approx(graph.error(expected), rel=1e-9)
    assert result.error == pytest.approx(graph.error(result.values), rel=0, abs=0)
    assert abs(result.iterations - optimizer.iterations()) <= 2
    assert result.initial_error == pytest.approx(graph.error(initial))


def test_fixed_lambda_policy_reproduces_gtsam_iterations():
    graph, initial = pose_chain(seed=3, start_noise=0.6)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams())
    expected = optimizer.optimize()
    result = levenberg_marquardt(graph, initial, SolverOptions(lambda_policy="fixed"))
    assert result.iterations == optimizer.iterations()
    assert max_pose_difference(expected, result.values) < 1e-9


def test_gauss_newton_matches_gtsam_gauss_newton():
    graph, initial = pose_chain(seed=4, start_noise=0.2)
    params = gtsam.GaussNewtonParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-12)
    expected = gtsam.GaussNewtonOptimizer(graph, initial, params).optimize()
    result = levenberg_marquardt(graph, initial, SolverOptions(gauss_newton=True, **TIGHT))
    assert result.converged
    assert max_pose_difference(expected, result.values) < 1e-6
    assert all(row["lambda_"] == 0.0 for row in result.log)


@pytest.mark.parametrize("ordering", ["time", "natural", "metis", "explicit"])
def test_orderings_agree(ordering):
    graph, initial = pose_chain(n=20, seed=5)
    reference = levenberg_marquardt(graph, initial, SolverOptions(**TIGHT))
    choice = list(reversed(list(initial.keys()))) if ordering == "explicit" else ordering
    result = levenberg_marquardt(graph, initial, SolverOptions(ordering=choice, **TIGHT))
    assert max_pose_difference(reference.values, result.values) < 1e-7



def test_nielsen_policy_wastes_fewer_solves_than_fixed_factor():
    """The default λ policy against GTSAM's ×10 / ÷10 on a robust curve fit from a poor start."""
    counts = {}
    for policy in ("nielsen", "fixed"):
        solves = rejected = 0
        for seed in range(4):
            graph, initial, key, truth, scale = exp_fit_problem(outliers=True, seed=seed)
            scale["c"] = 5.0
            result = levenberg_marquardt(graph, initial, SolverOptions(lambda_policy=policy, relative_tolerance=1e-8))
            assert result.converged
            np.testing.assert_allclose(result.values.atVector(key), truth, atol=0.05)
            solves += len(result.log)
            rejected += sum(not row["accepted"] for row in result.log)
        counts[policy] = (solves, rejected)
    assert counts["nielsen"][0] < counts["fixed"][0]
    assert counts["nielsen"][1] < counts["fixed"][1]

# (b) CustomFactors
def test_custom_factor_pose_chain_equals_builtin():
    graph, initial = pose_chain(n=25, seed=6)
    custom_graph, _ = pose_chain(n=25, seed=6, custom=True)
    assert custom_graph.error(initial) == pytest.approx(graph.error(initial), rel=1e-12)
    builtin = levenberg_marquardt(graph, initial, SolverOptions(**TIGHT))
    custom = levenberg_marquardt(custom_graph, initial, SolverOptions(**TIGHT))
    assert custom.converged
    assert max_pose_difference(builtin.values, custom.values) < 1e-6


def test_custom_factor_curve_fit_converges_to_truth():
    graph, initial, key, truth, _ = exp_fit_problem()
    initial_copy = np.array(initial.atVector(key))
    rows = []
    result = levenberg_marquardt(graph, initial, SolverOptions(**TIGHT), on_iteration=rows.append)
    assert result.converged
    np.testing.assert_allclose(result.values.atVector(key), truth, atol=1e-8)
    assert result.error < 1e-12
    np.testing.assert_array_equal(initial.atVector(key), initial_copy)  # the start is not modified
    assert rows == result.log and len(rows) >= result.iterations
    assert set(rows[0]) == set(SolveLog.__dataclass_fields__)
    accepted = [row for row in rows if row["accepted"]]
    assert all(row["cost_after"] < row["cost_before"] for row in accepted)


# (c) stages
def test_staged_solve_runs_setups_in_order_and_logs_stages():
    graph, initial, key, truth, scale = exp_fit_problem(outliers=True)
    calls = []

    def use_scale(c):
        def setup():
            calls.append(c)
            scale["c"] = c

        return setup

    coarse = SolverOptions(relative_tolerance=1e-2)
    fine = SolverOptions(relative_tolerance=1e-8, absolute_tolerance=1e-10)
    staged = solve_staged(
        graph, initial, [("l2", use_scale(math.inf), coarse), ("gm", use_scale(5.0), fine)]
    )
    assert calls == [math.inf, 5.0]
    stages = [row["stage"] for row in staged.log]
    assert stages[0] == "l2" and stages[-1] == "gm"
    assert stages == sorted(stages, key=["l2", "gm"].index)  # no interleaving
    assert staged.iterations == sum(1 for row in staged.log if row["attempt"] == 1)
    assert list(staged.stage_reasons) == ["l2", "gm"]
    assert staged.converged
    assert staged.error == pytest.approx(graph.error(staged.values))  # the last stage's objective

    scale["c"] = math.inf
    plain = levenberg_marquardt(graph, initial, fine)
    robust_error = np.abs(staged.values.atVector(key) - truth).max()
    assert robust_error < 0.02
    assert robust_error < 0.2 * np.abs(plain.values.atVector(key) - truth).max()


def test_staged_solve_needs_stages():
    graph, initial, *_ = exp_fit_problem()
    with pytest.raises(MocapgraphError):
        solve_staged(graph, initial, [])


# (d) projection
def bounded_problem():
    """x ∈ [0, 2] pulled towards 5, y pulled towards x and 1: constrained optimum x = 2, y = 1.5."""
    x_key, y_key = gtsam.symbol("x", 0), gtsam.symbol("y", 0)
    unit = gtsam.noiseModel.Unit.Create(1)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorVector(x_key, np.array([5.0]), unit))
    graph.add(gtsam.PriorFactorVector(y_key, np.array([1.0]), unit))

    def tie(this, values, jacobians):
        x, y = values.atVector(x_key), values.atVector(y_key)
        if jacobians is not None:
            jacobians[0] = np.array([[-1.0]])
            jacobians[1] = np.array([[1.0]])
        return y - x

    graph.add(gtsam.CustomFactor(unit, [x_key, y_key], tie))
    initial = gtsam.Values()
    initial.insert(x_key, np.array([0.0]))
    initial.insert(y_key, np.array([0.0]))
    return graph, initial, x_key, y_key


def test_project_keeps_variable_in_bounds_and_cost_non_increasing():
    graph, initial, x_key, y_key = bounded_problem()
    seen = []

    def clamp(values):
        projected = gtsam.Values(values)
        projected.update(x_key, np.clip(values.atVector(x_key), 0.0, 2.0))
        seen.append(float(projected.atVector(x_key)[0]))
        return projected

    result = levenberg_marquardt(graph, initial, SolverOptions(**TIGHT), project=clamp)
    assert seen and all(0.0 <= x <= 2.0 for x in seen)
    assert result.values.atVector(x_key)[0] == pytest.approx(2.0, abs=1e-9)
    assert result.values.atVector(y_key)[0] == pytest.approx(1.5, abs=1e-6)
    accepted = [row for row in result.log if row["accepted"]]
    costs = [accepted[0]["cost_before"]] + [row["cost_after"] for row in accepted]
    assert all(b <= a for a, b in zip(costs, costs[1:]))
    assert result.error == pytest.approx(graph.error(result.values), abs=0)  # evaluated after projecting


def test_project_that_raises_cost_is_never_accepted():
    graph, initial, x_key, _ = bounded_problem()

    def push_away(values):  # in place, returning None: the cost gets worse than at the start
        values.update(x_key, np.array([-10.0]))

    result = levenberg_marquardt(graph, initial, project=push_away)
    assert not any(row["accepted"] for row in result.log)
    assert result.error == pytest.approx(graph.error(initial))
    assert result.values.atVector(x_key)[0] == 0.0


def clamp_x(x_key, lo=0.0, hi=2.0):
    def clamp(values):
        projected = gtsam.Values(values)
        projected.update(x_key, np.clip(values.atVector(x_key), lo, hi))
        return projected

    return clamp


def test_active_set_is_kept_while_the_bound_stays_active():
    """x rests on its bound from the first step: later tries hold it from their first solve
    (no extra solve), and the solution is the constrained optimum."""
    graph, initial, x_key, y_key = bounded_problem()
    initial.update(y_key, np.array([-3.0]))  # y needs several damped steps to reach 1.5
    result = levenberg_marquardt(graph, initial, SolverOptions(initial_lambda=10.0, **TIGHT), project=clamp_x(x_key))
    assert result.values.atVector(x_key)[0] == pytest.approx(2.0, abs=1e-9)
    assert result.values.atVector(y_key)[0] == pytest.approx(1.5, abs=1e-6)
    extra = [row["active_set_solves"] for row in result.log]
    first = next(i for i, n in enumerate(extra) if n)  # the try that found the bound
    assert extra[first] == 1 and len(extra) - first >= 3
    assert not any(extra[first + 1 :])  # later tries held it from their first solve


def test_staged_solve_carries_the_active_set_into_the_next_stage():
    """A bound found in the first stage is held from the second stage's first solve."""
    graph, initial, x_key, y_key = bounded_problem()
    stages = [("a", None, SolverOptions(relative_tolerance=1e-3)), ("b", None, SolverOptions(**TIGHT))]
    result = solve_staged(graph, initial, stages, project=clamp_x(x_key))
    first = {stage: [row for row in result.log if row["stage"] == stage] for stage in ("a", "b")}
    assert any(row["active_set_solves"] for row in first["a"])
    assert first["b"] and first["b"][0]["active_set_solves"] == 0
    assert result.values.atVector(x_key)[0] == pytest.approx(2.0, abs=1e-9)
    assert result.values.atVector(y_key)[0] == pytest.approx(1.5, abs=1e-6)


def test_active_set_releases_a_bound_the_optimum_leaves():
    """x is driven onto its upper bound by the first damped steps, but the optimum is interior
    (x = y ≈ -4.9): the held bound is released when the model's gradient points inside."""
    x_key, y_key = gtsam.symbol("x", 0), gtsam.symbol("y", 0)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorVector(x_key, np.array([5.0]), gtsam.noiseModel.Unit.Create(1)))
    graph.add(gtsam.PriorFactorVector(y_key, np.array([-5.0]), gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))
    graph.add(gtsam.BetweenFactorVector(x_key, y_key, np.array([0.0]), gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))
    initial = gtsam.Values()
    initial.insert(x_key, np.array([1.9]))
    initial.insert(y_key, np.array([10.0]))
    result = levenberg_marquardt(
        graph, initial, SolverOptions(initial_lambda=1e3, **TIGHT), project=clamp_x(x_key, -10.0, 2.0)
    )
    # Unconstrained optimum of (x-5)² + 100(y+5)² + 100(y-x)²: solve the 2x2 normal equations.
    H = np.array([[1.0 + 100.0, -100.0], [-100.0, 200.0]])
    want = np.linalg.solve(H, [5.0, -500.0])
    assert want[0] < 2.0
    seen_x = [row for row in result.log if row["accepted"]]
    assert any(row["active_set_solves"] > 0 for row in seen_x)  # the bound was active on the way
    assert result.values.atVector(x_key)[0] == pytest.approx(want[0], abs=1e-6)
    assert result.values.atVector(y_key)[0] == pytest.approx(want[1], abs=1e-6)


# (e) marginal covariances
def test_marginal_covariances_match_gtsam_marginals():
    graph, initial = pose_chain(n=15, seed=7)
    values = levenberg_marquardt(graph, initial).values
    keys = [0, 4, 9, 14]
    ours = marginal_covariances(graph, values, keys)
    reference = gtsam.Marginals(graph, values)
    assert list(ours) == keys
    for key in keys:
        expected = reference.marginalCovariance(key)
        assert ours[key].shape == (6, 6)
        np.testing.assert_allclose(ours[key], expected, rtol=0, atol=1e-9 * max(1.0, np.abs(expected).max()))


def test_marginal_covariances_with_custom_factors_and_missing_key():
    graph, initial = pose_chain(n=15, seed=7)
    custom_graph, _ = pose_chain(n=15, seed=7, custom=True)
    values = levenberg_marquardt(graph, initial).values
    builtin = marginal_covariances(graph, values, [3, 12])
    custom = marginal_covariances(custom_graph, values, [3, 12])
    for key in builtin:
        np.testing.assert_allclose(custom[key], builtin[key], rtol=1e-9, atol=1e-14)
    with pytest.raises(MocapgraphError):
        marginal_covariances(graph, values, [99])


# (f) stopping rules
def test_optimal_start_stops_at_once():
    graph, initial = pose_chain(n=20, seed=8)
    solution = levenberg_marquardt(graph, initial, SolverOptions(**TIGHT)).values
    again = levenberg_marquardt(graph, solution)
    assert again.converged
    assert again.iterations <= 1
    assert max_pose_difference(solution, again.values) < 1e-9

    exact_graph, exact_initial, key, truth, _ = exp_fit_problem()
    exact = gtsam.Values()
    exact.insert(key, truth)
    zero_cost = levenberg_marquardt(exact_graph, exact)
    assert zero_cost.iterations == 0 and zero_cost.reason == "error_tolerance" and zero_cost.converged


def test_max_iterations_is_respected():
    graph, initial = pose_chain(seed=9, start_noise=0.8)
    result = levenberg_marquardt(graph, initial, SolverOptions(max_iterations=2))
    assert result.iterations == 2
    assert not result.converged and result.reason == "max_iterations"
    assert {row["iteration"] for row in result.log} == {1, 2}
    assert result.error < result.initial_error


def test_lambda_upper_bound_gives_up():
    graph, initial, x_key, _ = bounded_problem()
    result = levenberg_marquardt(
        graph, initial, SolverOptions(lambda_upper_bound=1e-3), project=lambda v: v.update(x_key, np.array([-10.0]))
    )
    assert result.reason == "lambda_upper_bound" and not result.converged
    assert all(row["lambda_"] <= 1e-3 * (1 + 1e-12) for row in result.log)


def test_invalid_options_raise():
    with pytest.raises(MocapgraphError):
        SolverOptions(ordering="amd")
    with pytest.raises(MocapgraphError):
        SolverOptions(lambda_lower_bound=0.0)
    with pytest.raises(MocapgraphError):
        SolverOptions(lambda_policy="magic")
