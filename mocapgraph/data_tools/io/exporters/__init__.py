"""Exports of a result for other tools, one module per format.

=========  ======  ==========================================================================
format     file    what it holds
=========  ======  ==========================================================================
``bvh``    .bvh    the 22-joint skeleton, per-frame joint rotations and root motion (Blender,
                   MotionBuilder); needs the body parameters
``gltf``   .glb    glTF 2.0 binary: the skinned mesh, its bone animation and the camera tracks
                   as animated cameras (Blender, three.js, any glTF viewer); needs the body
                   parameters and a backend with a mesh (Anny, SMPL)
``trc``    .trc    joints and keypoints as markers, metres, Y up as Pose2Sim writes them
                   (OpenSim, Pose2Sim); joints-only results too
``csv``    .csv    joints per frame, world frame, metres; joints-only results too
``smpl``   .npz    SMPL/AMASS-style parameters; only for results of the SMPL/SMPL-X backend
=========  ======  ==========================================================================

Axes: our world is Z up. BVH and glTF are Y up by convention; both are written in
:data:`Y_UP_FROM_Z_UP` coordinates ``(x, z, −y)``, which Blender's importers (default settings,
"forward −Z, up Y") turn back into exactly our world. Lengths stay in metres (Blender: 1 unit =
1 m at the importers' default scale).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.data_tools.io.files import refuse_existing, write_file_atomically
from mocapgraph.errors import MocapgraphError

log = logging.getLogger(__name__)

FORMATS: dict[str, str] = {"bvh": ".bvh", "gltf": ".glb", "trc": ".trc", "csv": ".csv", "smpl": ".npz"}
"""Export format → file suffix."""

NEEDS_BODY = ("bvh", "gltf", "smpl")
"""Formats written from the body parameters (not from the joints alone): they need the body model."""

Y_UP_FROM_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""``(3, 3)`` rotation taking our Z-up world to the Y-up frame of BVH and glTF: ``(x, y, z) → (x, z, −y)``."""


class ExportError(MocapgraphError):
    """A result that cannot be exported in the asked format; the message says why and what can."""


def require_body_parameters(result, fmt: str) -> None:
    """Raise an ExportError when ``result`` has joints only (e.g. the triangulation baseline)."""
    if not result.has_body_parameters:
        raise ExportError(
            f"{result.path or 'result'}: {fmt} needs the body parameters (root, pose, shape), but the "
            f"{result.pipeline} result has joints only; export trc or csv instead"
        )


def frame_time(timestamps: np.ndarray) -> float:
    """The median step of ``timestamps (T,)`` in seconds; a one-frame result gets 1 s."""
    if len(timestamps) < 2:
        return 1.0
    steps = np.diff(timestamps)
    step = float(np.median(steps))
    if np.max(np.abs(steps - step)) > 1e-3 * step:
        log.warning("the result's timestamps are not evenly spaced (steps %.4g to %.4g s); formats without a time column assume %.4g s",
                    steps.min(), steps.max(), step)  # fmt: skip
    return step


def body_for(result, body: BodyModel | None) -> BodyModel:
    """``body`` when given, else the result's own backend (anny; SMPL needs the user's model file)."""
    if body is not None:
        if body.name != result.body_model:
            raise ExportError(f"the result was solved with the {result.body_model} body model, not {body.name}")
        return body
    from mocapgraph.body import load_body_model

    if result.body_model != "anny":
        raise ExportError(f"the result was solved with the {result.body_model} body model: pass its model file (--model-path)")
    return load_body_model("anny")


def export_result(result, fmt: str, out: str | Path, *, body: BodyModel | None = None, capture=None, overwrite: bool = False) -> Path:
    """Write ``result`` as ``fmt`` (a key of :data:`FORMATS`) to ``out``, atomically.

    Args:
        out: the file to write; its suffix must be the format's (:data:`FORMATS`).
        body: the body model the result was solved with (default: loaded by its name; SMPL
            results need it, built from the user's model file).
        capture: the result's capture, for the cameras' intrinsics in glTF (optional: without
            it the glTF's camera nodes have no lens).
    """
    from mocapgraph.data_tools.io.exporters import bvh, gltf, joints_csv, smpl_npz, trc

    if fmt not in FORMATS:
        raise ExportError(f"unknown export format {fmt!r}; choose one of {', '.join(FORMATS)}")
    out = Path(out)
    if out.is_dir():
        raise ExportError(f"{out}: is a directory; give the file to write")
    if out.suffix.lower() != FORMATS[fmt]:
        raise ExportError(f"{out}: a {fmt} export is a {FORMATS[fmt]} file; name it {out.with_suffix(FORMATS[fmt]).name}")
    if fmt in NEEDS_BODY:
        require_body_parameters(result, fmt)
        if fmt == "smpl" and result.body_model not in ("smpl", "smplx"):
            raise ExportError(
                f"{result.path or 'result'}: smpl export needs a result of the SMPL or SMPL-X backend; this one used "
                f"{result.body_model} (its pose parameters do not drive SMPL): export bvh or gltf instead"
            )
        body = body_for(result, body)
    encode = {
        "bvh": lambda: bvh.bvh_text(result, body).encode("ascii"),
        "gltf": lambda: gltf.glb_bytes(result, body, capture),
        "trc": lambda: trc.trc_text(result, out.name).encode("utf-8"),
        "csv": lambda: joints_csv.csv_text(result).encode("utf-8"),
        "smpl": lambda: smpl_npz.smpl_bytes(result, body),
    }[fmt]
    refuse_existing(out, overwrite, ExportError)  # before the work, not after it
    content = encode()
    return write_file_atomically(out, overwrite, lambda tmp: tmp.write_bytes(content), ExportError)
