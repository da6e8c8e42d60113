"""Executors: the local pool (in-process and forked) and Ray give the results of a plain loop, in
order, and a failing task is named without losing the others' results."""

from __future__ import annotations

import functools
import sys

import gtsam
import numpy as np
import pytest

from mocapgraph.errors import MocapgraphError
from mocapgraph.pipelines import executors
from mocapgraph.pipelines.executors import TaskError, make_executor


def seeded_lstsq(seed: int) -> np.ndarray:
    """Least-squares line-and-plane fit of 40 noisy points drawn from ``seed``: ``(3,)``."""
    rng = np.random.default_rng(seed)
    A = np.column_stack([rng.normal(size=(40, 2)), np.ones(40)])
    b = A @ np.array([1.5, -0.5, float(seed)]) + rng.normal(scale=0.1, size=40)
    return np.linalg.lstsq(A, b, rcond=None)[0]


def seeded_pose_chain(seed: int) -> np.ndarray:
    """A 6-pose Pose2 chain with noisy odometry and a loop closure from ``seed``, solved by LM:
    ``(6, 3)`` rows of x, y (m), theta (rad)."""
    rng = np.random.default_rng(seed)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    noise = gtsam.noiseModel.Isotropic.Sigma(3, 0.1)
    graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(), noise))
    step = gtsam.Pose2(1.0, 0.0, np.pi / 3)
    pose = gtsam.Pose2()
    for i in range(6):
        values.insert(i, pose.compose(gtsam.Pose2(*rng.normal(scale=0.2, size=3))))
        pose = pose.compose(step)
        if i:
            graph.add(gtsam.BetweenFactorPose2(i - 1, i, step.compose(gtsam.Pose2(*rng.normal(scale=0.05, size=3))), noise))
    graph.add(gtsam.BetweenFactorPose2(5, 0, step, noise))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    return np.array([[result.atPose2(i).x(), result.atPose2(i).y(), result.atPose2(i).theta()] for i in range(6)])


def square_but_three(i: int) -> int:
    if i == 3:
        raise MocapgraphError("item 3 is bad")
    if i == 5:
        raise ValueError("item 5 is worse")
    return i * i


@pytest.mark.parametrize("workers", [1, 2])
def test_local_matches_a_plain_loop_in_order(workers, bars):
    made = bars(executors)
    expected = [seeded_lstsq(s) for s in range(8)]
    with make_executor("local", workers=workers) as pool:
        got = pool.map(seeded_lstsq, list(range(8)), progress="fit")
    assert len(got) == 8
    for e, g in zip(expected, got):
        np.testing.assert_array_equal(e, g)
    # the fits recover the plane they were drawn from, so the items did not get mixed up
    assert np.allclose([g[2] for g in got], np.arange(8), atol=0.1)
    (bar,) = made
    assert (bar.desc, bar.total, bar.updates) == ("fit", 8, 8)
    with make_executor("local", workers=workers) as pool:
        assert pool.map(functools.partial(pow, 2), [3, 5, 10]) == [8, 32, 1024]


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failing_task_is_named_and_the_others_are_kept(workers):
    with make_executor("local", workers=workers) as pool, pytest.raises(TaskError) as info:
        pool.map(square_but_three, list(range(7)))
    assert isinstance(info.value, MocapgraphError)
    assert str(info.value) == "task 3 of 7 failed: item 3 is bad (1 more failed: tasks 5)"
    assert info.value.failures == {3: "item 3 is bad", 5: "ValueError: item 5 is worse"}
    assert info.value.results == [0, 1, 4, None, 16, None, 36]


def test_bad_kind_workers_and_address():
    with pytest.raises(MocapgraphError, match="executor 'dask': choose one of local, ray"):
        make_executor("dask")
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(MocapgraphError, match="workers: a whole number of processes >= 1"):
            make_executor("local", workers=bad)
    with pytest.raises(MocapgraphError, match="only the ray executor joins a cluster"):
        make_executor("local", address="auto")


@pytest.fixture(scope="module")
def ray_pool():
    """A local Ray instance of 2 CPUs started by the executor, shut down with it.

    Ray's workers do not see pytest's ``tests/`` on their path, so this module's functions go
    by value; the package's own functions go by reference as usual.
    """
    import ray  # the [distributed] extra, installed by `make install`: missing must fail here

    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    with make_executor("ray", workers=2) as pool:
        assert ray.is_initialized() and ray.cluster_resources()["CPU"] == 2
        yield pool
    assert not ray.is_initialized()


def test_ray_gives_the_local_results(ray_pool, bars):
    made = bars(executors)
    seeds = list(range(6))
    with make_executor("local", workers=1) as local:
        expected = local.map(seeded_pose_chain, seeds)
    got = ray_pool.map(seeded_pose_chain, seeds, progress="ray")
    for e, g in zip(expected, got):
        np.testing.assert_array_equal(e, g)
    # consecutive poses sit about a metre apart around the loop: a solved chain, not the start
    steps = np.linalg.norm(np.diff(np.stack(got)[:, :, :2], axis=1), axis=2)
    assert np.allclose(steps, 1.0, atol=0.15)
    bar = made[-1]
    assert (bar.desc, bar.total, bar.updates) == ("ray", 6, 6)


def test_ray_failing_task_and_joining_a_running_instance(ray_pool):
    import ray

    with pytest.raises(TaskError) as info:
        ray_pool.map(square_but_three, list(range(7)))
    assert str(info.value) == "task 3 of 7 failed: item 3 is bad (1 more failed: tasks 5)"
    assert info.value.failures == {3: "item 3 is bad", 5: "ValueError: item 5 is worse"}
    assert info.value.results == [0, 1, 4, None, 16, None, 36]
    # a second executor joins the running instance and leaves it running when it closes
    with make_executor("ray", workers=2) as joined:
        assert joined.map(functools.partial(pow, 2), [3, 5, 10]) == [8, 32, 1024]
    assert ray.is_initialized()


def test_ray_missing_is_one_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray now raises ImportError
    with pytest.raises(MocapgraphError, match=r"needs the \[distributed\] extra: pip install 'mocapgraph\[distributed\]'"):
        make_executor("ray")
