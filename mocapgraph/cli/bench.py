"""``mocapgraph bench NAME``: speed and accuracy benchmarks, each printing one JSON object.

Every benchmark is a function of :mod:`mocapgraph.benchmarks` whose keyword defaults are the
flags' defaults (read from its signature, written once).
"""

from __future__ import annotations

import importlib
import inspect
import json
from pathlib import Path

from mocapgraph.cli.common import add_body_args, body_from, command, function_flags, group

BENCHES = {
    # name: (help, function, {parameter: (flag help, extra add_argument keywords)})
    "aircap": ("the AirCap variants on a synthetic capture", "mocapgraph.benchmarks.aircap:bench_aircap", {}),
    "smartmocap": (
        "SmartMocap on a rich capture (camera configurations, with and without the motion prior) and on phones captures of five CMU takes "
        "(with and without the phones' IMUs and the cameras' motion model)",
        "mocapgraph.benchmarks.smartmocap:bench_smartmocap",
        {"workers": ("parallel chunks", {}), "sections": ("comma-separated: rich, phones", {}),
         "phones_duration_s": ("seconds of each phones capture", {"flag": "--phones-duration"}),
         "phones_long_s": ("seconds of the long phones captures the default variant is run on again (0: none)", {"flag": "--phones-long"})},
    ),
    "faults": (
        "SmartMocap with realistic detector faults against none, and with swap handling off (rich, phones)",
        "mocapgraph.benchmarks.faults:bench_faults", {"workers": ("parallel chunks", {}), "presets": ("comma-separated: rich, phones", {})},
    ),
    "online": (
        "the online loop (fixed-lag iSAM2) on aircap and rich: updates/s, latency, memory, filtered/smoothed/offline errors",
        "mocapgraph.benchmarks.online:bench_online",
        {"lag_s": ("smoother window, seconds", {"flag": "--lag"}), "long_s": ("instead: streams this long (e.g. 600), a capture and its first minute played forwards and backwards; memory and latency per minute", {"flag": "--long"})},
    ),
    "colmap": (
        "COLMAP on rendered phones and rich captures: registration, its error against the truth, SmartMocap's cameras (on its own and "
        "with --cameras-from colmap) against COLMAP and the truth",
        "mocapgraph.benchmarks.colmap:bench_colmap",
        {"image_scale": ("image size relative to the presets' 1920x1080", {}), "frame_step": ("reconstruct every N-th frame", {}),
         "workers": ("parallel chunks", {}), "presets": ("comma-separated: phones, rich", {})},
    ),
    "definitions": (
        "keypoint-definition offsets of the real clip's detector format, the cameras held at the lab's calibration (the table of "
        "mocapgraph.body.definition_priors)",
        "mocapgraph.benchmarks.real:fit_clip_offsets", {"clip": ("the clip's folder (default tests/data/real)", {"type": Path, "metavar": "DIR"}),
         "person": ("which person", {}), "rounds": ("offset rounds", {}), "free": ("comma-separated cameras not held at the lab's pose", {})},
    ),
    "factors": (
        "the reprojection factor's microseconds per error call and per linearisation, for 1, 4 and 8 cameras, with and without labelling",
        "mocapgraph.benchmarks.factors:bench_factors", {"min_seconds": ("time spent per figure, seconds", {"flag": "--seconds"})},
    ),
    "airpose": ("AirPose vs AirPose+ on an airpose capture, for every initialiser (regressor ablation, PnP)", "mocapgraph.benchmarks.airpose:bench_airpose", {}),
    "priors": (
        "the shipped learned priors on held-out CMU subjects and on aircap",
        "mocapgraph.benchmarks.priors:bench_priors",
        {
            "motion_dir": ("CMU motion directory (default ../shared/motion/cmu_train)", {"type": Path, "metavar": "DIR", "flag": "--motion"}),
            "noise_scale": ("keypoint noise multiplier of the aircap capture", {}),
        },
    ),
}
COMMON = {"duration_s": ("seconds of capture", {"flag": "--duration"}), "seed": ("scenario seed", {})}


def _function(target: str):
    module, name = target.split(":")
    return getattr(importlib.import_module(module), name)


def cmd_bench(args) -> None:
    fn = _function(BENCHES[args.bench_command][1])
    print(json.dumps(fn(**{name: getattr(args, name) for name in args.bench_parameters})))


def cmd_bench_body(args) -> None:
    from mocapgraph.benchmarks.body import bench_body

    result = bench_body(body_from(args), frames=args.frames, min_seconds=args.min_seconds)
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:22s} {value}")


def cmd_bench_real(args) -> None:
    from mocapgraph.benchmarks.real import bench_real, format_report

    report = bench_real(args.clip, args.heldout_share, args.heldout_seed)
    print(json.dumps(report) if args.json else format_report(report))


def add_parsers(subparsers) -> None:
    bench = group(subparsers, "bench", "speed and accuracy benchmarks", "bench_command")
    body = command(bench, "body", "native vs numpy posing with Jacobians, one run")
    add_body_args(body)
    from mocapgraph.benchmarks.body import bench_body

    function_flags(body, bench_body, {"frames": "frames per batch", "min_seconds": ("time spent per variant, seconds", {"flag": "--seconds"})})
    body.add_argument("--json", action="store_true", help="print one JSON object")
    body.set_defaults(func=cmd_bench_body)
    real = command(bench, "real", "SmartMocap and the uncalibrated baseline self-calibrating a real four-camera clip, against the lab's calibration; one run")
    real.add_argument("--clip", type=Path, default=None, metavar="DIR", help="folder with tracks.npz and Calib.qca.txt (default: tests/data/real of the source tree)")
    from mocapgraph.benchmarks.heldout import HELDOUT_SEED, HELDOUT_SHARE

    real.add_argument(
        "--heldout-share", type=float, default=HELDOUT_SHARE, metavar="S",
        help=f"share of the camera-frames hidden from both pipelines in one more run each, predicted from their 3D (default {HELDOUT_SHARE:g}; 0: no such run)",
    )  # fmt: skip
    real.add_argument("--heldout-seed", type=int, default=HELDOUT_SEED, metavar="N", help=f"which camera-frames are hidden (default {HELDOUT_SEED})")
    real.add_argument("--json", action="store_true", help="print one JSON object")
    real.set_defaults(func=cmd_bench_real)
    for name, (help, target, extra) in BENCHES.items():
        parser = command(bench, name, f"{help}; one run, one JSON object")
        fn = _function(target)
        names = function_flags(parser, fn, {**{k: v for k, v in COMMON.items() if k in inspect.signature(fn).parameters}, **extra})
        parser.add_argument("--json", action="store_true", help="accepted for symmetry with bench body: the output is always JSON")
        parser.set_defaults(func=cmd_bench, bench_parameters=names)
