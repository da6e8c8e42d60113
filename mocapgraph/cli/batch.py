"""``mocapgraph batch PIPELINE CAPTURE... --out DIR``: many captures, one task each."""

from __future__ import annotations

import time
from pathlib import Path

from mocapgraph.cli.common import command, function_flags
from mocapgraph.errors import MocapgraphError


def cmd_batch(args) -> None:
    from mocapgraph.pipelines.batch import run_batch

    start = time.perf_counter()
    outcomes = run_batch(
        args.pipeline, args.captures, args.out, executor=args.executor, workers=args.workers, address=args.address,
        overwrite=args.overwrite, resume=args.resume,
    )  # fmt: skip
    width = max(len(o.name) for o in outcomes)
    for o in outcomes:
        status = f"ok ({o.frames} frames{', ' + o.message if o.message else ''})" if o.ok else f"failed: {o.message}"
        print(f"{o.name:{width}s}  {o.seconds:7.1f} s  {status}")
    failed = [o.name for o in outcomes if not o.ok]
    print(f"total: {len(outcomes) - len(failed)} of {len(outcomes)} captures ok in {time.perf_counter() - start:.1f} s, results in {args.out}")
    if failed:
        raise MocapgraphError(f"{len(failed)} of {len(outcomes)} captures failed: {', '.join(failed)}")


def add_parsers(subparsers) -> None:
    from mocapgraph.pipelines.batch import run_batch
    from mocapgraph.pipelines.executors import EXECUTORS
    from mocapgraph.pipelines.runner import PIPELINES

    parser = command(
        subparsers, "batch", "run a pipeline on many captures, one task each, on local processes or Ray",
        description="Run PIPELINE with its default options on every capture, writing OUT/<capture directory name>/. "
        "A failed capture is reported and the others still run; the exit status is 2 if any failed (docs/scaling.md).",
    )  # fmt: skip
    parser.add_argument("pipeline", choices=sorted(PIPELINES), help="pipeline to run")
    parser.add_argument("captures", nargs="+", type=Path, metavar="CAPTURE", help="capture directory")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="directory of the result directories")
    function_flags(
        parser, run_batch,
        {"executor": ("local process pool or ray", {"choices": EXECUTORS}),
         "address": "ray: cluster to join (host:6379 or auto; default: start a local instance)",
         "workers": "local processes, or CPUs of a local Ray instance"},
    )  # fmt: skip
    parser.add_argument("--overwrite", action="store_true", help="replace existing results")
    parser.add_argument("--resume", action="store_true", help="keep the results a stopped batch already wrote and run the rest")
    parser.set_defaults(func=cmd_batch)
