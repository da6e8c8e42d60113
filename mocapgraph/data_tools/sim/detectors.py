"""Simulated 2D keypoint detectors: realistic detections of a posed body from its ground truth.

:func:`simulate_detections` poses the body, projects its keypoints through an OpenCV camera
(:func:`project_points`, the one projection used by everything here) and applies, in this order:

0. **Definition** (``faults``, :class:`DetectorFaults`). A detector's hip, shoulder, knee or
   ankle is not the body model's point: each format point is moved by a fixed offset in the frame
   of the segment that carries it (``keypoint_offsets_m``, per format in
   :data:`KEYPOINT_DEFINITION_OFFSETS_M`, fitted on real footage; ``heavy`` takes the
   literature's, :data:`LITERATURE_DEFINITION_OFFSETS_M`), so its image effect changes with the viewing
   direction; then every point is scaled about the pelvis by ``size_bias``. Everything below
   acts on these points; ``DetectionInfo.body_pixels`` keeps the body's own projections.
1. **Frame.** A point is *in frame* when it lies in front of the camera (depth > ``MIN_DEPTH_M``),
   inside the image ``0 <= u < w, 0 <= v < h`` and inside the radius where the radial
   distortion is still monotonic (beyond it OpenCV's polynomial folds far points back into the
   image). Points out of frame are NaN. Format points the body cannot provide
   (``mapped`` False, e.g. BlazePose's finger tips, mouth and inner/outer eye corners) are
   always NaN: they are not synthesised.
2. **Whole person.** The person is missed in a frame (every point NaN, box NaN) with probability
   ``frame_miss_prob``, and always when the pelvis is behind the camera, when the person's image
   height is below ``min_person_height_px`` or fewer than ``min_keypoints_in_frame`` points are
   in frame.
3. **Self-occlusion** (:func:`self_occluded`). A point is occluded when the ray from the camera
   centre to it passes through a capsule around a bone of the 22-joint skeleton or the head
   sphere (:data:`CAPSULE_RADII_M`, :data:`HEAD_SPHERE_RADIUS_M`). A capsule is shrunk, for that
   point and frame only, so that the point lies ``occlusion_clearance_m`` outside it: a point
   never hides behind the bone it sits on (the wrist on its forearm, the hip inside the pelvis),
   yet the head still hides the nose from behind. A blended format point (OpenPose's neck and
   mid-hip, inside the body) is occluded only when every point it blends is. With probability
   ``faults.guess_prob`` an occluded point is *guessed*: placed at
   ``(1 - w) X + w M + N(0, guess_error_m²)`` (``M`` its left/right partner mirrored in the
   pelvis's sagittal plane, ``w = guess_mirror_weight``) and reported like a visible point, with a high
   confidence uniform in ``guess_conf_range``, as detectors trained to a "best guess" do. Other
   occluded points are dropped with probability ``occluded_drop_prob``, otherwise their noise is
   multiplied by ``occluded_noise_mult`` and their confidence by ``occluded_conf_mult``.
4. **Noise.** The person's image height is ``h = f_y · stature / depth(pelvis)``, where stature is
   the heel-to-eye extent of the body's rest keypoints (1.50 m for the default Anny body). Each
   point gets 2D noise of standard deviation per axis
   ``σ = sqrt((noise_frac_of_height · h)² + noise_floor_px²) · difficulty[part]``
   (× ``occluded_noise_mult`` if occluded and not guessed); Gaussian, or a 2D Student-t with ``noise_tail_dof``
   degrees of freedom scaled to the same σ; optionally AR(1)-correlated across frames
   (``noise_frame_correlation``), as real detectors jitter smoothly.
5. **Confidence** tracks the actual pixel error ``e`` of the point:
   ``c = clip(conf_max · exp(-e² / (2 (conf_error_frac_of_height · h)²)) + N(0, conf_noise_std²), 0, 1)``,
   times ``occluded_conf_mult`` when occluded and not guessed. Points with ``c <= conf_threshold`` are NaN.
6. **Outliers.** With probability ``outlier_prob`` a point in frame is placed elsewhere, with a
   confidence uniform in ``outlier_conf_range``: on its "shadow" (the point mirrored in the
   ground plane ``z = ground_z``, projected; share ``outlier_shadow_fraction``), on another
   in-frame point of the person (share ``outlier_other_point_fraction``), or else uniformly in
   the person's box. A shadow or other point that is unavailable falls back to the box.
7. **Dropout.** Each point in frame is missed with probability ``keypoint_miss_prob``; within
   ``border_dropout_px`` of the image border with probability ``border_drop_prob``; a point whose
   noisy position leaves the image is NaN.
8. **Swaps.** Runs of swapped left/right labels, whole body or one pair of limbs, start at a
   rate per second that depends on the viewing direction (from the side and from behind more
   than from the front) and last a drawn duration (``faults``; :class:`DetectorFaults` gives the
   chain): frame-rate independent. Away from runs (not in one, nor next to one), single frames
   are swapped: the whole body with probability ``body_swap_prob``, else one limb pair with
   probability ``limb_swap_prob``. A limb swap swaps the legs with share
   ``limb_swap_leg_fraction``, else the arms. One swap at most per frame, recorded as its code
   ``SWAP_KINDS.index(kind)`` in ``DetectionInfo.swaps``; the rows (position and confidence)
   move by :func:`~mocapgraph.body.labelling.swap_permutation`.
9. **Box.** The tight box around the exact projections of the in-frame points and the final
   detections, each side widened by ``max(0, box_margin + N(0, box_jitter²)) · h`` (so it always
   holds every detection), clipped to the image; score ``clip(N(box_score_mean,
   box_score_std²), 0, 1) · sqrt(fraction of mapped points visible)``.

Every random number is drawn up front in one fixed order with fixed shapes, so the same
generator state gives the same detections, and changing one rate does not reshuffle the others.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np
from scipy.stats import chi2

from mocapgraph.body.definition_priors import FITTED_OFFSETS_M
from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import SWAP_KINDS, part_name, swap_permutation
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES, JOINT_NAMES, NUM_JOINTS, PARENTS
from mocapgraph.data_tools.geometry.camera_model import MIN_DEPTH_M, in_frame_mask, in_image, project_points
from mocapgraph.data_tools.io.capture import Detector
from mocapgraph.errors import MocapgraphError

CAPSULE_RADII_M: dict[str, float] = {
    # bone parent → child, named by the child joint
    "left_hip": 0.10, "right_hip": 0.10,                      # pelvis to hip joints
    "spine1": 0.13, "spine2": 0.13, "spine3": 0.13,           # torso
    "neck": 0.12,                                             # upper chest (spine3 → neck base)
    "left_collar": 0.08, "right_collar": 0.08,
    "head": 0.06,                                             # the neck itself
    "left_knee": 0.08, "right_knee": 0.08,                    # upper legs
    "left_ankle": 0.06, "right_ankle": 0.06,                  # lower legs
    "left_foot": 0.04, "right_foot": 0.04,
    "left_shoulder": 0.06, "right_shoulder": 0.06,            # shoulder girdle
    "left_elbow": 0.05, "right_elbow": 0.05,                  # upper arms
    "left_wrist": 0.05, "right_wrist": 0.05,                  # forearms
}  # fmt: skip
"""Capsule radius around each bone of the 22-joint skeleton, by the bone's child joint (metres)."""

HEAD_SPHERE_RADIUS_M = 0.11
"""Radius of the head sphere, centred between the ears (metres)."""

CAPSULE_NAMES: tuple[str, ...] = JOINT_NAMES[1:] + ("head_sphere",)

DEFAULT_DIFFICULTY: dict[str, float] = {
    "nose": 0.8, "eye": 0.8, "eye_inner": 0.8, "eye_outer": 0.8, "ear": 1.0, "mouth": 0.9,
    "neck": 1.0, "shoulder": 1.0, "mid_hip": 1.1, "hip": 1.2,
    "elbow": 1.3, "knee": 1.2, "wrist": 1.6, "ankle": 1.4,
    "heel": 1.5, "big_toe": 1.5, "small_toe": 1.6, "foot_index": 1.5,
    "pinky": 2.0, "index": 2.0, "thumb": 2.0,
}  # fmt: skip
"""Noise multiplier per body part (point name without its left/right side); 1 when not listed."""

# ---------------------------------------------------------------------------------------------
# Detector faults: sustained swaps, far-side guesses, keypoint definitions, size bias

FAULT_LEVELS: tuple[str, ...] = ("none", "realistic", "heavy")
"""How strongly simulated detectors fail (:meth:`DetectorModel.at_fault_level`)."""

HEAVY_FACTOR = 2.0
"""``heavy`` multiplies every fault rate and amplitude of ``realistic`` by this, except the
definition offsets a detector gives for ``heavy`` itself (the literature's)."""

DEFAULT_FRAME_RATE_HZ = 30.0
"""Frame rate assumed by the simulator when it is given no frame timestamps."""

OFFSET_SEGMENTS: dict[str, str] = {
    "nose": "head", "eye": "head", "eye_inner": "head", "eye_outer": "head", "ear": "head", "mouth": "head",
    "neck": "spine3", "shoulder": "{side}_collar", "elbow": "{side}_shoulder", "wrist": "{side}_elbow",
    "pinky": "{side}_wrist", "index": "{side}_wrist", "thumb": "{side}_wrist",
    "mid_hip": "pelvis", "hip": "pelvis", "knee": "{side}_hip", "ankle": "{side}_knee",
    "heel": "{side}_ankle", "big_toe": "{side}_ankle", "small_toe": "{side}_ankle", "foot_index": "{side}_ankle",
}  # fmt: skip
"""The joint whose frame carries a keypoint-definition offset, by body part: the offset turns with
the segment the point sits on (the hip point with the pelvis, the ankle point with the shank)."""

UNSIDED_PARTS = ("nose", "neck", "mid_hip")
"""Parts on the body's midline: their offsets have no lateral component."""

LITERATURE_DEFINITION_OFFSETS_M: dict[str, dict[str, tuple[float, float, float]]] = {
    # COCO-17 annotations (HRNet, AlphaPose): Needham et al. 2021 found their 3D hips and knees
    # 30-50 mm and ankles 1-15 mm from marker-based joint centres; directions assumed.
    "coco17": {"shoulder": (0.010, 0.030, 0.0), "hip": (0.030, 0.0, 0.020), "knee": (0.0, 0.0, 0.020), "ankle": (0.010, 0.0, 0.0)},
    # OpenPose BODY_25, BlazePose and HALPE-26 hips: Pose2Sim's one hip marker for the three, 22 mm lateral, 15 mm
    # inferior and 7 mm anterior of its model's hip joint centre (Markers_*.xml).
    "openpose25": {"shoulder": (0.0, 0.030, 0.0), "hip": (0.022, -0.015, 0.007), "knee": (0.0, 0.0, 0.025), "ankle": (0.010, 0.0, -0.005)},
    "blazepose33": {"shoulder": (0.015, 0.020, -0.010), "hip": (0.022, -0.015, 0.007), "knee": (0.0, 0.0, 0.020), "ankle": (0.012, 0.0, 0.0)},
    "halpe26": {"shoulder": (0.010, 0.030, 0.0), "hip": (0.022, -0.015, 0.007), "knee": (0.0, 0.0, 0.020), "ankle": (0.010, 0.0, 0.0)},
    # BODY_25B is trained on COCO's annotations (and its foot points)
    "openpose25b": {"shoulder": (0.010, 0.030, 0.0), "hip": (0.030, 0.0, 0.020), "knee": (0.0, 0.0, 0.020), "ankle": (0.010, 0.0, 0.0)},
}  # fmt: skip
"""The literature's keypoint definitions (measured against marker-based joint centres, about three
times what real detectors show against this body model's points): ``heavy``'s offsets for the
parts they name (:attr:`DetectorFaults.heavy_keypoint_offsets_m`). Axes as
:data:`KEYPOINT_DEFINITION_OFFSETS_M`; sources in ``docs/detector_faults.md``."""


def _real_fit(source: str, fmt: str, renamed: dict[str, str] | None = None) -> dict[str, tuple[float, float, float]]:
    """By body part of format ``fmt``, the offsets fitted on real footage for format ``source``
    (:data:`~mocapgraph.body.definition_priors.FITTED_OFFSETS_M`); ``renamed`` maps a part of
    ``fmt`` to the part of ``source`` that stands for it. Parts ``source`` was not fitted on have none."""
    fitted = {part_name(name): value for name, value in FITTED_OFFSETS_M[source].items()}
    renamed = renamed or {}
    parts = sorted({part_name(name) for name in get_format(fmt).names})
    return {part: fitted[renamed.get(part, part)] for part in parts if renamed.get(part, part) in fitted}


KEYPOINT_DEFINITION_OFFSETS_M: dict[str, dict[str, tuple[float, float, float]]] = {
    # The real OpenPose BODY_25B fit: its body points are COCO's annotations, HALPE-26's body
    # points follow COCO's, and BODY_25 is an OpenPose network on the same body and foot labels.
    "coco17": _real_fit("openpose25b", "coco17"),
    "openpose25": _real_fit("openpose25b", "openpose25"),
    "halpe26": _real_fit("openpose25b", "halpe26"),
    # Crosswise, the other real detector's fit: SmartMocap's prior for these two formats is their
    # own fit, which a synthetic capture must not replay (a test of that prior would be circular).
    "blazepose33": _real_fit("openpose25b", "blazepose33", {"foot_index": "big_toe"}),
    "openpose25b": _real_fit("blazepose33", "openpose25b", {"big_toe": "foot_index"}),
}
"""Where each detector format puts a point relative to the body model's point of the same name
under ``realistic`` faults: ``(lateral, up, forward)`` metres of the left (or midline) point in
the frame of the segment carrying it (:data:`OFFSET_SEGMENTS`; the right point mirrors it), from
the fits of two real detectors on the lab's footage. Sources in ``docs/detector_faults.md``."""


def _check_triple(value, name: str, where: str, size: int) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        out = ()
    if len(out) != size or not all(math.isfinite(v) and v >= 0 for v in out):
        raise MocapgraphError(f"{where}: {name} must be {size} finite numbers >= 0, got {value!r}")
    return out


@dataclass(frozen=True)
class DetectorFaults:
    """The systematic failures of a 2D detector on video (defaults: none). ``docs/detector_faults.md``
    gives the footage and literature each preset's values come from.

    Swaps run as a semi-Markov chain per camera with the states of
    :data:`~mocapgraph.body.labelling.SWAP_KINDS`: from correct labels, a run of swapped labels
    starts at rate ``λ(θ) = λ_front·max(cos θ, 0)² + λ_side·sin² θ + λ_back·max(-cos θ, 0)²`` per
    second, θ being the angle between the body's facing direction and the direction from the
    body to the camera (0 = seen from the front, π/2 from the side, π from behind), and lasts a
    duration drawn log-uniformly in its range, covering the frames that start within that duration
    less half a frame (so ``round(duration · fps)`` frames, at least one); frame rates only change
    how finely the runs are sampled. Runs are separated by at least one correctly labelled frame.

    Attributes:
        body_swap_rate_hz: (front, side, back) onset rate of whole-body left/right swaps, 1/s.
        body_swap_duration_s: (shortest, longest) duration of a whole-body swap run, seconds.
        limb_swap_rate_hz: (front, side, back) onset rate of limb swaps (one pair of limbs;
            legs with the detector's ``limb_swap_leg_fraction``, else arms), 1/s.
        limb_swap_duration_s: (shortest, longest) duration of a limb swap run, seconds.
        guess_prob: probability that a self-occluded point is reported at a guess with a high
            confidence instead of the occluded treatment (noisier, less confident, maybe dropped).
        guess_conf_range: (low, high) uniform confidence of a guessed point.
        guess_mirror_weight: the guess lies this far (0..1) from the true point towards the
            point's left/right partner mirrored in the pelvis's sagittal plane (as if the pose
            were symmetric).
        guess_error_m: std per axis of a 3D Gaussian error added to the guess, metres.
        keypoint_offsets_m: by body part (``hip``, ``shoulder``, ...), ``(lateral, up, forward)``
            metres from the body model's point to where the detector puts it, for the left point
            in the frame of the segment carrying it (:data:`OFFSET_SEGMENTS`); right points mirror
            it, a point without a side must have no lateral part.
        heavy_keypoint_offsets_m: by body part, the offsets ``heavy`` uses instead of twice
            ``keypoint_offsets_m`` (the presets: :data:`LITERATURE_DEFINITION_OFFSETS_M`, the
            literature's hips, knees, ankles and shoulders); same axes.
        size_bias: the detector's points are scaled by this about the pelvis (its person is this
            much larger or smaller than the body).
    """

    body_swap_rate_hz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    body_swap_duration_s: tuple[float, float] = (0.1, 1.0)
    limb_swap_rate_hz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    limb_swap_duration_s: tuple[float, float] = (0.05, 0.3)
    guess_prob: float = 0.0
    guess_conf_range: tuple[float, float] = (0.6, 0.9)
    guess_mirror_weight: float = 0.0
    guess_error_m: float = 0.0
    keypoint_offsets_m: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    heavy_keypoint_offsets_m: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    size_bias: float = 1.0

    def __post_init__(self):
        where = "detector faults"
        _check_triple(self.body_swap_rate_hz, "body_swap_rate_hz", where, 3)
        _check_triple(self.limb_swap_rate_hz, "limb_swap_rate_hz", where, 3)
        for name in ("body_swap_duration_s", "limb_swap_duration_s"):
            lo, hi = _check_triple(getattr(self, name), name, where, 2)
            if not 0 < lo <= hi:
                raise MocapgraphError(f"{where}: {name} must be (shortest, longest) with 0 < shortest <= longest, got {getattr(self, name)!r}")
        lo, hi = _check_triple(self.guess_conf_range, "guess_conf_range", where, 2)
        if not lo <= hi <= 1:
            raise MocapgraphError(f"{where}: guess_conf_range must be (low, high) with 0 <= low <= high <= 1")
        for name in ("guess_prob", "guess_mirror_weight"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0 <= value <= 1):
                raise MocapgraphError(f"{where}: {name} must lie in [0, 1], got {value!r}")
        if not (isinstance(self.guess_error_m, (int, float)) and math.isfinite(self.guess_error_m) and self.guess_error_m >= 0):
            raise MocapgraphError(f"{where}: guess_error_m must be a finite number >= 0, got {self.guess_error_m!r}")
        if not (isinstance(self.size_bias, (int, float)) and 0.5 <= self.size_bias <= 2):
            raise MocapgraphError(f"{where}: size_bias must lie in [0.5, 2], got {self.size_bias!r}")
        for name in ("keypoint_offsets_m", "heavy_keypoint_offsets_m"):
            for part, offset in getattr(self, name).items():
                if part not in OFFSET_SEGMENTS:
                    raise MocapgraphError(f"{where}: {name} has unknown body part {part!r}; parts: {', '.join(OFFSET_SEGMENTS)}")
                vec = np.asarray(offset, dtype=float)
                if vec.shape != (3,) or not np.all(np.isfinite(vec)) or np.linalg.norm(vec) > 0.2:
                    raise MocapgraphError(f"{where}: {name}[{part!r}] must be 3 finite metres, at most 0.2 m long, got {offset!r}")
                if part in UNSIDED_PARTS and vec[0] != 0:
                    raise MocapgraphError(f"{where}: {name}[{part!r}]: a point without a side has no lateral offset")

    def scaled(self, factor: float) -> DetectorFaults:
        """These faults with every rate and amplitude times ``factor`` (probabilities and the
        mirror weight capped at 1; durations, confidences and ``heavy_keypoint_offsets_m`` unchanged)."""
        return replace(
            self,
            body_swap_rate_hz=tuple(factor * r for r in self.body_swap_rate_hz),
            limb_swap_rate_hz=tuple(factor * r for r in self.limb_swap_rate_hz),
            guess_prob=min(1.0, factor * self.guess_prob),
            guess_mirror_weight=min(1.0, factor * self.guess_mirror_weight),
            guess_error_m=factor * self.guess_error_m,
            keypoint_offsets_m={k: tuple(factor * v for v in o) for k, o in self.keypoint_offsets_m.items()},
            size_bias=1.0 + factor * (self.size_bias - 1.0),
        )


@dataclass(frozen=True)
class DetectorModel:
    """How a simulated 2D detector errs. Every rate is a parameter; defaults describe a decent
    top-down detector. See the module docstring for exactly where each one acts.

    Attributes:
        name: the detector's name in the capture (``Detector.name``).
        format: keypoint format of the registry (``coco17``, ``openpose25``, ``blazepose33``, …).
        noise_frac_of_height: pixel noise std per axis as a fraction of the person's image height.
        noise_floor_px: noise std (pixels) added in quadrature, the limit for tiny persons.
        noise_tail_dof: Student-t degrees of freedom of the noise (> 2); ``inf`` = Gaussian.
        noise_frame_correlation: AR(1) coefficient of the noise from one frame to the next, [0, 1).
        difficulty: noise multiplier per body part (:func:`part_name`), 1 for parts not listed.
        conf_max: confidence of an error-free, unoccluded point.
        conf_error_frac_of_height: the error (fraction of image height) at which the confidence
            has fallen to ``exp(-1/2)`` of ``conf_max``.
        conf_noise_std: std of the noise added to the confidence.
        conf_threshold: points with confidence at or below this are reported missing.
        occluded_drop_prob: probability that a self-occluded point is not reported.
        occluded_noise_mult: noise multiplier of a self-occluded point.
        occluded_conf_mult: confidence multiplier of a self-occluded point.
        occlusion_radius_scale: scales every capsule radius (heavier or slimmer bodies).
        occlusion_clearance_m: a point is kept this far outside any capsule it lies in.
        frame_miss_prob: probability that the whole person is missed in a frame.
        min_person_height_px: smaller persons (image height) are never detected.
        min_keypoints_in_frame: persons with fewer mapped points in frame are never detected.
        keypoint_miss_prob: probability that a point in frame is not reported.
        body_swap_prob: per-frame probability of a single-frame whole-body left/right label swap
            (a flicker; the sustained runs are in ``faults``).
        limb_swap_prob: per-frame probability that one limb's left/right labels swap for one frame.
        limb_swap_leg_fraction: share of limb swaps, single-frame and runs, that swap the legs
            (the rest swap the arms).
        outlier_prob: probability that a point in frame is placed elsewhere.
        outlier_shadow_fraction: share of outliers placed on the point's ground-plane mirror image.
        outlier_other_point_fraction: share of outliers placed on another point of the person.
        outlier_conf_range: (low, high) uniform confidence of an outlier.
        border_dropout_px: width of the image border band where points may drop out (0 = off).
        border_drop_prob: probability that a point inside that band is not reported.
        box_margin_frac_of_height: margin added on each side of the tight keypoint box.
        box_jitter_frac_of_height: std of the jitter of each side's margin (margin stays >= 0).
        box_score_mean: mean box score of a fully visible person.
        box_score_std: std of the box score.
        faults: the detector's systematic failures on video: sustained and view-dependent swaps,
            far-side guesses, keypoint-definition offsets, size bias (default: none; the presets
            carry realistic ones, :meth:`at_fault_level` switches them).
    """

    name: str = "simulated"
    format: str = "coco17"
    noise_frac_of_height: float = 0.01
    noise_floor_px: float = 0.0
    noise_tail_dof: float = math.inf
    noise_frame_correlation: float = 0.0
    difficulty: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_DIFFICULTY))
    conf_max: float = 0.95
    conf_error_frac_of_height: float = 0.03
    conf_noise_std: float = 0.05
    conf_threshold: float = 0.0
    occluded_drop_prob: float = 0.3
    occluded_noise_mult: float = 2.0
    occluded_conf_mult: float = 0.5
    occlusion_radius_scale: float = 1.0
    occlusion_clearance_m: float = 0.01
    frame_miss_prob: float = 0.02
    min_person_height_px: float = 10.0
    min_keypoints_in_frame: int = 3
    keypoint_miss_prob: float = 0.01
    body_swap_prob: float = 0.005
    limb_swap_prob: float = 0.01
    limb_swap_leg_fraction: float = 0.7
    outlier_prob: float = 0.005
    outlier_shadow_fraction: float = 0.3
    outlier_other_point_fraction: float = 0.3
    outlier_conf_range: tuple[float, float] = (0.3, 0.7)
    border_dropout_px: float = 0.0
    border_drop_prob: float = 0.5
    box_margin_frac_of_height: float = 0.06
    box_jitter_frac_of_height: float = 0.02
    box_score_mean: float = 0.9
    box_score_std: float = 0.05
    faults: DetectorFaults = field(default_factory=DetectorFaults)

    def __post_init__(self):
        get_format(self.format)  # an unknown format is an error that lists the known ones
        where = f"detector model {self.name!r}"
        probabilities = (
            "conf_max", "conf_threshold", "occluded_drop_prob", "frame_miss_prob",
            "keypoint_miss_prob", "body_swap_prob", "limb_swap_prob", "limb_swap_leg_fraction",
            "outlier_prob", "outlier_shadow_fraction", "outlier_other_point_fraction",
            "border_drop_prob", "box_score_mean",
        )  # fmt: skip
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("name", "format", "difficulty", "outlier_conf_range", "noise_tail_dof", "faults"):
                continue
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise MocapgraphError(f"{where}: {f.name} must be a finite number >= 0, got {value!r}")
            if f.name in probabilities and value > 1:
                raise MocapgraphError(f"{where}: {f.name} must lie in [0, 1], got {value!r}")
        if not self.noise_tail_dof > 2:
            raise MocapgraphError(f"{where}: noise_tail_dof must be > 2 (inf = Gaussian), got {self.noise_tail_dof!r}")
        if self.noise_frame_correlation >= 1:
            raise MocapgraphError(f"{where}: noise_frame_correlation must lie in [0, 1), got {self.noise_frame_correlation!r}")
        if self.outlier_shadow_fraction + self.outlier_other_point_fraction > 1 + 1e-12:
            raise MocapgraphError(f"{where}: outlier_shadow_fraction + outlier_other_point_fraction must not exceed 1")
        lo, hi = self.outlier_conf_range
        if not 0 <= lo <= hi <= 1:
            raise MocapgraphError(f"{where}: outlier_conf_range must be (low, high) with 0 <= low <= high <= 1")
        bad = {k: v for k, v in self.difficulty.items() if not (math.isfinite(v) and v >= 0)}
        if bad:
            raise MocapgraphError(f"{where}: difficulty multipliers must be finite and >= 0, got {bad}")
        if not isinstance(self.faults, DetectorFaults):
            raise MocapgraphError(f"{where}: faults must be a DetectorFaults, got {type(self.faults).__name__}")

    def without_effects(self) -> DetectorModel:
        """The same detector with every effect off: exact projections, confidence 1, nothing missed."""
        return replace(
            self,
            noise_frac_of_height=0.0, noise_floor_px=0.0, noise_tail_dof=math.inf,
            noise_frame_correlation=0.0, conf_max=1.0, conf_noise_std=0.0, conf_threshold=0.0,
            occluded_drop_prob=0.0, occluded_noise_mult=1.0, occluded_conf_mult=1.0,
            frame_miss_prob=0.0, min_person_height_px=0.0, min_keypoints_in_frame=1,
            keypoint_miss_prob=0.0, body_swap_prob=0.0, limb_swap_prob=0.0, outlier_prob=0.0,
            border_dropout_px=0.0, box_jitter_frac_of_height=0.0, box_score_std=0.0, faults=DetectorFaults(),
        )  # fmt: skip

    def at_fault_level(self, level: str) -> DetectorModel:
        """This detector with its faults at ``level`` (:data:`FAULT_LEVELS`): ``"none"`` has no
        swaps of any kind (runs or single frames), guesses, keypoint offsets or size bias, while
        noise, dropouts and outliers stay; ``"realistic"`` is the detector as it is; ``"heavy"``
        multiplies every fault rate and amplitude, the single-frame swaps' included, by
        :data:`HEAVY_FACTOR`, and puts the parts of ``faults.heavy_keypoint_offsets_m`` at those
        offsets instead."""
        if level not in FAULT_LEVELS:
            raise MocapgraphError(f"unknown detector fault level {level!r}; levels: {', '.join(FAULT_LEVELS)}")
        if level == "none":
            return replace(self, body_swap_prob=0.0, limb_swap_prob=0.0, faults=DetectorFaults())
        if level == "heavy":
            scaled = self.faults.scaled(HEAVY_FACTOR)
            return replace(
                self,
                body_swap_prob=min(1.0, HEAVY_FACTOR * self.body_swap_prob),
                limb_swap_prob=min(1.0, HEAVY_FACTOR * self.limb_swap_prob),
                faults=replace(scaled, keypoint_offsets_m={**scaled.keypoint_offsets_m, **self.faults.heavy_keypoint_offsets_m}),
            )
        return self

    def difficulties(self) -> np.ndarray:
        """``(K,)`` noise multiplier of each point of the format."""
        names = get_format(self.format).names
        return np.array([self.difficulty.get(part_name(n), 1.0) for n in names])


DETECTOR_PRESETS: dict[str, DetectorModel] = {
    # Bottom-up, part affinity fields: noisier, drops low-confidence and occluded parts, and
    # often swaps the legs in side views.
    "openpose": DetectorModel(
        name="openpose", format="openpose25",
        noise_frac_of_height=0.012, noise_floor_px=0.7, noise_tail_dof=4.0,
        noise_frame_correlation=0.5, conf_max=0.9, conf_error_frac_of_height=0.035,
        conf_noise_std=0.07, conf_threshold=0.05,
        occluded_drop_prob=0.5, occluded_noise_mult=2.0, occluded_conf_mult=0.4,
        frame_miss_prob=0.03, min_person_height_px=40.0, min_keypoints_in_frame=4,
        keypoint_miss_prob=0.03, body_swap_prob=0.0, limb_swap_prob=0.01,
        limb_swap_leg_fraction=0.8, outlier_prob=0.01, border_dropout_px=8.0,
        faults=DetectorFaults(
            body_swap_rate_hz=(0.015, 0.2, 0.8), limb_swap_rate_hz=(0.05, 0.6, 0.1),
            guess_prob=0.2, guess_mirror_weight=0.5, guess_error_m=0.04,
            keypoint_offsets_m=KEYPOINT_DEFINITION_OFFSETS_M["openpose25"],
            heavy_keypoint_offsets_m=LITERATURE_DEFINITION_OFFSETS_M["openpose25"], size_bias=1.02,
        ),
    ),
    # Top-down with a person detector (YOLO boxes, regional multi-person pose): always reports
    # every point, occluded ones with a low score.
    "alphapose": DetectorModel(
        name="alphapose", format="coco17",
        noise_frac_of_height=0.009, noise_floor_px=0.5, noise_tail_dof=5.0,
        noise_frame_correlation=0.4, conf_max=0.92, conf_error_frac_of_height=0.03,
        conf_noise_std=0.05, occluded_drop_prob=0.05, occluded_noise_mult=2.5,
        occluded_conf_mult=0.45, frame_miss_prob=0.02, min_person_height_px=24.0,
        keypoint_miss_prob=0.005, body_swap_prob=0.0, limb_swap_prob=0.005, outlier_prob=0.008,
        faults=DetectorFaults(
            body_swap_rate_hz=(0.01, 0.15, 0.6), limb_swap_rate_hz=(0.03, 0.4, 0.06),
            guess_prob=0.4, guess_mirror_weight=0.5, guess_error_m=0.04,
            keypoint_offsets_m=KEYPOINT_DEFINITION_OFFSETS_M["coco17"],
            heavy_keypoint_offsets_m=LITERATURE_DEFINITION_OFFSETS_M["coco17"], size_bias=1.015,
        ),
    ),
    # Top-down HRNet-W48 on COCO: the most precise of the set.
    "coco_hrnet": DetectorModel(
        name="coco_hrnet", format="coco17",
        noise_frac_of_height=0.007, noise_floor_px=0.4, noise_tail_dof=6.0,
        noise_frame_correlation=0.4, conf_max=0.95, conf_error_frac_of_height=0.025,
        conf_noise_std=0.04, occluded_drop_prob=0.02, occluded_noise_mult=2.0,
        occluded_conf_mult=0.5, frame_miss_prob=0.015, min_person_height_px=20.0,
        keypoint_miss_prob=0.003, body_swap_prob=0.0, limb_swap_prob=0.005, outlier_prob=0.005,
        faults=DetectorFaults(
            body_swap_rate_hz=(0.01, 0.12, 0.5), limb_swap_rate_hz=(0.02, 0.3, 0.05),
            guess_prob=0.4, guess_mirror_weight=0.5, guess_error_m=0.04,
            keypoint_offsets_m=KEYPOINT_DEFINITION_OFFSETS_M["coco17"],
            heavy_keypoint_offsets_m=LITERATURE_DEFINITION_OFFSETS_M["coco17"], size_bias=0.99,
        ),
    ),
    # MediaPipe BlazePose: single-person tracker, always all 33 landmarks with a visibility
    # score; loses the person more often and flips when the person faces away.
    "mediapipe": DetectorModel(
        name="mediapipe", format="blazepose33",
        noise_frac_of_height=0.015, noise_floor_px=1.0, noise_tail_dof=3.0,
        noise_frame_correlation=0.7, conf_max=0.97, conf_error_frac_of_height=0.04,
        conf_noise_std=0.05, occluded_drop_prob=0.0, occluded_noise_mult=2.5,
        occluded_conf_mult=0.3, frame_miss_prob=0.05, min_person_height_px=60.0,
        min_keypoints_in_frame=6, keypoint_miss_prob=0.0, body_swap_prob=0.0,
        limb_swap_prob=0.003, outlier_prob=0.005,
        # calibrated on the lab clip of issue 14: one camera swapped 31 of 100 frames (60 fps)
        faults=DetectorFaults(
            body_swap_rate_hz=(0.02, 0.25, 1.0), limb_swap_rate_hz=(0.03, 0.3, 0.05),
            guess_prob=0.5, guess_mirror_weight=0.5, guess_error_m=0.04,
            keypoint_offsets_m=KEYPOINT_DEFINITION_OFFSETS_M["blazepose33"],
            heavy_keypoint_offsets_m=LITERATURE_DEFINITION_OFFSETS_M["blazepose33"], size_bias=0.98,
        ),
    ),
}  # fmt: skip
"""Detector profiles with differing formats, noise and failure rates (orders of magnitude from the
published accuracies; not fitted to any particular benchmark), each with realistic
:class:`DetectorFaults` (``docs/detector_faults.md`` gives their sources)."""


# ---------------------------------------------------------------------------------------------
# Self-occlusion


def segment_distance(p0, p1, q0, q1) -> np.ndarray:
    """Closest distance between segments ``[p0, p1]`` and ``[q0, q1]`` (``(..., 3)``, broadcast);
    either may be a single point. Ericson, *Real-Time Collision Detection*, 5.1.9, vectorised."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    b = np.einsum("...i,...i->...", d1, d2)
    c = np.einsum("...i,...i->...", d1, r)
    f = np.einsum("...i,...i->...", d2, r)
    tiny = 1e-18
    a_ok, e_ok = a > tiny, e > tiny
    a_s, e_s = np.where(a_ok, a, 1.0), np.where(e_ok, e, 1.0)
    denom = a * e - b * b
    general = denom > 1e-12 * a * e  # not parallel
    s = np.where(general, np.clip((b * f - c * e) / np.where(general, denom, 1.0), 0, 1), 0.0)
    t = np.where(e_ok, (b * s + f) / e_s, 0.0)
    s = np.where(t < 0, np.clip(-c / a_s, 0, 1), np.where(t > 1, np.clip((b - c) / a_s, 0, 1), s))
    t = np.clip(t, 0, 1)
    # degenerate segments: q a point, p a point
    s = np.where(~e_ok, np.clip(-c / a_s, 0, 1), s)
    t = np.where(~e_ok, 0.0, t)
    t = np.where(~a_ok, np.clip(f / e_s, 0, 1) * e_ok, t)
    s = np.where(~a_ok, 0.0, s)
    gap = (p0 + s[..., None] * d1) - (q0 + t[..., None] * d2)
    return np.sqrt(np.einsum("...i,...i->...", gap, gap))


def body_capsules(joints, body_keypoints, radius_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Capsules approximating the body: ``segments (T, 22, 2, 3)`` and ``radii (22,)``.

    One capsule per bone of the 22-joint skeleton (parent → child, :data:`CAPSULE_RADII_M`), then
    the head sphere (a zero-length segment) centred between the ears; names in :data:`CAPSULE_NAMES`.
    """
    joints = np.asarray(joints, dtype=float)
    kp = np.asarray(body_keypoints, dtype=float)
    ears = kp[:, [BODY_KEYPOINT_NAMES.index("left_ear"), BODY_KEYPOINT_NAMES.index("right_ear")]]
    head = ears.mean(axis=1)
    children = np.arange(1, NUM_JOINTS)
    bones = np.stack([joints[:, PARENTS[children]], joints[:, children]], axis=2)
    sphere = np.stack([head, head], axis=1)[:, None]
    segments = np.concatenate([bones, sphere], axis=1)
    radii = np.array([CAPSULE_RADII_M[JOINT_NAMES[c]] for c in children] + [HEAD_SPHERE_RADIUS_M])
    return segments, radii * radius_scale


def occluded_by_capsules(points, camera_centres, segments, radii, clearance_m: float = 0.01) -> np.ndarray:
    """``(T, K)`` bool: the ray camera → point passes through a capsule.

    Args:
        points: ``(T, K, 3)`` world.
        camera_centres: ``(T, 3)`` world.
        segments: ``(T, B, 2, 3)`` capsule axes; radii ``(B,)``.
        clearance_m: each capsule is shrunk per point and frame so that the point lies at least
            this far outside it, so a point is never hidden by the bone it sits on or inside.
    """
    P = np.asarray(points, dtype=float)[:, :, None, :]  # (T, K, 1, 3)
    C = np.asarray(camera_centres, dtype=float)[:, None, None, :]
    A, B = segments[:, None, :, 0], segments[:, None, :, 1]  # (T, 1, B, 3)
    own = segment_distance(P, P, A, B)  # (T, K, B) point to capsule axis
    ray = segment_distance(C, P, A, B)
    r_eff = np.clip(np.minimum(radii, own - clearance_m), 0.0, None)
    return np.any(ray < r_eff, axis=-1)


def self_occluded(points, joints, body_keypoints, camera_centres, *, radius_scale=1.0, clearance_m=0.01) -> np.ndarray:
    """``(T, K)`` bool: ``points (T, K, 3)`` hidden from the cameras by the body itself
    (:func:`body_capsules` of ``joints (T, 22, 3)`` and ``body_keypoints (T, 23, 3)``)."""
    segments, radii = body_capsules(joints, body_keypoints, radius_scale)
    return occluded_by_capsules(points, camera_centres, segments, radii, clearance_m)


# ---------------------------------------------------------------------------------------------
# Simulation


@dataclass
class DetectionInfo:
    """What the simulator did, per frame and point (ground truth for evaluating robustness).

    Attributes:
        pixels: ``(T, K, 2)`` exact projections of the points the detector aims at: the body's
            format points moved by the keypoint-definition offsets and the size bias (NaN for
            unmapped points or behind the camera).
        body_pixels: ``(T, K, 2)`` exact projections of the body model's own format points (what
            a solver that knows the body predicts); ``pixels - body_pixels`` is the effect of the
            definition offsets and the size bias.
        depth: ``(T, K)`` camera z, metres (NaN for unmapped points).
        in_frame: ``(T, K)`` in front of the camera and inside the image (mapped points only).
        occluded: ``(T, K)`` self-occluded.
        guessed: ``(T, K)`` occluded and reported at a guess with a high confidence (not an
            outlier); indexed by the point's own label (before swaps).
        outlier: ``(T, K)`` placed elsewhere; indexed by the point's own label (before swaps),
            whether or not it was then dropped.
        person_detected: ``(T,)`` the person was reported at all.
        swaps: ``(T,)`` int8 code of the left/right swap applied in each frame,
            ``SWAP_KINDS.index(kind)`` (0 = none, 1 = body, 2 = arms, 3 = legs); 0 where the
            person was not detected. ``detections[t][:, swap_permutation(names, SWAP_KINDS[c])]``
            restores the true labels.
        view_angle: ``(T,)`` radians between the body's facing direction and the direction to
            the camera (0 = front, π = behind; :func:`view_angles`).
        person_height_px: ``(T,)`` the noise scale ``h``.
        noise_sigma_px: ``(T, K)`` noise std per axis of each point.
    """

    pixels: np.ndarray
    body_pixels: np.ndarray
    depth: np.ndarray
    in_frame: np.ndarray
    occluded: np.ndarray
    guessed: np.ndarray
    outlier: np.ndarray
    person_detected: np.ndarray
    swaps: np.ndarray
    view_angle: np.ndarray
    person_height_px: np.ndarray
    noise_sigma_px: np.ndarray

    @property
    def body_swapped(self) -> np.ndarray:
        """``(T,)`` the whole body's left/right labels are swapped."""
        return self.swaps == SWAP_KINDS.index("body")

    @property
    def limb_swapped(self) -> np.ndarray:
        """``(T,)`` ``""``, ``"arm"`` or ``"leg"``: the limb whose labels are swapped."""
        return np.select([self.swaps == SWAP_KINDS.index("arms"), self.swaps == SWAP_KINDS.index("legs")], ["arm", "leg"], "")


def body_axes(body_keypoints) -> np.ndarray:
    """``(T, 3, 3)`` orthonormal axes of the torso from ``body_keypoints (T, 23, 3)`` (world):
    columns left (right hip/shoulder → left ones), up (hips → shoulders) and forward (the facing
    direction, left × up), as the body frame's +X, +Y, +Z."""
    kp = np.asarray(body_keypoints, dtype=float)
    idx = {n: BODY_KEYPOINT_NAMES.index(n) for n in ("left_hip", "right_hip", "left_shoulder", "right_shoulder")}
    hips = kp[:, idx["left_hip"]] - kp[:, idx["right_hip"]]
    shoulders = kp[:, idx["left_shoulder"]] - kp[:, idx["right_shoulder"]]
    left = hips / np.linalg.norm(hips, axis=-1, keepdims=True) + shoulders / np.linalg.norm(shoulders, axis=-1, keepdims=True)
    left /= np.linalg.norm(left, axis=-1, keepdims=True)
    up = (kp[:, idx["left_shoulder"]] + kp[:, idx["right_shoulder"]] - kp[:, idx["left_hip"]] - kp[:, idx["right_hip"]]) / 2
    forward = np.cross(left, up)
    forward /= np.linalg.norm(forward, axis=-1, keepdims=True)
    return np.stack([left, np.cross(forward, left), forward], axis=-1)


def _mid_hip(body_keypoints: np.ndarray) -> np.ndarray:
    """``(T, 3)`` midpoint of the body keypoints' hips."""
    return (body_keypoints[:, BODY_KEYPOINT_NAMES.index("left_hip")] + body_keypoints[:, BODY_KEYPOINT_NAMES.index("right_hip")]) / 2


def view_angles(body_keypoints, camera_centres) -> np.ndarray:
    """``(T,)`` radians between the body's facing direction (:func:`body_axes`) and the direction
    from its mid-hip to the camera: 0 = seen from the front, π/2 from the side, π from behind.

    Args:
        body_keypoints: ``(T, 23, 3)`` world.
        camera_centres: ``(T, 3)`` or ``(3,)`` world.
    """
    kp = np.asarray(body_keypoints, dtype=float)
    to_camera = np.asarray(camera_centres, dtype=float) - _mid_hip(kp)
    to_camera /= np.linalg.norm(to_camera, axis=-1, keepdims=True)
    cos = np.einsum("ti,ti->t", body_axes(kp)[..., 2], to_camera)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def view_weights(view_angle) -> np.ndarray:
    """``(..., 3)`` weights (front, side, back) of ``view_angle (...)`` radians, summing to 1:
    ``max(cos θ, 0)²``, ``sin² θ``, ``max(-cos θ, 0)²``."""
    c = np.cos(np.asarray(view_angle, dtype=float))
    return np.stack([np.maximum(c, 0.0) ** 2, 1.0 - c * c, np.maximum(-c, 0.0) ** 2], axis=-1)


def swap_hazards(view_angle, faults: DetectorFaults, leg_fraction: float) -> np.ndarray:
    """``(..., 3)`` onset rates (1/s) of swap runs of the kinds body, arms, legs (codes 1, 2, 3 of
    ``SWAP_KINDS``) at ``view_angle (...)`` radians."""
    w = view_weights(view_angle)
    body = w @ np.asarray(faults.body_swap_rate_hz, dtype=float)
    limb = w @ np.asarray(faults.limb_swap_rate_hz, dtype=float)
    return np.stack([body, (1.0 - leg_fraction) * limb, leg_fraction * limb], axis=-1)


def _swap_runs(times: np.ndarray, hazards: np.ndarray, faults: DetectorFaults, u_onset, u_kind, u_duration) -> np.ndarray:
    """``(T,)`` int8 swap codes of the run chain (:class:`DetectorFaults`) at frame ``times (T,)``
    with onset ``hazards (T, 3)``; one onset, kind and duration number per frame."""
    T = len(times)
    codes = np.zeros(T, dtype=np.int8)
    if T == 0 or not np.any(hazards > 0):
        return codes
    steps = np.diff(times)
    step = float(np.median(steps)) if T > 1 else 1.0 / DEFAULT_FRAME_RATE_HZ
    total = hazards.sum(axis=1)
    p_onset = 1.0 - np.exp(-total * np.concatenate([[step], steps]))
    share = np.cumsum(hazards, axis=1) / np.where(total > 0, total, 1.0)[:, None]
    durations = (faults.body_swap_duration_s, faults.limb_swap_duration_s, faults.limb_swap_duration_s)
    k = 0
    while k < T:
        if u_onset[k] >= p_onset[k]:
            k += 1
            continue
        kind = min(int(np.searchsorted(share[k], u_kind[k], side="right")), 2)
        lo, hi = durations[kind]
        length = lo * (hi / lo) ** u_duration[k]
        # the frames starting within the run's duration less half a frame: round(duration / step) frames
        end = k + max(1, int(np.searchsorted(times[k:] - times[k], length - 0.5 * step, side="left")))
        codes[k:end] = kind + 1
        k = end + 1  # one correct frame at least: consecutive runs never merge into a longer one
    return codes


def _offset_points(points, fmt, rotations, faults: DetectorFaults) -> np.ndarray:
    """``(T, K, 3)`` world offsets of the format's points (:attr:`DetectorFaults.keypoint_offsets_m`)
    given the joints' world-aligned frames ``rotations (T, 22, 3, 3)``."""
    out = np.zeros_like(points)
    for k, name in enumerate(fmt.names):
        part = part_name(name)
        if part not in faults.keypoint_offsets_m:
            continue
        side = next((s for s in ("left", "right") if name.startswith(s + "_") or name.endswith("_" + s)), "")
        if not side and part not in UNSIDED_PARTS:  # e.g. HALPE's mid-hip "hip": not the sided hips' offset
            continue
        lateral, up, forward = faults.keypoint_offsets_m[part]
        local = np.array([-lateral if side == "right" else lateral, up, forward])
        joint = JOINT_NAMES.index(OFFSET_SEGMENTS[part].format(side=side))
        out[:, k] = rotations[:, joint] @ local
    return out


def _frames(value, name: str, T: int, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape == shape:
        arr = np.broadcast_to(arr, (T,) + shape)
    if arr.shape != (T,) + shape:
        raise MocapgraphError(f"{name}: expected shape ({T}, {', '.join(map(str, shape))}), got {arr.shape}")
    return arr


def _pick_other(candidates: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each (t, k), a uniformly chosen other index j != k with ``candidates[t, j]``;
    returns ``(index (T, K), found (T, K))``."""
    K = candidates.shape[1]
    allowed = candidates[:, None, :] & ~np.eye(K, dtype=bool)  # (T, K, K)
    count = allowed.sum(axis=-1)
    rank = np.minimum(np.floor(u * count), np.maximum(count - 1, 0))
    index = np.argmax(np.cumsum(allowed, axis=-1) > rank[..., None], axis=-1)
    return index, count > 0


def _nan_bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis min and max over axis 1 of ``(T, N, 2)`` ignoring NaN; NaN where a frame has none."""
    finite = np.isfinite(points)
    lo = np.where(finite, points, np.inf).min(axis=1)
    hi = np.where(finite, points, -np.inf).max(axis=1)
    none = ~finite.any(axis=1)
    return np.where(none, np.nan, lo), np.where(none, np.nan, hi)


def simulate_detections(
    body, shape, root, pose, world_T_camera, K, distortion, image_size, model: DetectorModel, rng, *,
    ground_z: float = 0.0, timestamps=None,
) -> Detector:  # fmt: skip
    """Simulated detections of a posed body by one camera (see the module docstring).

    Args:
        body: a :class:`~mocapgraph.body.BodyModel`; ``shape`` its shape vector.
        root: ``(T_c, 4, 4)`` world_T_root; ``pose``: ``(T_c, 21, 3)`` local axis-angle.
        world_T_camera: ``(T_c, 4, 4)`` or ``(4, 4)`` for a static camera.
        K: ``(3, 3)``; ``distortion``: OpenCV ``(5,)``; ``image_size``: ``(width, height)``.
        model: the detector's error model (e.g. ``DETECTOR_PRESETS["openpose"]``).
        rng: ``numpy.random.Generator`` (or a seed); the same state gives the same detections.
        ground_z: height of the ground plane, for shadow outliers.
        timestamps: ``(T_c,)`` seconds of the frames, strictly increasing, for the swap runs'
            rates and durations; None = frames at :data:`DEFAULT_FRAME_RATE_HZ`.

    Returns:
        a :class:`~mocapgraph.data_tools.io.capture.Detector` in the model's format: keypoints
        ``(T_c, K, 3)`` x, y, confidence in [0, 1], NaN rows where missing; boxes ``(T_c, 5)``.
    """
    return simulate_detections_with_info(
        body, shape, root, pose, world_T_camera, K, distortion, image_size, model, rng, ground_z=ground_z, timestamps=timestamps
    )[0]


def _frame_times(timestamps, T: int) -> np.ndarray:
    if timestamps is None:
        return np.arange(T) / DEFAULT_FRAME_RATE_HZ
    times = np.asarray(timestamps, dtype=float)
    if times.shape != (T,) or not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise MocapgraphError(f"timestamps: expected {T} finite, strictly increasing seconds, got shape {times.shape}")
    return times


def simulate_detections_with_info(
    body, shape, root, pose, world_T_camera, K, distortion, image_size, model: DetectorModel, rng, *,
    ground_z: float = 0.0, timestamps=None,
) -> tuple[Detector, DetectionInfo]:  # fmt: skip
    """:func:`simulate_detections`, and a :class:`DetectionInfo` of what happened to each point."""
    rng = np.random.default_rng(rng)
    fmt = get_format(model.format)
    faults = model.faults
    root = np.asarray(root, dtype=float)
    if root.ndim != 3 or root.shape[1:] != (4, 4):
        raise MocapgraphError(f"root: expected shape (T, 4, 4), got {root.shape}")
    T, Kp = root.shape[0], fmt.num_points
    pose = _frames(pose, "pose", T, (NUM_JOINTS - 1, 3))
    cams = _frames(world_T_camera, "world_T_camera", T, (4, 4))
    times = _frame_times(timestamps, T)
    K = np.asarray(K, dtype=float)
    width, height = image_size

    # --- every random number, in one fixed order (the faults' last, so that switching them off
    # leaves every other effect's numbers as they were)
    g_noise = rng.standard_normal((T, Kp, 2))
    u_tail = rng.random((T, Kp))
    g_conf = rng.standard_normal((T, Kp))
    u_frame_miss = rng.random(T)
    u_kp_miss = rng.random((T, Kp))
    u_occ_drop = rng.random((T, Kp))
    u_border = rng.random((T, Kp))
    u_outlier = rng.random((T, Kp))
    u_outlier_kind = rng.random((T, Kp))
    u_outlier_box = rng.random((T, Kp, 2))
    u_outlier_other = rng.random((T, Kp))
    u_outlier_conf = rng.random((T, Kp))
    u_body_swap = rng.random(T)
    u_limb_swap = rng.random(T)
    u_limb_choice = rng.random(T)
    g_box = rng.standard_normal((T, 4))
    g_score = rng.standard_normal(T)
    u_run_onset = rng.random(T)
    u_run_kind = rng.random(T)
    u_run_duration = rng.random(T)
    u_guess = rng.random((T, Kp))
    u_guess_conf = rng.random((T, Kp))
    g_guess = rng.standard_normal((T, Kp, 3))

    # --- geometry: the body's format points, and where this detector puts them
    posed = body.forward(shape, root, pose)
    mix = fmt.mix()
    mapped = mix.sum(axis=1) > 0
    X_body = np.einsum("kb,tbi->tki", mix, posed.keypoints)
    pelvis = posed.joints[:, :1]
    X = pelvis + faults.size_bias * (X_body + _offset_points(X_body, fmt, posed.rotations, faults) - pelvis)
    pixels, depth, in_frame = in_frame_mask(X, cams, K, distortion, image_size)
    body_pixels, _ = project_points(X_body, cams, K, distortion)
    in_frame &= mapped
    for arr in (pixels, depth, body_pixels):
        arr[:, ~mapped] = np.nan

    rest = body.forward(shape, np.eye(4)[None], np.zeros((1, NUM_JOINTS - 1, 3))).keypoints[0]
    stature = float(np.ptp(rest[:, 1]))
    _, pelvis_depth = project_points(posed.joints[:, 0], cams, K)
    with np.errstate(divide="ignore"):
        person_h = np.where(pelvis_depth > MIN_DEPTH_M, K[1, 1] * stature / pelvis_depth, 0.0)
    view_angle = view_angles(posed.keypoints, cams[:, :3, 3])

    # Occlusion is decided on the body keypoints; a blended point (OpenPose's neck, mid-hip: inside
    # the body) is occluded only when all the points it blends are.
    body_occluded = self_occluded(
        posed.keypoints, posed.joints, posed.keypoints, cams[:, :3, 3],
        radius_scale=model.occlusion_radius_scale, clearance_m=model.occlusion_clearance_m,
    )  # fmt: skip
    sources = mix > 0
    occluded = np.all(body_occluded[:, None, :] | ~sources, axis=-1) & in_frame

    detected_person = (
        (pelvis_depth > MIN_DEPTH_M)
        & (person_h >= model.min_person_height_px)
        & (in_frame.sum(axis=1) >= model.min_keypoints_in_frame)
        & (u_frame_miss >= model.frame_miss_prob)
    )

    # --- far side guessed: towards the partner point mirrored in the sagittal plane
    guessed = occluded & (u_guess < faults.guess_prob)
    left = posed.rotations[:, None, 0, :, 0]  # (T, 1, 3): the pelvis's left axis, normal of its sagittal plane
    partner = X[:, swap_permutation(fmt.names, "body")]
    mirrored_partner = partner - 2 * np.sum((partner - pelvis) * left, axis=-1, keepdims=True) * left
    w = faults.guess_mirror_weight
    guess = (1 - w) * X + w * mirrored_partner + faults.guess_error_m * g_guess
    guess_px, _ = project_points(guess, cams, K, distortion)
    aimed = np.where(guessed[..., None], guess_px, pixels)

    # --- noise
    hidden = occluded & ~guessed  # a guess is reported as if it were seen
    sigma = np.hypot(model.noise_frac_of_height * person_h, model.noise_floor_px)[:, None] * model.difficulties()
    sigma = np.where(hidden, sigma * model.occluded_noise_mult, sigma)
    rho = model.noise_frame_correlation
    unit = g_noise
    if rho > 0 and T > 1:
        from scipy.signal import lfilter  # scipy.signal takes a second to import: only when needed

        unit = lfilter([math.sqrt(1 - rho * rho)], [1.0, -rho], g_noise, axis=0, zi=((1 - math.sqrt(1 - rho * rho)) * g_noise[:1]))[0]
    if math.isfinite(model.noise_tail_dof):
        nu = model.noise_tail_dof
        unit = unit * np.sqrt((nu - 2) / chi2.ppf(np.clip(u_tail, 1e-300, 1.0), nu))[..., None]
    noise = unit * sigma[..., None]
    det = aimed + noise
    err = np.linalg.norm(noise, axis=-1)

    conf_scale = np.maximum(model.conf_error_frac_of_height * person_h[:, None], 1e-12)
    conf = model.conf_max * np.exp(-0.5 * (err / conf_scale) ** 2) + model.conf_noise_std * g_conf
    conf = np.where(hidden, conf * model.occluded_conf_mult, conf)
    g_lo, g_hi = faults.guess_conf_range
    conf = np.where(guessed, g_lo + (g_hi - g_lo) * u_guess_conf, conf)
    conf = np.clip(conf, 0.0, 1.0)

    # --- outliers
    outlier = in_frame & (u_outlier < model.outlier_prob)
    guessed &= ~outlier
    lo, hi = _nan_bounds(np.where(in_frame[..., None], pixels, np.nan))
    margin = (model.box_margin_frac_of_height * person_h)[:, None]
    box_lo = np.clip(lo - margin, 0, [width, height])
    box_hi = np.clip(hi + margin, 0, [width, height])
    in_box = box_lo[:, None] + u_outlier_box * (box_hi - box_lo)[:, None]

    shadows = X.copy()
    shadows[..., 2] = 2 * ground_z - shadows[..., 2]
    shadow_px, _, shadow_ok = in_frame_mask(shadows, cams, K, distortion, image_size)
    other, other_ok = _pick_other(in_frame, u_outlier_other)
    other_px = np.take_along_axis(pixels, other[..., None], axis=1) + noise
    other_ok &= in_image(other_px, image_size)
    shadow_share = model.outlier_shadow_fraction
    use_shadow = (u_outlier_kind < shadow_share) & shadow_ok
    use_other = (u_outlier_kind >= shadow_share) & (u_outlier_kind < shadow_share + model.outlier_other_point_fraction) & other_ok
    placed = np.where(use_shadow[..., None], shadow_px, np.where(use_other[..., None], other_px, in_box))
    det = np.where(outlier[..., None], placed, det)
    c_lo, c_hi = model.outlier_conf_range
    conf = np.where(outlier, c_lo + (c_hi - c_lo) * u_outlier_conf, conf)

    # --- dropout
    w_h = np.array([width, height], dtype=float)
    near_border = np.any((pixels < model.border_dropout_px) | (pixels >= w_h - model.border_dropout_px), axis=-1)
    reported = (
        in_frame
        & detected_person[:, None]
        & (u_kp_miss >= model.keypoint_miss_prob)
        & ~(hidden & (u_occ_drop < model.occluded_drop_prob))
        & ~(near_border & (u_border < model.border_drop_prob))
        & in_image(det, image_size)
        & (conf > model.conf_threshold)
    )
    rows = np.concatenate([det, conf[..., None]], axis=-1)
    rows[~reported] = np.nan

    # --- swaps: sustained runs, then single-frame flickers where no run is near
    hazards = swap_hazards(view_angle, faults, model.limb_swap_leg_fraction)
    swaps = _swap_runs(times, hazards, faults, u_run_onset, u_run_kind, u_run_duration)
    in_run = np.pad(swaps != 0, 1)
    away_from_runs = ~(in_run[:-2] | in_run[1:-1] | in_run[2:])
    flicker_limb = np.where(u_limb_choice < model.limb_swap_leg_fraction, SWAP_KINDS.index("legs"), SWAP_KINDS.index("arms"))
    flicker = np.where(u_body_swap < model.body_swap_prob, SWAP_KINDS.index("body"), np.where(u_limb_swap < model.limb_swap_prob, flicker_limb, 0))
    swaps = np.where(away_from_runs, flicker, swaps)
    swaps = np.where(detected_person, swaps, 0).astype(np.int8)
    for code in range(1, len(SWAP_KINDS)):
        sel = swaps == code
        rows[sel] = rows[sel][:, swap_permutation(fmt.names, SWAP_KINDS[code])]

    # --- boxes
    everything = np.concatenate([np.where(in_frame[..., None], pixels, np.nan), rows[..., :2]], axis=1)
    lo, hi = _nan_bounds(everything)
    side = np.maximum(0.0, model.box_margin_frac_of_height + model.box_jitter_frac_of_height * g_box) * person_h[:, None]
    boxes = np.empty((T, 5))
    boxes[:, 0:2] = np.clip(lo - side[:, :2], 0, w_h)
    boxes[:, 2:4] = np.clip(hi + side[:, 2:], 0, w_h)
    visible = (in_frame & ~occluded).sum(axis=1) / max(int(mapped.sum()), 1)
    boxes[:, 4] = np.clip(model.box_score_mean + model.box_score_std * g_score, 0, 1) * np.sqrt(visible)
    boxes[~detected_person] = np.nan

    keypoints = fmt.normalise(rows, source=f"simulated detector {model.name!r}")
    info = DetectionInfo(
        pixels=pixels, body_pixels=body_pixels, depth=depth, in_frame=in_frame, occluded=occluded, guessed=guessed,
        outlier=outlier, person_detected=detected_person, swaps=swaps, view_angle=view_angle,
        person_height_px=person_h, noise_sigma_px=sigma,
    )  # fmt: skip
    return Detector(name=model.name, format=fmt.name, keypoints=keypoints, boxes=boxes), info


__all__ = [
    "CAPSULE_NAMES",
    "CAPSULE_RADII_M",
    "DEFAULT_DIFFICULTY",
    "DEFAULT_FRAME_RATE_HZ",
    "DETECTOR_PRESETS",
    "DetectionInfo",
    "DetectorFaults",
    "DetectorModel",
    "FAULT_LEVELS",
    "HEAD_SPHERE_RADIUS_M",
    "HEAVY_FACTOR",
    "KEYPOINT_DEFINITION_OFFSETS_M",
    "LITERATURE_DEFINITION_OFFSETS_M",
    "MIN_DEPTH_M",
    "OFFSET_SEGMENTS",
    "UNSIDED_PARTS",
    "body_axes",
    "body_capsules",
    "occluded_by_capsules",
    "segment_distance",
    "self_occluded",
    "simulate_detections",
    "simulate_detections_with_info",
    "swap_hazards",
    "view_angles",
    "view_weights",
]
