"""``mocapgraph batch``: one pipeline over many captures, one task per capture.

The tasks run on an executor (:mod:`mocapgraph.pipelines.executors`): a local process pool by
default, or a Ray cluster. Each writes ``OUT/<capture directory name>/`` atomically; a capture
that fails is reported and the others are still written.

To add a pipeline, register a module-level function ``(capture_path, out, overwrite) -> Result``
in :data:`PIPELINES` that runs it with its default options and writes no progress.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from mocapgraph.errors import MocapgraphError
from mocapgraph.pipelines.executors import EXECUTORS, TaskError, describe_exception, make_executor


@contextlib.contextmanager
def _silenced():
    """Swallow what a pipeline prints: summaries and notes of several captures at once would
    interleave on the terminal, and the batch prints one line per capture instead."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        yield


def aircap(capture_path: Path, out: Path, overwrite: bool):
    """AirCap with its default options; one process (the batch's tasks are the parallelism)."""
    from mocapgraph.data_tools.io.capture import load_capture
    from mocapgraph.data_tools.io.result import write_result
    from mocapgraph.pipelines.aircap import AircapOptions, run_aircap

    with _silenced():
        result = run_aircap(load_capture(capture_path), AircapOptions(progress=False, workers=1), capture_label=str(capture_path))
    write_result(result, out, overwrite=overwrite)
    return result


def baseline(capture_path: Path, out: Path, overwrite: bool):
    """Calibrated-camera triangulation with its default options."""
    from mocapgraph.pipelines.baseline import run_baseline

    with _silenced():
        return run_baseline(capture_path, out, overwrite=overwrite)


def airpose(capture_path: Path, out: Path, overwrite: bool):
    """AirPose+ with its default options."""
    from mocapgraph.data_tools.io.capture import load_capture
    from mocapgraph.data_tools.io.result import write_result
    from mocapgraph.pipelines.airpose import AirposeOptions, run_airpose

    with _silenced():
        result = run_airpose(load_capture(capture_path), AirposeOptions(progress=False), capture_label=str(capture_path))
    write_result(result, out, overwrite=overwrite)
    return result


def smartmocap(capture_path: Path, out: Path, overwrite: bool):
    """SmartMocap with its default options; its chunks in this task's process (one worker)."""
    from mocapgraph.data_tools.io.capture import load_capture
    from mocapgraph.data_tools.io.result import write_result
    from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap

    with _silenced():
        result = run_smartmocap(load_capture(capture_path), SmartmocapOptions(progress=False, workers=1), capture_label=str(capture_path))
    write_result(result, out, overwrite=overwrite)
    return result


PIPELINES: dict[str, Callable] = {
    "aircap": aircap,
    "airpose": airpose,
    "baseline": baseline,
    "smartmocap": smartmocap,
}


@dataclass
class Outcome:
    """How one capture went: ``frames`` is the number of result timestamps (0 when it failed)."""

    name: str
    ok: bool
    message: str
    seconds: float
    frames: int = 0


def _run_one(job: tuple[Callable, str, str, bool]) -> Outcome:
    run, capture, out, overwrite = job
    start = time.perf_counter()
    try:
        result = run(Path(capture), Path(out), overwrite)
    except Exception as exc:  # a failed capture is reported, not raised: the others go on
        return Outcome(Path(capture).name, False, describe_exception(exc), time.perf_counter() - start)
    return Outcome(Path(capture).name, True, "", time.perf_counter() - start, len(result.timestamps))


def run_batch(
    pipeline: str, captures: list[Path], out: Path, executor: str = "local", workers: int = 2,
    address: str | None = None, overwrite: bool = False, progress: str | None = None,
) -> list[Outcome]:  # fmt: skip
    """Run ``pipeline`` on every capture directory, writing ``out/<capture name>/``.

    Everything the tasks would trip over at once (unknown pipeline, missing captures, two
    captures with one name, results already there without ``overwrite``) is raised as one
    MocapgraphError before any task starts. Returns one :class:`Outcome` per capture, in order.
    """
    if pipeline not in PIPELINES:
        raise MocapgraphError(f"pipeline {pipeline!r}: choose one of {', '.join(sorted(PIPELINES))}")
    if not captures:
        raise MocapgraphError("no captures given")
    # Absolute paths: Ray's workers do not share this process's working directory.
    captures = [Path(c).resolve() for c in captures]
    missing = [str(c) for c in captures if not c.is_dir()]
    if missing:
        raise MocapgraphError(f"capture directories not found: {', '.join(missing)}")
    by_name: dict[str, list[str]] = {}
    for c in captures:
        by_name.setdefault(c.name, []).append(str(c))
    clashes = {name: paths for name, paths in by_name.items() if len(paths) > 1}
    if clashes:
        listed = "; ".join(f"{name}: {', '.join(paths)}" for name, paths in clashes.items())
        raise MocapgraphError(f"captures share a directory name, so their results would share {out}/<name>: {listed}")
    out = Path(out).resolve()
    existing = [str(out / c.name) for c in captures if (out / c.name).exists()]
    if existing and not overwrite:
        raise MocapgraphError(f"results already exist (use --overwrite to replace them): {', '.join(existing)}")
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(PIPELINES[pipeline], str(c), str(out / c.name), overwrite) for c in captures]
    with make_executor(executor, workers, address) as pool:
        try:
            return pool.map(_run_one, jobs, progress=progress)
        except TaskError as exc:  # a worker died: keep the captures that finished
            return [
                r if r is not None else Outcome(captures[i].name, False, exc.failures[i], float("nan"))
                for i, r in enumerate(exc.results)
            ]


def cmd_batch(args) -> None:
    start = time.perf_counter()
    outcomes = run_batch(
        args.pipeline, args.captures, args.out, executor=args.executor, workers=args.workers, address=args.address,
        overwrite=args.overwrite, progress=None if args.quiet else "batch",
    )  # fmt: skip
    width = max(len(o.name) for o in outcomes)
    for o in outcomes:
        status = f"ok ({o.frames} frames)" if o.ok else f"failed: {o.message}"
        print(f"{o.name:{width}s}  {o.seconds:7.1f} s  {status}")
    failed = [o.name for o in outcomes if not o.ok]
    print(f"total: {len(outcomes) - len(failed)} of {len(outcomes)} captures ok in {time.perf_counter() - start:.1f} s, results in {args.out}")
    if failed:
        raise MocapgraphError(f"{len(failed)} of {len(outcomes)} captures failed: {', '.join(failed)}")


def add_batch_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``batch PIPELINE CAPTURE... --out DIR`` on a subparsers object; returns its parser."""
    parser = subparsers.add_parser(
        "batch",
        help="run a pipeline on many captures, one task each, on local processes or Ray",
        description="Run PIPELINE with its default options on every capture, writing OUT/<capture directory name>/. "
        "A failed capture is reported and the others still run; the exit status is 2 if any failed (docs/scaling.md).",
    )
    parser.add_argument("pipeline", choices=sorted(PIPELINES), help="pipeline to run")
    parser.add_argument("captures", nargs="+", type=Path, metavar="CAPTURE", help="capture directory")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="directory of the result directories")
    parser.add_argument("--executor", choices=EXECUTORS, default="local", help="local process pool (default) or ray")
    parser.add_argument("--address", help="ray: cluster to join (host:6379 or auto; default: start a local instance)")
    parser.add_argument("--workers", type=int, default=2, help="local processes, or CPUs of a local Ray instance (default 2)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing results")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    parser.set_defaults(func=cmd_batch)
    return parser
