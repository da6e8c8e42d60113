"""Which camera frames share a body state: the time axis of every body graph.

Cameras need not be synchronised. Three policies place body states in time and assign every
camera frame to one of them (or to none):

- ``"grid"``: body states on a regular time grid (``rate_hz``, e.g. 30 Hz), and every camera
  frame explained at its own timestamp by the state interpolated between its two neighbours
  (the frame's *fraction*; :mod:`mocapgraph.factors.interpolation`). There are as many states
  as grid points whatever the number of cameras, each one constrained by every camera that saw
  the body near it; the cost is the interpolation (slerp of the root, linear joint rotation
  vectors) between states 33 ms apart.
- ``"states"``: a body state at every distinct camera frame time; frames of different
  cameras share a state only when their timestamps lie within ``merge_s`` (default 2 ms) of each
  other: synchronised rigs, or near-coincidences of free-running cameras, where a body moving at
  1.5 m/s shifts by at most 1.5 mm from the state's (mean) time. Every detection is otherwise used
  at its own timestamp, with no interpolation error; the cost is more states (about the number of
  cameras times the frame rate per second), each seen by fewer cameras, which the temporal
  smoothness factors tie together. Merging near-coincident frames also keeps those factors well
  conditioned: their weights grow as 1/Δt².
- ``"closest"``: the thesis' pairing. States at the reference camera's frames; every other camera
  contributes its frame nearest in time if within half its frame period, as if taken at the
  reference time. Other frames belong to no state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mocapgraph.data_tools.geometry.timing import match_times
from mocapgraph.errors import MocapgraphError

SYNC_POLICIES = ("grid", "states", "closest")
_SNAP = 1e-6
"""A grid fraction this close to 0 or 1 is snapped to the grid state (33 ns at 30 Hz)."""
# A grid past this size is a clock offset between cameras (an epoch clock beside a zero-based
# one), not a capture: a day at 100 Hz is 8.6e6 states.
_MAX_GRID_STATES = 10_000_000


@dataclass
class Timeline:
    """Body-state times and where every camera frame sits among them.

    Attributes:
        times: ``(N,)`` seconds of the body states, increasing.
        state: per camera, ``(F_c,)`` the state each frame is explained by, -1 for none.
        fraction: per camera, ``(F_c,)`` where the frame lies between its state (0) and the next
            (towards 1, exclusive); 0 except under ``"grid"``.
    """

    times: np.ndarray
    state: list[np.ndarray]
    fraction: list[np.ndarray]


def _stamps(timestamps: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every frame of every camera in time order: ``(times, camera, frame)``."""
    t = np.concatenate([np.asarray(ts, dtype=float) for ts in timestamps]) if timestamps else np.zeros(0)
    cam = np.concatenate([np.full(len(ts), c) for c, ts in enumerate(timestamps)]) if timestamps else np.zeros(0, int)
    frame = np.concatenate([np.arange(len(ts)) for ts in timestamps]) if timestamps else np.zeros(0, int)
    order = np.argsort(t, kind="stable")
    return t[order], cam[order].astype(int), frame[order].astype(int)


def _empty(timestamps: list[np.ndarray]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    return [np.full(len(ts), -1, dtype=int) for ts in timestamps], [np.zeros(len(ts)) for ts in timestamps]


def _grid(timestamps: list[np.ndarray], rate_hz: float) -> Timeline:
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise MocapgraphError(f"grid rate: must be a finite number of Hz > 0, got {rate_hz}")
    t, cams, frames = _stamps(timestamps)
    period = 1.0 / rate_hz
    start, end = t[0], t[-1]
    count = math.ceil((end - start) / period - _SNAP) + 1  # the last state at or after the last frame
    if count > _MAX_GRID_STATES:
        raise MocapgraphError(
            f"grid: the frames span {end - start:.4g} s, which at {rate_hz:g} Hz is {count:.3g} body states "
            f"(at most {_MAX_GRID_STATES:.0e}); do the cameras' clocks share one time axis?"
        )
    state, fraction = _empty(timestamps)
    position = (t - start) / period
    k = np.minimum(np.floor(position).astype(int), count - 1)
    a = position - k
    up = a > 1.0 - _SNAP
    k = np.where(up, np.minimum(k + 1, count - 1), k)
    a = np.where(up | (a < _SNAP) | (k == count - 1), 0.0, a)
    for c, j, kk, aa in zip(cams, frames, k, a):
        state[c][j], fraction[c][j] = kk, aa
    return Timeline(start + period * np.arange(count), state, fraction)


def _merged(timestamps: list[np.ndarray], merge_s: float) -> Timeline:
    t, cams, frames = _stamps(timestamps)
    state, fraction = _empty(timestamps)
    times: list[float] = []
    counts: list[int] = []
    first = 0.0
    for time, c, j in zip(t, cams, frames):
        if times and time - first <= merge_s:
            counts[-1] += 1
            times[-1] += (float(time) - times[-1]) / counts[-1]  # running mean of the members
        else:
            first = float(time)
            times.append(first)
            counts.append(1)
        state[c][j] = len(times) - 1
    return Timeline(np.array(times), state, fraction)


def _closest(timestamps: list[np.ndarray], frame_rates: list[float], reference: int) -> Timeline:
    ref = np.asarray(timestamps[reference], dtype=float)
    state, fraction = _empty(timestamps)
    for c, ts in enumerate(timestamps):
        state[c] = np.arange(len(ts)) if c == reference else match_times(ref, ts, tolerance=0.5 / frame_rates[c])
    return Timeline(ref.copy(), state, fraction)


def timeline(
    timestamps: list[np.ndarray],
    sync: str = "states",
    *,
    frame_rates: list[float] | None = None,
    reference: int = 0,
    merge_s: float = 2e-3,
    rate_hz: float = 30.0,
) -> Timeline:
    """The body states of cameras with frame times ``timestamps`` (per camera ``(F_c,)``,
    seconds, increasing) under the ``sync`` policy.

    ``frame_rates`` (per camera, Hz) set ``"closest"``'s half-period tolerance (default: from
    the median frame interval); ``reference`` is its camera; ``merge_s`` is ``"states"``'s
    merging window and ``rate_hz`` ``"grid"``'s state rate.
    """
    if sync not in SYNC_POLICIES:
        raise MocapgraphError(f"unknown synchronisation policy {sync!r}; choose one of {', '.join(SYNC_POLICIES)}")
    if not any(len(ts) for ts in timestamps):
        raise MocapgraphError("no camera has frames")
    if sync == "grid":
        return _grid(timestamps, rate_hz)
    if sync == "states":
        return _merged(timestamps, merge_s)
    if not 0 <= reference < len(timestamps) or not len(timestamps[reference]):
        raise MocapgraphError(f"reference camera {reference}: has no frames to place the states at")
    if frame_rates is None:
        frame_rates = [1.0 / float(np.median(np.diff(ts))) if len(ts) > 1 else 1.0 for ts in timestamps]
    return _closest(timestamps, list(frame_rates), reference)
