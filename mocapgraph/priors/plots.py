"""Figures of the learned priors: skeletons drawn with matplotlib (Agg backend, no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.body.skeleton import PARENTS

# world_T_root standing the body up: body +Y (up) → world +Z, body +Z (forward) → world −Y.
_STANDING = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw_skeleton(ax, joints: np.ndarray, parents: np.ndarray = PARENTS, color: str = "0.2") -> None:
    """Bones and joints of one skeleton on a 3D ``ax``: ``joints (22, 3)`` in a Z-up frame (m)."""
    for child, parent in enumerate(parents):
        if parent >= 0:
            ax.plot(*joints[[parent, child]].T, "-", color=color, lw=2)
    ax.scatter(*joints.T, color="tab:blue", s=6, depthshade=False)


def pose_grid_png(poses: np.ndarray, path: str | Path, body: BodyModel, title: str = "") -> Path:
    """PNG of one skeleton per pose in a square grid, each seen from the front and a little to its
    left, pelvis at the origin.

    Args:
        poses: ``(N, 63)`` joint rotations (axis-angle, radians), posed on ``body`` with its
            default shape.
        path: the PNG to write (atomically; parent directories are created).
        body: the body model (``load_body_model("anny")``).
        title: the figure's title.
    """
    plt = _pyplot()
    poses = np.asarray(poses, dtype=float).reshape(-1, 21, 3)
    joints = body.forward(body.default_shape, np.tile(_STANDING, (len(poses), 1, 1)), poses).joints
    cols = int(np.ceil(np.sqrt(len(poses))))
    rows = -(-len(poses) // cols)
    fig = plt.figure(figsize=(2.0 * cols, 2.6 * rows))
    for n, skeleton in enumerate(joints):
        ax = fig.add_subplot(rows, cols, n + 1, projection="3d")
        draw_skeleton(ax, skeleton)
        # Equal scale on all axes, sized for a standing adult (pelvis at 0, head ≈ +0.7 m, feet ≈ −0.95 m).
        ax.set(xlim=(-0.6, 0.6), ylim=(-0.6, 0.6), zlim=(-1.0, 0.8))
        ax.set_box_aspect((1.2, 1.2, 1.8), zoom=1.6)
        ax.view_init(elev=10, azim=-70)
        ax.set_axis_off()
    return _save(fig, path, title)


def motion_windows_png(windows_positions: np.ndarray, path: str | Path, frames=(0, 6, 12, 18, 24), title: str = "") -> Path:
    """PNG of motion windows as skeleton strips: one row per window, one panel per frame in
    ``frames``, every panel of a row on the same axes limits so the body's travel shows.

    Args:
        windows_positions: ``(N, 25, 22, 3)`` joint positions in each window's canonical frame
            (metres, Z up, ground at z = 0, the first frame's root above the origin facing +Y;
            :func:`mocapgraph.priors.motion_windows.feature_positions`).
        path: the PNG to write (atomically; parent directories are created).
        frames: the frames of each window to draw.
        title: the figure's title.
    """
    plt = _pyplot()
    windows = np.asarray(windows_positions, dtype=float)
    rows, cols = len(windows), len(frames)
    fig = plt.figure(figsize=(1.7 * cols, 2.3 * rows))
    for r, window in enumerate(windows):
        # A box around everything the row shows, at least 1.2 m wide, equal scale on x and y.
        lo, hi = window[:, :, :2].min(axis=(0, 1)), window[:, :, :2].max(axis=(0, 1))
        centre, half = (lo + hi) / 2, max(0.6, (hi - lo).max() / 2 + 0.1)
        top = max(2.0, window[..., 2].max() + 0.1)
        for c, frame in enumerate(frames):
            ax = fig.add_subplot(rows, cols, r * cols + c + 1, projection="3d")
            ground = centre + half * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1]])
            ax.plot(ground[:, 0], ground[:, 1], 0.0, "-", color="0.75", lw=1)
            draw_skeleton(ax, window[frame])
            ax.set(xlim=(centre[0] - half, centre[0] + half), ylim=(centre[1] - half, centre[1] + half), zlim=(0.0, top))
            ax.set_box_aspect((1.0, 1.0, top / (2 * half)), zoom=1.3)
            # Seen from the subject's right (canonical +X) and a little from the front and above:
            # forward (+Y) runs to the right.
            ax.view_init(elev=12, azim=20)
            ax.set_axis_off()
            if r == 0:
                ax.set_title(f"frame {frame}", fontsize=9)
    return _save(fig, path, title)


def _save(fig, path: str | Path, title: str) -> Path:
    """Title, tight layout, then an atomic write of the PNG (80 dpi); closes the figure."""
    if title:
        fig.suptitle(title, fontsize=11)
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.95 if title else 1, wspace=0, hspace=0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp, dpi=80)
    _pyplot().close(fig)
    tmp.replace(path)
    return path
