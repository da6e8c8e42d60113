"""How well a solved body explains each keypoint, and the keypoint-definition offsets it shows.

With the cameras solved, the views of each body state triangulate each detected point; compared
in the frame of the segment carrying it (:mod:`mocapgraph.body.keypoint_offsets`) with the body's
own point, frame after frame, the difference is where the detector format puts that point. Its
median over the capture, pooled over left and right (mirrored), shrunk towards zero (or a prior
fitted on real footage, :mod:`mocapgraph.body.definition_priors`) when few frames saw it and dropped when larger than any format's measured offset, is the format's offset
estimate: :func:`estimate_offsets`. A pipeline solves again with it (:class:`~mocapgraph.graphs.body_graph.BodyGraph`'s
``keypoint_offsets``), a step of a joint estimation of body and offsets by alternation.

:func:`reprojection_medians` reports a fit's pixel errors per camera and per keypoint, and
:func:`outlier_views` finds the views it explains far worse than the rest.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import spsolve

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.keypoint_offsets import MIRROR, carrier_joints, drifted, with_offsets
from mocapgraph.body.model import BodyModel
from mocapgraph.body.native import forward_kinematics
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES, left_right_pairs
from mocapgraph.data_tools.geometry.triangulation import triangulate_points, triangulate_ransac
from mocapgraph.graphs.state_model import Estimate, StateModel

PRIOR_FRAMES = 30.0
"""An offset seen in ``n`` frames is shrunk by ``n / (n + PRIOR_FRAMES)`` towards zero (or its prior)."""
MAX_OFFSET_M = 0.08
"""Offsets larger than this are not a definition but a failure (another person, a bad solve): dropped."""


def _names(fmt: str) -> tuple[str, ...]:
    return BODY_KEYPOINT_NAMES if fmt == "body" else get_format(fmt).names


def _intrinsics(model: StateModel, estimate: Estimate, c: int) -> np.ndarray:
    K = model.cameras[c].K.copy()
    K[:2, :2] *= np.exp(estimate.focal_log[c])
    return K


def _posed(body: BodyModel, estimate: Estimate, fmt: str, offsets=None, drift=None):
    """The format's table (with ``offsets``) and its forward kinematics at ``estimate``, the
    keypoints moved by the per-state ``drift`` where given (:func:`estimate_drift`)."""
    table = body.table(estimate.shape, keypoints=fmt)
    if offsets is not None:
        table = with_offsets(table, offsets)
    fk = forward_kinematics(table, estimate.roots, estimate.poses)
    return table, fk if drift is None else replace(fk, keypoints=drifted(fk.keypoints, fk.rotations, table, drift))


@dataclass
class OffsetFit:
    """Keypoint-definition offsets of one format estimated from a solve.

    Attributes:
        fmt: the format; offsets: ``(K, 3)`` metres in the carrier frames (zero where not estimated).
        frames: ``(K,)`` how many state-frames triangulated each point (pooled over its pair).
        dropped: names of the points whose estimate exceeded :data:`MAX_OFFSET_M`.
    """

    fmt: str
    offsets: np.ndarray
    frames: np.ndarray
    dropped: list[str]

    def as_table(self) -> dict[str, list[float]]:
        """``{point: [x, y, z] metres}`` of the non-zero offsets, rounded to 0.1 mm."""
        names, rounded = _names(self.fmt), np.round(self.offsets, 4)
        return {names[k]: [float(v) for v in rounded[k]] for k in np.flatnonzero(np.any(rounded != 0, axis=1))}


def offsets_from_table(fmt: str, table: dict[str, list[float]]) -> np.ndarray:
    """``(K, 3)`` metres: the offsets of format ``fmt`` from :meth:`OffsetFit.as_table`'s
    ``{point: [x, y, z]}`` (a result's ``keypoint_offsets_m[fmt]``; unnamed points zero)."""
    names = _names(fmt)
    out = np.zeros((len(names), 3))
    for name, value in table.items():
        out[names.index(name)] = value
    return out


def _samples(body: BodyModel, model: StateModel, estimate: Estimate, fmt: str, offsets=None, threshold_px: float | None = None):
    """The format's table and ``(N, K, 3)`` per state, each point triangulated from the solved
    cameras minus the body's (with ``offsets``), in its carrier's frame (metres; NaN where fewer
    than two views see it or the body has no such point). Triangulated by weighted DLT, or with
    ``threshold_px`` by RANSAC over the views (a detector's gross miss in one view left out)."""
    table, fk = _posed(body, estimate, fmt, offsets)
    N, K = fk.keypoints.shape[:2]
    carrier = carrier_joints(table)
    samples = np.full((N, K, 3), np.nan)
    for i, obs in enumerate(model.states):
        views = [o for o in obs if o.fmt == fmt and o.fraction == 0.0]
        if len(views) < 2:
            continue
        P = np.stack([_intrinsics(model, estimate, o.camera) @ np.linalg.inv(estimate.cameras[o.camera][o.frame])[:3] for o in views])
        x, w = np.stack([o.observed for o in views]), np.stack([o.weights for o in views])
        X = triangulate_points(P, x, w) if threshold_px is None else triangulate_ransac(P, x, w, threshold_px=threshold_px)[0]
        G = fk.rotations[i, carrier]  # (K, 3, 3) world-aligned carrier frames
        samples[i] = np.einsum("kyx,ky->kx", G, X - fk.keypoints[i])
    samples[:, ~table.mapped] = np.nan
    return table, samples


def estimate_offsets(
    body: BodyModel, model: StateModel, estimate: Estimate, fmt: str, prior: np.ndarray | None = None, hold_root_shift: bool = False
) -> OffsetFit:
    """The offsets of format ``fmt``'s points from the body's, at the solve ``estimate`` of ``model``
    (its observations as the solve labelled them): see the module docstring. With a ``prior``
    ``(K, 3)`` (:func:`~mocapgraph.body.definition_priors.prior_offsets`) each median is shrunk
    towards it instead of zero, and a point never seen or dropped keeps it.

    With ``hold_root_shift``, the points the root carries (the hips; a mid-hip) keep the prior's
    up and forward parts, the parts a left/right pair shares: to first order they are the root
    moved in its own frame, the spine and legs turned back, which the body's per-state root takes
    up as readily, so their measure is the pose priors' lean, not the detector's definition (on
    ``rich``, 10 s: the hips 3 mm forward without any offset, 10 mm off the simulated ones with
    the real fits, the pelvis 14 mm behind the truth). Only their lateral part, the pair's
    width, is measured."""
    table, samples = _samples(body, model, estimate, fmt)
    K = samples.shape[1]
    names = _names(fmt)
    offsets, frames = np.zeros((K, 3)), np.zeros(K, dtype=int)
    groups = [(i, j) for i, j in left_right_pairs(list(names))]
    paired = {k for pair in groups for k in pair}
    groups += [(k, None) for k in range(K) if k not in paired]
    prior = np.zeros((K, 3)) if prior is None else np.asarray(prior, dtype=float)
    offsets[table.mapped] = prior[table.mapped]
    carriers = carrier_joints(table)
    dropped = []
    for i, j in groups:
        pooled = samples[:, i] if j is None else np.concatenate([samples[:, i], MIRROR * samples[:, j]])
        pooled = pooled[np.isfinite(pooled).all(axis=1)]
        if not len(pooled):
            continue
        median = prior[i] + (np.median(pooled, axis=0) - prior[i]) * len(pooled) / (len(pooled) + PRIOR_FRAMES)
        if j is None:
            median[0] = 0.0  # a midline point has no side to be off towards
        if hold_root_shift and carriers[i] == 0:
            median[1:] = prior[i, 1:]
        members = [i] if j is None else [i, j]
        frames[members] = len(pooled)
        if np.linalg.norm(median) > MAX_OFFSET_M:
            dropped += [names[k] for k in members]
            continue
        offsets[i] = median
        if j is not None:
            offsets[j] = MIRROR * median
    return OffsetFit(fmt, offsets, frames, dropped)


DRIFT_THRESHOLD_PX = 15.0
"""RANSAC threshold of the per-state triangulation :func:`estimate_drift` measures from."""


def estimate_drift(
    body: BodyModel, model: StateModel, estimate: Estimate, fmt: str, offsets: np.ndarray | None, sigmas: tuple[float, float, float]
) -> np.ndarray:
    """``(N, K, 3)`` metres, carrier frames: how format ``fmt``'s points drift from their constant
    ``offsets`` over the states of the solve ``estimate`` (a detector's definition moves with the
    pose and the view), smoothed in time.

    Per state, each point is triangulated from the solved cameras (RANSAC,
    :data:`DRIFT_THRESHOLD_PX`) and compared with the body's (with ``offsets``) in its carrier's
    frame; per point and axis the drift ``d`` minimises ``Σ_t (d_t − s_t)²/σ_obs² + Σ_t (d_t −
    d_{t−1})²/σ_step² + Σ_t d_t²/σ_prior²`` over the samples ``s`` seen, ``sigmas = (σ_obs,
    σ_step, σ_prior)``: the step's σ keeps it slowly varying and the prior's keeps it a few
    centimetres at most, so the body stays a body. Zero where the body has no such point."""
    sigma_obs, sigma_step, sigma_prior = sigmas
    table, samples = _samples(body, model, estimate, fmt, offsets, DRIFT_THRESHOLD_PX)
    N, K = samples.shape[:2]
    seen = np.isfinite(samples).all(axis=-1)  # (N, K)
    smoothing = _drift_smoothing(N, sigma_step, sigma_prior)
    out = np.zeros((N, K, 3))
    for k in np.flatnonzero(table.mapped & seen.any(axis=0)):
        A = (smoothing + sparse.diags(seen[:, k] / sigma_obs**2)).tocsc()
        out[:, k] = spsolve(A, np.where(seen[:, k, None], samples[:, k], 0.0) / sigma_obs**2)
    return out


def _drift_smoothing(N: int, sigma_step: float, sigma_prior: float) -> sparse.csc_matrix:
    """``(N, N)`` sparse: the information of the drift's smoothing prior over ``N`` states, its steps
    (σ ``sigma_step``) and its size (σ ``sigma_prior``); tridiagonal, so a capture's drift costs
    in proportion to its length."""
    step = sparse.diags([-np.ones(N - 1), np.ones(N - 1)], [0, 1], shape=(N - 1, N))
    return (step.T @ step / sigma_step**2 + sparse.identity(N) / sigma_prior**2).tocsc()


DRIFT_GM_SIGMA_PX = 10.0
"""Geman-McClure scale (pixels) of :func:`refine_drift_in_images`: the free points' (the static
cameras' adjustment and the generic baseline use it), so a gross miss counts as little there."""
DRIFT_ITERATIONS = 6
"""Gauss-Newton steps of :func:`refine_drift_in_images` at most (it stops once a step moves no
point by more than 0.01 mm)."""


def refine_drift_in_images(
    body: BodyModel, model: StateModel, estimate: Estimate, fmt: str, offsets: np.ndarray | None, sigmas: tuple[float, float, float], drift: np.ndarray
) -> np.ndarray:
    """``(N, K, 3)`` metres, carrier frames: :func:`estimate_drift`'s ``drift`` refined against the
    detections themselves instead of against one triangulated sample per state.

    Per point, over all states at once, the drift minimises the Geman-McClure reprojection error
    (scale :data:`DRIFT_GM_SIGMA_PX`) of every view at a state, with the body's point moved by it,
    plus the same smoothing prior as :func:`estimate_drift` (``σ_step``, ``σ_prior``), by
    iteratively reweighted Gauss-Newton. A view's pixel σ is the sample's ``σ_obs`` seen from that
    camera, ``σ_obs · f / z · √n`` (``z`` its depth, ``n`` the views of the point at that state):
    the same model as the samples', in pixels. What the sample's DLT cannot do: weigh each view by
    its own reprojection, and leave a view's gross miss aside without losing the state. The body
    and cameras stay as solved. Points the body has no counterpart for stay at zero."""
    sigma_obs, sigma_step, sigma_prior = sigmas
    table, fk = _posed(body, estimate, fmt, offsets)
    N, K = fk.keypoints.shape[:2]
    carrier = carrier_joints(table)
    prior = sparse.kron(_drift_smoothing(N, sigma_step, sigma_prior), sparse.identity(3), format="csc")  # (3N, 3N), per axis
    rows = [(i, o) for i, obs in enumerate(model.states) for o in obs if o.fmt == fmt and o.fraction == 0.0]
    out = np.array(drift, dtype=float, copy=True)
    if not rows:
        return out
    state = np.array([i for i, _ in rows])
    camera_T_world = np.stack([np.linalg.inv(estimate.cameras[o.camera][o.frame]) for _, o in rows])
    intrinsics = np.stack([_intrinsics(model, estimate, o.camera) for _, o in rows])
    observed = np.stack([o.observed for _, o in rows])  # (M, K, 2)
    weights = np.stack([o.weights for _, o in rows])  # (M, K)
    for k in np.flatnonzero(table.mapped):
        use = (weights[:, k] > 0) & np.isfinite(observed[:, k]).all(axis=1)
        if not use.any():
            continue
        idx, R, t, Kc, x = state[use], camera_T_world[use, :3, :3], camera_T_world[use, :3, 3], intrinsics[use], observed[use, k]
        G = fk.rotations[idx, carrier[k]]  # (M, 3, 3) carrier frames in the world
        views = np.bincount(idx, minlength=N)[idx]
        focal = Kc[:, [0, 1], [0, 1]]  # (M, 2)
        base = fk.keypoints[idx, k]

        def pixels(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            """Camera-frame points (M, 3), whether ahead of the camera, pixel residuals (M, 2)."""
            p = np.einsum("mab,mb->ma", R, base + np.einsum("mab,mb->ma", G, d[idx])) + t
            ahead = p[:, 2] > 0
            z = np.where(ahead, p[:, 2], 1.0)
            return p, ahead, p[:, :2] / z[:, None] * focal + Kc[:, :2, 2] - x

        d = out[:, k].copy()
        _, ahead, residual = pixels(d)
        before = np.median(np.linalg.norm(residual[ahead], axis=1)) if ahead.any() else np.inf
        for _ in range(DRIFT_ITERATIONS):
            p, ahead, residual = pixels(d)
            z = np.where(ahead, p[:, 2], 1.0)
            dp = np.zeros((len(z), 2, 3))  # d(pixel)/d(camera point)
            dp[:, [0, 1], [0, 1]] = focal / z[:, None]
            dp[:, :, 2] = -focal * p[:, :2] / z[:, None] ** 2
            J = dp @ R @ G  # (M, 2, 3) d(pixel)/d(drift)
            sigma_px = sigma_obs * focal[:, 0] / z * np.sqrt(views)
            robust = (DRIFT_GM_SIGMA_PX**2 / (DRIFT_GM_SIGMA_PX**2 + (residual**2).sum(axis=1))) ** 2  # Geman-McClure's IRLS weight
            information = np.where(ahead, robust / sigma_px**2, 0.0)
            blocks, gradients = np.zeros((N, 3, 3)), prior @ d.reshape(-1)
            np.add.at(blocks, idx, np.einsum("mia,mib,m->mab", J, J, information))
            np.add.at(gradients.reshape(N, 3), idx, np.einsum("mia,mi,m->ma", J, residual, information))
            H = prior + sparse.bsr_matrix((blocks, np.arange(N), np.arange(N + 1)), shape=(3 * N, 3 * N))  # the views' blocks on the diagonal
            change = spsolve(H.tocsc(), -gradients).reshape(N, 3)
            d += change
            if np.abs(change).max() < 1e-5:
                break
        _, ahead, residual = pixels(d)
        # The kernel redescends: where most views sit beyond it (a solve that failed), the
        # refinement gives them up and the point's median gets worse; such a point keeps its samples'.
        if ahead.any() and np.median(np.linalg.norm(residual[ahead], axis=1)) <= before:
            out[:, k] = d
    return out


def _observation_errors(body: BodyModel, model: StateModel, estimate: Estimate, offsets: dict[str, np.ndarray] | None = None, drift: dict[str, np.ndarray] | None = None):
    """Per observation at a state (not interpolated): ``(state, observation, (K,) pixel errors,
    (K,) usable)``, the body posed with the formats' ``offsets`` (and per-state ``drift``); a
    point the body has no counterpart for (unmapped, e.g. BlazePose's fingers) is never usable."""
    posed = {fmt: _posed(body, estimate, fmt, (offsets or {}).get(fmt), (drift or {}).get(fmt)) for fmt in model.formats}
    mapped = {fmt: table.mapped for fmt, (table, _) in posed.items()}
    posed = {fmt: fk.keypoints for fmt, (_, fk) in posed.items()}
    for i, obs in enumerate(model.states):
        for o in obs:
            if o.fraction != 0.0:
                continue
            camera = np.linalg.inv(estimate.cameras[o.camera][o.frame])
            p = posed[o.fmt][i] @ camera[:3, :3].T + camera[:3, 3]
            with np.errstate(divide="ignore", invalid="ignore"):
                uv = p[:, :2] / p[:, 2:] @ _intrinsics(model, estimate, o.camera)[:2, :2].T + model.cameras[o.camera].K[:2, 2]
            error = np.linalg.norm(uv - o.observed, axis=1)
            yield i, o, error, (o.weights > 0) & np.isfinite(error) & (p[:, 2] > 0) & mapped[o.fmt]


def reprojection_medians(
    body: BodyModel, model: StateModel, estimate: Estimate, offsets: dict[str, np.ndarray] | None = None, drift: dict[str, np.ndarray] | None = None
) -> dict:
    """Median pixel distance between each observation and the solved body's projection (with
    the formats' ``offsets`` and per-state ``drift``): ``{"camera": {name: px}, "keypoint": {format: {point: px}}, "all": px}``,
    over the observations at a state (not interpolated) with confidence > 0."""
    per_camera: dict[int, list] = {}
    per_point: dict[str, dict[int, list]] = {}
    for _, o, error, use in _observation_errors(body, model, estimate, offsets, drift):
        per_camera.setdefault(o.camera, []).extend(error[use])
        points = per_point.setdefault(o.fmt, {})
        for k in np.flatnonzero(use):
            points.setdefault(int(k), []).append(error[k])
    every = [e for errors in per_camera.values() for e in errors]
    return {
        "camera": {model.cameras[c].name: round(float(np.median(e)), 2) for c, e in sorted(per_camera.items())},
        "keypoint": {fmt: {_names(fmt)[k]: round(float(np.median(e)), 2) for k, e in sorted(pts.items())} for fmt, pts in per_point.items()},
        "all": round(float(np.median(every)), 2) if every else float("nan"),
    }


OUTLIER_FACTOR = 4.0
"""A view is an outlier when its median pixel error exceeds this many times the median of all views…"""
OUTLIER_FLOOR_PX = 25.0
"""…and this many pixels: a detector that followed someone else, or lost the person, for a frame."""


def outlier_views(body: BodyModel, model: StateModel, estimate: Estimate, offsets: dict[str, np.ndarray] | None = None) -> dict[int, np.ndarray]:
    """Per camera, the frames whose observation the solved body explains far worse than the others
    (median pixel error above :data:`OUTLIER_FACTOR` times the median view's and
    :data:`OUTLIER_FLOOR_PX`): whole views to leave out of a second solve."""
    views = [(o.camera, o.frame, float(np.median(error[use]))) for _, o, error, use in _observation_errors(body, model, estimate, offsets) if use.any()]
    if not views:
        return {}
    limit = max(OUTLIER_FACTOR * float(np.median([e for _, _, e in views])), OUTLIER_FLOOR_PX)
    out: dict[int, list[int]] = {}
    for c, j, e in views:
        if e > limit:
            out.setdefault(c, []).append(j)
    return {c: np.array(sorted(frames)) for c, frames in out.items()}


def camera_views(body: BodyModel, model: StateModel, estimate: Estimate, c: int, offsets: dict[str, np.ndarray] | None = None):
    """Camera ``c``'s observations at its frames (one format each, at a state) against the
    solved body's keypoints there (with the formats' ``offsets``).

    Returns ``(frames (M,), points (M, N, 3) world metres, NaN where the body has no such point,
    observed (M, N, 2) undistorted pixels, weights (M, N), K (3, 3))``, ``N`` the largest format's
    size (rows padded with NaN points and zero weights)."""
    posed: dict[str, np.ndarray] = {}
    rows = []
    seen = set()
    for i, obs in enumerate(model.states):
        for o in obs:
            if o.camera != c or o.fraction != 0.0 or o.frame in seen:
                continue
            if o.fmt not in posed:
                table, fk = _posed(body, estimate, o.fmt, (offsets or {}).get(o.fmt))
                posed[o.fmt] = np.where(table.mapped[:, None], fk.keypoints, np.nan)
            seen.add(o.frame)
            rows.append((int(o.frame), posed[o.fmt][i], o.observed, o.weights))
    rows.sort(key=lambda row: row[0])
    n = max((len(r[1]) for r in rows), default=0)
    return (
        np.array([r[0] for r in rows], dtype=int), np.array([_padded(r[1], n, np.nan) for r in rows]).reshape(-1, n, 3),
        np.array([_padded(r[2], n, np.nan) for r in rows]).reshape(-1, n, 2), np.array([_padded(r[3], n, 0.0) for r in rows]).reshape(-1, n),
        _intrinsics(model, estimate, c),
    )  # fmt: skip


def _padded(a: np.ndarray, n: int, fill: float) -> np.ndarray:
    """``a`` with rows of ``fill`` appended up to ``n`` rows."""
    return np.concatenate([a, np.full((n - len(a),) + a.shape[1:], fill)]) if len(a) < n else a
