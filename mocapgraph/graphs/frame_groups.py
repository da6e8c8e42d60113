"""Which camera frames share a body state: the time axis of every body graph.

Cameras need not be synchronised. Three policies:

- ``"grid"``: body states on a regular time grid (``rate_hz``, e.g. 30 Hz), and every camera
  frame explained at its own timestamp by the state interpolated between its two neighbours
  (``FrameGroup.fractions``; :mod:`mocapgraph.factors.interpolation`). There are as many states
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
  reference time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.data_tools.geometry.timing import match_times
from mocapgraph.errors import MocapgraphError

SYNC_POLICIES = ("grid", "states", "closest")
_SNAP = 1e-6
"""A grid fraction this close to 0 or 1 is snapped to the grid state (33 ns at 30 Hz)."""


@dataclass
class FrameGroup:
    """One body state: its time (seconds) and the ``(camera index, frame index)`` pairs it explains."""

    time: float
    members: list[tuple[int, int]]
    fractions: list[float] = field(default_factory=list)
    """``"grid"`` only: per member, where its frame lies between this state (0) and the next
    (towards 1, exclusive); empty means every member is at the state's own time."""

    def fraction(self, m: int) -> float:
        """Where member ``m`` lies between this state and the next (0: at this state)."""
        return self.fractions[m] if self.fractions else 0.0


def _grid_groups(stamps: list[tuple[float, int, int]], rate_hz: float) -> list[FrameGroup]:
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise MocapgraphError(f"grid rate: must be a finite number of Hz > 0, got {rate_hz}")
    period = 1.0 / rate_hz
    start, end = stamps[0][0], stamps[-1][0]
    count = math.ceil((end - start) / period - _SNAP) + 1  # the last state at or after the last frame
    groups = [FrameGroup(start + k * period, [], []) for k in range(count)]
    for t, c, j in stamps:
        position = (t - start) / period
        k = min(int(math.floor(position)), count - 1)
        fraction = position - k
        if fraction > 1.0 - _SNAP:
            k, fraction = min(k + 1, count - 1), 0.0
        elif fraction < _SNAP or k == count - 1:
            fraction = 0.0
        groups[k].members.append((c, j))
        groups[k].fractions.append(fraction)
    return groups


def frame_groups(
    capture: Capture, sync: str = "states", reference: int = 0, merge_s: float = 2e-3, rate_hz: float = 30.0
) -> list[FrameGroup]:
    """The body states of ``capture`` in time order, under the ``sync`` policy (``rate_hz``:
    the ``"grid"`` policy's state rate)."""
    if sync not in SYNC_POLICIES:
        raise MocapgraphError(f"unknown synchronisation policy {sync!r}; choose one of {', '.join(SYNC_POLICIES)}")
    if sync in ("states", "grid"):
        stamps = [(float(t), c, j) for c, cam in enumerate(capture.cameras) for j, t in enumerate(cam.timestamps)]
        stamps.sort()
        if not stamps:
            raise MocapgraphError(f"capture {capture.name!r}: no camera has frames")
        if sync == "grid":
            return _grid_groups(stamps, rate_hz)
        groups: list[FrameGroup] = []
        first = 0.0
        for t, c, j in stamps:
            if groups and t - first <= merge_s:
                groups[-1].members.append((c, j))
                n = len(groups[-1].members)
                groups[-1].time += (float(t) - groups[-1].time) / n  # running mean of the members
            else:
                first = float(t)
                groups.append(FrameGroup(first, [(c, j)]))
        return groups
    ref = capture.cameras[reference]
    groups = [FrameGroup(float(t), [(reference, j)]) for j, t in enumerate(ref.timestamps)]
    for c, cam in enumerate(capture.cameras):
        if c == reference:
            continue
        nearest = match_times(ref.timestamps, cam.timestamps, tolerance=0.5 / cam.frame_rate)
        for j in np.flatnonzero(nearest >= 0):
            groups[nearest[j]].members.append((c, int(j)))
    return groups
