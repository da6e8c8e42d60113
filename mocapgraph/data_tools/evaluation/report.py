"""Evaluation reports: a metrics table and the thesis' figures, as one self-contained HTML page
(the PNGs embedded, and written beside it).

Figures: the estimated root trajectory against ground truth, one panel per axis; the joint
error per frame over the number of detections per frame (as a grey background), as AirCap's
thesis plots them; and, when the results estimate cameras, every camera's estimated and true
trajectory in 3D. Results are drawn after the alignment ``eval`` uses for their world frame.
"""

from __future__ import annotations

import base64
import html
import os
from pathlib import Path

import numpy as np

from mocapgraph.body.skeleton import PARENTS
from mocapgraph.data_tools.evaluation.evaluate import Evaluation, aligned
from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.data_tools.io.result import Result


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_result(result: Result, path: Path, poses: int = 5) -> Path:
    """A result in 3D, in its own world frame: every camera's track (its centre over time, and
    its viewing direction at its first frame) and the body's skeleton at ``poses`` instants
    spread over the capture, coloured by time. Written atomically (a PNG at ``path``)."""
    plt = _pyplot()
    fig = plt.figure(figsize=(8, 7))
    ax = fig.add_subplot(projection="3d")
    joints = result.joints
    known = np.flatnonzero(np.isfinite(joints).all(axis=(1, 2)))
    points = [joints[known].reshape(-1, 3)] if len(known) else []
    colours = plt.cm.viridis(np.linspace(0, 1, max(poses, 1)))
    for colour, t in zip(colours, known[np.linspace(0, len(known) - 1, min(poses, len(known))).astype(int)] if len(known) else []):
        for j, p in enumerate(PARENTS):
            if p >= 0:
                ax.plot(*joints[t, [p, j]].T, color=colour, lw=1.5)
        ax.text(*joints[t, 15], f"{result.timestamps[t]:.1f} s", fontsize=7, color=colour)
    for name, track in result.cameras.items():
        centres = track.world_T_camera[:, :3, 3]
        ax.plot(*centres.T, lw=1)
        axis = track.world_T_camera[0, :3, 2]
        ax.quiver(*centres[0], *axis, length=0.5, color="black", lw=1)
        ax.text(*centres[0], name, fontsize=8)
        points.append(centres)
    if points:
        every = np.concatenate(points)
        every = every[np.isfinite(every).all(axis=1)]
        centre, half = every.mean(axis=0), max(np.ptp(every, axis=0).max() / 2, 0.5)
        for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
            setter(c - half, c + half)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title(f"{result.pipeline}: {len(result.cameras)} cameras, {len(known)} body states; world: {result.world_frame}", fontsize=9)
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    tmp.replace(path)
    return path


def plot_root_trajectory(results: dict[str, Result], capture: Capture, path: Path) -> Path:
    """Root position per axis (x, y, z) of each result against the ground truth."""
    plt = _pyplot()
    gt = capture.ground_truth
    fig, axes = plt.subplots(3, 1, figsize=(9, 6.5), sharex=True)
    for a, axis in enumerate("xyz"):
        ax = axes[a]
        ax.plot(gt.timestamps, gt.root[:, a, 3], color="black", lw=2, label="ground truth")
        for label, res in results.items():
            if res.root is not None:
                ax.plot(res.timestamps, res.root[:, a, 3], lw=1, label=label)
        ax.set_ylabel(f"root {axis} (m)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_error_per_frame(evaluations: dict[str, Evaluation], result: Result, path: Path) -> Path:
    """Joint position error per frame (lines) over the detections per frame (grey bars)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 3.5))
    detections = result.flags.get("num_detections")
    if detections is not None:
        back = ax.twinx()
        back.bar(result.timestamps, detections, width=np.median(np.diff(result.timestamps)), color="0.85", zorder=0)
        back.set_ylabel("keypoints detected", color="0.5")
        ax.set_zorder(back.get_zorder() + 1)
        ax.patch.set_visible(False)
    for label, ev in evaluations.items():
        if "mpjpe_m" in ev.per_frame:
            ax.plot(ev.per_frame["timestamps"], 100 * ev.per_frame["mpjpe_m"], lw=1, label=label)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("MPJPE (cm)")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_camera_trajectories(results: dict[str, Result], capture: Capture, path: Path) -> Path:
    """3D: each camera's true trajectory (black; a static camera as a triangle) and each
    result's estimate (coloured, same marker), with the subject's true root path (grey)."""
    plt = _pyplot()
    gt = capture.ground_truth
    fig = plt.figure(figsize=(8, 7))
    ax = fig.add_subplot(projection="3d")
    ax.plot(*gt.root[:, :3, 3].T, color="0.6", lw=1, label="subject (true root)")
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for c, cam in enumerate(capture.cameras):
        truth = gt.cameras.get(cam.name)
        if truth is None:
            continue
        style = dict(marker="^", ms=7, ls="none") if not cam.moving else dict(lw=2)
        ax.plot(*truth[:, :3, 3].T, color="black", label="true cameras" if c == 0 else None, **style)
        ax.text(*truth[0, :3, 3], f" {cam.name}", fontsize=7)
        for k, (label, res) in enumerate(results.items()):
            track = res.cameras.get(cam.name)
            if track is not None:
                est = dict(marker="v", ms=6, ls="none") if not cam.moving else dict(lw=1, ls="--")
                ax.plot(*track.world_T_camera[:, :3, 3].T, color=colours[k % len(colours)], label=label if c == 0 else None, **est)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def embedded_image(path: Path, alt: str, out_dir: Path, style: str = "") -> str:
    """An ``<img>`` carrying the PNG or GIF at ``path`` as a data URI, so that the report is one
    self-contained file; ``data-file`` names the file beside it (relative to ``out_dir``)."""
    kind = "gif" if path.suffix.lower() == ".gif" else "png"
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    rel = html.escape(Path(os.path.relpath(path, out_dir)).as_posix())
    extra = f' style="{style}"' if style else ""
    return f'<img src="data:image/{kind};base64,{data}" alt="{html.escape(alt)}" data-file="{rel}"{extra}>'


def look_section(out_dir: Path, files: dict[str, Path], stills: dict[str, Path], commands: list[str]) -> str:
    """HTML of a report's "look at it and take it elsewhere" part: links to ``files`` (label →
    path), the ``stills`` (caption → PNG) and shell ``commands`` to run; paths relative to ``out_dir``."""

    def rel(path: Path) -> str:
        return html.escape(Path(os.path.relpath(path, out_dir)).as_posix())

    links = "".join(f'<li><a href="{rel(p)}">{html.escape(label)}</a> (<code>{rel(p)}</code>)</li>' for label, p in files.items())
    images = "".join(f"<figure>{embedded_image(p, c, out_dir, 'max-width:45%')}<figcaption>{html.escape(c)}</figcaption></figure>" for c, p in stills.items())
    lines = "".join(f"<pre>{html.escape(c)}</pre>" for c in commands)
    return f"<h2>Look at it and take it elsewhere</h2><ul>{links}</ul>{lines}{images}"


def write_report(
    out_dir: Path, title: str, capture: Capture, results: dict[str, Result], evaluations: dict[str, Evaluation], extra: str = ""
) -> Path:
    """``report.html`` with a metrics table (one row per result) and the figures (embedded: the page
    is one self-contained file; the PNGs stay beside it); ``extra`` is HTML appended at the end
    (e.g. :func:`look_section`)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    keys = list(dict.fromkeys(k for ev in evaluations.values() for k in ev.metrics if "." not in k))
    rows = []
    for label, ev in evaluations.items():
        cells = "".join(f"<td>{ev.metrics[k]:.4f}</td>" if k in ev.metrics else "<td>–</td>" for k in keys)
        rows.append(f"<tr><th>{html.escape(label)}</th>{cells}<td>{html.escape(ev.alignment)}</td></tr>")
    header = "".join(f"<th>{html.escape(k)}</th>" for k in keys)
    main = next(iter(results.values()))
    moved = {label: aligned(res, capture)[0] for label, res in results.items()}
    plot_root_trajectory(moved, capture, out_dir / "root_trajectory.png")
    plot_error_per_frame(evaluations, main, out_dir / "error_per_frame.png")
    cameras = ""
    if any(res.cameras for res in results.values()):
        plot_camera_trajectories(moved, capture, out_dir / "camera_trajectories.png")
        cameras = "<h2>Camera trajectories (after alignment)</h2>" + embedded_image(out_dir / "camera_trajectories.png", "estimated and true camera trajectories", out_dir)

    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;margin:2em}} table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:4px 8px;text-align:right}}</style></head><body>
<h1>{html.escape(title)}</h1>
<p>Capture <code>{html.escape(capture.name)}</code>: {len(capture.cameras)} cameras,
{len(main.timestamps)} body states. Lengths in metres, angles in radians.</p>
<table><tr><th>variant</th>{header}<th>alignment</th></tr>
{"".join(rows)}
</table>
<h2>Root trajectory</h2>{embedded_image(out_dir / "root_trajectory.png", "root trajectory per axis", out_dir)}
<h2>Error per frame</h2>{embedded_image(out_dir / "error_per_frame.png", "MPJPE per frame with detections", out_dir)}
{cameras}
{extra}
</body></html>
"""
    path = out_dir / "report.html"
    path.write_text(page, encoding="utf-8")
    return path
