"""Matching timestamps between streams that were not recorded on a common grid."""

from __future__ import annotations

import numpy as np


def match_times(
    reference: np.ndarray, query: np.ndarray, tolerance: float, *, rtol: float = 0.0, atol: float = 0.0
) -> np.ndarray:
    """Index of the ``reference`` time nearest to each ``query`` time, or -1 where none is close enough.

    Args:
        reference: ``(N,)`` sorted seconds, N >= 1.
        query: ``(T,)`` seconds, any order.
        tolerance: largest accepted gap, seconds.
        rtol, atol: slack on the tolerance: a gap is accepted when
            ``|reference[i] - query[t]| <= tolerance * (1 + rtol) + atol``. Tolerances such as half
            a frame period put frames exactly on the boundary, where rounding alone would decide.

    Returns:
        ``(T,)`` int64 indices into ``reference``; between two equally near times, the earlier.
    """
    reference = np.asarray(reference, dtype=float)
    query = np.asarray(query, dtype=float)
    right = np.clip(np.searchsorted(reference, query), 0, len(reference) - 1)
    left = np.clip(right - 1, 0, len(reference) - 1)
    nearest = np.where(np.abs(reference[left] - query) <= np.abs(reference[right] - query), left, right)
    return np.where(np.abs(reference[nearest] - query) <= tolerance * (1 + rtol) + atol, nearest, -1)
