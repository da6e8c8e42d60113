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
    if args.reference:
        _eval_reference(result, load_capture(capture_path), args)
        return
    evaluation = evaluate(result, load_capture(capture_path))
    if args.json:
        print(json.dumps({"pipeline": result.pipeline, "alignment": evaluation.alignment, **evaluation.metrics}))
        return
    print(f"{result.pipeline} on {capture_path}: {evaluation.frames_compared} frames compared ({evaluation.frames_without_truth} without ground truth)")
    print(f"alignment: {evaluation.alignment}")
    for key, value in evaluation.metrics.items():
        print(f"  {key:28s} {value:.4f}")


SECTIONS = {
    "result_vs_reference": "the result against the reference (reference mapped onto the result: the result's units)",
    "reference_vs_truth": "the reference's own error against the true cameras",
    "result_vs_truth": "the result against the true cameras, aligned the same way, on the frames the reference has",
}


def _eval_reference(result, capture, args) -> None:
    from mocapgraph.data_tools.evaluation.colmap_reference import load_reference
    from mocapgraph.data_tools.evaluation.reference_eval import flat_metrics, reference_report

    reference = load_reference(capture.path, args.reference)
    report = reference_report(result, capture, reference)
    if args.json:
        print(json.dumps({"pipeline": result.pipeline, "reference": args.reference, **flat_metrics(report)}))
        return
    stats = report["reference_stats"]
    print(f"{result.pipeline} on {capture.path} against reference {args.reference!r} "
          f"({100 * stats.get('registration_rate', float('nan')):.0f} % of its sampled frames registered, "
          f"{stats.get('mean_reprojection_error_px', float('nan')):.2f} px)")
    for section, scores in report.items():
        if section == "reference_stats":
            continue
        print(f"{SECTIONS[section]}:")
        for name, s in scores.items():
            kind = "moving" if s.moving else "static"
            print(f"  {name:20s} {kind:6s} {100 * s.mcpe_m:8.1f} cm {s.mcoe_deg:6.2f} deg  {s.frames:4d} frames  ({s.alignment})")


def add_parsers(subparsers) -> None:
    parser = command(subparsers, "eval", "score a result against its capture's ground truth")
    parser.add_argument("result", type=Path, help="result directory")
    parser.add_argument("--capture", type=Path, help="capture directory (default: the one the result names)")
    parser.add_argument("--reference", metavar="NAME", help="score the cameras against the capture's reference NAME (e.g. colmap, from `mocapgraph colmap`) instead")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(func=cmd_eval)
