"""Which camera frames each body state explains, under the three synchronisation policies."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mocapgraph.data_tools.io.capture import Camera, Capture
from mocapgraph.errors import MocapgraphError
from mocapgraph.graphs.frame_groups import frame_groups

K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])


def capture_with(*timestamps) -> Capture:
    cameras = [
        Camera(
            name=f"cam{c}", K=K, distortion=np.zeros(5), image_size=(640, 480), moving=False,
            timestamps=np.asarray(t, dtype=float), frame_rate=30.0,
        )  # fmt: skip
        for c, t in enumerate(timestamps)
    ]
    return Capture(name="timing", cameras=cameras)


@pytest.fixture
def free_running() -> Capture:
    """Two free-running cameras: 30 Hz from 0.010 s and 25 Hz from 0.000 s, and one frame of
    camera 1 within 1 ms of camera 0's."""
    rng = np.random.default_rng(0)
    a = 0.010 + np.arange(30) / 30.0 + rng.uniform(-1e-3, 1e-3, 30)
    b = np.arange(25) / 25.0
    b[10] = a[12] + 0.0008
    return capture_with(np.sort(a), np.sort(b))


def members(groups) -> list[tuple[int, int]]:
    return sorted(m for g in groups for m in g.members)


def every_frame(capture: Capture) -> list[tuple[int, int]]:
    return sorted((c, j) for c, cam in enumerate(capture.cameras) for j in range(cam.num_frames))


def test_grid_places_every_frame_between_two_states_at_its_own_time(free_running):
    """Each frame is in exactly one group, and group time + fraction / rate is its timestamp."""
    for rate in (30.0, 12.5, 100.0):
        groups = frame_groups(free_running, "grid", rate_hz=rate)
        assert members(groups) == every_frame(free_running)
        times = np.array([g.time for g in groups])
        np.testing.assert_allclose(np.diff(times), 1.0 / rate, rtol=0, atol=1e-12)
        stamps = np.concatenate([cam.timestamps for cam in free_running.cameras])
        assert times[0] == stamps.min() and times[-1] >= stamps.max() > times[-2]
        for k, g in enumerate(groups):
            assert len(g.fractions) == len(g.members)
            for (c, j), a in zip(g.members, g.fractions):
                assert 0.0 <= a < 1.0
                assert g.time + a / rate == pytest.approx(free_running.cameras[c].timestamps[j], abs=1e-9)
                assert a == 0.0 or k + 1 < len(groups)  # never interpolates past the last state


def test_grid_snaps_frames_on_grid_points():
    """Frames on the grid (to within float round-off) get fraction 0 at their own state."""
    capture = capture_with(np.arange(10) / 30.0, np.arange(10) / 30.0 + 0.5 / 30.0)
    groups = frame_groups(capture, "grid", rate_hz=30.0)
    assert len(groups) == 11  # the last state lies after camera 1's last frame at 9.5 / 30 s
    for k, g in enumerate(groups[:10]):
        at = dict(zip(g.members, g.fractions))
        assert at[(0, k)] == 0.0
        assert at[(1, k)] == pytest.approx(0.5)
    assert groups[10].members == []


def test_states_merges_only_near_coincident_frames(free_running):
    groups = frame_groups(free_running, "states")
    assert members(groups) == every_frame(free_running)
    assert len(groups) == 30 + 25 - 1
    merged = [g for g in groups if len(g.members) == 2]
    assert len(merged) == 1 and sorted(merged[0].members) == [(0, 12), (1, 10)]
    assert all(g.fraction(m) == 0.0 for g in groups for m in range(len(g.members)))
    assert np.all(np.diff([g.time for g in groups]) > 0)


def test_closest_pairs_with_the_reference_camera(free_running):
    groups = frame_groups(free_running, "closest")
    assert len(groups) == 30
    ref = free_running.cameras[0].timestamps
    other = free_running.cameras[1].timestamps
    for g, t in zip(groups, ref):
        assert g.time == t
        for c, j in g.members[1:]:
            assert c == 1 and abs(other[j] - t) <= 0.5 / 25.0


def test_bad_policies_and_rates(free_running):
    with pytest.raises(MocapgraphError, match="unknown synchronisation policy"):
        frame_groups(free_running, "nearest")
    for bad in (0.0, -30.0, float("nan"), float("inf")):
        with pytest.raises(MocapgraphError, match="grid rate"):
            frame_groups(free_running, "grid", rate_hz=bad)
    empty = replace(free_running, cameras=[replace(cam, timestamps=np.zeros(0)) for cam in free_running.cameras])
    with pytest.raises(MocapgraphError, match="no camera has frames"):
        frame_groups(empty, "grid")
