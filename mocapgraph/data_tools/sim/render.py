"""Rendered video of a synthetic capture: what each camera would film, for structure from motion.

The background is ray-cast, not rasterised: every pixel's ray (the lens distortion undone once per
camera by :func:`~mocapgraph.data_tools.geometry.camera_model.undistort_pixels`, so the image
obeys the capture's distortion exactly, straight edges bending as they should) meets the ground
plane ``z = 0`` and a set of axis-aligned boxes (walls, crates, poles) by the slab test; each box
is tested only over the pixels of its projected bounding rectangle. Surfaces carry deterministic
blocky value noise at three scales (hashed integer cells, so no two places look alike), faded to
its mean where a cell is smaller than a few pixels (no shimmering aliasing far away). The person is
the body's mesh, rasterised by :func:`~mocapgraph.data_tools.geometry.raster.rasterize` with the
distortion applied to its vertices, Lambert-shaded by a sun, z-buffered against the background
(a triangle's depth is its vertices' mean: its ~2 cm size is far below any background gap).

Everything derives from a seed and the capture's geometry: the same capture renders to the same
pixels. Depths are camera z in metres throughout (rays have unit z).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from mocapgraph.body import load_body_model
from mocapgraph.data_tools.geometry.camera_model import MIN_DEPTH_M, distortion_max_radius2, project_points, undistort_pixels
from mocapgraph.data_tools.geometry.raster import rasterize
from mocapgraph.data_tools.geometry.timing import match_times
from mocapgraph.errors import MocapgraphError
from mocapgraph.progress import progress_bar

log = logging.getLogger(__name__)

SUN = np.array([0.45, 0.3, 0.84]) / np.linalg.norm([0.45, 0.3, 0.84])
"""World direction towards the sun (Z up)."""
AMBIENT = 0.45
SKY_BGR = np.array([235.0, 210.0, 180.0])
BODY_BGR = np.array([90.0, 120.0, 190.0])
TEXTURE_CELLS_M = (0.9, 0.3, 0.1)
"""Cell sizes of the three octaves of value noise, metres."""
TEXTURE_WEIGHTS = (0.45, 0.33, 0.22)
MIN_CELL_PX = 2.5
"""An octave whose cells span fewer pixels than this fades to its mean."""
VIDEO_FOURCC = "mp4v"


@dataclass(frozen=True)
class Box:
    """An axis-aligned box: ``lo (3,)``, ``hi (3,)`` world metres; ``bgr (3,)`` base colour; ``seed`` of its texture."""

    lo: np.ndarray
    hi: np.ndarray
    bgr: np.ndarray
    seed: int


@dataclass(frozen=True)
class Scene:
    """The static world a capture is rendered in: the textured ground ``z = 0`` and ``boxes``."""

    boxes: tuple[Box, ...]
    ground_bgr: np.ndarray
    seed: int


def _hash01(i: np.ndarray, j: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic uniform values in [0, 1) of integer cells ``(i, j)`` (same shape), per ``seed``."""
    mask = np.uint64(0xFFFFFFFF)
    h = (i.astype(np.int64).astype(np.uint64) * np.uint64(0x8DA6B343) + j.astype(np.int64).astype(np.uint64) * np.uint64(0xD8163841)
         + np.uint64((seed * 0xCB1AB31F) & 0xFFFFFFFF)) & mask  # fmt: skip
    h ^= h >> np.uint64(13)
    h = (h * np.uint64(0x5BD1E995)) & mask
    h ^= h >> np.uint64(15)
    h = (h * np.uint64(0x27D4EB2F)) & mask
    h ^= h >> np.uint64(16)
    return h.astype(np.float64) / 2.0**32


def surface_texture(u: np.ndarray, v: np.ndarray, footprint_m: np.ndarray, seed: int) -> np.ndarray:
    """Brightness in [0.1, 1] of surface coordinates ``u, v (N,)`` metres seen with pixels of
    ``footprint_m (N,)`` metres: three octaves of blocky value noise, each faded to its mean 0.5
    where its cells span fewer than :data:`MIN_CELL_PX` pixels."""
    value = np.zeros_like(u)
    for octave, (cell, weight) in enumerate(zip(TEXTURE_CELLS_M, TEXTURE_WEIGHTS)):
        noise = _hash01(np.floor(u / cell), np.floor(v / cell), seed * 7 + octave)
        fade = np.clip(cell / (footprint_m * MIN_CELL_PX) - 1.0, 0.0, 1.0)
        value += weight * (0.5 + fade * (noise - 0.5))
    # The sum of octaves bunches near its mean: stretched, so that blocks differ enough for SIFT.
    return np.clip(0.55 + 2.2 * (value - 0.5), 0.1, 1.0)


def build_scene(subject_xy: np.ndarray, camera_xyz: np.ndarray, seed: int) -> Scene:
    """Walls, crates and poles around the place where the subject moves and the cameras stand.

    Args:
        subject_xy: ``(T, 2)`` the subject's ground positions, world metres.
        camera_xyz: ``(N, 3)`` camera positions (any frames), world metres.
        seed: the same seed (and geometry) gives the same scene.

    Structures stand only outside the rectangle holding the subject's path and every camera (plus
    1 m), so they never hide the person from a camera nor stand in a camera: a wall on each side
    3-8 m out, then crates and poles scattered in the ring between.
    """
    rng = np.random.default_rng([int(seed), 0x5CE7E])
    xy = np.concatenate([np.asarray(subject_xy, float)[:, :2], np.asarray(camera_xyz, float)[:, :2]])
    lo, hi = xy.min(axis=0) - 1.0, xy.max(axis=0) + 1.0
    boxes = []

    def add(box_lo, box_hi, bgr):
        boxes.append(Box(np.asarray(box_lo, float), np.asarray(box_hi, float), np.asarray(bgr, float), int(rng.integers(1 << 30))))

    gaps = rng.uniform(3.0, 8.0, size=4)
    outer_lo, outer_hi = lo - gaps[[0, 1]], hi + gaps[[2, 3]]
    for axis in (0, 1):
        other = 1 - axis
        for side, at in ((0, outer_lo[axis]), (1, outer_hi[axis])):
            # Not the whole side: the ends of walls and what shows between them give depth edges.
            span = outer_hi[other] - outer_lo[other]
            start = outer_lo[other] + rng.uniform(0.0, 0.25) * span
            stop = outer_hi[other] - rng.uniform(0.0, 0.25) * span
            box_lo, box_hi = np.zeros(3), np.zeros(3)
            box_lo[axis], box_hi[axis] = (at - 0.3, at) if side == 0 else (at, at + 0.3)
            box_lo[other], box_hi[other] = start, stop
            box_hi[2] = rng.uniform(2.5, 4.5)
            add(box_lo, box_hi, rng.uniform(120, 230, size=3))

    def ring_point():
        # Uniform in the ring between the inner rectangle and the walls.
        while True:
            p = rng.uniform(outer_lo + 0.5, outer_hi - 0.5)
            if np.any(p < lo - 0.5) or np.any(p > hi + 0.5):
                return p

    for _ in range(14):
        p, half = ring_point(), rng.uniform(0.2, 0.8, size=2)
        add([*(p - half), 0.0], [*(p + half), rng.uniform(0.4, 2.0)], rng.uniform(60, 230, size=3))
    for _ in range(10):
        p = ring_point()
        add([*(p - 0.08), 0.0], [*(p + 0.08), rng.uniform(2.0, 4.0)], rng.uniform(40, 200, size=3))
    return Scene(tuple(boxes), rng.uniform(110, 170, size=3), int(seed))


def camera_rays(K: np.ndarray, distortion: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """``(H·W, 3)`` each pixel centre's ray in the camera frame with unit z (a point at camera depth
    ``d`` along it is ``d · ray``); NaN for pixels beyond the distortion's monotonic range."""
    width, height = image_size
    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    pixels = undistort_pixels(np.stack([u.ravel(), v.ravel()], axis=1), K, distortion)
    Kinv = np.linalg.inv(np.asarray(K, float))
    rays = np.column_stack([pixels, np.ones(len(pixels))]) @ Kinv.T
    rays /= rays[:, 2:3]
    rays[rays[:, 0] ** 2 + rays[:, 1] ** 2 >= distortion_max_radius2(distortion)] = np.nan
    return rays


def _box_pixels(box: Box, world_T_camera: np.ndarray, K, distortion, image_size) -> np.ndarray | None:
    """Pixel rectangle ``(x0, y0, x1, y1)`` that can show ``box``, None if it is wholly behind the
    camera; all pixels when part of it is behind (its projection is then unbounded)."""
    corners = np.array([[box.lo[0] if i & 1 else box.hi[0], box.lo[1] if i & 2 else box.hi[1], box.lo[2] if i & 4 else box.hi[2]] for i in range(8)])
    pixels, depth = project_points(corners, world_T_camera, K, distortion)
    width, height = image_size
    if np.all(depth <= MIN_DEPTH_M):
        return None
    if np.any(depth <= MIN_DEPTH_M) or not np.all(np.isfinite(pixels)):
        return np.array([0, 0, width, height])
    # Distortion bends edges outward by a few pixels at most at our lenses: pad the rectangle.
    x0, y0 = np.floor(pixels.min(axis=0)).astype(int) - 8
    x1, y1 = np.ceil(pixels.max(axis=0)).astype(int) + 9
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
    if x0 >= x1 or y0 >= y1:
        return None
    return np.array([x0, y0, x1, y1])


def render_frame(scene: Scene, rays: np.ndarray, world_T_camera: np.ndarray, K, distortion, image_size, vertices=None, faces=None) -> np.ndarray:
    """One camera image ``(H, W, 3)`` BGR uint8.

    Args:
        rays: ``(H·W, 3)`` from :func:`camera_rays` for this camera's ``K``, ``distortion``, ``image_size``.
        world_T_camera: ``(4, 4)`` OpenCV camera pose.
        vertices: ``(V, 3)`` the person's posed mesh, world metres, with ``faces (F, 3)``; or None.
    """
    width, height = image_size
    R, centre = world_T_camera[:3, :3], world_T_camera[:3, 3]
    # (N, 3) world, scaled so that the camera depth along them is the ray parameter (einsum: BLAS's
    # matmul of a tall (N, 3) by (3, 3) costs ten times more here).
    dirs = np.einsum("ij,nj->ni", R, rays)
    focal = 0.5 * (K[0, 0] + K[1, 1])
    ray_len = np.linalg.norm(rays, axis=1)

    depth = np.full(len(rays), np.inf)
    bgr = np.broadcast_to(SKY_BGR, (len(rays), 3)).copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -centre[2] / dirs[:, 2]
    hit = np.isfinite(t) & (t > MIN_DEPTH_M)
    if hit.any():
        idx = np.flatnonzero(hit)
        p = centre + t[idx, None] * dirs[idx]
        # Pixel footprint on the surface: distance / focal, over |cos| of the incidence.
        cos = np.abs(dirs[idx, 2]) / np.linalg.norm(dirs[idx], axis=1)
        footprint = t[idx] * ray_len[idx] / focal / np.maximum(cos, 0.05)
        shade = AMBIENT + (1 - AMBIENT) * SUN[2]
        bgr[idx] = (shade * surface_texture(p[:, 0], p[:, 1], footprint, scene.seed))[:, None] * scene.ground_bgr
        depth[idx] = t[idx]

    grid = np.arange(width * height).reshape(height, width)
    with np.errstate(divide="ignore"):
        inv = 1.0 / dirs
    for b, box in enumerate(scene.boxes):
        rect = _box_pixels(box, world_T_camera, K, distortion, image_size)
        if rect is None:
            continue
        window = (slice(rect[1], rect[3]), slice(rect[0], rect[2]))
        inv_window = inv.reshape(height, width, 3)[window]  # a view: no gather over the window
        # Slab test by columns: numpy's reductions over a trailing axis of 3 are slow.
        near, far = [], []
        for a in range(3):
            t1 = (box.lo[a] - centre[a]) * inv_window[..., a]
            t2 = (box.hi[a] - centre[a]) * inv_window[..., a]
            near.append(np.fmin(t1, t2))
            far.append(np.fmax(t1, t2))
        t_in = np.maximum(np.maximum(near[0], near[1]), near[2])
        t_out = np.minimum(np.minimum(far[0], far[1]), far[2])
        seen = (t_out >= t_in) & (t_in > MIN_DEPTH_M) & (t_in < depth.reshape(height, width)[window])
        if not seen.any():
            continue
        idx, t_in = grid[window][seen], t_in[seen]
        axis = np.where(near[0][seen] == t_in, 0, np.where(near[1][seen] == t_in, 1, 2))
        d = dirs[idx]
        p = centre + t_in[:, None] * d
        rows = np.arange(len(idx))
        normal = np.zeros((len(idx), 3))
        normal[rows, axis] = -np.sign(d[rows, axis])
        # Face coordinates: the two axes other than the normal's.
        u = np.where(axis == 0, p[:, 1], p[:, 0])
        v = np.where(axis == 2, p[:, 1], p[:, 2])
        cos = np.abs(np.sum(normal * d, axis=1)) / np.linalg.norm(d, axis=1)
        footprint = t_in * ray_len[idx] / focal / np.maximum(cos, 0.05)
        shade = AMBIENT + (1 - AMBIENT) * np.maximum(normal @ SUN, 0.0)
        # Each face of a box its own texture (seed per axis and side).
        face_seed = box.seed + 3 * axis + (normal[rows, axis] > 0)
        texture = np.empty(len(idx))
        for s in np.unique(face_seed):
            sel = face_seed == s
            texture[sel] = surface_texture(u[sel], v[sel], footprint[sel], int(s))
        bgr[idx] = (shade * texture)[:, None] * box.bgr
        depth[idx] = t_in

    if vertices is not None:
        pixels, vdepth = project_points(vertices, world_T_camera, K, distortion)
        seen_face = rasterize(pixels, vdepth, faces, image_size).ravel()
        on = np.flatnonzero(seen_face >= 0)
        face = seen_face[on]
        face_depth = vdepth[faces[face]].mean(axis=1)
        front = face_depth < depth[on]
        on, face = on[front], face[front]
        tri = vertices[faces]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        shade = AMBIENT + (1 - AMBIENT) * np.abs(normal @ SUN)  # two-sided: a mesh's winding is not assumed
        bgr[on] = shade[face, None] * BODY_BGR
    return np.clip(bgr, 0, 255).astype(np.uint8).reshape(height, width, 3)


def scene_for_capture(capture) -> Scene:
    """The :func:`build_scene` of a synthetic capture (its ground truth and ``metadata["seed"]``)."""
    gt = capture.ground_truth
    if gt is None:
        raise MocapgraphError(f"capture {capture.name!r}: rendering needs ground truth (the person and the cameras' poses)")
    cams = np.concatenate([poses[:, :3, 3] for poses in gt.cameras.values()])
    return build_scene(gt.root[:, :2, 3], cams, int(capture.metadata.get("seed", 0)))


def video_name(camera_name: str) -> str:
    """Where a camera's rendered video lives in a capture directory."""
    return f"cameras/{camera_name}/video.mp4"


def render_capture_videos(capture, root: Path) -> dict[str, float]:
    """Render every camera of the synthetic ``capture`` to ``root / video_name(camera)`` (MP4, the
    camera's frame rate and image size, frame ``i`` = the camera's frame ``i``); sets each camera's
    ``video`` to that relative path. Returns frames per second of rendering per camera.
    """
    gt = capture.ground_truth
    scene = scene_for_capture(capture)
    body = load_body_model(gt.body_model)
    mesh = body.mesh(gt.shape)
    speeds = {}
    for cam in capture.cameras:
        truth = gt.cameras.get(cam.name)
        if truth is None:
            raise MocapgraphError(f"capture {capture.name!r}: camera {cam.name} has no ground-truth poses to render from")
        frames = cam.num_frames
        states = match_times(gt.timestamps, cam.timestamps, tolerance=0.5 / cam.frame_rate)
        if np.any(states < 0):
            raise MocapgraphError(f"capture {capture.name!r}: camera {cam.name} has frames without a ground-truth body state")
        rays = camera_rays(cam.K, cam.distortion, cam.image_size)
        path = Path(root) / video_name(cam.name)
        path.parent.mkdir(parents=True, exist_ok=True)
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*VIDEO_FOURCC), float(cam.frame_rate), tuple(cam.image_size))
        if not writer.isOpened():
            raise MocapgraphError(f"{path}: OpenCV cannot write an MP4 video here")
        start = time.perf_counter()
        try:
            for i in progress_bar(range(frames), desc=f"render {cam.name}", unit="frame"):
                s = states[i]
                vertices = mesh.vertices(mesh.bone_poses(body.forward(gt.shape, gt.root[s : s + 1], gt.pose[s : s + 1])))[0]
                writer.write(render_frame(scene, rays, truth[i], cam.K, cam.distortion, cam.image_size, vertices, mesh.faces))
        finally:
            writer.release()
        speeds[cam.name] = frames / (time.perf_counter() - start)
        cam.video = video_name(cam.name)
        log.info("rendered %s: %d frames at %.2f frames/s", cam.name, frames, speeds[cam.name])
    return speeds
