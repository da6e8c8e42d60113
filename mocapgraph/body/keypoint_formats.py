"""Registry of 2D keypoint formats and how each point maps onto the body's keypoints.

Every detector format names its points in its own order; each point is a fixed blend of the 23
body keypoints (:data:`~mocapgraph.body.skeleton.BODY_KEYPOINT_NAMES`), or unmapped when no body
point corresponds (e.g. BlazePose's finger tips). Detections are normalised to
``(..., K, 3) = x, y, confidence`` with confidence in [0, 1] and NaN for every missing point.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES, left_right_pairs
from mocapgraph.body.table import BodyTable
from mocapgraph.errors import MocapgraphError

COCO17 = BODY_KEYPOINT_NAMES[:17]

_MIDPOINT = 0.5


@dataclass(frozen=True)
class KeypointFormat:
    """One detector's keypoint layout.

    Attributes:
        name: registry name.
        names: the format's point names, in its order.
        mapping: per point, ``{body keypoint: weight}`` (weights sum to 1), or None if unmapped.
        zero_is_missing: the format writes a missing point as ``(0, 0, 0)`` (OpenPose does).
        min_confidence: points with confidence at or below this are treated as missing.
        confidence: what the format's third column means.
    """

    name: str
    names: tuple[str, ...]
    mapping: tuple[dict[str, float] | None, ...]
    zero_is_missing: bool
    min_confidence: float
    confidence: str
    aliases: tuple[str, ...] = field(default=())

    @property
    def num_points(self) -> int:
        return len(self.names)

    @property
    def left_right_pairs(self) -> list[tuple[int, int]]:
        """Index pairs (left, right) that swap under a mirror, for flip detection and augmentation."""
        return left_right_pairs(self.names)

    def mix(self) -> np.ndarray:
        """``(K_format, 23)`` blend of body keypoints giving each format point (zero row = unmapped)."""
        out = np.zeros((self.num_points, len(BODY_KEYPOINT_NAMES)))
        for i, m in enumerate(self.mapping):
            for body_name, w in (m or {}).items():
                out[i, BODY_KEYPOINT_NAMES.index(body_name)] = w
        return out

    def normalise(self, detections, source: str = "detections") -> np.ndarray:
        """``(..., K, 3)`` raw detections → x, y, confidence in [0, 1], NaN where missing.

        ``source`` names the file or field in error messages.
        """
        arr = np.array(detections, dtype=float, copy=True)
        if arr.ndim < 2 or arr.shape[-2:] != (self.num_points, 3):
            raise MocapgraphError(
                f"{source}: {self.name} keypoints must have shape (..., {self.num_points}, 3), got {arr.shape}"
            )
        conf = arr[..., 2]
        if np.any(conf[np.isfinite(conf)] < 0):
            raise MocapgraphError(f"{source}: negative confidence in {self.name} keypoints")
        missing = ~np.all(np.isfinite(arr), axis=-1) | (conf <= self.min_confidence)
        if self.zero_is_missing:
            missing |= np.all(arr == 0, axis=-1)
        arr[..., 2] = np.clip(conf, 0.0, 1.0)
        arr[missing] = np.nan
        return arr


def _one_to_one(names) -> tuple[dict[str, float] | None, ...]:
    return tuple({n: 1.0} if n in BODY_KEYPOINT_NAMES else None for n in names)


def _pascal_to_snake(name: str) -> str:
    """OpenPose's ``LBigToe`` → ``left_big_toe``."""
    side = ""
    if len(name) > 1 and name[0] in "LR" and name[1].isupper():
        side, name = ("left_" if name[0] == "L" else "right_"), name[1:]
    return side + re.sub(r"(?<!^)([A-Z])", r"_\1", name).lower()


_BODY25 = (
    "Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist", "MidHip",
    "RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar", "LEar",
    "LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel",
)  # fmt: skip
_BODY25_SNAKE = tuple(_pascal_to_snake(n) for n in _BODY25)

_BLAZEPOSE33 = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
    "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_pinky",
    "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_heel",
    "right_heel", "left_foot_index", "right_foot_index",
)  # fmt: skip


# OpenPose's experimental BODY_25B (``poseParameters.cpp``, POSE_BODY_25B_BODY_PARTS): COCO-17's
# order, then two MPII head points and BODY_25's six foot points.
_BODY25B = COCO17 + ("upper_neck", "head_top") + _BODY25_SNAKE[19:]

# Halpe-FullBody's 26 body points (AlphaPose, RTMPose's halpe26 models, Pose2Sim's default
# "Body_with_feet"): COCO-17's order, then head top, neck, pelvis and the feet.
_HALPE26 = COCO17 + (
    "head", "neck", "hip", "left_big_toe", "right_big_toe", "left_small_toe", "right_small_toe",
    "left_heel", "right_heel",
)  # fmt: skip

# Points with no body keypoint behind them. BODY_25B's neck is MPII's "upper neck" and Halpe's
# sits with it: Pose2Sim's OpenSim marker sets put both 8 cm above the shoulder line, where
# BODY_25's neck sits (OpenSim_Setup/Markers_Body25b.xml, Markers_Halpe26.xml, Markers_Body25.xml),
# so neither is the shoulders' midpoint. Head tops lie above every face point.
_UNMAPPED = ("upper_neck", "head_top", "head", "neck")


def _body25_mapping():
    mapping = list(_one_to_one(_BODY25_SNAKE))
    # OpenPose's neck and mid-hip were trained as midpoints of the COCO shoulders and hips.
    mapping[_BODY25.index("Neck")] = {"left_shoulder": _MIDPOINT, "right_shoulder": _MIDPOINT}
    mapping[_BODY25.index("MidHip")] = {"left_hip": _MIDPOINT, "right_hip": _MIDPOINT}
    return tuple(mapping)


def _head_and_feet_mapping(names):
    """COCO-17 plus head and foot points: one-to-one by name, the pelvis as the hips' midpoint."""
    mapping = list(_one_to_one(names))
    for i, name in enumerate(names):
        if name in _UNMAPPED:
            mapping[i] = None
        elif name == "hip":
            mapping[i] = {"left_hip": _MIDPOINT, "right_hip": _MIDPOINT}
    return tuple(mapping)


def _blazepose_mapping():
    mapping = list(_one_to_one(_BLAZEPOSE33))
    # BlazePose's foot index is the tip of the toes, next to the big toe.
    for side in ("left", "right"):
        mapping[_BLAZEPOSE33.index(f"{side}_foot_index")] = {f"{side}_big_toe": 1.0}
    return tuple(mapping)


FORMATS: dict[str, KeypointFormat] = {
    f.name: f
    for f in (
        KeypointFormat(
            name="coco17",
            names=COCO17,
            mapping=_one_to_one(COCO17),
            zero_is_missing=False,
            min_confidence=0.0,
            confidence="detector score in [0, 1] (heatmap peak or regression score)",
            aliases=("coco",),
        ),
        KeypointFormat(
            name="openpose25",
            names=_BODY25_SNAKE,
            mapping=_body25_mapping(),
            zero_is_missing=True,
            min_confidence=0.0,
            confidence="OpenPose part confidence in [0, 1]; (0, 0, 0) marks a missing part",
            aliases=("body25", "openpose"),
        ),
        KeypointFormat(
            name="openpose25b",
            names=_BODY25B,
            mapping=_head_and_feet_mapping(_BODY25B),
            zero_is_missing=True,
            min_confidence=0.0,
            confidence="OpenPose part confidence in [0, 1]; (0, 0, 0) marks a missing part",
            aliases=("body25b",),
        ),
        KeypointFormat(
            name="halpe26",
            names=_HALPE26,
            mapping=_head_and_feet_mapping(_HALPE26),
            zero_is_missing=False,
            min_confidence=0.0,
            confidence="detector score (AlphaPose, RTMPose); scores above 1 are clipped to 1",
            aliases=("halpe",),
        ),
        KeypointFormat(
            name="blazepose33",
            names=_BLAZEPOSE33,
            mapping=_blazepose_mapping(),
            zero_is_missing=False,
            min_confidence=0.0,
            confidence="MediaPipe landmark visibility in [0, 1] (probability the point is visible)",
            aliases=("blazepose", "mediapipe"),
        ),
        KeypointFormat(
            name="body23",
            names=BODY_KEYPOINT_NAMES,
            mapping=_one_to_one(BODY_KEYPOINT_NAMES),
            zero_is_missing=False,
            min_confidence=0.0,
            confidence="in [0, 1]; the body model's own 23 keypoints (COCO-17 + 6 foot points)",
            aliases=("body",),
        ),
    )
}

def _key(name: str) -> str:
    """Registry lookup key: case, ``_`` and ``-`` ignored, so Pose2Sim's ``BODY_25B`` and ``HALPE_26`` resolve."""
    return re.sub(r"[_\-]", "", str(name).lower())


_ALIASES = {_key(alias): f.name for f in FORMATS.values() for alias in (f.name, *f.aliases)}


def get_format(name: str) -> KeypointFormat:
    """The registered format ``name`` (or an alias), or a MocapgraphError listing the known ones."""
    key = _key(name)
    if key not in _ALIASES:
        raise MocapgraphError(f"unknown keypoint format {name!r}; known formats: {_known()}")
    return FORMATS[_ALIASES[key]]


def _known() -> str:
    return ", ".join(f"{f.name} ({f.num_points} points)" for f in FORMATS.values())


UNSUPPORTED_POINT_COUNTS = {18: "OpenPose's COCO-18 model, which is not supported: run OpenPose with BODY_25"}
"""Point counts of known layouts that are not in the registry, with what to do instead."""


def formats_with_points(num_points: int) -> list[str]:
    """Names of the registered formats with ``num_points`` points, in registry order."""
    return [f.name for f in FORMATS.values() if f.num_points == num_points]


def format_for_points(num_points: int, source: str = "keypoints") -> KeypointFormat:
    """The one registered format with ``num_points`` points, or a MocapgraphError naming ``source``
    when none has that many or several do (BODY_25 and BODY_25B both have 25)."""
    names = formats_with_points(num_points)
    if len(names) == 1:
        return FORMATS[names[0]]
    if not names:
        hint = f" ({num_points} points is {UNSUPPORTED_POINT_COUNTS[num_points]})" if num_points in UNSUPPORTED_POINT_COUNTS else ""
        raise MocapgraphError(f"{source}: {num_points} points per person match no known format{hint}; known formats: {_known()}")
    raise MocapgraphError(f"{source}: {num_points} points per person could be {' or '.join(names)}; say which with --format")


def format_table(table: BodyTable, name: str) -> BodyTable:
    """The body table re-expressed in the points of detector format ``name``."""
    fmt = get_format(name)
    return table.combine(fmt.mix(), fmt.names)
