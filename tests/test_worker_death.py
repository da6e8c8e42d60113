"""Child processes die with their parent (issue 19): a killed run leaves no worker computing on,
and none holds the caller's stdout/stderr, so a caller reading those pipes sees them close."""

from __future__ import annotations

import os
import selectors
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


def children(pid: int) -> set[int]:
    found: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*/children"):
        found |= {int(c) for c in task.read_text().split()}
    return found


def running(pid: int) -> bool:
    """Alive and not a zombie waiting to be reaped."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, IndexError):
        return False


def wait_for_workers(run: subprocess.Popen, count: int, timeout: float) -> set[int]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert run.poll() is None, f"the run ended ({run.returncode}) before its workers started"
        workers = children(run.pid)
        if len(workers) >= count:
            return workers
        time.sleep(0.05)
    raise AssertionError(f"no {count} workers after {timeout} s")


def kill_and_check(run: subprocess.Popen, workers: set[int], within_s: float = 5.0) -> None:
    """SIGKILL the run; every worker must be gone and both pipes closed within ``within_s``."""
    run.send_signal(signal.SIGKILL)
    run.wait()
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline and any(running(w) for w in workers):
        time.sleep(0.05)
    survivors = [w for w in workers if running(w)]
    for w in survivors:  # leave no stray process behind this test, then fail
        os.kill(w, signal.SIGKILL)
    assert not survivors, f"workers {survivors} outlived their parent by {within_s} s"
    # EOF on both pipes: nobody holds their write ends any more.
    selector = selectors.DefaultSelector()
    for pipe in (run.stdout, run.stderr):
        os.set_blocking(pipe.fileno(), False)
        selector.register(pipe, selectors.EVENT_READ)
    open_pipes = {run.stdout, run.stderr}
    while open_pipes and time.monotonic() < deadline + within_s:
        for key, _ in selector.select(timeout=0.2):
            if not key.fileobj.read():
                selector.unregister(key.fileobj)
                open_pipes.discard(key.fileobj)
    assert not open_pipes, "a pipe of the killed run is still held open"


def test_pool_workers_die_with_a_killed_parent_and_release_its_pipes():
    script = textwrap.dedent(
        """
        import time
        from mocapgraph.pipelines.executors import make_executor
        with make_executor("local", 2) as pool:
            pool.map(time.sleep, [600, 600, 600])
        """
    )
    run = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    kill_and_check(run, wait_for_workers(run, 2, timeout=60))


def test_a_worker_started_after_its_parent_died_exits_at_once():
    """The race the pid check covers: the parent gone before the worker could ask to die with it."""
    script = textwrap.dedent(
        """
        import os, sys
        from mocapgraph.pipelines.executors import die_with_parent
        die_with_parent(os.getppid() + 1 if os.getppid() != 1 else 2)  # not its parent: as if adopted already
        print("survived", flush=True)
        """
    )
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert run.returncode == 1 and "survived" not in run.stdout


@pytest.mark.slow
def test_killing_run_smartmocap_leaves_no_worker(tmp_path):
    from mocapgraph.data_tools.io.capture import write_capture
    from mocapgraph.data_tools.sim.synthetic import synthesize

    cap = write_capture(synthesize("rich", seed=0, duration_s=2.0), tmp_path / "cap")
    argv = [sys.executable, "-m", "mocapgraph.cli.main", "run", "smartmocap", str(cap), "--out", str(tmp_path / "res"), "--workers", "2"]
    run = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    workers = wait_for_workers(run, 2, timeout=240)
    time.sleep(1.0)  # into the chunks' solves
    kill_and_check(run, workers)
    assert not (tmp_path / "res").exists()


def descendants(pid: int) -> set[int]:
    found, todo = set(), [pid]
    while todo:
        for child in children(todo.pop()) - found:
            found.add(child)
            todo.append(child)
    return found


@pytest.mark.slow  # 10-20 s: starts a local Ray instance
def test_ray_tasks_die_with_a_killed_driver():
    """A local Ray instance started by the run: its task workers (``ray::_apply``) and its raylet
    stop within 10 s of the driver's SIGKILL and release the caller's pipes. Ray's two agent
    processes (dashboard, runtime environment) outlive the raylet by up to a minute before they
    notice (measured); they compute nothing."""
    pytest.importorskip("ray")
    script = textwrap.dedent(
        """
        import time
        from mocapgraph.pipelines.executors import make_executor
        with make_executor("ray", 2) as pool:
            pool.map(time.sleep, [600, 600, 600])
        """
    )
    run = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    tasks: set[int] = set()
    while len(tasks) < 2:
        assert time.monotonic() < deadline and run.poll() is None, "no two Ray tasks running after 120 s"
        time.sleep(0.2)
        tree = descendants(run.pid)
        tasks = {p for p in tree if Path(f"/proc/{p}/cmdline").exists() and Path(f"/proc/{p}/cmdline").read_bytes().startswith(b"ray::_apply")}
    agents = {p for p in tree if Path(f"/proc/{p}/cmdline").exists() and b"Agent" in Path(f"/proc/{p}/cmdline").read_bytes()[:40]}
    try:
        kill_and_check(run, tree - agents, within_s=10.0)
    finally:
        for p in agents:
            if running(p):
                os.kill(p, signal.SIGKILL)
