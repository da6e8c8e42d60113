"""`bench priors`' pieces that need no motion directory: the corruptions and the held-out take links."""

import numpy as np
import pytest
from conftest import random_root

from mocapgraph.benchmarks.priors import corrupt, held_out_takes
from mocapgraph.errors import MocapgraphError


@pytest.fixture
def motion():
    rng = np.random.default_rng(0)
    return random_root(rng, 300), rng.normal(scale=0.3, size=(300, 21, 3))


def test_jitter_adds_noise_of_the_stated_size(motion):
    root, pose = motion
    r, p = corrupt("jitter", root, pose, np.random.default_rng(1))
    assert np.std(p - pose) == pytest.approx(np.deg2rad(5.0), rel=0.05)
    assert np.std(r[:, :3, 3] - root[:, :3, 3]) == pytest.approx(0.02, rel=0.1)
    np.testing.assert_array_equal(r[:, :3, :3], root[:, :3, :3])


def test_skating_glides_the_root_and_keeps_the_pose(motion):
    root, pose = motion
    r, p = corrupt("skate", root, pose, np.random.default_rng(1))
    np.testing.assert_allclose(r[:, 0, 3] - root[:, 0, 3], 1.25 * np.arange(300) / 30.0)
    np.testing.assert_array_equal(r[:, 1:3, 3], root[:, 1:3, 3])
    np.testing.assert_array_equal(p, pose)


def test_flip_turns_the_body_up_axis_into_its_forward_axis(motion):
    root, pose = motion
    r, _ = corrupt("flip", root, pose, np.random.default_rng(1))
    np.testing.assert_allclose(r[:, :3, 1], root[:, :3, 2], atol=1e-12)  # body +Y (up) now where +Z (forward) was
    np.testing.assert_allclose(r[:, :3, 3], root[:, :3, 3])
    with pytest.raises(MocapgraphError, match="unknown corruption 'melt'"):
        corrupt("melt", root, pose, np.random.default_rng(1))


def test_held_out_takes_are_only_the_held_out_subjects(tmp_path):
    source = tmp_path / "motion"
    source.mkdir()
    for name in ("cmu_02_01.npz", "cmu_03_07_s1.npz", "cmu_15_01.npz", "index.json"):
        (source / name).write_bytes(b"x")
    held_out = held_out_takes(source, [2, 15])
    assert [p.name for p in held_out] == ["cmu_02_01.npz", "cmu_15_01.npz"]
    with pytest.raises(MocapgraphError, match="nowhere: motion directory not found"):
        held_out_takes(tmp_path / "nowhere", [2])
