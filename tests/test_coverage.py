"""Coverage of the joints' 95 % ellipsoids (the uncertainty score of `bench aircap`) against χ²₃."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from mocapgraph.data_tools.evaluation.metrics import Unit, covariance_coverage


def result_with_errors(scale: float, seed: int = 0, frames: int = 400):
    """Joints off the truth by draws of N(0, Σ) with random per-joint Σ, reported as ``scale² Σ``.
    Returns ``(estimate, covariances, truth)``."""
    rng = np.random.default_rng(seed)
    A = rng.normal(scale=0.02, size=(frames, 22, 3, 3))
    cov = A @ np.swapaxes(A, -1, -2) + 1e-6 * np.eye(3)
    truth = rng.normal(size=(frames, 22, 3))
    noise = np.einsum("tjab,tjb->tja", np.linalg.cholesky(cov), rng.normal(size=(frames, 22, 3)))
    return truth + noise, scale**2 * cov, truth


def coverage(est, cov, truth, states=slice(None)) -> float:
    result = covariance_coverage(est[states], truth, cov[states])
    assert result.unit is Unit.FRACTION
    return result.value


def test_coverage_of_honest_covariances_is_the_level():
    est, cov, truth = result_with_errors(1.0)
    assert coverage(est, cov, truth) == pytest.approx(0.95, abs=0.01)  # 8800 joints: 0.95 ± 0.005 (2σ)


def test_coverage_of_inflated_and_shrunk_covariances():
    """Doubling σ covers P(χ²₃ ≤ 4·7.81); halving it P(χ²₃ ≤ 7.81 / 4)."""
    est, inflated, truth = result_with_errors(2.0, seed=1)
    _, shrunk, _ = result_with_errors(0.5, seed=1)
    threshold = chi2.ppf(0.95, 3)
    assert coverage(est, inflated, truth) == pytest.approx(chi2.cdf(4 * threshold, 3), abs=0.01)
    assert coverage(est, shrunk, truth) == pytest.approx(chi2.cdf(threshold / 4, 3), abs=0.01)


def test_coverage_on_selected_states_and_skips_non_finite():
    est, cov, truth = result_with_errors(1.0, seed=2)
    est[5] = np.nan
    keep = np.zeros(len(truth), bool)
    keep[:200] = True
    full = coverage(est, cov, truth[keep], keep)
    cov[300:] = 1e-12  # states outside the selection do not count
    assert coverage(est, cov, truth[keep], keep) == full
    assert full == pytest.approx(0.95, abs=0.02)
    assert covariance_coverage(est[keep], truth[keep], cov[keep]).excluded == 22  # frame 5's joints
