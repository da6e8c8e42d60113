"""The one exception type users see, and input checks that raise it with the offending field named."""

from __future__ import annotations

import math

import numpy as np


class MocapgraphError(Exception):
    """A problem with the user's input or environment, worded for the user (no traceback needed)."""


def is_positive_number(value) -> bool:
    """Whether an option's ``value`` is a finite int or float above zero (the options classes'
    common check; each raises its own message naming the field)."""
    return isinstance(value, (int, float)) and math.isfinite(value) and value > 0


def as_checked_array(
    value, name: str, shape: tuple[int | None, ...], *, finite: bool = True
) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` (None = any size), or a MocapgraphError naming ``name``."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise MocapgraphError(f"{name}: not a numeric array ({exc})") from None
    if arr.ndim != len(shape) or any(s is not None and s != g for s, g in zip(shape, arr.shape)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise MocapgraphError(f"{name}: expected shape {want}, got {arr.shape}")
    if finite and not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise MocapgraphError(f"{name}: contains NaN or inf (first at index {tuple(int(i) for i in bad)})")
    return arr
