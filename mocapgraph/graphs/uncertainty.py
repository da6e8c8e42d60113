"""Covariances of a solved body graph, in the units a user reads: joints in metres², root and
cameras in their Pose3 tangent (rotation first, radians then metres)."""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from scipy import sparse
from scipy.sparse.linalg import splu

from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import skew
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.factors.keys import pose_key, root_key, shape_key


def joint_covariances(
    body: BodyModel, marginals: gtsam.Marginals, roots: np.ndarray, poses: np.ndarray, shape: np.ndarray, states=None, fk=None
) -> tuple[np.ndarray, np.ndarray]:
    """Per body state: joints ``(N, 22, 3, 3)`` (m²) pushed through the forward-kinematics
    Jacobian, and root ``(N, 6, 6)`` (Pose3 tangent, rotation first); NaN for states not in
    ``states`` (default: all).

    ``marginals`` of the solved graph; ``roots (N, 4, 4)``, ``poses (N, 21, 3)``, ``shape (S,)``
    the solution. The joint marginal of (root, pose) of each state is exact; the shape, shared by
    all states, is added as an independent term. Its cross-covariance with one state is
    neglected: querying it costs about 100x more (0.4 s against 4 ms per state, measured), and
    the shape is pinned by the whole sequence. ``fk``: the states' forward kinematics with
    Jacobians, if already computed.
    """
    n = len(roots)
    S = body.shape_dim
    shape_cov = marginals.marginalCovariance(shape_key())
    joints_cov = np.full((n, NUM_JOINTS, 3, 3), np.nan)
    root_cov = np.full((n, 6, 6), np.nan)
    fk = fk if fk is not None else body.forward(shape, roots, poses.reshape(n, NUM_JOINTS - 1, 3), jacobians=True)
    diag = np.arange(NUM_JOINTS)
    for i in range(n) if states is None else states:
        keys = [root_key(i), pose_key(i)]
        joint = marginals.jointMarginalCovariance(gtsam.KeyVector(keys))
        cov = np.zeros((69 + S, 69 + S))
        cov[:69, :69] = np.block([[joint.at(a, b) for b in keys] for a in keys])
        cov[69:, 69:] = shape_cov
        J = fk.d_joints[i].reshape(NUM_JOINTS * 3, 69 + S)
        joints_cov[i] = (J @ cov @ J.T).reshape(NUM_JOINTS, 3, NUM_JOINTS, 3)[diag, :, diag, :]
        root_cov[i] = cov[:6, :6]
    return joints_cov, root_cov


# -- calibration: variance components and the evaluation's datum ----------------------------------
#
# Marginals of the solved graph are honest only if every factor's noise model is (the detector's
# σ, the priors' σ) and only in the gauge the graph fixes. Neither holds: the keypoints' definitions
# differ from the body's joints, the motion prior misfits motion it never saw, and the world frame
# is pinned to the first body state while any comparison with another frame (``eval``'s similarity
# over all joints) removes a similarity. The corrections below (docs/uncertainty.md) use the
# solved graph alone: each factor group's variance measured from its residuals, and the
# covariances taken into the datum of that similarity.

VARIANCE_SAMPLES = 32
"""Samples of the posterior for the groups' redundancies: the trace a group spends on the solution,
``tr(A_g Σ A_gᵀ)``, to about ``±√(2·spent/32)`` (the reprojection factors: about ±5 of their
thousands of redundant rows)."""
VARIANCE_ITERATIONS = 1
"""Variance-component iterations (each a sparse factorisation and the samples' solves): one step
from unit factors; only groups whose variance exceeds their noise models' are changed (below)."""
MIN_REDUNDANCY = 5.0
"""A group with less redundancy than this says nothing about its own variance: kept at 1."""
MAX_REDUNDANCY_ERROR = 0.1
"""A group whose redundancy the samples measure to worse than this (relative standard error) is
kept at 1. A prior spends most of its rows on the solution: its redundancy is a small difference of
large numbers, and from a few samples it could come out near 0 (a motion prior's factor 256 on one
take, from 16 samples)."""
_CHI2_2_MEDIAN = 2.0 * np.log(2.0)


@dataclass
class LinearSystem:
    """A graph linearised at its solution as one whitened sparse system ``A δ = b``.

    ``A (m, n)`` CSR, ``b (m,)``; ``columns[key] = (offset, dim)`` of each variable's tangent
    (GTSAM's local coordinates); ``rows[f]`` the rows of the graph's factor ``f`` (an empty slice
    for a factor with no rows)."""

    A: sparse.csr_matrix
    b: np.ndarray
    columns: dict[int, tuple[int, int]]
    rows: list[slice]

    @property
    def n(self) -> int:
        return self.A.shape[1]

    def cols(self, key: int) -> np.ndarray:
        offset, dim = self.columns[key]
        return np.arange(offset, offset + dim)


def linear_system(linear: gtsam.GaussianFactorGraph, values: gtsam.Values) -> LinearSystem:
    """``linear`` (``graph.linearize(values)``, robust kernels' weights at the solution in it) as
    a :class:`LinearSystem`, columns in sorted key order."""
    dims = values.dims()
    columns, offset = {}, 0
    for key in sorted(dims):
        columns[key] = (offset, dims[key])
        offset += dims[key]
    data, ri, ci, bs, rows, m = [], [], [], [], [], 0
    for f in range(linear.size()):
        factor = linear.at(f)
        if factor is None:
            rows.append(slice(m, m))
            continue
        A, b = factor.jacobian()
        cols = np.concatenate([np.arange(columns[k][0], columns[k][0] + columns[k][1]) for k in factor.keys()])
        r, c = np.nonzero(A)
        data.append(A[r, c])
        ri.append(r + m)
        ci.append(cols[c])
        bs.append(b)
        rows.append(slice(m, m + len(b)))
        m += len(b)
    A = sparse.csr_matrix((np.concatenate(data), (np.concatenate(ri), np.concatenate(ci))), shape=(m, offset))
    return LinearSystem(A, np.concatenate(bs), columns, rows)


def factor_groups(graph: gtsam.NonlinearFactorGraph) -> dict[str, np.ndarray]:
    """The graph's factors grouped by the kinds of variable they touch (their keys' symbols,
    sorted: ``"bcqr"`` = shape, camera, pose, root: the reprojection factors), each group's factor
    indices. Factors of one kind share one noise model's family, so one variance factor each."""
    groups: dict[str, list[int]] = {}
    for f in range(graph.size()):
        factor = graph.at(f)
        if factor is None:
            continue
        kinds = "".join(sorted({chr(gtsam.Symbol(k).chr()) for k in factor.keys()}))
        groups.setdefault(kinds, []).append(f)
    return {kinds: np.array(fs) for kinds, fs in groups.items()}


def _group_rows(system: LinearSystem, factors: np.ndarray, pairs: bool = False) -> np.ndarray:
    """The rows of ``factors``; with ``pairs``, each factor's whole (x, y) pairs only (a
    reprojection factor's trailing row is its relabellings' cost, no measurement)."""
    spans = [(system.rows[f].start, system.rows[f].stop) for f in factors]
    return np.concatenate([np.arange(a, a + 2 * ((b - a) // 2) if pairs else b) for a, b in spans] or [np.zeros(0, int)])


def _information(system: LinearSystem, row_scale: np.ndarray):
    A = sparse.diags(row_scale) @ system.A
    # The information matrix is symmetric positive definite: no pivoting, a symmetric ordering.
    # SuperLU's default (COLAMD, partial pivoting) filled it ~7x more and took ~10x longer
    # (phones 3 s, 9312 columns: 3.7 s -> 0.4 s, solutions equal to 5e-9 relative).
    return A, splu((A.T @ A).tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})


def variance_factors(
    system: LinearSystem, groups: dict[str, np.ndarray], robust: set[str] = frozenset(), seed: int = 0,
    samples: int = VARIANCE_SAMPLES, iterations: int = VARIANCE_ITERATIONS, floor: float = 1.0,
) -> dict[str, float]:  # fmt: skip
    """Per factor group, its variance factor ``s²`` (by how much its noise models' variances
    understate what the solution left): iterated variance-component estimation (Förstner 1979,
    Koch's "Parameter estimation"), ``s²_g = χ²_g / r_g`` with ``χ²_g`` the group's squared
    whitened residuals and ``r_g = m_g − tr(A_g Σ A_gᵀ)`` its redundancy (its rows less what the
    solution spent on them), ``Σ`` the posterior at the current weights; the trace from
    ``samples`` draws of ``N(0, Σ)`` (``Σ Aᵀε``, ``ε`` white: one sparse factorisation each
    iteration, then triangular solves), ``seed`` fixing them.

    A group in ``robust`` (per-keypoint Geman-McClure inside, two rows per keypoint) is measured
    by the median of its keypoints' squared residuals instead of their sum: a detector's fault
    the kernel already set aside (its residual saturates at the kernel's scale) would otherwise
    inflate every good keypoint's variance; a trailing odd row of one of its factors (a
    relabelling's cost) is no measurement and left out. A group with less than
    :data:`MIN_REDUNDANCY`, or whose redundancy the samples do not measure to within
    :data:`MAX_REDUNDANCY_ERROR`, keeps 1. No group goes below ``floor``: by default a group is never
    trusted beyond its noise models. The priors' residuals are the motion itself, not draws of
    their noise: a smooth take would otherwise tighten the smoothness terms and with them every
    marginal (measured on a walk: every prior group 0.05-0.5, joints' coverage 0.73 → 0.35).
    """
    rng = np.random.default_rng(seed)
    rows = {g: _group_rows(system, fs, g in robust) for g, fs in groups.items()}
    s2 = {g: 1.0 for g in groups}
    for _ in range(iterations):
        scale = np.ones(system.A.shape[0])
        for g, r in rows.items():
            scale[r] = 1.0 / np.sqrt(s2[g])
        A, lu = _information(system, scale)
        noise = rng.standard_normal((A.shape[0], samples))
        draws = np.column_stack([lu.solve(np.asarray(A.T @ noise[:, k])) for k in range(samples)])  # one at a time: SuperLU is slower on blocks
        spent = np.asarray(A @ draws) ** 2
        out = {}
        for g, r in rows.items():
            per_draw = spent[r].sum(0)
            redundancy = len(r) - per_draw.mean()
            b = system.b[r] * scale[r]
            if redundancy < MIN_REDUNDANCY or per_draw.std() / np.sqrt(samples) > MAX_REDUNDANCY_ERROR * redundancy:
                out[g] = 1.0
            elif g in robust:
                per_keypoint = (b.reshape(-1, 2) ** 2).sum(1)
                out[g] = max(floor, s2[g] * len(r) * np.median(per_keypoint) / _CHI2_2_MEDIAN / redundancy)
            else:
                out[g] = max(floor, s2[g] * float(b @ b) / redundancy)
        s2 = out
    return s2


def window_misfit(system: LinearSystem, graph: gtsam.NonlinearFactorGraph, latent_symbol: str, windows: list[int], window: int, num_states: int) -> np.ndarray:
    """``(num_states,)``: per body state, the motion prior's own misfit at the solution, ``χ²/m``
    (squared whitened residuals over rows, noise models as stated) of the factors on the latent
    (``latent_symbol``, index ``w``) of each window ``w`` starting at ``windows[w]`` and
    ``window`` states long (the decoder's fit and the latent's prior); a state in several
    windows takes the largest, a state in none 0. What the prior does not know of a motion shows
    here: the walks of the training takes stay near 1, a pirouette's fast turn goes far above."""
    chi2 = np.zeros(len(windows))
    rows = np.zeros(len(windows))
    code = ord(latent_symbol)
    for f in range(graph.size()):
        factor = graph.at(f)
        if factor is None:
            continue
        latents = [gtsam.Symbol(k).index() for k in factor.keys() if gtsam.Symbol(k).chr() == code]
        r = system.rows[f]
        for w in latents:
            chi2[w] += float(system.b[r] @ system.b[r])
            rows[w] += r.stop - r.start
    out = np.zeros(num_states)
    for w, i0 in enumerate(windows):
        if rows[w]:
            out[i0 : i0 + window] = np.maximum(out[i0 : i0 + window], chi2[w] / rows[w])
    return out


def scaled_linear_graph(linear: gtsam.GaussianFactorGraph, values: gtsam.Values, sigma_scale: np.ndarray) -> gtsam.GaussianFactorGraph:
    """``linear`` with factor ``f``'s rows divided by ``sigma_scale[f]`` (its noise models' σ
    times that): each factor re-linearised through a :class:`gtsam.CustomFactor` whose noise model
    carries the scale, so ``gtsam.Marginals`` runs on it as on any linearised graph."""
    out = gtsam.GaussianFactorGraph()
    dims = values.dims()
    for f in range(linear.size()):
        factor = linear.at(f)
        if factor is None:
            continue
        if sigma_scale[f] == 1.0:
            out.push_back(factor)
            continue
        A, b = factor.jacobian()
        keys = list(factor.keys())
        blocks = np.split(A, np.cumsum([dims[k] for k in keys])[:-1], axis=1)

        def error(_, __, H, blocks=blocks, b=b):
            if H is not None:
                for i, block in enumerate(blocks):
                    H[i] = block
            return -b

        custom = gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(len(b), float(sigma_scale[f])), gtsam.KeyVector(keys), error)
        out.push_back(custom.linearize(values))
    return out


class SimilarityDatum:
    """Baarda's S-transformation onto the datum of a similarity fitted over a set of points.

    Args:
        lu: the factorised information ``AᵀA`` of the system the covariances come from.
        points: ``(P, 3)`` world, the estimate's points that define the datum (every joint of
            every state: what ``eval`` aligns by).
        point_rows: ``(3P, n)`` their Jacobian in the system's tangent.

    :meth:`apply` gives the covariance of a quantity with Jacobian ``rows`` whose change under a
    small similarity (translation, rotation, log-scale about the points' centroid) is ``G``,
    once the similarity that best maps the estimate's points onto any other frame's is removed:
    to first order the error left is ``(I − G (G_Jᵀ G_J)⁻¹ G_Jᵀ L_J) δ``, what a comparison after
    that alignment sees. It costs 7 solves with the factorisation; each block then a few small
    products.
    """

    def __init__(self, lu, points: np.ndarray, point_rows: sparse.spmatrix):
        self.centroid = points.mean(0)
        G_J = similarity_jacobian(points - self.centroid)
        fit = np.linalg.solve(G_J.T @ G_J, G_J.T)  # (7, 3P): the fitted similarity per unit of the points' errors
        W = np.asarray((point_rows.T @ fit.T).T)  # (7, n)
        self.Z = lu.solve(np.ascontiguousarray(W.T))  # (n, 7) Σ Wᵀ
        self.WZ = W @ self.Z  # (7, 7) the fitted similarity's covariance
        self.points_Z = np.asarray(point_rows @ self.Z)  # (3P, 7): the datum's own points' rows_Z

    def apply(self, cov: np.ndarray, rows_Z: np.ndarray, G: np.ndarray) -> np.ndarray:
        """``cov (..., d, d)``, ``rows_Z (..., d, 7)`` = ``rows @ Z``, ``G (..., d, 7)`` → ``(..., d, d)``."""
        cross = rows_Z @ np.swapaxes(G, -1, -2)
        return cov - cross - np.swapaxes(cross, -1, -2) + G @ self.WZ @ np.swapaxes(G, -1, -2)


def similarity_jacobian(centred: np.ndarray) -> np.ndarray:
    """``(3P, 7)``: how points ``centred (P, 3)`` (about the similarity's centre) move under a
    small similarity ``[translation (3), rotation (3), log-scale (1)]``: ``t + ω × p + s p``."""
    P = len(centred)
    G = np.zeros((P, 3, 7))
    G[:, :, :3] = np.eye(3)
    G[:, :, 3:6] = -skew(centred)
    G[:, :, 6] = centred
    return G.reshape(3 * P, 7)


def pose_similarity_jacobian(pose: np.ndarray, centroid: np.ndarray) -> np.ndarray:
    """``(6, 7)``: how the tangent (rotation first, body frame) of ``pose (4, 4)`` world_T_x moves
    under the similarity of :func:`similarity_jacobian` about ``centroid``."""
    R, t = pose[:3, :3], pose[:3, 3]
    G = np.zeros((6, 7))
    G[:3, 3:6] = R.T
    G[3:, :] = R.T @ similarity_jacobian((t - centroid)[None])
    return G


@dataclass
class Calibration:
    """A solved graph's variance factors applied: ``linear`` (the graph linearised at the
    solution, each group's rows divided by ``√s²``) for ``gtsam.Marginals``, the same as one
    sparse ``system`` with its information factorised (``lu``), and ``factors`` the ``s²`` per
    group (:func:`factor_groups`)."""

    linear: gtsam.GaussianFactorGraph
    system: LinearSystem
    lu: object
    factors: dict[str, float]


def calibrated(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, robust: set[str], seed: int = 0) -> Calibration:
    """:func:`variance_factors` of ``graph``'s groups at ``values`` (the solution), ``robust``
    naming the groups with a per-keypoint kernel inside, applied to its linearisation."""
    linear = graph.linearize(values)
    system = linear_system(linear, values)
    groups = factor_groups(graph)
    factors = variance_factors(system, groups, robust & set(groups), seed)
    sigma = np.ones(graph.size())
    for g, fs in groups.items():
        sigma[fs] = np.sqrt(factors[g])
    row_scale = np.ones(system.A.shape[0])
    for f, rows in enumerate(system.rows):
        row_scale[rows] = 1.0 / sigma[f]
    _, lu = _information(system, row_scale)
    return Calibration(scaled_linear_graph(linear, values, sigma), system, lu, factors)


def joints_datum(calibration: Calibration, fk, roots_keys: list[int], pose_keys: list[int], shape: int | None) -> SimilarityDatum:
    """The datum of a similarity over every joint of every state: ``fk`` the states' forward
    kinematics with Jacobians (``joints (N, 22, 3)``, ``d_joints (N, 22, 3, 69 + S)``), their
    root and pose keys, the shape's key (None: a constant shape, its columns not variables)."""
    system = calibration.system
    n = len(roots_keys)
    S = fk.d_joints.shape[-1] - 69
    d = fk.d_joints.reshape(n, 3 * NUM_JOINTS, 69 + S)
    if shape is None:
        d = d[..., :69]
    ri, ci, data = [], [], []
    for i in range(n):
        cols = np.concatenate([system.cols(roots_keys[i]), system.cols(pose_keys[i])] + ([system.cols(shape)] if shape is not None else []))
        r, c = np.nonzero(d[i])
        ri.append(r + 3 * NUM_JOINTS * i)
        ci.append(cols[c])
        data.append(d[i][r, c])
    rows = sparse.csr_matrix((np.concatenate(data), (np.concatenate(ri), np.concatenate(ci))), shape=(3 * NUM_JOINTS * n, system.n))
    return SimilarityDatum(calibration.lu, fk.joints.reshape(-1, 3), rows)


def with_shape_cross(calibration: Calibration, fk, root_keys: list[int], pose_keys: list[int], shape: int, joints_cov: np.ndarray) -> np.ndarray:
    """``joints_cov (N, 22, 3, 3)`` of :func:`joint_covariances` (the shape an independent term)
    with each state's cross-covariance with the shape added: ``S`` solves with the factorisation
    give the shape's whole column block. The datum needs it: the shape is mostly the scene's
    scale, which the similarity removes, so the neglected term no longer stays small beside what
    is left (it made joints' covariances indefinite, measured on rich)."""
    system = calibration.system
    S = system.columns[shape][1]
    unit = np.zeros((system.n, S))
    unit[system.cols(shape), np.arange(S)] = 1.0
    column = calibration.lu.solve(unit)  # Σ[:, shape]
    out = joints_cov.copy()
    d = fk.d_joints.reshape(len(root_keys), NUM_JOINTS, 3, -1)
    for i, (r, q) in enumerate(zip(root_keys, pose_keys)):
        cross = column[np.concatenate([system.cols(r), system.cols(q)])]  # (69, S)
        term = d[i, ..., :69] @ cross @ np.swapaxes(d[i, ..., 69:], -1, -2)  # (22, 3, 3)
        out[i] += term + np.swapaxes(term, -1, -2)
    return out


def joints_in_datum(datum: SimilarityDatum, joints: np.ndarray, joints_cov: np.ndarray) -> np.ndarray:
    """``joints_cov (N, 22, 3, 3)`` of ``joints (N, 22, 3)`` in ``datum`` (built by :func:`joints_datum` on them)."""
    G = similarity_jacobian((joints - datum.centroid).reshape(-1, 3)).reshape(joints.shape[:2] + (3, 7))
    return datum.apply(joints_cov, datum.points_Z.reshape(joints.shape[:2] + (3, 7)), G)


def poses_in_datum(datum: SimilarityDatum, calibration: Calibration, keys: list[int], poses: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """``covs (M, 6, 6)`` of the Pose3 variables ``keys`` at ``poses (M, 4, 4)`` (world_T_x) in ``datum``."""
    rows_Z = np.stack([datum.Z[calibration.system.cols(k)] for k in keys])
    G = np.stack([pose_similarity_jacobian(T, datum.centroid) for T in poses])
    return datum.apply(covs, rows_Z, G)
