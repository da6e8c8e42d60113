"""Thread budgets (issue 19): pool workers share the cores they are given, and OpenMP threads
sleep rather than spin while they wait (spinning threads beside another busy process slowed the
motion prior's Jacobian tenfold)."""

from __future__ import annotations

import os
import subprocess
import sys

from mocapgraph.pipelines.executors import make_executor, worker_threads


def _threads(_item) -> tuple[int, str]:
    import torch

    return torch.get_num_threads(), os.environ.get("OMP_NUM_THREADS")


def test_workers_split_the_cores_between_them():
    import torch  # loaded in the parent, so the forked workers inherit its thread pool setting

    cores = len(os.sched_getaffinity(0))
    own = torch.get_num_threads()
    assert worker_threads(2) == max(1, cores // 2) and worker_threads(cores + 5) == 1
    with make_executor("local", 2) as pool:
        seen = pool.map(_threads, range(4))
    assert set(seen) == {(max(1, cores // 2), str(max(1, cores // 2)))}
    assert torch.get_num_threads() == own  # the parent's own setting is untouched by its workers


def test_openmp_threads_wait_passively_unless_the_user_says_otherwise():
    probe = "import mocapgraph, os; print(os.environ['OMP_WAIT_POLICY'])"
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    assert subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True).stdout.strip() == "PASSIVE"
    env["OMP_WAIT_POLICY"] = "ACTIVE"
    assert subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True).stdout.strip() == "ACTIVE"
