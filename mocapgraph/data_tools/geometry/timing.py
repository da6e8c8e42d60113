"""Matching timestamps between streams that were not recorded on a common grid."""

from __future__ import annotations

import numpy as np


def match_times(reference: np.ndarray, query: np.ndarray, tolerance: float) -> np.ndarray:
    """Index into sorted ``reference (N,)`` nearest to each ``query (T,)`` time; -1 if farther than ``tolerance``."""
    reference = np.asarray(reference, dtype=float)
    query = np.asarray(query, dtype=float)
    right = np.clip(np.searchsorted(reference, query), 0, len(reference) - 1)
    left = np.clip(right - 1, 0, len(reference) - 1)
    nearest = np.where(np.abs(reference[left] - query) <= np.abs(reference[right] - query), left, right)
    return np.where(np.abs(reference[nearest] - query) <= tolerance, nearest, -1)
