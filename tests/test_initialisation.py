"""Initial values of uncalibrated rigs against exact geometry: relative cameras from the body
both see, robust means, the ground plane under the feet, PnP of the mean body."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.body import load_body_model
from mocapgraph.data_tools.geometry.camera_model import project_points
from mocapgraph.graphs.initialisation import (
    fuse_bodies,
    ground_frame,
    neutral_pose,
    pnp_view,
    relative_cameras,
    robust_pose_mean,
)
from mocapgraph.priors.views import ViewEstimate


@pytest.fixture(scope="module")
def body():
    return load_body_model()


def rigid(rotvec, t):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def camera(position, target=(0.0, 0.0, 1.0)):
    """world_T_camera of an OpenCV camera at ``position`` looking at ``target``, image rows down."""
    z = np.asarray(target, float) - position
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    return np.block([[np.column_stack([x, np.cross(z, x), z]), np.asarray(position, float)[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]])


def scene(T=20, seed=0):
    """World roots walking on z = 0 (pelvis 0.9 m up, body +Y up) and three cameras, the last moving."""
    rng = np.random.default_rng(seed)
    upright = Rotation.from_euler("x", 90, degrees=True).as_matrix()  # body +Y -> world +Z
    roots = np.tile(np.eye(4), (T, 1, 1))
    for t in range(T):
        roots[t, :3, :3] = Rotation.from_euler("z", 0.05 * t).as_matrix() @ upright
        roots[t, :3, 3] = [0.08 * t, 0.02 * t, 0.9]
    static = [camera([5.0, 0.5, 2.0]), camera([-1.0, 6.0, 3.0])]
    moving = np.stack([camera([3.0 * np.cos(0.05 * t), -5.0 + 0.1 * t, 1.5]) for t in range(T)])
    cams = [np.repeat(static[0][None], T, 0), np.repeat(static[1][None], T, 0), moving]
    return roots, cams, rng


def views_from(roots, cams, valid=None):
    T = len(roots)
    return [
        ViewEstimate(np.linalg.inv(c) @ roots, np.zeros((T, 21, 3)), np.full((T, 6), 0.5), np.ones(T, bool) if valid is None else valid[k])
        for k, c in enumerate(cams)
    ]


def test_relative_cameras_are_exact_for_exact_views():
    roots, cams, _ = scene()
    rel, known = relative_cameras(views_from(roots, cams), [False, False, True], reference=0)
    for c in range(3):
        want = np.linalg.inv(cams[0]) @ cams[c]
        np.testing.assert_allclose(rel[c], want, atol=1e-9)
    assert known.all()


def test_moving_camera_gaps_are_filled_and_flips_rejected():
    roots, cams, _ = scene(T=30)
    views = views_from(roots, cams)
    views[2].valid[10:14] = False
    views[2].camera_T_root[20, :3, 3] *= -1.0  # a PnP flip: the body behind the camera
    rel, known = relative_cameras(views, [False, False, True], reference=0)
    assert not known[2, 10:14].any() and not known[2, 20]
    truth = np.linalg.inv(cams[0]) @ cams[2]
    assert np.abs(rel[2, :, :3, 3] - truth[:, :3, 3]).max() < 0.1  # interpolated over 4 frames of a smooth path


def test_robust_mean_ignores_outliers():
    rng = np.random.default_rng(3)
    base = rigid([0.1, -0.2, 0.3], [1.0, 2.0, 3.0])
    poses = np.stack([base @ rigid(rng.normal(scale=0.01, size=3), rng.normal(scale=0.01, size=3)) for _ in range(40)])
    poses[:5] = rigid([2.0, 0.0, 0.0], [10.0, 0.0, 0.0])
    mean = robust_pose_mean(poses)
    assert np.linalg.norm(mean[:3, 3] - base[:3, 3]) < 0.01
    assert np.linalg.norm(mean[:3, :3] - base[:3, :3]) < 0.01


def test_fused_body_is_the_reference_frame_body():
    roots, cams, _ = scene()
    views = views_from(roots, cams)
    rel, known = relative_cameras(views, [False, False, True], reference=0)
    fused = fuse_bodies(views, rel, known)
    np.testing.assert_allclose(fused.camera_T_root, np.linalg.inv(cams[0]) @ roots, atol=1e-9)


@pytest.mark.parametrize("walking", [True, False])
def test_ground_plane_under_the_feet(body, walking):
    """Feet on a plane tilted 0.1 rad, seen from a camera: the found world's z axis is the plane's
    normal (from the feet when they spread, else the body's up) and the first root sits above its origin."""
    T = 40
    tilt = Rotation.from_rotvec([0.1, 0.0, 0.0]).as_matrix()
    upright = Rotation.from_euler("x", 90, degrees=True).as_matrix()
    shape = body.default_shape
    pose = np.repeat(neutral_pose()[None], T, 0)
    rest = body.forward(shape, np.eye(4)[None], pose[:1], keypoints="body").keypoints[0]
    sole = -rest[:, 1].min()  # pelvis height above the soles when standing
    roots = np.tile(np.eye(4), (T, 1, 1))
    for t in range(T):
        x, y = (1.5 * np.cos(0.15 * t), 1.5 * np.sin(0.15 * t)) if walking else (0.0, 0.0)
        roots[t, :3, :3] = tilt @ upright
        roots[t, :3, 3] = tilt @ [x, y, sole]
    cam = camera([0.5, -6.0, 2.0])
    bodies = ViewEstimate(np.linalg.inv(cam) @ roots, pose, np.repeat(shape[None], T, 0), np.ones(T, bool))
    g = ground_frame(body, bodies, shape)
    normal_world = cam[:3, :3] @ g.ref_T_world[:3, 2]
    assert g.from_feet == walking
    assert np.degrees(np.arccos(np.clip(normal_world @ tilt[:, 2], -1, 1))) < 1.0
    world_T_root0 = np.linalg.inv(g.ref_T_world) @ bodies.camera_T_root[0]
    assert np.linalg.norm(world_T_root0[:2, 3]) < 1e-6
    assert abs(world_T_root0[2, 3] - sole) < 0.03


def test_pnp_of_the_mean_body_places_an_exact_view(body):
    """Keypoints of the mean body itself, projected: PnP recovers its pose to a millimetre."""
    cam = camera([0.5, -6.0, 2.0])
    roots, _, _ = scene(T=3)
    kp = body.forward(body.default_shape, roots, np.repeat(neutral_pose()[None], 3, 0), keypoints="coco17").keypoints
    K = np.array([[1200.0, 0, 960], [0, 1200.0, 540], [0, 0, 1]])
    px, _ = project_points(kp, cam, K)
    view = pnp_view(body, np.concatenate([px, np.ones(px.shape[:-1] + (1,))], -1), "coco17", K)
    assert view.valid.all()
    np.testing.assert_allclose(view.camera_T_root[:, :3, 3], (np.linalg.inv(cam) @ roots)[:, :3, 3], atol=1e-3)
    missing = np.full((1, 17, 3), np.nan)
    assert not pnp_view(body, missing, "coco17", K).valid[0]


def test_carried_camera_behind_a_swapped_detector_placed_behind(body):
    """A carried camera 5 m behind a person whose detector labels the sides as if the person faced
    it (swapped as a whole in 14 of 20 frames): the swapped labels fit the static cameras'
    triangulation as well as the camera's mirror image in front of the person, so the labels as
    detected place it there in those frames. With the face (nose, eyes) reported at a third of
    the body's confidence, as a detector sees it from behind, every frame is placed within
    0.3 m of the truth (measured: under 0.1 mm), and the swapped frames, and only they, are
    returned to be relabelled."""
    from mocapgraph.body.keypoint_formats import COCO17
    from mocapgraph.body.labelling import swap_permutation
    from mocapgraph.graphs.initialisation import moving_cameras_from_static

    T = 20
    upright = Rotation.from_euler("x", 90, degrees=True).as_matrix()  # body +Y -> world +Z, facing -Y
    roots = np.tile(np.eye(4), (T, 1, 1))
    roots[:, :3, :3] = upright
    roots[:, :3, 3] = [0.0, 0.0, 0.9]
    points = body.forward(body.default_shape, roots, np.zeros((T, 21, 3)), keypoints="coco17").keypoints  # (T, 17, 3) world
    K = np.array([[1400.0, 0, 960], [0, 1400, 540], [0, 0, 1]])
    static = [camera([0.5, -6.0, 1.4]), camera([6.0, 1.0, 1.4])]
    carried = np.stack([camera([0.2 * np.sin(0.2 * t), 5.0, 1.5]) for t in range(T)])
    world_T = [np.repeat(static[0][None], T, 0), np.repeat(static[1][None], T, 0), carried]
    swapped = np.ones(T, bool)
    swapped[[0, 5, 6, 12, 18, 19]] = False
    flip = swap_permutation(COCO17, "body")
    face = [COCO17.index(n) for n in ("nose", "left_eye", "right_eye")]

    def views(face_conf: float) -> list[np.ndarray]:
        out = []
        for k, pose in enumerate(world_T):
            px = np.stack([project_points(points[t], pose[t], K)[0] for t in range(T)])
            kp = np.concatenate([px, np.full((T, 17, 1), 0.9)], axis=-1)
            if k == 2:
                kp[swapped] = kp[swapped][:, flip]
                kp[:, face, 2] = face_conf
            out.append(kp)
        return out

    ref = np.linalg.inv(world_T[0][0])
    ref_T_c = np.stack([ref @ p for p in world_T])
    start = ref_T_c.copy()
    start[2] = np.eye(4)
    known = np.array([np.ones(T, bool), np.ones(T, bool), np.zeros(T, bool)])
    truth = ref_T_c[2, :, :3, 3]
    seen_front, _, turned = moving_cameras_from_static(views(0.9), [K] * 3, start, known, [False, False, True])
    assert np.sum(np.linalg.norm(seen_front[2, :, :3, 3] - truth, axis=1) > 3.0) >= 10 and not turned  # the mirror in front
    seen_back, ok, turned = moving_cameras_from_static(views(0.3), [K] * 3, start, known, [False, False, True])
    assert ok[2].all() and np.linalg.norm(seen_back[2, :, :3, 3] - truth, axis=1).max() < 0.3
    np.testing.assert_array_equal(turned[2], swapped)  # those frames' labels to be undone: exactly the swapped ones


def test_back_views_told_by_the_face():
    """A face reported at a third of the body's confidence is a back view, at its confidence
    not; a detector that never reports a face says nothing; a camera that sees the person in
    fewer than half a window's states is not judged."""
    from mocapgraph.graphs.initialisation import _seen_from_behind

    kp = np.zeros((40, 17, 3))
    kp[..., 2] = 0.9
    kp[:20, :3, 2] = 0.3  # the first 20 states from behind
    behind = _seen_from_behind(kp)
    assert behind[:5].all() and not behind[-5:].any()
    faceless = kp.copy()
    faceless[:, :3, 2] = np.nan
    assert not _seen_from_behind(faceless).any()
    sparse = kp.copy()
    sparse[::3] = np.nan
    sparse[1::3] = np.nan
    assert not _seen_from_behind(sparse).any()
