"""Keypoint-definition offsets fitted on real footage: the prior means of a pipeline's offsets.

A detector format's points sit a few centimetres off the body model's (:mod:`mocapgraph.body.keypoint_offsets`).
Estimated from one capture alone, part of such an offset is taken up by the body instead (a wider
pelvis explains a hip point placed laterally as well as the offset does), and which part depends
on where the estimate starts. A table measured once on real footage, with the cameras held at a
lab's calibration so that the triangulated points are where the detector put them, is the
estimate's prior mean and start.

Only formats measured on real footage are in the table; every other format's prior mean is zero.
The simulator's ``realistic`` definitions (:data:`mocapgraph.data_tools.sim.detectors.KEYPOINT_DEFINITION_OFFSETS_M`)
come from this table too, but never a format's own entry (BlazePose takes BODY_25B's and back):
a synthetic test of the prior against its own mean would be circular.
"""

from __future__ import annotations

import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.keypoint_offsets import MIRROR

FITTED_OFFSETS_M: dict[str, dict[str, tuple[float, float, float]]] = {
    # MediaPipe Pose (BlazePose GHUM, full model) through `mocapgraph detect`, on the lab clip
    "blazepose33": {
        "nose": (0.0, 0.0048, -0.0089),
        "left_eye": (-0.0074, 0.002, -0.0062),
        "left_ear": (-0.0267, 0.0069, 0.0286),
        "left_shoulder": (0.0051, 0.011, -0.0035),
        "left_elbow": (-0.0087, 0.0099, -0.0185),
        "left_wrist": (0.0007, -0.0033, 0.0184),
        "left_hip": (-0.0004, -0.0079, -0.0058),
        "left_knee": (-0.0051, 0.0127, 0.0111),
        "left_ankle": (0.0012, 0.0238, -0.0012),
        "left_heel": (0.0, 0.0249, 0.0008),
        "left_foot_index": (0.0084, 0.0116, -0.0141),
    },
    # OpenPose BODY_25B as shipped in the pose2sim 0.8.4 wheel, on the lab's two-participant trial
    "openpose25b": {
        "nose": (0.0, 0.0043, -0.0005),
        "left_eye": (-0.0038, -0.0007, 0.0058),
        "left_ear": (-0.0037, -0.0038, 0.0136),
        "left_shoulder": (0.0032, 0.005, -0.007),
        "left_elbow": (0.0001, -0.0011, -0.0092),
        "left_wrist": (0.0055, -0.0017, 0.0024),
        "left_hip": (0.0083, 0.0047, -0.002),
        "left_knee": (-0.0049, -0.0062, -0.0012),
        "left_ankle": (0.0033, -0.0061, 0.0092),
        "left_big_toe": (0.0075, -0.0087, -0.0074),
        "left_small_toe": (-0.0128, -0.0046, -0.0145),
        "left_heel": (0.002, 0.0102, 0.0079),
    },
}  # fmt: skip
"""Per format, the left and midline points' offsets ``(x left, y up, z forward)`` in metres, in the
frame of the body segment carrying the point (right points mirror their left partner)."""

PROVENANCE: dict[str, dict[str, str]] = {
    "blazepose33": {
        "clip": "tests/data/real (Pose2Sim Demo_MultiPerson, the largest person)",
        "command": "mocapgraph bench definitions --json (SmartMocap, lab intrinsics, cam01, cam02 and cam04 held at the lab's Calib.qca.txt, 4 offset rounds from zero)",
        "date": "2026-11-25, fitted again after the seventh session's merges (entries moved up to 11 mm since the first fit: elbow, knee, ankle)",
    },
    "openpose25b": {
        "clip": "tests/data/real_body25b (pose2sim 0.8.4's OpenPose BODY_25B output of a two-participant trial in the same lab, the largest person)",
        "command": "mocapgraph bench definitions --clip tests/data/real_body25b --json (SmartMocap, lab intrinsics, cam01, cam02 and cam04 held at the lab's Calib.qca.txt, 4 offset rounds from zero)",
        "date": "2026-11-25",
    },
}
"""Per format of :data:`FITTED_OFFSETS_M`: the clip, the command and the date of its fit."""


def prior_offsets(fmt: str) -> np.ndarray | None:
    """``(K, 3)`` metres, carrier frames: format ``fmt``'s fitted offsets (right points mirrored,
    points absent from the table zero), or None for a format never fitted on real footage."""
    table = FITTED_OFFSETS_M.get(get_format(fmt).name)
    if table is None:
        return None
    names = get_format(fmt).names
    out = np.zeros((len(names), 3))
    for name, value in table.items():
        out[names.index(name)] = value
        if name.startswith("left_"):
            out[names.index("right_" + name[5:])] = MIRROR * np.asarray(value)
    return out


__all__ = ["FITTED_OFFSETS_M", "PROVENANCE", "prior_offsets"]
