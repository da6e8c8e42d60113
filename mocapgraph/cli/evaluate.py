"""``mocapgraph eval RESULT``: a result scored against its capture's ground truth."""

from __future__ import annotations

import json
from pathlib import Path

from mocapgraph.cli.common import command


def cmd_eval(args) -> None:
    from mocapgraph.data_tools.evaluation.evaluate import evaluate
    from mocapgraph.data_tools.io.capture import load_capture
    from mocapgraph.data_tools.io.result import load_result

    result = load_result(args.result)
    capture_path = args.capture or Path(result.capture)
    evaluation = evaluate(result, load_capture(capture_path))
    if args.json:
        print(json.dumps({"pipeline": result.pipeline, "alignment": evaluation.alignment, **evaluation.metrics}))
        return
    print(f"{result.pipeline} on {capture_path}: {evaluation.frames_compared} frames compared ({evaluation.frames_without_truth} without ground truth)")
    print(f"alignment: {evaluation.alignment}")
    for key, value in evaluation.metrics.items():
        print(f"  {key:28s} {value:.4f}")


def add_parsers(subparsers) -> None:
    parser = command(subparsers, "eval", "score a result against its capture's ground truth")
    parser.add_argument("result", type=Path, help="result directory")
    parser.add_argument("--capture", type=Path, help="capture directory (default: the one the result names)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(func=cmd_eval)
