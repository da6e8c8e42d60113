"""Property-based fuzzing of the capture and result formats: whatever is done to a valid
directory (tests/format_mutations.py), the loaders and the commands ``capture info``,
``run baseline`` and ``eval`` (and, in the slow suite, ``run smartmocap`` and ``run aircap``) end in
a result or in one MocapgraphError (exit 2), never in another exception, a hang or unbounded memory.

``make test`` runs a CI-sized budget (about 10 s); ``make test-all`` (``-m slow``) the long one,
over 10 000 inputs. Every crasher these found is a regression test in tests/test_bad_inputs.py.
"""

from __future__ import annotations

import contextlib
import io
import resource
import shutil
import signal
import tempfile
from pathlib import Path

import pytest
from format_mutations import mutate
from hypothesis import HealthCheck, given, note, settings
from hypothesis import strategies as st
from test_capture import make_capture

from mocapgraph.cli.main import main
from mocapgraph.data_tools.io.capture import load_capture, write_capture
from mocapgraph.data_tools.io.result import load_result
from mocapgraph.errors import MocapgraphError

HANG_S = 60  # one input's loaders and commands take well under a second
# A damaged capture that still loads goes through the whole fit: 10 s on the 2-core machine at
# load 10, and the slow suite's 60 s bound was passed by such a valid input when the fuzzer ran
# at low priority beside other work; a hang is not a slow fit, so this bound only has to end it.
PIPELINE_HANG_S = 300


def _settings(examples: int):
    return settings(
        max_examples=examples, deadline=None, database=None, derandomize=True, print_blob=True,
        suppress_health_check=list(HealthCheck),
    )  # fmt: skip


@contextlib.contextmanager
def no_hang(seconds: int = HANG_S):
    def stop(signum, frame):
        raise TimeoutError(f"an input ran longer than {seconds} s")

    previous = signal.signal(signal.SIGALRM, stop)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    """A unit capture with every field (sensors, mount, ground truth), a small synthetic one and a
    baseline result of it: the directories every input starts from."""
    from mocapgraph.data_tools.sim.synthetic import synthesize

    root = tmp_path_factory.mktemp("pristine")
    write_capture(make_capture(), root / "unit")
    write_capture(synthesize("rich", seed=0, duration_s=0.5), root / "rich")
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", "baseline", str(root / "rich"), "--out", str(root / "result"), "-q"]) == 0
    return root


def _copy(source: Path) -> Path:
    work = Path(tempfile.mkdtemp(prefix="fuzz-"))
    shutil.copytree(source, work / source.name, symlinks=True)
    return work


def _command(argv: list[str]) -> int:
    """``mocapgraph ARGV`` in this process: its exit code (any other exception propagates)."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return main([*argv, "-q"])


def check_loader(pristine: Path, name: str, manifest: str, load, draw) -> None:
    work = _copy(pristine / name)
    try:
        note(mutate(work / name, manifest, draw))
        with no_hang():
            try:
                load(work / name)
            except MocapgraphError:
                pass
    finally:
        shutil.rmtree(work, ignore_errors=True)


def check_commands(pristine: Path, draw) -> None:
    """Damage the capture or the result, then run the three commands on them."""
    work = _copy(pristine / "rich")
    shutil.copytree(pristine / "result", work / "result")
    try:
        target = draw(st.sampled_from(["rich", "result"]))
        note(target)
        note(mutate(work / target, "capture.toml" if target == "rich" else "result.toml", draw))
        cap, res = str(work / "rich"), str(work / "result")
        with no_hang():
            assert _command(["capture", "info", cap]) in (0, 2)
            if target == "rich":
                assert _command(["run", "baseline", cap, "--out", str(work / "out")]) in (0, 2)
            assert _command(["eval", res, "--capture", cap]) in (0, 2)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def check_pipelines(pristine: Path, draw) -> None:
    """Damage the capture, then fit it with SmartMocap and AirCap (short settings)."""
    work = _copy(pristine / "rich")
    try:
        note(mutate(work / "rich", "capture.toml", draw))
        cap = str(work / "rich")
        with no_hang(PIPELINE_HANG_S):
            argv = ["--motion-prior", "none", "--workers", "1", "--no-covariances"]
            assert _command(["run", "smartmocap", cap, "--out", str(work / "sm"), *argv]) in (0, 2)
            assert _command(["run", "aircap", cap, "--out", str(work / "ac"), "--mode", "per-frame", "--no-covariances"]) in (0, 2)
    finally:
        shutil.rmtree(work, ignore_errors=True)


@pytest.mark.slow  # 0.1-5 s an input: most damaged captures are refused on loading
@_settings(300)
@given(data=st.data())
def test_pipelines(pristine, data):
    check_pipelines(pristine, data.draw)


def _budgeted(examples: tuple[int, int, int], slow: bool):
    """The three fuzz tests at one budget: (unit captures, results, commands) examples."""
    mark = pytest.mark.slow if slow else (lambda f: f)

    @mark
    @_settings(examples[0])
    @given(data=st.data())
    def captures(pristine, data):
        check_loader(pristine, "unit", "capture.toml", load_capture, data.draw)

    @mark
    @_settings(examples[1])
    @given(data=st.data())
    def results(pristine, data):
        check_loader(pristine, "result", "result.toml", load_result, data.draw)

    @mark
    @_settings(examples[2])
    @given(data=st.data())
    def commands(pristine, data):
        check_commands(pristine, data.draw)

    return captures, results, commands


test_capture_loader, test_result_loader, test_commands = _budgeted((120, 60, 12), slow=False)
test_capture_loader_long, test_result_loader_long, test_commands_long = _budgeted((7000, 2000, 1200), slow=True)


@pytest.mark.slow
def test_peak_memory_stays_bounded():
    """Runs last in this module (pytest keeps file order): after every long budget, the process'
    peak resident memory is what the README reports (under 2 GiB with torch loaded)."""
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak resident memory {peak_mib:.0f} MiB")
    assert peak_mib < 2048
