"""``batch --resume`` (issue 19): a batch killed part way continues from the captures it finished
and ends with the same results as a batch that was never interrupted."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from mocapgraph.cli.main import main
from mocapgraph.data_tools.io.capture import write_capture
from mocapgraph.data_tools.io.result import load_result
from mocapgraph.errors import MocapgraphError
from mocapgraph.pipelines.batch import run_batch


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    from mocapgraph.data_tools.sim.synthetic import synthesize

    root = tmp_path_factory.mktemp("resume")
    return [write_capture(synthesize("rich", seed=s, duration_s=4.0), root / f"cap{s}") for s in range(3)]


@pytest.mark.slow  # 4 s: two batches of real runs, one killed
def test_a_killed_batch_resumes_from_its_finished_captures_to_the_same_results(captures, tmp_path, capsys):
    reference = tmp_path / "reference"
    assert main(["batch", "baseline", *map(str, captures), "--out", str(reference), "--workers", "1", "-q"]) == 0

    out = tmp_path / "out"
    argv = [sys.executable, "-m", "mocapgraph.cli.main", "batch", "baseline", *map(str, captures), "--out", str(out), "--workers", "1", "-q"]
    run = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while not (out / "cap0" / "result.toml").exists() and time.monotonic() < deadline and run.poll() is None:
        time.sleep(0.02)
    run.send_signal(signal.SIGKILL)
    run.wait()
    finished = sorted(p.name for p in out.iterdir() if (p / "result.toml").exists())
    assert finished and len(finished) < 3, finished  # killed part way

    assert main(["batch", "baseline", *map(str, captures), "--out", str(out), "--workers", "1"]) == 2  # not without --resume
    capsys.readouterr()
    assert main(["batch", "baseline", *map(str, captures), "--out", str(out), "--workers", "1", "--resume"]) == 0
    printed = capsys.readouterr().out
    for name in finished:
        assert "kept from an earlier run" in next(line for line in printed.splitlines() if line.startswith(name))
    for cap in captures:
        got, want = load_result(out / cap.name), load_result(reference / cap.name)
        np.testing.assert_array_equal(got.timestamps, want.timestamps)
        np.testing.assert_array_equal(got.joints, want.joints)


def test_resume_and_overwrite_are_exclusive(captures, tmp_path):
    with pytest.raises(MocapgraphError, match="choose one"):
        run_batch("baseline", captures[:1], tmp_path, workers=1, overwrite=True, resume=True)


@pytest.mark.slow
def test_a_killed_smartmocap_run_resumes_from_its_solved_chunks_to_the_same_result(tmp_path, capsys):
    from mocapgraph.data_tools.sim.synthetic import synthesize

    cap = write_capture(synthesize("rich", seed=0, duration_s=3.0, detector_faults="none"), tmp_path / "cap")
    common = ["run", "smartmocap", str(cap), "--workers", "1", "--no-covariances", "--no-keypoint-offsets"]
    assert main([*common, "--out", str(tmp_path / "reference"), "-q"]) == 0

    out = tmp_path / "res"
    chunks = tmp_path / ".res.chunks"
    run = subprocess.Popen([sys.executable, "-m", "mocapgraph.cli.main", *common, "--out", str(out), "-q"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 600
    while not list(chunks.glob("chunk-*.pkl")) and time.monotonic() < deadline and run.poll() is None:
        time.sleep(0.02)
    run.send_signal(signal.SIGKILL)
    run.wait()
    kept = len(list(chunks.glob("chunk-*.pkl")))
    assert kept and not out.exists()  # killed after a chunk, before the result

    capsys.readouterr()
    assert main([*common, "--out", str(out), "--resume"]) == 0
    said = re.search(r"smartmocap: (\d+) of (\d+) chunks kept from an earlier run", capsys.readouterr().err)
    assert said and int(said[1]) == kept < int(said[2])  # read back, the others solved
    assert not chunks.exists()  # cleared once the result is written
    got, want = load_result(out), load_result(tmp_path / "reference")
    np.testing.assert_array_equal(got.timestamps, want.timestamps)
    np.testing.assert_allclose(got.joints, want.joints, rtol=0, atol=1e-9)
