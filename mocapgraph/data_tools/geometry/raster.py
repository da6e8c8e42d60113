"""A z-buffer in numpy: which triangle of a mesh is seen at each pixel.

Every triangle's candidate pixels (its bounding box, in batches of triangles of similar size) are
tested by their barycentric coordinates at once, and the nearest triangle per pixel wins. Used by
the overlay (a result drawn over a video) and the renderer of synthetic video.
"""

from __future__ import annotations

import numpy as np

from mocapgraph.data_tools.geometry.camera_model import MIN_DEPTH_M

MAX_CANDIDATES = 2_000_000
"""Candidate pixels tested at once by :func:`rasterize` (bounds its memory, ~100 MB)."""


def rasterize(pixels: np.ndarray, depth: np.ndarray, faces: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Which triangle is seen at each pixel.

    Args:
        pixels: ``(V, 2)`` vertex pixel coordinates (pixel centres at integers, as OpenCV's).
        depth: ``(V,)`` vertex camera depth, metres; triangles with a vertex closer than
            ``MIN_DEPTH_M`` (or not finite) are dropped.
        faces: ``(F, 3)`` vertex indices.
        image_size: ``(width, height)``.

    Returns:
        ``(height, width)`` int index of the nearest triangle covering each pixel centre, -1 for none.
    """
    width, height = image_size
    tri, z = pixels[faces], depth[faces]  # (F, 3, 2), (F, 3)
    lo, hi = np.floor(tri.min(axis=1)), np.ceil(tri.max(axis=1))
    lo, hi = np.maximum(lo, 0), np.minimum(hi, [width - 1, height - 1])
    ok = np.all(np.isfinite(tri), axis=(1, 2)) & np.all(z > MIN_DEPTH_M, axis=1) & np.all(hi >= lo, axis=1)
    index = np.flatnonzero(ok)
    extent = (hi[index] - lo[index]).max(axis=1) + 1
    found_pixel, found_depth, found_face = [], [], []
    side = 1
    while len(index):
        # Triangles whose box fits a side × side window, tested over that window.
        batch = extent <= side
        chosen, index, extent = index[batch], index[~batch], extent[~batch]
        step = max(1, MAX_CANDIDATES // (side * side))
        offsets = np.stack(np.meshgrid(np.arange(side), np.arange(side), indexing="xy"), axis=-1).reshape(-1, 2)
        for start in range(0, len(chosen), step):
            f = chosen[start : start + step]
            p = lo[f][:, None, :] + offsets[None]  # (n, side², 2) candidate pixel centres
            a, b, c = tri[f, 0][:, None], tri[f, 1][:, None], tri[f, 2][:, None]
            area = (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])
            with np.errstate(divide="ignore", invalid="ignore"):
                w1 = ((p[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (p[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])) / area
                w2 = ((b[..., 0] - a[..., 0]) * (p[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (p[..., 0] - a[..., 0])) / area
            w0 = 1.0 - w1 - w2
            inside = (w0 >= 0) & (w1 >= 0) & (w2 >= 0) & (p[..., 0] <= hi[f][:, None, 0]) & (p[..., 1] <= hi[f][:, None, 1])
            rows, cols = np.nonzero(inside)
            if not len(rows):
                continue
            zf = z[f[rows]]
            # Depth is affine in 1/z across a projected triangle (perspective-correct).
            inv = w0[rows, cols] / zf[:, 0] + w1[rows, cols] / zf[:, 1] + w2[rows, cols] / zf[:, 2]
            px = p[rows, cols].astype(np.int64)
            found_pixel.append(px[:, 1] * width + px[:, 0])
            found_depth.append(1.0 / inv)
            found_face.append(f[rows])
        side *= 2
    out = np.full(width * height, -1, dtype=np.int64)
    if found_pixel:
        pixel, dep, face = np.concatenate(found_pixel), np.concatenate(found_depth), np.concatenate(found_face)
        order = np.lexsort((dep, pixel))
        first = np.unique(pixel[order], return_index=True)[1]
        out[pixel[order][first]] = face[order][first]
    return out.reshape(height, width)
