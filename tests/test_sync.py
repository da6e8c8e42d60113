"""Which camera frames each body state explains, under the three synchronisation policies."""

from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.errors import MocapgraphError
from mocapgraph.graphs.sync import timeline


@pytest.fixture
def free_running() -> list[np.ndarray]:
    """Two free-running cameras: 30 Hz from 0.010 s and 25 Hz from 0.000 s, and one frame of
    camera 1 within 1 ms of camera 0's."""
    rng = np.random.default_rng(0)
    a = np.sort(0.010 + np.arange(30) / 30.0 + rng.uniform(-1e-3, 1e-3, 30))
    b = np.arange(25) / 25.0
    b[10] = a[12] + 0.0008
    return [a, np.sort(b)]


def members(line) -> list[tuple[int, int]]:
    return sorted((c, int(j)) for c, s in enumerate(line.state) for j in np.flatnonzero(s >= 0))


def every_frame(stamps) -> list[tuple[int, int]]:
    return sorted((c, j) for c, ts in enumerate(stamps) for j in range(len(ts)))


def test_grid_places_every_frame_between_two_states_at_its_own_time(free_running):
    """Each frame belongs to exactly one state, and state time + fraction / rate is its timestamp."""
    stamps = np.concatenate(free_running)
    for rate in (30.0, 12.5, 100.0):
        line = timeline(free_running, "grid", rate_hz=rate)
        assert members(line) == every_frame(free_running)
        np.testing.assert_allclose(np.diff(line.times), 1.0 / rate, rtol=0, atol=1e-12)
        assert line.times[0] == stamps.min() and line.times[-1] >= stamps.max() > line.times[-2]
        for c, ts in enumerate(free_running):
            k, a = line.state[c], line.fraction[c]
            assert np.all((0.0 <= a) & (a < 1.0))
            np.testing.assert_allclose(line.times[k] + a / rate, ts, rtol=0, atol=1e-9)
            assert np.all((a == 0.0) | (k + 1 < len(line.times)))  # never interpolates past the last state


def test_grid_snaps_frames_on_grid_points():
    """Frames on the grid (to within float round-off) get fraction 0 at their own state."""
    stamps = [np.arange(10) / 30.0, np.arange(10) / 30.0 + 0.5 / 30.0]
    line = timeline(stamps, "grid", rate_hz=30.0)
    assert len(line.times) == 11  # the last state lies after camera 1's last frame at 9.5 / 30 s
    np.testing.assert_array_equal(line.state[0], np.arange(10))
    np.testing.assert_array_equal(line.fraction[0], 0.0)
    np.testing.assert_array_equal(line.state[1], np.arange(10))
    np.testing.assert_allclose(line.fraction[1], 0.5)
    assert not any(np.any(s == 10) for s in line.state)  # no frame at the last state


def test_states_merges_only_near_coincident_frames(free_running):
    line = timeline(free_running, "states")
    assert members(line) == every_frame(free_running)
    assert len(line.times) == 30 + 25 - 1
    assert line.state[0][12] == line.state[1][10]
    shared = np.intersect1d(line.state[0], line.state[1])
    assert shared.tolist() == [line.state[0][12]]
    assert all(np.all(a == 0.0) for a in line.fraction)
    assert np.all(np.diff(line.times) > 0)
    assert line.times[line.state[0][12]] == pytest.approx(0.5 * (free_running[0][12] + free_running[1][10]))


def test_closest_pairs_with_the_reference_camera(free_running):
    line = timeline(free_running, "closest", frame_rates=[30.0, 25.0])
    np.testing.assert_array_equal(line.times, free_running[0])
    np.testing.assert_array_equal(line.state[0], np.arange(30))
    paired = np.flatnonzero(line.state[1] >= 0)
    assert len(paired) > 0
    gaps = np.abs(free_running[1][paired] - line.times[line.state[1][paired]])
    assert np.all(gaps <= 0.5 / 25.0)
    # an unpaired frame of camera 1 is farther than half its period from every reference frame
    for j in np.flatnonzero(line.state[1] < 0):
        assert np.min(np.abs(free_running[0] - free_running[1][j])) > 0.5 / 25.0


def test_bad_policies_and_rates(free_running):
    with pytest.raises(MocapgraphError, match="unknown synchronisation policy"):
        timeline(free_running, "nearest")
    for bad in (0.0, -30.0, float("nan"), float("inf")):
        with pytest.raises(MocapgraphError, match="grid rate"):
            timeline(free_running, "grid", rate_hz=bad)
    with pytest.raises(MocapgraphError, match="no camera has frames"):
        timeline([np.zeros(0), np.zeros(0)], "grid")
    with pytest.raises(MocapgraphError, match="reference camera 1: has no frames"):
        timeline([free_running[0], np.zeros(0)], "closest", reference=1)
