"""Realistic detector faults in the simulator: sustained view-dependent left/right swaps, far-side
guesses, keypoint-definition offsets and a size bias, each asserted against the simulator's own
ground truth; the swap codes' round trip through the capture format."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from mocapgraph.body import load_body_model
from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import SWAP_KINDS, swap_permutation
from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.data_tools.geometry.camera_model import project_points
from mocapgraph.data_tools.io.capture import CaptureError, load_capture, write_capture
from mocapgraph.data_tools.sim.detectors import (
    DETECTOR_PRESETS,
    FAULT_LEVELS,
    HEAVY_FACTOR,
    KEYPOINT_DEFINITION_OFFSETS_M,
    LITERATURE_DEFINITION_OFFSETS_M,
    UNSIDED_PARTS,
    DetectorFaults,
    DetectorModel,
    simulate_detections_with_info,
    swap_hazards,
    view_angles,
)
from mocapgraph.data_tools.sim.scenarios import look_at
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.errors import MocapgraphError

K = np.array([[1000.0, 0.0, 640.0], [0.0, 1000.0, 360.0], [0.0, 0.0, 1.0]])
IMAGE = (1280, 720)
UPRIGHT = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # body +Y up → world +Z; the body faces -Y
BODY = (1, 2, 3)  # swap codes of body, arms, legs
FRONT_CAMERA = (0.0, -5.0, 1.2)


@pytest.fixture(scope="module")
def body():
    return load_body_model()


def person(frames: int, fps: float, turn_rate: float = 0.0, right_arm: float = 1.3):
    """``times, root, pose`` of a person at the origin (pelvis 0.95 m up), the left arm down and
    the right arm ``right_arm`` radians below horizontal (1.3: down too), facing world -Y at
    t = 0 and turning about the vertical at ``turn_rate`` rad/s."""
    t = np.arange(frames) / fps
    root = np.tile(np.eye(4), (frames, 1, 1))
    root[:, :3, :3] = rotvec_to_matrix(np.outer(turn_rate * t, [0.0, 0.0, 1.0])) @ UPRIGHT
    root[:, :3, 3] = [0.0, 0.0, 0.95]
    pose = np.zeros((frames, 21, 3))
    pose[:, 15] = [0.0, 0.0, -1.3]
    pose[:, 16] = [0.0, 0.0, right_arm]
    return t, root, pose


def simulate(body, model, frames=1, fps=30.0, turn_rate=0.0, camera=FRONT_CAMERA, seed=0, right_arm=1.3):
    t, root, pose = person(frames, fps, turn_rate, right_arm)
    cam = look_at(np.asarray(camera, dtype=float), np.array([0.0, 0.0, 0.9]))
    return simulate_detections_with_info(
        body, body.default_shape, root, pose, cam, K, np.zeros(5), IMAGE, model, np.random.default_rng(seed), timestamps=t
    )


def quiet(fmt="blazepose33", **faults) -> DetectorModel:
    """A detector with every effect off except the given faults."""
    return replace(DetectorModel(name="test", format=fmt).without_effects(), faults=DetectorFaults(**faults))


def runs(codes: np.ndarray, code: int) -> tuple[np.ndarray, np.ndarray]:
    """Start frames and lengths (frames) of the runs of ``code`` that end before the last frame."""
    x = np.r_[0, (codes == code).astype(int), 0]
    starts, ends = np.flatnonzero(np.diff(x) == 1), np.flatnonzero(np.diff(x) == -1)
    whole = ends < len(codes)
    return starts[whole], (ends - starts)[whole]


# ---------------------------------------------------------------------------------------------
# Sustained swaps


@pytest.mark.parametrize("fps", [30.0, 60.0])
def test_body_swap_runs_last_0_1_to_1_s_at_their_rate_per_second(body, fps):
    """Constant onset rate 1/s from every side: runs last 0.1-1 s, log-uniformly (median
    sqrt(0.1 · 1) s), and start at 1 per second of correct labels, whatever the frame rate."""
    seconds = 150
    model = quiet(body_swap_rate_hz=(1.0, 1.0, 1.0))
    _, info = simulate(body, model, frames=int(seconds * fps), fps=fps, turn_rate=0.4, seed=int(fps))
    starts, lengths = runs(info.swaps, 1)
    assert set(np.unique(info.swaps)) == {0, 1}
    seconds_each = lengths / fps
    assert len(lengths) > 80
    assert seconds_each.min() >= 0.1 - 1e-9 and seconds_each.max() <= 1.0 + 1e-9
    assert np.median(seconds_each) == pytest.approx(math.sqrt(0.1), rel=0.25)
    correct_s = np.sum(info.swaps == 0) / fps
    assert len(starts) / correct_s == pytest.approx(1.0, rel=0.25)
    # a run's duration is log-uniform: a quarter of the log-range each quarter
    quartiles = np.histogram(np.log10(seconds_each), bins=[-1, -0.75, -0.5, -0.25, 0.0 + 1e-9])[0] / len(lengths)
    assert np.all(np.abs(quartiles - 0.25) < 0.12), quartiles


def test_limb_swap_runs_are_a_few_frames_and_mostly_legs(body):
    fps = 30.0
    model = replace(quiet(limb_swap_rate_hz=(2.0, 2.0, 2.0), limb_swap_duration_s=(0.05, 0.3)), limb_swap_leg_fraction=0.8)
    _, info = simulate(body, model, frames=int(120 * fps), fps=fps, turn_rate=0.4, seed=3)
    _, legs = runs(info.swaps, SWAP_KINDS.index("legs"))
    _, arms = runs(info.swaps, SWAP_KINDS.index("arms"))
    assert not np.any(info.swaps == SWAP_KINDS.index("body"))
    assert len(legs) / (len(legs) + len(arms)) == pytest.approx(0.8, abs=0.08)
    lengths = np.concatenate([legs, arms])
    assert lengths.min() >= 2 and lengths.max() <= 9  # 0.05-0.3 s at 30 fps


def test_swaps_start_more_often_from_behind_and_the_side(body):
    """A person turning in front of a static camera: the onset rate per second of correct labels
    in each viewing sector matches the model's hazard there, and from behind it is many times the
    rate from the front."""
    fps = 30.0
    model = replace(DETECTOR_PRESETS["mediapipe"], frame_miss_prob=0.0)
    _, info = simulate(body, model, frames=int(300 * fps), fps=fps, turn_rate=0.3, seed=4)
    assert np.ptp(info.view_angle) > 0.95 * math.pi  # every view from front to back
    onset = np.r_[info.swaps[0] == 1, (info.swaps[1:] == 1) & (info.swaps[:-1] != 1)]
    correct = info.swaps == 0
    cos = np.cos(info.view_angle)
    hazard = swap_hazards(info.view_angle, model.faults, model.limb_swap_leg_fraction)[:, 0]
    rates = {}
    for sector, sel in (("front", cos > 0.7), ("side", np.abs(cos) < 0.3), ("back", cos < -0.7)):
        exposure = sel & (correct | onset)
        rates[sector] = (onset[sel].sum(), exposure.sum() / fps, hazard[exposure].mean())
    count, seconds, expected = rates["back"]
    assert count / seconds == pytest.approx(expected, rel=0.3)
    count, seconds, expected = rates["side"]
    assert count / seconds == pytest.approx(expected, rel=0.4)
    front_count, front_s, _ = rates["front"]
    assert (rates["back"][0] / rates["back"][1]) > 8 * (front_count + 1) / front_s
    assert (rates["side"][0] / rates["side"][1]) > 3 * (front_count + 1) / front_s
    # and the swapped share of frames follows
    swapped = info.swaps == 1
    assert swapped[cos < -0.7].mean() > 5 * swapped[cos > 0.7].mean() + 0.05


def test_view_angle_is_zero_from_the_front_and_pi_from_behind(body):
    _, root, pose = person(1, 30.0)
    kp = body.forward(body.default_shape, root, pose).keypoints
    cams = np.array([[0.0, -5.0, 0.9], [5.0, 0.0, 0.9], [0.0, 5.0, 0.9]])
    angles = [view_angles(kp, c[None])[0] for c in cams]
    assert angles[0] < 0.05 and abs(angles[1] - math.pi / 2) < 0.05 and angles[2] > math.pi - 0.05


def test_recorded_codes_undo_the_swaps_exactly(body):
    """The same seed without swaps draws every other number alike: undoing the recorded swaps
    with swap_permutation gives that run's detections, NaN for NaN."""
    fps = 60.0
    model = replace(DETECTOR_PRESETS["openpose"], limb_swap_prob=0.02, body_swap_prob=0.01)
    swapped_det, info = simulate(body, model, frames=1200, fps=fps, turn_rate=0.5, camera=(2.0, -4.0, 1.5), seed=5)
    plain = replace(model, body_swap_prob=0.0, limb_swap_prob=0.0, faults=replace(model.faults, body_swap_rate_hz=(0, 0, 0), limb_swap_rate_hz=(0, 0, 0)))
    plain_det, plain_info = simulate(body, plain, frames=1200, fps=fps, turn_rate=0.5, camera=(2.0, -4.0, 1.5), seed=5)
    assert not plain_info.swaps.any()
    names = get_format(model.format).names
    counts = {code: int(np.sum(info.swaps == code)) for code in BODY}
    assert all(n > 10 for n in counts.values()), counts
    undone = swapped_det.keypoints.copy()
    for code in BODY:
        sel = info.swaps == code
        undone[sel] = undone[sel][:, swap_permutation(names, SWAP_KINDS[code])]
    assert np.array_equal(undone, plain_det.keypoints, equal_nan=True)
    assert not np.array_equal(swapped_det.keypoints, plain_det.keypoints, equal_nan=True)
    # no codes where nobody was detected
    assert not np.any(info.swaps[~info.person_detected])


# ---------------------------------------------------------------------------------------------
# Far-side guesses


def test_occluded_points_are_guessed_towards_the_mirrored_partner_with_high_confidence(body):
    """Seen from the left, the right side is hidden: every hidden point is reported halfway
    between itself and its partner mirrored in the pelvis's sagittal plane (here x = 0),
    confidently, never dropped."""
    model = replace(
        quiet("coco17", guess_prob=1.0, guess_mirror_weight=0.5, guess_conf_range=(0.8, 0.9)),
        occluded_drop_prob=1.0, occluded_conf_mult=0.1,
    )  # fmt: skip
    det, info = simulate(body, model, frames=3, camera=(4.0, 0.0, 1.2), right_arm=0.3)
    names = get_format("coco17").names
    hidden = info.occluded
    assert hidden[:, names.index("right_knee")].all() and np.array_equal(info.guessed, hidden)
    # independent computation: the plane x = 0 is the standing body's sagittal plane
    _, root, pose = person(3, 30.0, right_arm=0.3)
    X = body.forward(body.default_shape, root, pose, keypoints="coco17").keypoints
    mirrored = X[:, swap_permutation(names, "body")] * [-1.0, 1.0, 1.0]
    cam = look_at(np.array([4.0, 0.0, 1.2]), np.array([0.0, 0.0, 0.9]))
    expected, _ = project_points(0.5 * (X + mirrored), cam, K)
    assert np.abs(det.keypoints[hidden][:, :2] - expected[hidden]).max() < 1e-6
    conf = det.keypoints[..., 2][hidden]
    assert conf.min() >= 0.8 and conf.max() <= 0.9
    # the hidden right wrist, held out, is guessed halfway down towards the left one
    off = np.linalg.norm(det.keypoints[..., :2] - info.pixels, axis=-1)
    assert off[:, names.index("right_wrist")].min() > 20.0


def test_guess_probability_and_error(body):
    model = replace(quiet("coco17", guess_prob=0.5, guess_error_m=0.05), occluded_drop_prob=1.0)
    det, info = simulate(body, model, frames=400, camera=(4.0, 0.0, 1.2), seed=6)
    hidden = info.occluded
    assert info.guessed[hidden].mean() == pytest.approx(0.5, abs=0.04)
    assert not info.guessed[~hidden].any()
    reported = np.isfinite(det.keypoints[..., 0])
    assert np.array_equal(reported[hidden], info.guessed[hidden])  # the others were dropped
    # 5 cm per axis at ~4 m with f = 1000: ~12 px per image axis, minus the part along the ray
    err = (det.keypoints[..., :2] - info.pixels)[info.guessed]
    assert 8.0 < np.std(err) < 14.0


# ---------------------------------------------------------------------------------------------
# Keypoint definitions and size


def test_definition_offsets_are_a_few_pixels_at_5_m_and_change_with_the_view(body):
    offsets = LITERATURE_DEFINITION_OFFSETS_M["blazepose33"]  # heavy's: the largest of the tables
    model = quiet(keypoint_offsets_m=offsets)
    names = get_format("blazepose33").names
    hip = names.index("left_hip")
    sizes = {}
    for view, camera in (("front", (0.0, -5.0, 0.95)), ("side", (5.0, 0.0, 0.95))):
        _, info = simulate(body, model, camera=camera)
        shift = info.pixels - info.body_pixels
        # independent: the standing pelvis frame is UPRIGHT, so (lateral, up, forward) of the left
        # hip is world (+lateral, -forward, up)
        lateral, up, forward = offsets["hip"]
        _, root, pose = person(1, 30.0)
        X = body.forward(body.default_shape, root, pose, keypoints="blazepose33").keypoints[0, hip]
        cam = look_at(np.asarray(camera), np.array([0.0, 0.0, 0.9]))
        expected = project_points(X + [lateral, -forward, up], cam, K)[0] - project_points(X, cam, K)[0]
        assert np.allclose(shift[0, hip], expected, atol=1e-9)
        sizes[view] = np.linalg.norm(shift[0], axis=-1)
    moved = np.isfinite(sizes["front"]) & (sizes["front"] > 0)
    assert set(np.array(names)[moved]) == {f"{s}_{p}" for s in ("left", "right") for p in ("shoulder", "hip", "knee", "ankle")}
    largest = np.maximum(sizes["front"], sizes["side"])[moved]
    assert np.all((largest > 1.5) & (largest < 8.0))  # a few px at 5 m (f = 1000) in one view at least
    # the hip: 22 mm lateral and 15 mm down seen from the front, 7 mm forward and 15 mm down from the side
    assert sizes["front"][hip] == pytest.approx(1000 * math.hypot(0.022, 0.015) / 5.0, rel=0.1)
    assert sizes["side"][hip] == pytest.approx(1000 * math.hypot(0.007, 0.015) / 5.0, rel=0.1)
    assert np.abs(sizes["front"][moved] - sizes["side"][moved]).max() > 1.5


def triangulate(pixels: np.ndarray, cameras: list[np.ndarray]) -> np.ndarray:
    """``(T, K, 3)`` world points from their exact pinhole projections ``pixels (C, T, K, 2)`` in
    ``cameras`` (``world_T_camera``, intrinsics :data:`K`): the linear multi-view triangulation
    (NaN pixels give meaningless points)."""
    P = [K @ np.linalg.inv(cam)[:3] for cam in cameras]
    A = np.stack([pixels[c][..., i, None] * P[c][2] - P[c][i] for c in range(len(P)) for i in (0, 1)], axis=-2)  # (T, K, 2C, 4)
    X = np.linalg.svd(np.nan_to_num(A))[2][..., -1, :]
    return X[..., :3] / X[..., 3:]


@pytest.mark.parametrize(
    ("preset", "source", "renamed"),
    [
        ("coco_hrnet", "openpose25b", {}),  # rich's detector: BODY_25B's fit (COCO's annotations)
        ("openpose", "openpose25b", {}),
        ("mediapipe", "openpose25b", {"foot_index": "big_toe"}),  # phones': crosswise, not BlazePose's own fit
    ],
)
def test_realistic_definitions_measured_from_the_renders_are_a_real_detectors_fit(body, preset, source, renamed):
    """The offsets a preset's detector renders under ``realistic`` faults, measured back: its points
    triangulated from four exact views of a moving, turning person, minus the body's own points,
    in the frame of the joint that carries each point in SmartMocap's offset estimate
    (:func:`carrier_joints`), are the fit of a real detector (``source``) in
    :data:`FITTED_OFFSETS_M`, constant over the frames; and never the fit SmartMocap's prior uses
    for the detector's own format. The collars and toes do not move: there the simulator's carrying
    segment (clavicle, hindfoot) is not the estimate's (chest, forefoot)."""
    from mocapgraph.body.definition_priors import FITTED_OFFSETS_M, prior_offsets
    from mocapgraph.body.keypoint_offsets import MIRROR, carrier_joints
    from mocapgraph.body.labelling import part_name

    model = DETECTOR_PRESETS[preset]
    faults = DetectorFaults(keypoint_offsets_m=model.faults.keypoint_offsets_m)  # the offsets alone: no size bias
    detector = replace(model.without_effects(), faults=faults)
    frames = 12
    _, root, pose = person(frames, 30.0, turn_rate=2.0)
    rng = np.random.default_rng(4)
    pose += rng.uniform(-0.4, 0.4, size=pose.shape)
    pose[:, [9, 10, 12, 13]] = 0.0  # feet and collars (joints 10, 11, 13, 14)
    cameras = [look_at(np.array([5 * math.cos(a), 5 * math.sin(a), 1.2]), np.array([0.0, 0.0, 0.9])) for a in (0.3, 1.9, 3.4, 5.0)]
    t = np.arange(frames) / 30.0
    pixels = np.stack([
        simulate_detections_with_info(body, body.default_shape, root, pose, cam, K, np.zeros(5), IMAGE, detector, 0, timestamps=t)[1].pixels
        for cam in cameras
    ])  # fmt: skip
    posed = body.forward(body.default_shape, root, pose, keypoints=model.format)
    names = get_format(model.format).names
    carriers = carrier_joints(body.table(body.default_shape, keypoints=model.format))
    shift = triangulate(pixels, cameras) - posed.keypoints
    local = np.einsum("tkji,tkj->tki", posed.rotations[:, carriers], shift)  # into each carrier's frame

    fitted = FITTED_OFFSETS_M[source]
    expected = np.zeros((len(names), 3))
    for k, name in enumerate(names):
        part = part_name(name)
        left = name.replace("right_", "left_").replace(part, renamed.get(part, part))
        if left in fitted:
            expected[k] = MIRROR * np.asarray(fitted[left]) if name.startswith("right_") else fitted[left]
    seen = np.all(np.isfinite(pixels), axis=(0, 1, 3))
    assert np.count_nonzero(np.any(expected != 0, axis=1) & seen) >= 12
    np.testing.assert_allclose(local[:, seen], np.broadcast_to(expected[seen], local[:, seen].shape), atol=1e-6)
    # the world shift turns with the body: the same offset, not the same displacement
    assert np.ptp(shift[:, names.index("left_hip")], axis=0).max() > 0.005
    prior = prior_offsets(model.format)
    if prior is not None:  # a synthetic test of that prior must not find its own mean in the simulator
        both = np.any(prior != 0, axis=1) & np.any(expected != 0, axis=1)
        assert np.median(np.linalg.norm(prior[both] - expected[both], axis=1)) > 0.005


def test_size_bias_scales_the_box(body):
    heights = {}
    for bias in (1.0, 1.03, 0.97):
        model = replace(quiet(size_bias=bias), box_margin_frac_of_height=0.0)
        det, _ = simulate(body, model, frames=2, camera=(1.0, -5.0, 1.0))
        heights[bias] = (det.boxes[0, 3] - det.boxes[0, 1], det.boxes[0, 2] - det.boxes[0, 0])
    for bias in (1.03, 0.97):
        for axis in range(2):
            assert heights[bias][axis] / heights[1.0][axis] == pytest.approx(bias, abs=0.003)


# ---------------------------------------------------------------------------------------------
# Levels and validation


def test_fault_levels():
    for name, model in DETECTOR_PRESETS.items():
        assert model.at_fault_level("realistic") == model
        assert max(model.faults.body_swap_rate_hz) > 0 and model.faults.keypoint_offsets_m and model.faults.size_bias != 1.0, name
        none = model.at_fault_level("none")
        assert none.faults == DetectorFaults() and none.body_swap_prob == 0 and none.limb_swap_prob == 0
        assert none.noise_frac_of_height == model.noise_frac_of_height and none.outlier_prob == model.outlier_prob
        heavy = model.at_fault_level("heavy")
        assert np.allclose(heavy.faults.body_swap_rate_hz, HEAVY_FACTOR * np.asarray(model.faults.body_swap_rate_hz))
        assert heavy.faults.size_bias - 1 == pytest.approx(HEAVY_FACTOR * (model.faults.size_bias - 1))
        # the literature's definitions where it gives one (hips, knees, ankles, shoulders), twice the real fit's elsewhere
        literature = model.faults.heavy_keypoint_offsets_m
        assert set(literature) == {"hip", "knee", "ankle", "shoulder"}, name
        assert set(heavy.faults.keypoint_offsets_m) == set(model.faults.keypoint_offsets_m) | set(literature)
        for part, offset in heavy.faults.keypoint_offsets_m.items():
            expected = literature[part] if part in literature else HEAVY_FACTOR * np.asarray(model.faults.keypoint_offsets_m[part])
            np.testing.assert_allclose(offset, expected, err_msg=f"{name} {part}")
        # the literature's hips are a few times the real fit's
        assert np.linalg.norm(literature["hip"]) > 2.5 * np.linalg.norm(model.faults.keypoint_offsets_m["hip"]), name
        assert heavy.faults.guess_prob == pytest.approx(min(1.0, HEAVY_FACTOR * model.faults.guess_prob))
    assert FAULT_LEVELS == ("none", "realistic", "heavy")
    with pytest.raises(MocapgraphError, match="unknown detector fault level 'wild'"):
        DETECTOR_PRESETS["openpose"].at_fault_level("wild")


def test_invalid_faults_are_errors():
    with pytest.raises(MocapgraphError, match="body_swap_rate_hz must be 3 finite numbers >= 0"):
        DetectorFaults(body_swap_rate_hz=(1.0, -1.0, 0.0))
    with pytest.raises(MocapgraphError, match="body_swap_duration_s must be"):
        DetectorFaults(body_swap_duration_s=(1.0, 0.1))
    with pytest.raises(MocapgraphError, match="guess_prob must lie in"):
        DetectorFaults(guess_prob=1.5)
    with pytest.raises(MocapgraphError, match="unknown body part 'spleen'"):
        DetectorFaults(keypoint_offsets_m={"spleen": (0.0, 0.0, 0.0)})
    with pytest.raises(MocapgraphError, match="no lateral offset"):
        DetectorFaults(keypoint_offsets_m={"nose": (0.01, 0.0, 0.0)})
    with pytest.raises(MocapgraphError, match="size_bias must lie"):
        DetectorFaults(size_bias=3.0)
    with pytest.raises(MocapgraphError, match="timestamps: expected 3 finite, strictly increasing"):
        simulate_detections_with_info(
            load_body_model(), load_body_model().default_shape, person(3, 30.0)[1], person(3, 30.0)[2],
            look_at(np.array(FRONT_CAMERA), np.zeros(3)), K, np.zeros(5), IMAGE, quiet(), 0, timestamps=[0.0, 0.0, 0.1],
        )  # fmt: skip


# ---------------------------------------------------------------------------------------------
# Synthetic captures: on by default, the truth in the capture


@pytest.fixture(scope="module")
def turning():
    """A turning subject in the room with 8 cameras, 6 s, at each fault level."""
    return {level: synthesize("rich", seed=7, duration_s=6.0, motion="turn", detector_faults=level) for level in FAULT_LEVELS}


def swapped_fraction(capture) -> float:
    codes = np.concatenate([c for by_det in capture.ground_truth.swaps.values() for c in by_det.values()])
    return float(np.mean(codes != 0))


def test_faults_are_on_by_default_and_none_has_no_swaps(turning):
    none, realistic, heavy = (turning[level] for level in FAULT_LEVELS)
    assert realistic.metadata["detector_faults"] == "realistic"
    assert set(realistic.ground_truth.swaps) == {cam.name for cam in realistic.cameras}
    assert swapped_fraction(none) == 0.0
    assert 0.03 < swapped_fraction(realistic) < 0.2
    assert swapped_fraction(heavy) > 1.4 * swapped_fraction(realistic)
    # same seed: without faults only the swaps, guesses, offsets and size differ
    default = synthesize("rich", seed=7, duration_s=6.0, motion="turn")
    for a, b in zip(default.cameras, realistic.cameras):
        assert np.array_equal(a.detectors["coco_hrnet"].keypoints, b.detectors["coco_hrnet"].keypoints, equal_nan=True)


def test_swaps_in_a_capture_follow_the_view(turning, body):
    """From the capture's own ground truth: frames seen from behind swap far more often than
    frames seen from the front."""
    capture = turning["heavy"]
    gt = capture.ground_truth
    front, back = [], []
    for cam in capture.cameras:
        idx = np.searchsorted(gt.timestamps, cam.timestamps)
        kp = body.forward(gt.shape, gt.root[idx], gt.pose[idx]).keypoints
        cos = np.cos(view_angles(kp, gt.cameras[cam.name][:, :3, 3]))
        codes = gt.swaps[cam.name]["coco_hrnet"]
        front.append(codes[cos > 0.5] == 1)
        back.append(codes[cos < -0.5] == 1)
    front, back = np.concatenate(front), np.concatenate(back)
    assert len(front) > 300 and len(back) > 300
    assert back.mean() > 4 * front.mean() + 0.03


def test_swap_truth_round_trips_through_the_capture_format(turning, tmp_path):
    capture = turning["realistic"]
    loaded = load_capture(write_capture(capture, tmp_path / "cap"))
    for cam in capture.cameras:
        for det, codes in capture.ground_truth.swaps[cam.name].items():
            got = loaded.ground_truth.swaps[cam.name][det]
            assert got.dtype == np.int8 and np.array_equal(got, codes)
    # captures without swap truth (written before it existed) still load, and save as they were
    capture.ground_truth.swaps = {}
    older = load_capture(write_capture(capture, tmp_path / "old"))
    assert older.ground_truth.swaps == {}
    assert not (tmp_path / "old" / "ground_truth" / "swaps.npz").exists()


def test_bad_swap_truth_is_one_clear_error(turning, tmp_path):
    capture = turning["none"]
    cam = capture.cameras[0].name
    path = write_capture(capture, tmp_path / "cap")
    np.savez(path / "ground_truth" / "swaps.npz", **{f"{cam}.coco_hrnet": np.full(capture.cameras[0].num_frames, 7)})
    with pytest.raises(CaptureError, match=r"ground_truth/swaps.npz.*swap codes must lie in 0..3"):
        load_capture(path)
    np.savez(path / "ground_truth" / "swaps.npz", **{f"{cam}.openpose": np.zeros(capture.cameras[0].num_frames, np.int8)})
    with pytest.raises(CaptureError, match="unknown camera detectors"):
        load_capture(path)


def test_keypoint_definitions_reach_the_body_points_of_every_format():
    """Every table entry names parts the format has, on both sides or on the midline."""
    for tables in (KEYPOINT_DEFINITION_OFFSETS_M, LITERATURE_DEFINITION_OFFSETS_M):
        for fmt, table in tables.items():
            names = get_format(fmt).names
            for part in table:
                if part in UNSIDED_PARTS:
                    assert part in names and table[part][0] == 0, (fmt, part)
                else:
                    assert f"left_{part}" in names and f"right_{part}" in names, (fmt, part)
