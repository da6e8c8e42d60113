"""The multi-camera reprojection factor of one body state, with per-keypoint Geman-McClure inside.

One factor covers one body state (root, joint rotations, shape) seen by C cameras at once, so
forward kinematics is shared between the cameras. Its keys are ``[root, pose, shape, *the
refined camera keys]``; a camera can instead be fixed (a constant ``world_T_camera``, no key,
no Jacobian). The state can also lie between two states of a time grid (``next_state`` and
``fraction``, :func:`mocapgraph.factors.interpolation.interpolate_root`): the keys are then ``[root, pose,
next root, next pose, shape, *cameras]``.

Residual: the native kernel's robust residual (:mod:`mocapgraph.factors.reprojection_kernel`)
divided by ``noise_px``: two rows (x, y) per usable observation (finite pixels, weight > 0),
camera-major, in keypoint order. Missing observations have no rows at all: they would only be
zero rows, and GTSAM's linear solve pays for every row (forming ``AᵀA`` costs rows × columns²,
the bulk of a solve with these factors). Per keypoint with pixel error ``e`` and weight ``w``::

    L2 (scale.sigma_px = inf):  ½ w² |e|² / noise_px²
    Geman-McClure (σ finite):   ½ w² σ²|e|² / (noise_px² (σ² + |e|²))

The factor carries a unit noise model of that dimension and whitens itself: a GTSAM robust
noise model on the whole residual vector would saturate every factor together (see the GTSAM
performance notes), so the kernel has to be per keypoint, inside.

An evaluation is one native call on the shape's prepared table (``mocapgraph._native.Body``,
built once per shape by the :class:`ShapeTableCache`): labelling choice, usable rows and focal
columns included; Python only reads the variables and slices the Jacobian per key
(``mocapgraph bench factors`` times it).

- ``noise_px``: standard deviation of a good detection, in pixels. It sets the weight of the
  reprojection terms against the priors.
- ``weights (C, K)``: per-observation multipliers of the residual, typically the detector's
  confidences in [0, 1]; the effective standard deviation is ``noise_px / w``, and 0 drops the
  observation. NaN pixels mark missing detections and are dropped whatever their weight.
- **Several detectors** (keypoint formats) on the same frames: add one factor per
  (frame group, detector), each with its detector's ``keypoint_format`` and a
  :class:`ShapeTableCache` of that format. Their costs add up, so lower each detector's
  ``weights`` (or raise its ``noise_px``) if they see the same joints and are correlated.
- **Annealing**: the factor reads ``scale.sigma_px`` (a shared :class:`RobustScale`) at every
  evaluation; change it between solver stages without rebuilding the graph.
- **Shape**: the body table depends on the shape only. A :class:`ShapeTableCache`, shared by
  all factors on the same shape key and format, rebuilds it only when the shape changes. The
  shape must stay within the body's bounds (``body.shape_bounds``): a shape outside them is a
  :class:`~mocapgraph.errors.MocapgraphError` naming the parameter, so a solver clamps the
  shape after each step or keeps it inside with :func:`~mocapgraph.factors.body_priors.shape_prior_factor`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.keypoint_offsets import carrier_joints, offset_shape_table, with_offsets
from mocapgraph.body.model import BodyModel
from mocapgraph.body.native import native_module, table_arrays
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.body.table import BodyTable
from mocapgraph.errors import MocapgraphError, as_checked_array
from mocapgraph.factors.robust import RobustScale

POSE_DIM = 3 * (NUM_JOINTS - 1)


@dataclass(frozen=True)
class _TableEntry:
    key: bytes
    table: BodyTable
    arrays: tuple[np.ndarray, ...]
    all_mapped: bool
    carriers: np.ndarray  # (K,) the joint carrying each point's offset
    native: object  # the table prepared once for the native kernels (mocapgraph._native.Body)
    mapped: np.ndarray  # (K,) float64, 1 where the body has the point


class ShapeTableCache:
    """The body table of one keypoint format for a shape vector, rebuilt only when the shape changes.

    Building a table takes about 10 ms (Anny); a factor evaluation takes tens of µs. Share one
    cache between all factors on the same shape key and keypoint format.

    Shapes are compared exactly (their float64 bytes). The cache keeps the ``size`` most recently
    used shapes: with 2, a Levenberg-Marquardt trial step that is rejected (evaluate at the trial
    shape, then linearise again at the old one) builds no table twice.

    Attributes:
        body: the body model.
        keypoint_format: ``"body"`` or a registered detector format name (canonical).
        builds: how many tables were built (a counter for tests and profiling).
        offsets: ``(K, 3)`` the format's keypoint-definition offsets added to every table
            (:mod:`mocapgraph.body.keypoint_offsets`), or None.
        offset_basis: ``(K, 3, D)`` offsets as variables
            (:func:`~mocapgraph.body.keypoint_offsets.offset_basis`), or None: every table is
            then :func:`~mocapgraph.body.keypoint_offsets.offset_shape_table`'s, whose last ``D``
            shape columns are the parameters', and :meth:`arrays` adds their offsets.
    """

    def __init__(self, body: BodyModel, keypoint_format: str = "body", size: int = 2, offsets=None, offset_basis=None):
        if size < 1:
            raise MocapgraphError(f"ShapeTableCache size must be >= 1, got {size}")
        self.body = body
        self.keypoint_format = "body" if keypoint_format == "body" else get_format(keypoint_format).name
        self.offsets = None if offsets is None else np.asarray(offsets, dtype=float)
        self.offset_basis = None if offset_basis is None else as_checked_array(offset_basis, "offset_basis", (self.num_keypoints, 3, None))
        self.size = int(size)
        self.builds = 0
        self._entries: list[_TableEntry] = []

    @property
    def num_keypoints(self) -> int:
        """K, the number of points of the format (without building a table)."""
        if self.keypoint_format == "body":
            return len(self.body.keypoint_names)
        return get_format(self.keypoint_format).num_points

    def entry(self, shape) -> _TableEntry:
        """The cached table, its native arrays and whether all its points are mapped."""
        key = np.asarray(shape, dtype=float).tobytes()
        for i, e in enumerate(self._entries):
            if e.key == key:
                if i:
                    self._entries.insert(0, self._entries.pop(i))
                return e
        table = self.body.table(np.frombuffer(key), keypoints=self.keypoint_format)
        if self.offsets is not None:
            table = with_offsets(table, self.offsets)
        if self.offset_basis is not None:
            table = offset_shape_table(table, self.offset_basis)
        self.builds += 1
        arrays = table_arrays(table)
        e = _TableEntry(key, table, arrays, bool(np.all(table.mapped)), carrier_joints(table), native_module().Body(*arrays), table.mapped.astype(float))
        self._entries.insert(0, e)
        del self._entries[self.size :]
        return e

    @property
    def offset_dim(self) -> int:
        """D, the number of offset parameters appended to the tables' shape (0 without a basis)."""
        return 0 if self.offset_basis is None else self.offset_basis.shape[-1]

    def arrays(self, entry: _TableEntry, parameters) -> tuple[np.ndarray, ...]:
        """The native arrays of ``entry``'s table with the offsets of ``parameters (D,)`` added
        at the points' carriers (the markers copied; the rest shared)."""
        if self.offset_basis is None:
            return entry.arrays
        markers = entry.arrays[4].copy()
        markers[np.arange(len(markers)), entry.carriers] += self.offset_basis @ np.asarray(parameters, dtype=float)
        return entry.arrays[:4] + (markers,) + entry.arrays[5:]

    def __call__(self, shape) -> BodyTable:
        """The :class:`BodyTable` of ``shape`` (``(S,)``), from the cache when the shape is known."""
        return self.entry(shape).table

    def state_joints(self, root: np.ndarray, pose: np.ndarray, shape, jacobians: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """One body state's 22 joints through the native kernel (a cache of format ``"body"``).

        ``root (4, 4)`` world_T_root, ``pose (63,)`` axis-angle, ``shape (S,)``. Returns the joints
        ``(22, 3)`` (world, metres) and, when ``jacobians``, their derivatives ``(22, 3, 6 + 63 + S)``
        with respect to the root's Pose3 tangent (rotation first), the joint rotations and the shape.
        """
        joints, _, _, d_joints, _ = self.entry(shape).native.fk(root[None], np.asarray(pose).reshape(1, NUM_JOINTS - 1, 3), jacobians)
        return joints[0], (d_joints[0] if jacobians else None)


def _check_rigid(T: np.ndarray, name: str) -> np.ndarray:
    T = as_checked_array(T, name, (4, 4))
    R = T[:3, :3]
    if (
        np.abs(R.T @ R - np.eye(3)).max() > 1e-6
        or abs(np.linalg.det(R) - 1.0) > 1e-6
        or np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-12
    ):
        raise MocapgraphError(
            f"{name}: not a rigid transform (rotation block not orthonormal or last row not 0 0 0 1)"
        )
    return T


@dataclass
class Labelling:
    """The labelling hypotheses of one reprojection factor's cameras: a max-mixture over
    permutations of the detected points (left/right swaps, :mod:`mocapgraph.body.labelling`).

    At every evaluation each camera takes the permutation under which its robust cost, plus
    ``cost`` for any but the first, is lowest; the choice is re-made at each linearisation, as
    a max-mixture linearises only its most probable component. Only under a robust scale: with
    the scale at infinity (L2, the first stage of an annealed solve, which finds the body from a
    rough start) the points stay as detected, since from a rough start every camera relabelled
    and the body turned around is as good a fit as the truth, and a solve could settle there. Evaluate the factor (e.g.
    ``graph.error(values)``) and read ``choice`` to learn which labelling each camera took there.

    Attributes:
        permutations: ``(H, K)`` integer permutations of the format's points, the first the
            identity (the points as detected); hypothesis ``h`` reads point ``k`` of the body
            from detected point ``permutations[h, k]``.
        cost: the cost of relabelling one camera, in the units of the factor's error
            (``½|r|²``, whitened): it keeps a camera as detected unless another labelling
            clearly fits better.
        enabled: False keeps every camera as detected (a solver switches the hypotheses on
            once the body is roughly in place).
        allowed: ``(C, H)`` bool, which hypotheses each camera may take (None: all).
        choice: ``(C,)`` per camera, the hypothesis the last evaluation took.
    """

    permutations: np.ndarray
    cost: float
    enabled: bool = True
    allowed: np.ndarray | None = None
    choice: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))

    def check(self, K: int, C: int) -> None:
        p = np.asarray(self.permutations)
        if (
            p.ndim != 2
            or p.shape[1] != K
            or not np.issubdtype(p.dtype, np.integer)
            or np.any(np.sort(p, axis=1) != np.arange(K))
            or np.any(p[0] != np.arange(K))
        ):
            raise MocapgraphError(f"labelling.permutations: (H, {K}) permutations of the points, the first the identity; got shape {p.shape}")
        if not (np.isfinite(self.cost) and self.cost >= 0):
            raise MocapgraphError(f"labelling.cost must be a finite number >= 0, got {self.cost}")
        if self.allowed is not None and (np.shape(self.allowed) != (C, len(p)) or not np.all(np.asarray(self.allowed)[:, 0])):
            raise MocapgraphError(f"labelling.allowed: ({C}, {len(p)}) bools with the identity allowed for every camera")
        self.choice = np.zeros(C, dtype=np.intp)


class _ReprojectionError:
    """The CustomFactor callback: reads the variables and hands them to the native factor
    kernel (``mocapgraph._native.Body.reproject_factor``), which picks each camera's labelling,
    keeps only the usable rows and adds the focal columns in one pass; then slices the Jacobian.
    Everything that does not change between evaluations is prepared here once."""

    def __init__(self, cache, states, fraction, shape_key, fixed_shape, refined, cameras, intrinsics, observed, weights, scale, min_depth, labelling, focals, offset_key):
        self.cache = cache
        self.states = states  # [(root key, pose key)]: one state, or two interpolated by `fraction`
        self.fraction = fraction
        self.shape_key = shape_key
        self.fixed_shape = fixed_shape
        self.first_camera = 2 * len(states) + (shape_key is not None)  # index of the first camera Jacobian in H
        self.refined = refined  # [(camera index, key)]
        self.cameras = cameras  # (C, 4, 4), fixed cameras filled in, refined ones overwritten per call
        self.intrinsics = intrinsics
        self.observed = observed
        # The kernel's residual and Jacobian are linear in the weights, so whitening by noise_px
        # is folded into them (free, where scaling the Jacobian afterwards cost ~10 µs).
        self.weights = weights
        self.scale = scale
        self.min_depth = min_depth
        self.interpolate = native_module().interpolate_pose  # interpolate_root without its wrapper: ~1 µs a call
        self.labelling = labelling
        C = len(cameras)
        # the hypotheses are read from the labelling at each call (a solver may change them);
        # without one, none (the points as detected)
        self.no_hypotheses = np.zeros((0, observed.shape[1]), dtype=np.int64)
        self.none_allowed = np.zeros((C, 0), dtype=bool)
        self.all_allowed = None if labelling is None else np.ones((C, len(labelling.permutations)), dtype=bool)
        self.focals = focals  # [(camera index, key)]: cameras whose focal length is a variable
        # cameras may share a focal length: one Jacobian column per distinct key, in key order
        self.focal_keys = list(dict.fromkeys(k for _, k in focals))
        self.focal_columns = np.full(C, -1, dtype=np.int64)  # per camera, its focal key's column
        for c, k in focals:
            self.focal_columns[c] = self.focal_keys.index(k)
        self.offset_key = offset_key  # the format's keypoint-offset parameters (Vector(D)), or None

    def __call__(self, this, values: gtsam.Values, H) -> np.ndarray:
        shape = self.fixed_shape if self.shape_key is None else values.atVector(self.shape_key)
        entry = self.cache.entry(shape)
        body = entry.native if self.offset_key is None else native_module().Body(*self.cache.arrays(entry, values.atVector(self.offset_key)))
        cameras = self.cameras
        for c, key in self.refined:
            cameras[c] = values.atPose3(key).matrix()
        (root_key, pose_key), a = self.states[0], self.fraction
        if len(self.states) == 1:
            root, pose = values.atPose3(root_key).matrix(), values.atVector(pose_key)
        else:
            next_root, next_pose = self.states[1]
            root, A0, A1 = self.interpolate(values.atPose3(root_key).matrix(), values.atPose3(next_root).matrix(), a)
            pose = (1.0 - a) * values.atVector(pose_key) + a * values.atVector(next_pose)
        intrinsics = self.intrinsics
        if self.focals:
            intrinsics = intrinsics.copy()
            for c, key in self.focals:
                intrinsics[c, :2] *= np.exp(values.atVector(key)[0])
        labelling = self.labelling
        if labelling is None:
            hypotheses, allowed, cost, relabel = self.no_hypotheses, self.none_allowed, 0.0, False
        else:
            hypotheses = np.ascontiguousarray(labelling.permutations, dtype=np.int64)
            allowed = self.all_allowed if labelling.allowed is None else np.ascontiguousarray(labelling.allowed, dtype=bool)
            # the kernel keeps the points as detected under L2 all the same (see Labelling)
            cost, relabel = labelling.cost, labelling.enabled
        try:
            residual, jac, choice = body.reproject_factor(
                root, pose.reshape(NUM_JOINTS - 1, 3), cameras, intrinsics, self.observed, self.weights, entry.mapped, self.scale.sigma_px,
                self.min_depth, H is not None, hypotheses, allowed, cost, relabel, labelling is not None, self.focal_columns, len(self.focal_keys),
            )  # fmt: skip
        except ValueError as exc:
            raise MocapgraphError(str(exc)) from None
        if labelling is not None:
            labelling.choice = choice
        if H is not None:
            P = body.num_params
            S = P - self.cache.offset_dim  # the shape's columns end here, the offset parameters' follow
            if len(self.states) == 1:
                H[0] = jac[:, 0:6]
                H[1] = jac[:, 6 : 6 + POSE_DIM]
            else:
                H[0] = jac[:, 0:6] @ A0
                H[1] = (1.0 - a) * jac[:, 6 : 6 + POSE_DIM]
                H[2] = jac[:, 0:6] @ A1
                H[3] = a * jac[:, 6 : 6 + POSE_DIM]
            if self.shape_key is not None:
                H[self.first_camera - 1] = jac[:, 6 + POSE_DIM : S]
            for i, (c, _) in enumerate(self.refined):
                H[self.first_camera + i] = jac[:, P + 6 * c : P + 6 * c + 6]
            focal = P + 6 * len(cameras)  # the focal keys' columns follow the cameras'
            for i in range(len(self.focal_keys)):
                H[self.first_camera + len(self.refined) + i] = jac[:, focal + i : focal + i + 1]
            if self.offset_key is not None:
                H[-1] = jac[:, S:P]
        return residual


def reprojection_factor(
    body: BodyModel,
    table_cache: ShapeTableCache | None,
    root_key: int,
    pose_key: int,
    shape_key: int | None,
    camera_keys: list[int | None],
    fixed_cameras: list[np.ndarray | None],
    intrinsics,
    observed,
    weights,
    keypoint_format: str,
    scale: RobustScale,
    noise_px: float = 1.0,
    min_depth: float = 0.05,
    fixed_shape=None,
    next_state: tuple[int, int] | None = None,
    fraction: float = 0.0,
    labelling: Labelling | None = None,
    focal_keys: list[int | None] | None = None,
    offset_key: int | None = None,
) -> gtsam.CustomFactor:
    """Reprojection of one body state's keypoints into C cameras (see the module docstring).

    Args:
        body: the body model (the same one ``table_cache`` was made for).
        table_cache: a :class:`ShapeTableCache` of ``body`` and ``keypoint_format``, shared between
            factors; None makes a private one.
        root_key, pose_key, shape_key: the body state's keys (``Pose3``, ``Vector(63)``, ``Vector(S)``);
            ``shape_key`` None holds the shape at ``fixed_shape`` (no key, no Jacobian), which
            spares a table rebuild per step when the shape is not being estimated.
        camera_keys: per camera, its ``Pose3`` key (world_T_camera) when the camera is refined, else None.
        fixed_cameras: per camera, its constant ``(4, 4)`` world_T_camera when fixed, else None.
            Exactly one of ``camera_keys[c]`` and ``fixed_cameras[c]`` is set.
        intrinsics: ``(C, 4)`` ``fx, fy, cx, cy`` in pixels (pinhole, OpenCV axes).
        observed: ``(C, K, 2)`` detected pixels, NaN where missing; K points of ``keypoint_format``.
        weights: ``(C, K)`` ``>= 0`` residual multipliers (detector confidences); 0 drops a point.
        keypoint_format: the detector's format (``"coco17"``, ...) or ``"body"``.
        scale: the shared Geman-McClure scale, read at every evaluation (inf = L2).
        noise_px: pixel standard deviation of a confident detection; the residual is divided by it.
        min_depth: metres; points closer to or behind a camera contribute nothing.
        fixed_shape: ``(S,)`` the constant shape when ``shape_key`` is None.
        next_state: ``(root key, pose key)`` of the next grid state: the observed body is then
            the state ``fraction`` of the way from ``(root_key, pose_key)`` to it
            (:func:`~mocapgraph.factors.interpolation.interpolate_root`, joint rotations linear).
        fraction: in ``(0, 1)`` with ``next_state``.
        labelling: the labelling hypotheses of every camera (:class:`Labelling`; its ``choice``
            says after each evaluation which one each camera took); None: the points as detected.
        focal_keys: per camera, the key of its focal length's log scale ``s`` (``Vector(1)``:
            ``fx, fy = e^s`` times the ``intrinsics``' ones, principal point fixed) when the focal
            length is estimated, else None; None: every focal length as given. Cameras may
            share a key (one focal length for several cameras of the same model).
        offset_key: the key of the format's keypoint-definition offset parameters (``Vector(D)``,
            the ``table_cache``'s ``offset_basis``), or None: the cache's tables as they are.

    Returns:
        A ``gtsam.CustomFactor`` on ``[root_key, pose_key, *next_state, shape_key, *refined
        camera keys, *distinct focal keys, offset key]`` (camera order), two rows per usable observation (camera-major) and, with
        ``labelling``, one row for the relabellings' cost; unit noise model (whitened inside).

    Raises:
        MocapgraphError: for inconsistent cameras, shapes, negative weights, non-positive
            ``noise_px`` or focal lengths, a cache of another body or format, or no usable
            observation at all.
    """
    if table_cache is None:
        table_cache = ShapeTableCache(body, keypoint_format)
    fmt = "body" if keypoint_format == "body" else get_format(keypoint_format).name
    if table_cache.body is not body or table_cache.keypoint_format != fmt:
        raise MocapgraphError(
            f"table_cache is for {table_cache.body.name!r} / {table_cache.keypoint_format!r}, "
            f"the factor for {body.name!r} / {fmt!r}: use one ShapeTableCache per body and keypoint format"
        )
    C = len(camera_keys)
    if C == 0 or len(fixed_cameras) != C:
        raise MocapgraphError(
            f"camera_keys ({C}) and fixed_cameras ({len(fixed_cameras)}) need one entry per camera, "
            "and there must be at least one camera"
        )
    K = table_cache.num_keypoints
    intrinsics = as_checked_array(intrinsics, "intrinsics (fx, fy, cx, cy)", (C, 4))
    if np.any(intrinsics[:, :2] <= 0):
        raise MocapgraphError("intrinsics: focal lengths fx, fy must be > 0")
    observed = as_checked_array(observed, f"observed (pixels, {fmt} points)", (C, K, 2), finite=False)
    weights = as_checked_array(weights, "weights (detector confidences)", (C, K))
    if np.any(weights < 0):
        raise MocapgraphError("weights: must be >= 0")
    noise_px = float(noise_px)
    if not (np.isfinite(noise_px) and noise_px > 0):
        raise MocapgraphError(f"noise_px must be a finite number > 0, got {noise_px}")
    if not isinstance(scale, RobustScale):
        raise MocapgraphError(f"scale must be a RobustScale, got {type(scale).__name__}")

    cameras = np.tile(np.eye(4), (C, 1, 1))
    refined = []
    for c, (key, fixed) in enumerate(zip(camera_keys, fixed_cameras)):
        if (key is None) == (fixed is None):
            raise MocapgraphError(f"camera {c}: give exactly one of camera_keys[{c}] and fixed_cameras[{c}]")
        if key is None:
            cameras[c] = _check_rigid(fixed, f"fixed_cameras[{c}] (world_T_camera)")
        else:
            refined.append((c, int(key)))
    if (shape_key is None) == (fixed_shape is None):
        raise MocapgraphError("reprojection_factor: give exactly one of shape_key and fixed_shape")
    states = [(int(root_key), int(pose_key))]
    if next_state is not None:
        if not 0.0 < float(fraction) < 1.0:
            raise MocapgraphError(f"fraction: must lie in (0, 1) with next_state, got {fraction}")
        states.append((int(next_state[0]), int(next_state[1])))
    elif fraction != 0.0:
        raise MocapgraphError("fraction: needs next_state (the state it interpolates towards)")
    keys = [k for state in states for k in state] + ([] if shape_key is None else [int(shape_key)])
    keys += [k for _, k in refined]
    focal_keys = [None] * C if focal_keys is None else list(focal_keys)
    if len(focal_keys) != C:
        raise MocapgraphError(f"focal_keys: one entry per camera ({C}), got {len(focal_keys)}")
    focals = [(c, int(k)) for c, k in enumerate(focal_keys) if k is not None]
    keys += list(dict.fromkeys(k for _, k in focals))
    if offset_key is not None:
        if table_cache.offset_basis is None:
            raise MocapgraphError("offset_key: the table_cache has no offset_basis (ShapeTableCache(..., offset_basis=...))")
        keys.append(int(offset_key))
    if len(set(keys)) != len(keys):
        raise MocapgraphError("reprojection_factor: the root, pose, shape, camera, focal and offset keys must all differ")
    if fixed_shape is not None:
        fixed_shape = as_checked_array(fixed_shape, "fixed_shape", (body.shape_dim,))
    # the native kernel's rule (on the whitened weights, as it sees them)
    usable = np.isfinite(observed).all(-1) & (weights / noise_px > 0)
    if not usable.any():
        raise MocapgraphError("reprojection_factor: no usable observation (every point is NaN or has weight 0)")
    if labelling is not None:
        labelling.check(K, C)
    error = _ReprojectionError(
        table_cache,
        states,
        float(fraction),
        None if shape_key is None else int(shape_key),
        fixed_shape,
        refined,
        cameras,
        np.ascontiguousarray(intrinsics),
        np.ascontiguousarray(observed),
        np.ascontiguousarray(weights / noise_px),
        scale,
        float(min_depth),
        labelling,
        focals,
        None if offset_key is None else int(offset_key),
    )
    rows = 2 * int(usable.sum()) + (labelling is not None)
    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(rows), keys, error)
