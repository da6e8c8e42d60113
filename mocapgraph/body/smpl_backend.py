"""SMPL and SMPL-X from the user's own licensed model file, reduced to the 22-joint table.

mocapgraph never ships or downloads SMPL/SMPL-X files; :class:`SMPLBody` reads the file the user
points it at (``.npz`` as distributed, or the authors' original ``.pkl``) and keeps only what the
table form needs:

* ``v_template (V, 3)``, ``shapedirs (V, 3, B)``, ``J_regressor (J, V)``, ``weights (V, J)`` and
  ``kintree_table (2, J)``.
* Shape vector β = the first ``num_betas`` PCA shape coefficients (default 10). For SMPL-X only
  the identity part of ``shapedirs`` is used (the first 300 components in SMPL-X ≥ 1.1 files,
  the first 10 in the older 20-component files); the expression components are ignored.
* Pose correctives (``posedirs``) are ignored: posed points are plain linear blend skinning of
  the shaped rest mesh. The triangles ``f`` are read when the file has them, for :meth:`SMPLBody.mesh`.

Everything is linear in β, so offsets and markers are affine in β and their derivatives are
constants::

    J_rest(β) = J_regressor · (v_template + shapedirs · β)
    o_c = J_rest_c − J_rest_parent(c)

Joints beyond the first 22 (SMPL's two hand joints; SMPL-X's jaw, eyes and fingers) are frozen
at zero rotation: each is rigidly attached to its nearest ancestor among the first 22, so its
skinning weight folds into that ancestor. This is exact, because a frozen child ``f`` of a driven
joint ``c`` has ``G_f = G_c`` and ``J_f = J_c + G_c (J_f_rest − J_c_rest)``, hence
``J_f + G_f (v − J_f_rest) = J_c + G_c (v − J_c_rest)``.

Body keypoints: the COCO shoulders, elbows, wrists, hips, knees and ankles are the SMPL joints
themselves; nose, eyes, ears, toes and heels are single mesh vertices (the vertex ids of the
smplx package's ``vertex_ids`` table), skinned with their folded LBS weights:
``a_kc = w_vc`` and ``ℓ_kc = w_vc (v_rest(β) − J_rest_c(β))``.

Loading ``.pkl`` files does not need chumpy: a restricted unpickler maps chumpy objects to a
stand-in that keeps only their array data, rebuilds scipy sparse matrices from their stored
arrays, and refuses every other global (a pickle naming e.g. ``os.system`` is never executed).
"""

from __future__ import annotations

import io
import pickle
from pathlib import Path

import numpy as np

from mocapgraph.body.mesh import SkinnedMesh
from mocapgraph.body.model import BodyModel
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES, JOINT_NAMES, NUM_JOINTS, PARENTS
from mocapgraph.body.table import BodyTable
from mocapgraph.errors import MocapgraphError, as_checked_array

KINDS = ("smpl", "smplx")

#: Vertex count of each supported mesh layout.
NUM_VERTICES = {"smpl": 6890, "smplx": 10475}

#: Mesh vertex of each body keypoint that is not an SMPL joint, per layout (as in the smplx
#: package's ``vertex_ids``: its ``smplh`` table for the 6890-vertex SMPL/SMPL-H mesh).
KEYPOINT_VERTICES: dict[str, dict[str, int]] = {
    "smpl": {
        "nose": 332, "left_eye": 2800, "right_eye": 6260, "left_ear": 583, "right_ear": 4071,
        "left_big_toe": 3216, "right_big_toe": 6617, "left_small_toe": 3226,
        "right_small_toe": 6624, "left_heel": 3387, "right_heel": 6787,
    },
    "smplx": {
        "nose": 9120, "left_eye": 9448, "right_eye": 9929, "left_ear": 6, "right_ear": 616,
        "left_big_toe": 5770, "right_big_toe": 8463, "left_small_toe": 5780,
        "right_small_toe": 8474, "left_heel": 8846, "right_heel": 8635,
    },
}  # fmt: skip

#: The PCA betas are unit-variance, so ±5 standard deviations is a generous box.
SHAPE_BOUND = 5.0

#: Identity components at the front of an SMPL-X ``shapedirs`` (the rest are expression).
SMPLX_SHAPE_SPACE = 300
SMPLX_LEGACY_SHAPE_SPACE = 10

REQUIRED_FIELDS = ("v_template", "shapedirs", "J_regressor", "weights", "kintree_table")
OPTIONAL_FIELDS = ("f",)


# --------------------------------------------------------------------------------------------
# Reading the file


class _ChumpyStandIn:
    """Takes the place of any chumpy class while unpickling and keeps what was pickled."""

    def __new__(cls, *args, **kwargs):
        obj = super().__new__(cls)
        obj.args, obj.state = args, None
        return obj

    def __init__(self, *args, **kwargs):
        self.args = args

    def __setstate__(self, state):
        self.state = state

    def array(self, depth: int = 0) -> np.ndarray | None:
        """The chumpy object's value: its ``x`` entry, else the first array in its state."""
        if depth > 20:
            return None
        state = self.state
        dicts = [state] if isinstance(state, dict) else []
        if isinstance(state, tuple):
            dicts = [s for s in state if isinstance(s, dict)]
        candidates = []
        for d in dicts:
            if "x" in d:
                candidates.append(d["x"])
        for d in dicts:
            candidates.extend(v for k, v in d.items() if k != "x")
        candidates.extend(self.args)
        for value in candidates:
            if isinstance(value, np.ndarray) and value.dtype != object:
                return value
            if isinstance(value, _ChumpyStandIn):
                inner = value.array(depth + 1)
                if inner is not None:
                    return inner
        return None


class _SparseStandIn:
    """Takes the place of a scipy.sparse matrix class; rebuilt from its stored arrays."""

    format = ""

    def __new__(cls, *args, **kwargs):
        obj = super().__new__(cls)
        obj.state = None
        return obj

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        self.state = state

    def dense(self) -> np.ndarray:
        import scipy.sparse

        state = self.state
        if isinstance(state, tuple):  # (dict, slots) form
            state = next((s for s in state if isinstance(s, dict)), None)
        if not isinstance(state, dict):
            raise ValueError(f"{self.format} sparse matrix without stored arrays")
        shape = state.get("_shape", state.get("shape"))
        shape = tuple(int(s) for s in shape)
        if self.format in ("csc", "csr", "bsr"):
            arrays = (state["data"], state["indices"], state["indptr"])
            cls = {"csc": scipy.sparse.csc_matrix, "csr": scipy.sparse.csr_matrix}.get(
                self.format, scipy.sparse.bsr_matrix
            )
            return np.asarray(cls(arrays, shape=shape).toarray())
        if self.format == "coo":
            coords = state.get("coords") or (state["row"], state["col"])
            matrix = scipy.sparse.coo_matrix((state["data"], tuple(coords)), shape=shape)
            return np.asarray(matrix.toarray())
        raise ValueError(f"unsupported sparse matrix format {self.format!r}")


def _sparse_class(fmt: str) -> type:
    return type(f"_{fmt}_stand_in", (_SparseStandIn,), {"format": fmt})


_SPARSE_CLASSES = {
    f"{fmt}_{kind}": _sparse_class(fmt)
    for fmt in ("csc", "csr", "coo", "bsr")
    for kind in ("matrix", "array")
}


def _latin1_encode(text, encoding="latin1"):
    """``_codecs.encode`` as Python 3 pickles use it for bytes, restricted to latin-1."""
    if not isinstance(text, str) or encoding.replace("-", "").replace("_", "").lower() != "latin1":
        raise pickle.UnpicklingError(f"refusing _codecs.encode({type(text).__name__}, {encoding!r})")
    return text.encode("latin1")


class _RefusedGlobal(pickle.UnpicklingError):
    pass


class _ModelUnpickler(pickle.Unpickler):
    """Unpickles only numpy arrays, scipy sparse matrices and chumpy objects (as stand-ins)."""

    _reconstruct = np.ndarray.__reduce__(np.zeros(1))[0]
    _scalar = np.float64(0).__reduce__()[0]

    def find_class(self, module: str, name: str):
        module = {"copy_reg": "copyreg", "__builtin__": "builtins"}.get(module, module)
        top = module.split(".")[0]
        if top == "chumpy":
            return _ChumpyStandIn
        if top == "numpy":
            if name == "_reconstruct" and module.endswith("multiarray"):
                return self._reconstruct
            if name == "scalar" and module.endswith("multiarray"):
                return self._scalar
            if (module, name) == ("numpy", "ndarray"):
                return np.ndarray
            if (module, name) == ("numpy", "dtype"):
                return np.dtype
        if top == "scipy" and module.startswith("scipy.sparse") and name in _SPARSE_CLASSES:
            return _SPARSE_CLASSES[name]
        if (module, name) == ("_codecs", "encode"):
            return _latin1_encode
        if (module, name) == ("copyreg", "_reconstructor"):
            import copyreg

            return copyreg._reconstructor  # only ever instantiates classes allowed here
        if module == "builtins" and name in ("object", "set", "frozenset", "slice", "complex"):
            import builtins

            return getattr(builtins, name)
        if (module, name) == ("collections", "OrderedDict"):
            from collections import OrderedDict

            return OrderedDict
        raise _RefusedGlobal(f"{module}.{name}")


def _read_pickle(path: Path, where: str) -> dict:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise MocapgraphError(f"{where}: cannot read it ({exc.strerror or exc})") from None
    try:
        content = _ModelUnpickler(io.BytesIO(data), encoding="latin1").load()
    except _RefusedGlobal as exc:
        raise MocapgraphError(
            f"{where}: refused: the pickle asks for {exc}, and only numpy arrays, scipy.sparse "
            "matrices and chumpy data are loaded (nothing in the file was run)"
        ) from None
    except Exception as exc:  # corrupt pickles raise almost anything
        raise MocapgraphError(
            f"{where}: cannot read it as a pickled model ({type(exc).__name__}: {exc})"
        ) from None
    if not isinstance(content, dict):
        raise MocapgraphError(
            f"{where}: expected a pickled dict of model arrays, got {type(content).__name__}"
        )
    return content


def _read_npz(path: Path, where: str) -> dict:
    try:
        with open(path, "rb") as f:
            magic = f.read(4)
    except OSError as exc:
        raise MocapgraphError(f"{where}: cannot read it ({exc.strerror or exc})") from None
    if magic not in (b"PK\x03\x04", b"PK\x05\x06"):
        raise MocapgraphError(f"{where}: cannot read it as a numpy .npz archive (not a zip file)")
    try:
        archive = np.load(path, allow_pickle=False)
    except Exception as exc:
        raise MocapgraphError(
            f"{where}: cannot read it as a numpy .npz archive ({type(exc).__name__}: {exc})"
        ) from None
    content = {}
    with archive:
        for field in REQUIRED_FIELDS + OPTIONAL_FIELDS:
            if field not in archive.files:
                continue
            try:
                content[field] = archive[field]
            except ValueError as exc:
                if "allow_pickle" in str(exc):
                    raise MocapgraphError(
                        f"{where}: field {field!r} is stored as a pickled Python object, "
                        "which mocapgraph does not load from .npz files; re-save it as a plain array"
                    ) from None
                raise MocapgraphError(f"{where}: field {field!r} is unreadable ({exc})") from None
            except Exception as exc:
                raise MocapgraphError(
                    f"{where}: field {field!r} is unreadable ({type(exc).__name__}: {exc})"
                ) from None
    return content


def _plain_array(value, where: str, field: str) -> np.ndarray:
    """A loaded value as a plain numeric ndarray (chumpy and sparse stand-ins unwrapped)."""
    where = f"{where}: field {field!r}"
    try:
        if isinstance(value, _ChumpyStandIn):
            arr = value.array()
            if arr is None:
                raise MocapgraphError(f"{where}: a chumpy object without array data")
            value = arr
        elif isinstance(value, _SparseStandIn):
            value = value.dense()
        arr = np.asarray(value)
    except MocapgraphError:
        raise
    except Exception as exc:
        raise MocapgraphError(f"{where}: unreadable ({type(exc).__name__}: {exc})") from None
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
        raise MocapgraphError(f"{where}: not a numeric array (dtype {arr.dtype})")
    return arr


# --------------------------------------------------------------------------------------------
# The model


def _frozen_drivers(parents: np.ndarray) -> np.ndarray:
    """Per source joint, itself if among the first 22, else its nearest ancestor that is."""
    drivers = np.arange(len(parents))
    for j in range(NUM_JOINTS, len(parents)):
        d, steps = j, 0
        while d >= NUM_JOINTS:
            d = int(parents[d])
            steps += 1
            if d < 0 or steps > len(parents):
                raise ValueError(f"joint {j} has no ancestor among the first {NUM_JOINTS} joints")
        drivers[j] = d
    return drivers


class SMPLBody(BodyModel):
    """SMPL or SMPL-X from a user's model file, reduced to SMPL-22 joints and 23 keypoints.

    Args:
        model_path: the licensed ``.npz`` or ``.pkl`` model file (e.g. ``SMPL_NEUTRAL.npz``).
        kind: ``"smpl"`` (6890-vertex mesh; SMPL-H files work too) or ``"smplx"`` (10475).
        num_betas: how many leading shape coefficients form the shape vector.
    """

    def __init__(self, model_path: str | Path, kind: str = "smpl", num_betas: int = 10):
        if kind not in KINDS:
            raise MocapgraphError(f"unknown SMPL model kind {kind!r}; choose one of {', '.join(KINDS)}")
        self.name = kind
        try:
            path = Path(model_path).expanduser()
        except TypeError:
            raise MocapgraphError(f"{kind} model path must be a file path, got {model_path!r}") from None
        self.source = str(path)
        label = "SMPL-X" if kind == "smplx" else "SMPL"
        self._where = where = f"{label} model file {path}"
        if isinstance(num_betas, bool) or not isinstance(num_betas, (int, np.integer)) or num_betas < 1:
            raise MocapgraphError(f"{where}: num_betas must be a positive integer, got {num_betas!r}")
        self.num_betas = int(num_betas)
        if not path.exists():
            raise MocapgraphError(
                f"{where} does not exist (mocapgraph never downloads SMPL files: "
                "point --model-path at your own licensed copy)"
            )
        if path.is_dir():
            raise MocapgraphError(
                f"{where} is a directory; pass the model file itself "
                f"(e.g. {path / ('SMPLX_NEUTRAL.npz' if kind == 'smplx' else 'SMPL_NEUTRAL.npz')})"
            )
        suffix = path.suffix.lower()
        if suffix == ".npz":
            content = _read_npz(path, where)
        elif suffix == ".pkl":
            content = _read_pickle(path, where)
        else:
            raise MocapgraphError(f"{where}: unknown extension {path.suffix!r} (expected .npz or .pkl)")
        self._build(content)

    # ---- loading -----------------------------------------------------------------------------

    def _field(self, content: dict, field: str) -> np.ndarray:
        if field not in content:
            raise MocapgraphError(
                f"{self._where}: missing field {field!r} (required: {', '.join(REQUIRED_FIELDS)})"
            )
        return _plain_array(content[field], self._where, field)

    def _build(self, content: dict) -> None:
        kind, S = self.name, self.num_betas

        def name(field: str) -> str:
            return f"{self._where}: field {field!r}"

        v_template = as_checked_array(self._field(content, "v_template"), name("v_template"), (None, 3))
        V = v_template.shape[0]
        layout = next((k for k, n in NUM_VERTICES.items() if n == V), None)
        if layout is None:
            raise MocapgraphError(
                f"{self._where}: field 'v_template' has {V} vertices, which matches neither the "
                f"SMPL/SMPL-H mesh ({NUM_VERTICES['smpl']}) nor the SMPL-X mesh "
                f"({NUM_VERTICES['smplx']})"
            )
        if layout != kind:
            raise MocapgraphError(
                f"{self._where}: field 'v_template' has {V} vertices, the {layout} layout, but the "
                f"{kind} backend needs {NUM_VERTICES[kind]}; use the {layout} backend for this file"
            )

        raw = self._field(content, "shapedirs")
        if raw.ndim != 3 or raw.shape[:2] != (V, 3):
            raise MocapgraphError(f"{name('shapedirs')}: expected shape ({V}, 3, B), got {raw.shape}")
        B = raw.shape[2]
        if kind == "smplx":
            available = SMPLX_SHAPE_SPACE if B >= SMPLX_SHAPE_SPACE else min(B, SMPLX_LEGACY_SHAPE_SPACE)
        else:
            available = B
        if S > available:
            raise MocapgraphError(
                f"{name('shapedirs')}: num_betas = {S} but the file has only {available} "
                "shape components"
            )
        shapedirs = as_checked_array(raw[:, :, :S], name("shapedirs"), (V, 3, S))

        regressor = as_checked_array(self._field(content, "J_regressor"), name("J_regressor"), (None, V))
        J = regressor.shape[0]
        if J < NUM_JOINTS:
            raise MocapgraphError(
                f"{name('J_regressor')}: has {J} joints, expected at least {NUM_JOINTS}"
            )
        weights = as_checked_array(self._field(content, "weights"), name("weights"), (V, J))
        parents = self._parents(self._field(content, "kintree_table"), J)

        drivers = _frozen_drivers(parents)
        self.num_vertices, self.num_source_joints = V, J
        self.num_shape_components = available

        # Rest joints of the 22 driven joints, affine in β (frozen joints' positions cancel out).
        joints0 = regressor[:NUM_JOINTS] @ v_template  # (22, 3)
        d_joints = np.einsum("jv,vxs->jxs", regressor[:NUM_JOINTS], shapedirs)  # (22, 3, S)
        self._pelvis0, self._d_pelvis = joints0[0], d_joints[0]
        self._v_template, self._shapedirs, self._regressor = v_template, shapedirs, regressor[:NUM_JOINTS]
        self._faces = None
        if "f" in content:
            faces = self._field(content, "f")
            if faces.ndim != 2 or faces.shape[1] != 3 or not np.all((faces >= 0) & (faces < V) & (faces == np.round(faces))):
                raise MocapgraphError(f"{name('f')}: expected (F, 3) vertex indices below {V}, got shape {faces.shape}")
            self._faces = faces.astype(np.int64)
        child = np.arange(1, NUM_JOINTS)
        self._offsets0 = np.zeros((NUM_JOINTS, 3))
        self._d_offsets = np.zeros((NUM_JOINTS, 3, S))
        self._offsets0[child] = joints0[child] - joints0[PARENTS[child]]
        self._d_offsets[child] = d_joints[child] - d_joints[PARENTS[child]]

        K = len(BODY_KEYPOINT_NAMES)
        self._weights = np.zeros((K, NUM_JOINTS))
        self._markers0 = np.zeros((K, NUM_JOINTS, 3))
        self._d_markers = np.zeros((K, NUM_JOINTS, 3, S))
        fold = np.zeros((J, NUM_JOINTS))
        fold[np.arange(J), drivers] = 1.0
        self._skin = weights @ fold  # (V, 22): frozen joints' weights on their driven ancestor
        vertex_ids = KEYPOINT_VERTICES[kind]
        self.keypoint_vertices = dict(vertex_ids)
        for k, kp in enumerate(BODY_KEYPOINT_NAMES):
            if kp in JOINT_NAMES:
                self._weights[k, JOINT_NAMES.index(kp)] = 1.0
                continue
            v = vertex_ids[kp]
            w = weights[v] @ fold  # (22,) folded skinning weights
            self._weights[k] = w
            self._markers0[k] = w[:, None] * (v_template[v][None] - joints0)
            self._d_markers[k] = w[:, None, None] * (shapedirs[v][None] - d_joints)

    def _parents(self, kintree: np.ndarray, J: int) -> np.ndarray:
        where = f"{self._where}: field 'kintree_table'"
        if kintree.shape != (2, J):
            raise MocapgraphError(
                f"{where}: expected shape (2, {J}) to match J_regressor, got {kintree.shape}"
            )
        if not np.all(np.isfinite(kintree)) or not np.all(kintree == np.round(kintree)):
            raise MocapgraphError(f"{where}: contains non-integer entries")
        table = kintree.astype(np.int64)  # float files keep 4294967295 exactly
        ids = table[1]
        if not np.array_equal(np.sort(ids), np.arange(J)):
            raise MocapgraphError(f"{where}: row 1 is not a permutation of the joint ids 0..{J - 1}")
        parents = np.empty(J, dtype=np.int64)
        parents[ids] = table[0]
        roots = np.flatnonzero((parents < 0) | (parents >= J))
        if not np.array_equal(roots, [0]):
            raise MocapgraphError(
                f"{where}: expected joint 0 to be the only root, found roots {roots.tolist()}"
            )
        parents[0] = -1
        if np.any(parents[1:] == np.arange(1, J)):
            raise MocapgraphError(f"{where}: a joint is its own parent")
        if not np.array_equal(parents[:NUM_JOINTS], PARENTS):
            raise MocapgraphError(
                f"{where}: the first {NUM_JOINTS} parents {parents[:NUM_JOINTS].tolist()} differ from "
                f"SMPL's kinematic tree {PARENTS.tolist()}"
            )
        try:
            _frozen_drivers(parents)
        except ValueError as exc:
            raise MocapgraphError(f"{where}: {exc} (the tree has a cycle)") from None
        return parents

    # ---- BodyModel ---------------------------------------------------------------------------

    @property
    def shape_names(self) -> tuple[str, ...]:
        return tuple(f"beta{i}" for i in range(self.num_betas))

    @property
    def shape_bounds(self) -> np.ndarray:
        return np.tile([-SHAPE_BOUND, SHAPE_BOUND], (self.num_betas, 1)).astype(float)

    @property
    def default_shape(self) -> np.ndarray:
        return np.zeros(self.num_betas)

    def rest_pelvis(self, shape) -> np.ndarray:
        """``(3,)`` the pelvis joint of the unposed model in the model file's own frame: SMPL's
        ``transl`` is our root translation minus this (SMPL turns the root about it)."""
        return self._pelvis0 + self._d_pelvis @ self.check_shape(shape)

    def _table(self, shape: np.ndarray) -> BodyTable:
        return BodyTable(
            parents=PARENTS.copy(),
            offsets=self._offsets0 + self._d_offsets @ shape,
            d_offsets=self._d_offsets.copy(),
            weights=self._weights.copy(),
            markers=self._markers0 + self._d_markers @ shape,
            d_markers=self._d_markers.copy(),
            keypoint_names=BODY_KEYPOINT_NAMES,
            mapped=np.ones(len(BODY_KEYPOINT_NAMES), dtype=bool),
        )

    def mesh(self, shape) -> SkinnedMesh:
        """The shaped mesh skinned to the 22 joints (frozen joints folded in, no pose correctives);
        bind and neutral pose are both SMPL's rest T-pose, pelvis at the origin."""
        shape = self.check_shape(shape)
        if self._faces is None:
            raise MocapgraphError(f"{self._where}: has no triangles (field 'f'), so no mesh")
        vertices = self._v_template + self._shapedirs @ shape
        joints = self._regressor @ vertices
        vertices, joints = vertices - joints[0], joints - joints[0]
        poses = np.tile(np.eye(4), (NUM_JOINTS, 1, 1))
        poses[:, :3, 3] = joints
        width = int(np.max(np.sum(self._skin > 0, axis=1)))
        order = np.argsort(-self._skin, axis=1, kind="stable")[:, :width]
        return SkinnedMesh(
            bind_vertices=vertices, faces=self._faces, bone_names=JOINT_NAMES, bone_parents=PARENTS.copy(),
            bind_poses=poses, neutral_poses=poses, skin_indices=order, skin_weights=np.take_along_axis(self._skin, order, axis=1),
            bone_driver=np.arange(NUM_JOINTS), bone_anchor=np.maximum(PARENTS, 0), bone_pivot=joints, neutral_joints=joints,
            joint_bones=tuple((c,) for c in range(NUM_JOINTS)),
        )  # fmt: skip

    def describe(self) -> dict:
        info = super().describe()
        info["model_file"] = self.source
        info["source_joints"] = self.num_source_joints
        info["vertices"] = self.num_vertices
        return info
