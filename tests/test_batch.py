"""``mocapgraph batch``: one result per capture, equal to running the pipeline directly; a broken
capture is reported and the others are still written; input mistakes stop it before it runs."""

from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.cli.main import main
from mocapgraph.data_tools.io.capture import write_capture
from mocapgraph.data_tools.io.result import load_result
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.errors import MocapgraphError
from mocapgraph.pipelines.batch import run_batch
from mocapgraph.pipelines.runner import PIPELINES, run_capture


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """Two 1-second ``rich`` captures (7 calibrated cameras + a handheld one), seeds 1 and 2."""
    root = tmp_path_factory.mktemp("captures")
    return [write_capture(synthesize("rich", seed=s, duration_s=1.0), root / f"walk{s}") for s in (1, 2)]


def test_batch_baseline_equals_the_pipeline_run_directly(captures, tmp_path, capsys):
    out = tmp_path / "results"
    assert main(["batch", "baseline", *map(str, captures), "--out", str(out), "--workers", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    for cap in captures:
        batched = load_result(out / cap.name)
        direct = run_capture("baseline", cap, tmp_path / f"direct_{cap.name}")
        assert batched.pipeline == "baseline" and len(batched.timestamps) == 31
        np.testing.assert_array_equal(batched.timestamps, direct.timestamps)
        np.testing.assert_array_equal(batched.joints, direct.joints)  # NaN: the baseline has no body
        np.testing.assert_array_equal(batched.keypoints, direct.keypoints)
        assert np.isfinite(batched.keypoints).all()
        assert any(line.startswith(cap.name) and line.endswith("ok (31 frames)") for line in lines)
    assert lines[-1].startswith("total: 2 of 2 captures ok in ")


def test_a_broken_capture_is_reported_and_the_others_written(captures, tmp_path, capsys):
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "capture.toml").write_text("format = [not toml")
    out = tmp_path / "results"
    assert main(["batch", "baseline", str(captures[0]), str(broken), str(captures[1]), "--out", str(out), "--workers", "2"]) == 2
    captured = capsys.readouterr()
    for cap in captures:
        assert len(load_result(out / cap.name).timestamps) == 31
    assert not (out / "broken").exists()
    (line,) = [line for line in captured.out.splitlines() if line.startswith("broken")]
    assert "failed: " in line and "capture.toml" in line
    assert "total: 2 of 3 captures ok" in captured.out
    assert "mocapgraph: error: 1 of 3 captures failed: broken" in captured.err


def test_input_mistakes_stop_the_batch_before_it_runs(captures, tmp_path):
    out = tmp_path / "results"
    with pytest.raises(MocapgraphError, match=r"capture directories not found: .*nowhere1, .*nowhere2"):
        run_batch("baseline", [captures[0], tmp_path / "nowhere1", tmp_path / "nowhere2"], out)
    twin = tmp_path / "elsewhere" / captures[0].name
    twin.mkdir(parents=True)
    with pytest.raises(MocapgraphError, match=f"captures share a directory name.*{captures[0].name}: "):
        run_batch("baseline", [captures[0], twin], out)
    with pytest.raises(MocapgraphError, match="pipeline 'nope': choose one of aircap, airpose, baseline, smartmocap"):
        run_batch("nope", captures, out)
    assert not out.exists()
    (out / captures[1].name).mkdir(parents=True)
    with pytest.raises(MocapgraphError, match=f"results already exist .*{captures[1].name}"):
        run_batch("baseline", captures, out, workers=1)
    assert not (out / captures[0].name).exists()


def test_registry_entries_name_what_their_modules_hold():
    """Every pipeline's options dataclass, run function and summary are importable by name."""
    from dataclasses import is_dataclass

    for name, entry in PIPELINES.items():
        assert is_dataclass(entry.default_options()), name
        assert callable(entry.attribute("run")) and callable(entry.attribute("summary")), name


@pytest.mark.slow  # 6 s: Ray's start; Ray against local is also in test_executors
def test_batch_on_ray_writes_what_the_local_pool_writes(captures, tmp_path):
    """Ray's workers import the package afresh (no fork) and send the outcomes back by pickle."""
    local = run_batch("baseline", captures, tmp_path / "local", workers=1)
    remote = run_batch("baseline", captures, tmp_path / "ray", executor="ray", workers=2)
    assert [(o.name, o.ok, o.frames) for o in remote] == [(o.name, o.ok, o.frames) for o in local] == [
        (c.name, True, 31) for c in captures
    ]
    for cap in captures:
        np.testing.assert_array_equal(load_result(tmp_path / "ray" / cap.name).keypoints, load_result(tmp_path / "local" / cap.name).keypoints)
