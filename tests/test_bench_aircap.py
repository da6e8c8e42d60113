"""The uncertainty score of `bench aircap`: coverage of the joints' 95 % ellipsoids."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from mocapgraph.benchmarks.aircap import coverage
from mocapgraph.data_tools.io.result import Result


def result_with_errors(scale: float, seed: int = 0, frames: int = 400):
    """Joints off the truth by draws of N(0, Σ) with random per-joint Σ; the result reports
    ``scale² Σ``. Returns (result, truth)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(scale=0.02, size=(frames, 22, 3, 3))
    cov = A @ np.swapaxes(A, -1, -2) + 1e-6 * np.eye(3)
    truth = rng.normal(size=(frames, 22, 3))
    noise = np.einsum("tjab,tjb->tja", np.linalg.cholesky(cov), rng.normal(size=(frames, 22, 3)))
    result = Result("aircap", "synthetic", "capture", np.arange(frames) / 30.0, truth + noise)
    result.covariances["joints"] = scale**2 * cov
    return result, truth


def test_coverage_of_honest_covariances_is_the_level():
    result, truth = result_with_errors(1.0)
    assert coverage(result, truth) == pytest.approx(0.95, abs=0.01)  # 8800 joints: 0.95 ± 0.005 (2σ)


def test_coverage_of_inflated_and_shrunk_covariances():
    """Doubling σ covers P(χ²₃ ≤ 4·7.81); halving it P(χ²₃ ≤ 7.81 / 4)."""
    inflated, truth = result_with_errors(2.0, seed=1)
    shrunk, _ = result_with_errors(0.5, seed=1)
    threshold = chi2.ppf(0.95, 3)
    assert coverage(inflated, truth) == pytest.approx(chi2.cdf(4 * threshold, 3), abs=0.01)
    assert coverage(shrunk, truth) == pytest.approx(chi2.cdf(threshold / 4, 3), abs=0.01)


def test_coverage_on_selected_states_and_skips_non_finite():
    result, truth = result_with_errors(1.0, seed=2)
    result.joints[5] = np.nan
    keep = np.zeros(len(truth), bool)
    keep[:200] = True
    full = coverage(result, truth[keep], keep)
    result.covariances["joints"][300:] = 1e-12  # states outside the selection do not count
    assert coverage(result, truth[keep], keep) == full
    assert full == pytest.approx(0.95, abs=0.02)
