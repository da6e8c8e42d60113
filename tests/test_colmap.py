"""The rendered video, the COLMAP reference and scoring against it (``eval --reference``)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.data_tools.evaluation.alignment import Similarity
from mocapgraph.data_tools.evaluation.reference_eval import compare_tracks
from mocapgraph.data_tools.geometry.camera_model import project_points
from mocapgraph.data_tools.io.capture import load_capture, write_capture
from mocapgraph.data_tools.sim.render import Box, Scene, camera_rays, render_frame
from mocapgraph.data_tools.sim.scenarios import look_at
from mocapgraph.data_tools.sim.synthetic import synthesize


def _orbit(frames: int, radius: float, height: float, phase: float) -> np.ndarray:
    """``(frames, 4, 4)`` a camera circling the origin while looking at it."""
    angle = phase + np.linspace(0.0, 1.2, frames)
    return np.stack([look_at([radius * np.cos(a), radius * np.sin(a), height + 0.2 * np.sin(3 * a)], [0.0, 0.0, 1.0]) for a in angle])


def test_compare_tracks_undoes_a_hand_made_similarity():
    frames = 20
    truth = {
        "walk1": _orbit(frames, 4.0, 1.5, 0.0),
        "walk2": _orbit(frames, 5.0, 1.2, 2.0),
        "tripod1": np.repeat(look_at([6.0, 1.0, 1.4], [0.0, 0.0, 1.0])[None], frames, axis=0),
        "tripod2": np.repeat(look_at([-1.0, -6.0, 2.0], [0.0, 0.0, 1.0])[None], frames, axis=0),
    }
    moving = {"walk1": True, "walk2": True, "tripod1": False, "tripod2": False}
    # A COLMAP-like world: rotated, shifted, 0.37 times the size; one frame of walk2 not registered.
    colmap_world_T_true = Similarity(0.37, rotvec_to_matrix(np.array([0.3, -1.1, 0.5])), np.array([2.0, -1.0, 0.4]))
    inverse = Similarity(1 / 0.37, colmap_world_T_true.R.T, -colmap_world_T_true.R.T @ colmap_world_T_true.t / 0.37)
    reference = {n: colmap_world_T_true.apply_pose(p) for n, p in truth.items()}
    reference["walk2"][7] = np.nan
    np.testing.assert_allclose(inverse.apply_pose(reference["walk1"]), truth["walk1"], atol=1e-12)

    scores = compare_tracks(reference, truth, moving)
    for name, s in scores.items():
        assert s.mcpe_m < 1e-9 and s.mcoe_deg < 1e-6, (name, s)
        assert s.alignment == ("procrustes" if moving[name] else "similarity over 4 cameras")
    assert scores["walk2"].frames == frames - 1

    # A tripod 5 cm off in the truth's units: one similarity over four cameras cannot absorb it
    # (it spreads part of it over the others), and the error is in metres, not COLMAP's units.
    off = truth["tripod1"].copy()
    off[:, 2, 3] += 0.05
    shifted = dict(reference, tripod1=colmap_world_T_true.apply_pose(off))
    scores = compare_tracks(shifted, truth, moving)
    assert 0.01 < scores["tripod1"].mcpe_m < 0.05
    assert scores["walk1"].mcpe_m < 1e-9


def test_static_cameras_without_enough_cameras_are_reported_not_evaluable():
    frames = 10
    truth = {"walk": _orbit(frames, 4.0, 1.5, 0.0), "tripod": np.repeat(look_at([6.0, 1.0, 1.4], [0.0, 0.0, 1.0])[None], frames, axis=0)}
    scores = compare_tracks(truth, truth, {"walk": True, "tripod": False})
    assert scores["walk"].mcpe_m < 1e-9
    assert np.isnan(scores["tripod"].mcpe_m) and scores["tripod"].alignment.startswith("not evaluable: static")


def test_render_frame_is_deterministic_and_draws_the_box_where_it_projects():
    K = np.array([[200.0, 0.0, 159.5], [0.0, 200.0, 119.5], [0.0, 0.0, 1.0]])
    distortion = np.array([0.05, -0.015, 0.0, 0.0, 0.0])
    size = (320, 240)
    pose = look_at(np.array([0.0, -6.0, 1.5]), np.array([0.0, 0.0, 1.0]))
    box = Box(np.array([-0.5, -0.5, 0.0]), np.array([0.5, 0.5, 2.0]), np.array([0.0, 0.0, 255.0]), seed=3)
    scene = Scene((box,), np.array([0.0, 255.0, 0.0]), seed=1)
    rays = camera_rays(K, distortion, size)
    image = render_frame(scene, rays, pose, K, distortion, size)
    np.testing.assert_array_equal(image, render_frame(scene, rays, pose, K, distortion, size))
    # The box's front-face centre projects (with the distortion) onto a red pixel, the ground
    # in front of it onto a green one, and the top of the image is sky.
    for point, channel in (([0.0, -0.5, 1.0], 2), ([0.0, -2.5, 0.0], 1)):
        u, v = np.round(project_points(np.array(point), pose, K, distortion)[0]).astype(int)
        bgr = image[v, u].astype(int)
        assert bgr[channel] > 20 and bgr[channel] == bgr.max() and np.sum(bgr) == bgr[channel], (point, bgr)
    assert np.all(image[0] == image[0, 0]) and image[0, 0, 0] > 200


pycolmap = pytest.importorskip("pycolmap")


def test_a_blank_video_gives_a_clear_error(tmp_path):
    from mocapgraph.data_tools.evaluation.colmap_reference import ColmapOptions, ReferenceError, reconstruct

    capture = synthesize("phones", seed=0, duration_s=0.6, image_scale=0.2)

    def blank_videos(root):
        for cam in capture.cameras:
            cam.video = f"cameras/{cam.name}/video.mp4"
            (root / cam.video).parent.mkdir(parents=True, exist_ok=True)
            writer = cv2.VideoWriter(str(root / cam.video), cv2.VideoWriter_fourcc(*"mp4v"), cam.frame_rate, cam.image_size)
            for _ in range(cam.num_frames):
                writer.write(np.full((cam.image_size[1], cam.image_size[0], 3), 40, np.uint8))
            writer.release()

    write_capture(capture, tmp_path / "blank", extra_files=blank_videos)
    with pytest.raises(ReferenceError, match="no SIFT features .* phone_static1, phone_static2"):
        reconstruct(load_capture(tmp_path / "blank"), ["phone_static1", "phone_static2"], ColmapOptions(frame_step=6))


def _rendered(tmp_path, preset: str, seed: int, duration_s: float, image_scale: float, cameras: tuple[str, ...]):
    """A rendered synthetic capture of only ``cameras``, loaded back."""
    from mocapgraph.data_tools.sim.render import render_capture_videos

    capture = synthesize(preset, seed=seed, duration_s=duration_s, image_scale=image_scale)
    capture.cameras = [c for c in capture.cameras if c.name in cameras]
    gt = capture.ground_truth
    gt.cameras = {n: p for n, p in gt.cameras.items() if n in cameras}
    gt.swaps = {n: s for n, s in gt.swaps.items() if n in cameras}
    return load_capture(write_capture(capture, tmp_path / preset, extra_files=lambda root: render_capture_videos(capture, root)))


def _registered_and_accurate(capture, reference, max_cm: float, max_deg: float):
    moving = {c.name: c.moving for c in capture.cameras}
    assert reference.stats["registration_rate"] >= 0.9, reference.failures
    scores = compare_tracks(reference.cameras, capture.ground_truth.cameras, moving, reference.groups())
    for name, s in scores.items():
        if s.moving:
            assert s.frames >= 0.9 * reference.stats["cameras"][name]["sampled"]
            assert s.mcpe_m < max_cm / 100 and s.mcoe_deg < max_deg, (name, s)
    return scores


@pytest.mark.slow  # 25-35 s: rendering, SIFT and mapping; the reference format, the alignment and the errors have fast tests
def test_a_walking_phone_registers_and_its_track_matches_the_truth(tmp_path):
    """Tiny (~25 s): one walking phone, 1 s at 576x324 (its portrait 324x576), every 2nd frame."""
    from mocapgraph.data_tools.evaluation.colmap_reference import ColmapOptions, load_reference, reconstruct, write_reference

    capture = _rendered(tmp_path, "phones", 3, 1.0, 0.3, ("phone_walk1",))
    reference = reconstruct(capture, options=ColmapOptions(frame_step=2))
    # COLMAP's track of a 30 cm walk, after Procrustes: within 1 cm and 1° of the truth
    # (measured: 0.3 cm, 0.4°; every 3rd frame only, 1.3 cm and 1.5°).
    _registered_and_accurate(capture, reference, 1.0, 1.0)
    write_reference(reference, capture.path)
    again = load_reference(capture.path, "colmap")
    np.testing.assert_allclose(again.cameras["phone_walk1"], reference.cameras["phone_walk1"], atol=1e-9)
    assert again.stats["cameras"]["phone_walk1"]["registered"] == reference.stats["cameras"]["phone_walk1"]["registered"]


@pytest.mark.slow
def test_a_tripod_and_a_walking_phone_register_together(tmp_path):
    """2 s of phones at 960x540, every 3rd frame: the static phone and the walking one in one model."""
    from mocapgraph.data_tools.evaluation.colmap_reference import ColmapOptions, reconstruct

    capture = _rendered(tmp_path, "phones", 1, 2.0, 0.5, ("phone_static2", "phone_walk1"))
    reference = reconstruct(capture, options=ColmapOptions(frame_step=3))
    assert reference.groups() == {"phone_static2": 0, "phone_walk1": 0}
    _registered_and_accurate(capture, reference, 1.0, 1.0)


def test_eval_reference_cli_scores_against_a_hand_made_reference(tmp_path, capsys):
    """A reference that is the truth in another world (rotated, shifted, scaled 0.37): its own
    error is nil, and the result scores the same against it as against the truth."""
    import json

    from mocapgraph.cli.main import main
    from mocapgraph.data_tools.evaluation.colmap_reference import ColmapReference, write_reference

    assert main(["synth", "rich", "--duration", "1", "--seed", "2", "--out", str(tmp_path / "cap")]) == 0
    assert main(["run", "baseline", str(tmp_path / "cap"), "--out", str(tmp_path / "res")]) == 0
    capture = load_capture(tmp_path / "cap")
    world = Similarity(0.37, rotvec_to_matrix(np.array([0.3, -1.1, 0.5])), np.array([2.0, -1.0, 0.4]))
    cameras = {n: world.apply_pose(p) for n, p in capture.ground_truth.cameras.items()}
    sampled = {n: np.ones(len(p), bool) for n, p in cameras.items()}
    stats = {"registration_rate": 1.0, "mean_reprojection_error_px": 0.0, "cameras": {n: {"model": 0} for n in cameras}}
    write_reference(ColmapReference("colmap", cameras, sampled, np.zeros((0, 3)), np.zeros(0), np.zeros(0), stats), capture.path)
    capsys.readouterr()
    assert main(["eval", str(tmp_path / "res"), "--reference", "colmap", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    static = [c.name for c in capture.cameras if not c.moving]
    for name in static:
        assert report[f"reference_vs_truth.mcpe_m.{name}"] < 1e-9
        assert report[f"reference_vs_truth.alignment.{name}"] == f"similarity over {len(cameras)} cameras"
        # Against the reference the baseline's calibrated cameras keep their calibration error,
        # in metres (the reference is mapped onto the result), as against the truth.
        assert report[f"result_vs_reference.mcpe_m.{name}"] == pytest.approx(report[f"result_vs_truth.mcpe_m.{name}"], rel=0.25, abs=0.005)
    assert main(["eval", str(tmp_path / "res"), "--reference", "nothing"]) == 2
    assert "has no reference 'nothing' (it has: colmap" in capsys.readouterr().err
