"""The fixed-lag smoother against the full-history batch solution of a linear problem."""

from __future__ import annotations

import gtsam
import numpy as np

from mocapgraph.graphs.fixed_lag import FixedLagSmoother, Relinearisation


def test_window_matches_the_full_batch_solution_without_batch_steps():
    """A chain of 3-vectors with a kept key all states see and observations that reach 4 and 7
    states back (late ones): on a linear problem marginalisation is exact, so every key in the
    window equals the batch solution of the whole history; the tree stays ordered in time, so
    a new state re-eliminates only the newest ones, and every leaving key is a leaf."""
    x = lambda i: gtsam.symbol("x", i)  # noqa: E731
    shared = gtsam.symbol("c", 0)
    rng = np.random.default_rng(0)
    tight, loose = gtsam.noiseModel.Isotropic.Sigma(3, 0.1), gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
    smoother = FixedLagSmoother(0.5, Relinearisation(enabled=False))
    history, start = gtsam.NonlinearFactorGraph(), gtsam.Values()
    batches, left = [], 0
    for i in range(120):
        factors, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {x(i): 0.05 * i}
        values.insert(x(i), np.zeros(3))
        if i == 0:
            factors.add(gtsam.PriorFactorVector(x(0), np.zeros(3), tight))
            factors.add(gtsam.PriorFactorVector(shared, np.ones(3), tight))
            values.insert(shared, np.zeros(3))
            stamps[shared] = 0.0
        else:
            factors.add(gtsam.BetweenFactorVector(x(i - 1), x(i), 0.1 + rng.normal(0, 0.05, 3), tight))
        factors.add(gtsam.BetweenFactorVector(shared, x(i), 0.1 * i - 1 + rng.normal(0, 0.1, 3), loose))
        for back in (4, 7):
            if i >= back and i % back == 0:
                factors.add(gtsam.BetweenFactorVector(x(i - back), x(i), np.full(3, 0.1 * back), tight))
        report = smoother.update(factors, values, stamps, keep=[shared])
        batches.append(report.batch)
        left += len(report.marginalised)
        history.push_back(factors)
        start.insert(values)
    reference = gtsam.LevenbergMarquardtOptimizer(history, start).optimize()
    assert left == 120 - 11 and len(smoother.timestamps) == 12  # 11 states in 0.5 s, and the kept key
    for key in smoother.estimate.keys():
        np.testing.assert_allclose(smoother.estimate.atVector(key), reference.atVector(key), atol=1e-7)
    # batch steps: while the window fills, and where an observation reaches 7 of its 11 states
    # back (iSAM2 re-eliminates those and the newer ones: over its 65 % line); none for 4 back
    steps = [i for i, b in enumerate(batches) if b]
    assert all(i < 5 or i % 7 == 0 for i in steps) and not any(batches[i] for i in range(8, 120, 4) if i % 7)
