"""Which camera frames share a body state: the time axis of every body graph.

Cameras need not be synchronised. Two policies:

- ``"states"`` (default): a body state at every distinct camera frame time; frames of different
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

from dataclasses import dataclass

import numpy as np

from mocapgraph.data_tools.capture import Capture
from mocapgraph.data_tools.timing import match_times
from mocapgraph.errors import MocapgraphError

SYNC_POLICIES = ("states", "closest")


@dataclass
class FrameGroup:
    """One body state: its time (seconds) and the ``(camera index, frame index)`` pairs it explains."""

    time: float
    members: list[tuple[int, int]]


def frame_groups(capture: Capture, sync: str = "states", reference: int = 0, merge_s: float = 2e-3) -> list[FrameGroup]:
    """The body states of ``capture`` in time order, under the ``sync`` policy."""
    if sync not in SYNC_POLICIES:
        raise MocapgraphError(f"unknown synchronisation policy {sync!r}; choose one of {', '.join(SYNC_POLICIES)}")
    if sync == "states":
        stamps = [(t, c, j) for c, cam in enumerate(capture.cameras) for j, t in enumerate(cam.timestamps)]
        stamps.sort()
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
