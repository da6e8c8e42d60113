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
    if title:
        fig.suptitle(title, fontsize=11)
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.95 if title else 1, wspace=0, hspace=0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp, dpi=80)
    plt.close(fig)
    tmp.replace(path)
    return path
