"""One pipeline over many captures, one task per capture (``mocapgraph batch``).

The tasks run on an executor (:mod:`mocapgraph.pipelines.executors`): a local process pool by
default, or a Ray cluster. Each runs the pipeline with its default options through
:func:`~mocapgraph.pipelines.runner.run_capture` and writes ``OUT/<capture directory name>/``
atomically; a capture that fails is reported and the others are still written. A task logs
warnings only: the messages of several captures at once would interleave, and the batch
reports one line per capture instead.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace
from pathlib import Path

from mocapgraph.data_tools.io.result import MANIFEST, load_result
from mocapgraph.errors import MocapgraphError
from mocapgraph.pipelines.executors import TaskError, describe_exception, make_executor
from mocapgraph.pipelines.runner import pipeline as find_pipeline
from mocapgraph.pipelines.runner import run_capture
from mocapgraph.progress import log_level


@dataclass
class Outcome:
    """How one capture went: ``frames`` is the number of result timestamps (0 when it failed)."""

    name: str
    ok: bool
    message: str
    seconds: float
    frames: int = 0


def task_options(name: str):
    """A pipeline's default options for one batch task: the captures are the parallelism, so a
    pipeline that pools its own work uses one process."""
    options = find_pipeline(name).default_options()
    return replace(options, workers=1) if hasattr(options, "workers") else options


def _run_one(job: tuple[str, str, str, bool]) -> Outcome:
    name, capture, out, overwrite = job
    start = time.perf_counter()
    try:
        with log_level(logging.WARNING):
            result = run_capture(name, Path(capture), Path(out), task_options(name), overwrite)
    except Exception as exc:  # a failed capture is reported, not raised: the others go on
        return Outcome(Path(capture).name, False, describe_exception(exc), time.perf_counter() - start)
    return Outcome(Path(capture).name, True, "", time.perf_counter() - start, len(result.timestamps))


def run_batch(
    pipeline: str, captures: list[Path], out: Path, executor: str = "local", workers: int = 2,
    address: str | None = None, overwrite: bool = False, resume: bool = False,
) -> list[Outcome]:  # fmt: skip
    """Run ``pipeline`` on every capture directory, writing ``out/<capture name>/``.

    Everything the tasks would trip over at once (unknown pipeline, missing captures, two
    captures with one name, results already there without ``overwrite``) is raised as one
    MocapgraphError before any task starts. Returns one :class:`Outcome` per capture, in order.

    ``resume`` continues a batch that was stopped: a capture whose result of ``pipeline`` is
    already there (results are written atomically, so one that loads is whole) is kept as it is
    and reported with 0 seconds; the others run.
    """
    find_pipeline(pipeline)  # an unknown name is refused before any task starts
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
    if resume and overwrite:
        raise MocapgraphError("--resume keeps the results already written and --overwrite replaces them: choose one")
    kept = _finished(pipeline, captures, out) if resume else {}
    existing = [str(out / c.name) for c in captures if c.name not in kept and (out / c.name).exists()]
    if existing and not overwrite:
        hint = "" if resume else "; --resume keeps the finished ones"
        raise MocapgraphError(f"results already exist (use --overwrite to replace them{hint}): {', '.join(existing)}")
    out.mkdir(parents=True, exist_ok=True)
    todo = [c for c in captures if c.name not in kept]
    jobs = [(pipeline, str(c), str(out / c.name), overwrite) for c in todo]
    with make_executor(executor, workers, address) as pool:
        try:
            done = pool.map(_run_one, jobs, progress="batch") if jobs else []
        except TaskError as exc:  # a worker died: keep the captures that finished
            done = [r if r is not None else Outcome(todo[i].name, False, exc.failures[i], float("nan")) for i, r in enumerate(exc.results)]
    by_name = {**kept, **{o.name: o for o in done}}
    return [by_name[c.name] for c in captures]


def _finished(pipeline: str, captures: list[Path], out: Path) -> dict[str, Outcome]:
    """The captures whose result of ``pipeline`` is already under ``out``, by name."""
    kept = {}
    for c in captures:
        if not (out / c.name / MANIFEST).is_file():
            continue
        try:
            result = load_result(out / c.name)
        except MocapgraphError:
            continue  # not a readable result: left to the existing-output check
        if result.pipeline == pipeline:
            kept[c.name] = Outcome(c.name, True, "kept from an earlier run", 0.0, len(result.timestamps))
    return kept
