"""Outputs that cannot be lost (issue 19): ``--overwrite`` replaces only a mocapgraph result (or
capture) and never the command's input; OUT is checked and reserved before the work; a bad
location is a clean error before any work; a kill at any instant of a write leaves the old
output or the new one, and the next write repairs what the kill left.

The kill and race tests run real ``mocapgraph run baseline`` processes on a small synthetic capture."""

from __future__ import annotations

import errno
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mocapgraph.cli.main import main
from mocapgraph.data_tools.io import result as result_io
from mocapgraph.data_tools.io.capture import load_capture, write_capture
from mocapgraph.data_tools.io.files import KILL_AT_ENV, release_output, reserve_output
from mocapgraph.data_tools.io.result import ResultError, load_result, write_result
from mocapgraph.errors import MocapgraphError

CLI = [sys.executable, "-m", "mocapgraph.cli.main"]


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    from mocapgraph.data_tools.sim.synthetic import synthesize

    return write_capture(synthesize("rich", seed=0, duration_s=0.5), tmp_path_factory.mktemp("outputs") / "cap")


def baseline(capture: Path, out: Path, seed: int, *extra: str) -> int:
    return main(["run", "baseline", str(capture), "--out", str(out), "--seed", str(seed), "-q", *extra])


def seed_of(out: Path) -> int:
    return load_result(out).parameters["seed"]


def leftovers(out: Path) -> list[str]:
    return sorted(p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}."))


# --- what --overwrite may replace -----------------------------------------------------------------


def test_overwrite_never_replaces_the_commands_input(capture, tmp_path, capsys):
    before = load_capture(capture)
    assert baseline(capture, capture, 0, "--overwrite") == 2
    assert "is the command's input" in capsys.readouterr().err
    assert baseline(capture, capture.parent, 0, "--overwrite") == 2  # nor a folder holding it
    assert "is a folder around the command's input" in capsys.readouterr().err
    after = load_capture(capture)
    np.testing.assert_array_equal(after.cameras[0].timestamps, before.cameras[0].timestamps)


def test_overwrite_refuses_what_is_not_a_result(capture, tmp_path, capsys):
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / "holiday.jpg").write_bytes(b"precious")
    assert baseline(capture, folder, 0, "--overwrite") == 2
    assert f"{folder}: not a mocapgraph result (no result.toml)" in capsys.readouterr().err
    assert (folder / "holiday.jpg").read_bytes() == b"precious"

    plain = tmp_path / "notes.txt"
    plain.write_text("keep me")
    assert baseline(capture, plain, 0, "--overwrite") == 2
    assert f"{plain}: not a directory" in capsys.readouterr().err
    assert plain.read_text() == "keep me" and leftovers(plain) == []


def test_overwrite_replaces_a_result_and_an_empty_folder(capture, tmp_path):
    out = tmp_path / "res"
    out.mkdir()
    assert baseline(capture, out, 1, "--overwrite") == 0 and seed_of(out) == 1
    assert baseline(capture, out, 2) == 2 and seed_of(out) == 1  # without --overwrite: kept
    assert baseline(capture, out, 2, "--overwrite") == 0 and seed_of(out) == 2
    assert leftovers(out) == []


# --- bad locations: a clean error before any work ------------------------------------------------


@pytest.mark.parametrize(
    ("out", "message"),
    [
        ("/dev/null/res", "/dev/null is not a directory"),
        ("/proc/res", "cannot be written"),
        ("{tmp}/" + "r" * 300, "name too long"),
        ("{tmp}/a\0b", "cannot be written"),
    ],
)
def test_a_bad_output_location_is_refused_before_the_capture_is_read(tmp_path, capsys, out, message):
    out = out.format(tmp=tmp_path)
    # The capture does not exist: the error about the output comes first, so no work was done.
    assert main(["run", "baseline", str(tmp_path / "no-capture"), "--out", out, "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mocapgraph: error:") and message in err and "no-capture" not in err


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_parent_is_refused_before_the_run(tmp_path, capsys):
    parent = tmp_path / "ro"
    parent.mkdir()
    parent.chmod(0o555)
    assert main(["run", "baseline", str(tmp_path / "no-capture"), "--out", str(parent / "res"), "-q"]) == 2
    assert "Permission denied" in capsys.readouterr().err


def _small_result(seed: int) -> result_io.Result:
    return result_io.Result(
        pipeline="baseline", capture="cap", world_frame="capture", timestamps=np.arange(3) / 30.0,
        joints=np.full((3, 22, 3), float(seed)), parameters={"seed": seed},
    )  # fmt: skip


def test_a_full_disk_is_a_clean_error_and_keeps_the_old_result(tmp_path, monkeypatch):
    out = write_result(_small_result(1), tmp_path / "res")

    def full(result, root):
        (root / "body.npz").write_bytes(b"partial")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(result_io, "_write_into", full)
    with pytest.raises(ResultError, match=r"res: cannot be written \(No space left on device\)"):
        write_result(_small_result(2), out, overwrite=True)
    assert seed_of(out) == 1 and leftovers(out) == []


# --- what a kill leaves, repaired by the next write ------------------------------------------------


def test_the_next_write_restores_an_output_a_kill_left_aside(tmp_path):
    """The state a kill between the two renames of a replace leaves: OUT missing, the previous
    version at .OUT.old-PID, a temporary folder half written."""
    out = write_result(_small_result(1), tmp_path / "res")
    os.rename(out, tmp_path / ".res.old-12345")
    (tmp_path / ".res.tmp-abcdef").mkdir()
    (tmp_path / ".res.tmp-abcdef" / "body.npz").write_bytes(b"half")
    with pytest.raises(ResultError, match="already exists"):  # restored first, so it is not overwritten
        write_result(_small_result(2), out)
    assert seed_of(out) == 1 and leftovers(out) == []
    write_result(_small_result(2), out, overwrite=True)
    assert seed_of(out) == 2 and leftovers(out) == []


def _killed_run(capture: Path, out: Path, step: str) -> subprocess.CompletedProcess:
    env = {**os.environ, KILL_AT_ENV: step}
    argv = [*CLI, "run", "baseline", str(capture), "--out", str(out), "--overwrite", "--seed", "2", "-q"]
    return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize(
    ("step", "survivor"),
    [
        pytest.param("written", 1, marks=pytest.mark.slow),
        ("old-aside", None),  # OUT missing until the next write restores it
        pytest.param("new-in-place", 2, marks=pytest.mark.slow),
    ],
)
def test_a_run_killed_at_each_step_of_its_write_leaves_the_old_or_the_new_result(capture, tmp_path, step, survivor):
    out = tmp_path / "res"
    assert baseline(capture, out, 1) == 0
    run = _killed_run(capture, out, step)
    assert run.returncode == -signal.SIGKILL, run.stderr
    if survivor is None:
        assert not out.exists() and any(name.startswith(".res.old-") for name in leftovers(out))
        survivor = 1
        assert baseline(capture, out, 3) == 2  # the next run restores it first, then keeps it (no --overwrite)
    assert seed_of(out) == survivor
    assert baseline(capture, out, 3, "--overwrite") == 0 and seed_of(out) == 3
    assert leftovers(out) == []


def test_concurrent_runs_into_one_output_one_wins_the_others_are_refused_at_once(capture, tmp_path):
    out = tmp_path / "res"
    argv = [*CLI, "run", "baseline", str(capture), "--out", str(out), "-q"]
    runs = [subprocess.Popen([*argv, "--seed", str(i)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for i in range(3)]
    outcomes = [(r.wait(timeout=300), r.stderr.read()) for r in runs]
    codes = sorted(code for code, _ in outcomes)
    assert codes == [0, 2, 2], outcomes
    for code, err in outcomes:
        if code == 2:
            assert "another mocapgraph process" in err or "already exists" in err, err
    winner = next(i for i, (code, _) in enumerate(outcomes) if code == 0)
    assert seed_of(out) == winner and leftovers(out) == []


def test_a_reservation_is_refused_while_another_process_holds_it(tmp_path):
    out = tmp_path / "res"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from mocapgraph.data_tools.io.files import reserve_output; "
         f"reserve_output({str(out)!r}, False, 'result.toml'); print('held', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(MocapgraphError, match=rf"res: another mocapgraph process \(pid {holder.pid}\) is writing it"):
            reserve_output(out, False, "result.toml")
    finally:
        holder.kill()
        holder.wait()
    release_output(reserve_output(out, False, "result.toml"))  # the kernel dropped the dead holder's lock


@pytest.mark.slow
def test_runs_killed_at_random_instants_never_lose_the_result(capture, tmp_path):
    out = tmp_path / "res"
    assert baseline(capture, out, 1) == 0
    rng = random.Random(0)
    argv = [*CLI, "run", "baseline", str(capture), "--out", str(out), "--overwrite", "-q"]
    for attempt in range(8):
        run = subprocess.Popen([*argv, "--seed", str(attempt + 2)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(rng.uniform(0.0, 8.0))
        run.send_signal(signal.SIGKILL)
        run.wait()
        release_output(reserve_output(out, True, "result.toml"))  # the next write's repair
        assert seed_of(out) in (1, *range(2, attempt + 3))  # an old result or the new one, whole
    assert leftovers(out) == []
