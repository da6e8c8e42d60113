"""``mocapgraph body info|prepare``: the body models."""

from __future__ import annotations

import json

from mocapgraph.cli.common import add_body_args, body_from, command, group


def cmd_info(args) -> None:
    info = body_from(args).describe()
    if args.json:
        print(json.dumps(info, indent=2))
        return
    print(f"backend: {info['backend']}")
    print(f"joints ({len(info['joints'])}, SMPL order; parent in brackets):")
    for i, (name, parent) in enumerate(zip(info["joints"], info["parents"])):
        print(f"  {i:2d} {name:15s} [{info['joints'][parent] if parent >= 0 else '-'}]")
    print(f"keypoints ({len(info['keypoints'])}): {', '.join(info['keypoints'])}")
    print(f"shape parameters ({len(info['shape'])}):")
    for s in info["shape"]:
        print(f"  {s['name']:12s} range [{s['min']:g}, {s['max']:g}]  default {s['default']:g}")


def cmd_prepare(args) -> None:
    from mocapgraph.body.anny_backend import ensure_anny_table

    print(ensure_anny_table(rebuild=args.rebuild))


def add_parsers(subparsers) -> None:
    body = group(subparsers, "body", "inspect and prepare body models", "body_command")
    info = command(body, "info", "joints, keypoints and shape parameters of a body model")
    add_body_args(info)
    info.add_argument("--json", action="store_true", help="print one JSON object")
    info.set_defaults(func=cmd_info)
    prepare = command(body, "prepare", "export the Anny model into the cache (done on first use)")
    prepare.add_argument("--rebuild", action="store_true", help="export again even if the cache is fresh")
    prepare.set_defaults(func=cmd_prepare)
