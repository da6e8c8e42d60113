"""The default body model: Anny (Apache-2.0 / CC0), evaluated from a cached numpy export.

Shape vector β = Anny's six default phenotypes ``(gender, age, muscle, weight, height,
proportions)``, each in its anchor range. The phenotype → skeleton map is Anny's own, evaluated
exactly (no linear shape basis), with analytic derivatives:

    phenotypes ──piecewise-multilinear──▶ 624 blend weights ──projection──▶ 136 coefficients c
    rest heads h(c) affine · rest orientations R(c) = Procrustes(M0 + Σ c_i M_i)
    step vectors s_e = U_p R_pᵀ (h_e − h_p) · markers ℓ = U_b R_bᵀ (m_b(c) − a·h_b)

The export (``anny_export``) runs once per Anny version and lands in the user's cache directory
(``$MOCAPGRAPH_CACHE_DIR``, else ``$XDG_CACHE_HOME/mocapgraph``, else ``~/.cache/mocapgraph``).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from functools import lru_cache
from pathlib import Path

import numpy as np

from mocapgraph.body.anny_export import EXPORT_FORMAT, SMPL_TO_ANNY
from mocapgraph.body.mesh import SkinnedMesh
from mocapgraph.body.model import BodyModel
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES, JOINT_NAMES, NUM_JOINTS, PARENTS
from mocapgraph.body.table import BodyTable
from mocapgraph.errors import MocapgraphError

log = logging.getLogger(__name__)

SHAPE_NAMES = ("gender", "age", "muscle", "weight", "height", "proportions")


def cache_dir() -> Path:
    """Where mocapgraph keeps generated files (created on demand)."""
    if "MOCAPGRAPH_CACHE_DIR" in os.environ:
        return Path(os.environ["MOCAPGRAPH_CACHE_DIR"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or "~/.cache"
    return Path(base).expanduser() / "mocapgraph"


def _installed_anny_version() -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("anny")
    except PackageNotFoundError:
        return None


def anny_table_path() -> Path:
    """The export file for the installed Anny version (the newest cached one if Anny is absent)."""
    version = _installed_anny_version()
    if version is not None:
        return cache_dir() / f"anny-{version}-export{EXPORT_FORMAT}.npz"
    cached = sorted(cache_dir().glob(f"anny-*-export{EXPORT_FORMAT}.npz"))
    if not cached:
        raise MocapgraphError(
            "the Anny body model is not installed and no exported table is cached in "
            f"{cache_dir()}; install it with `pip install anny`"
        )
    return cached[-1]


def ensure_anny_table(rebuild: bool = False) -> Path:
    """Export Anny into the cache if the file is missing, unreadable or from another format."""
    path = anny_table_path()
    if not rebuild and path.exists():
        try:
            with np.load(path) as data:
                if int(data["export_format"]) == EXPORT_FORMAT:
                    return path
        except (OSError, ValueError, KeyError):
            pass  # corrupt or stale: rebuilt below
    from mocapgraph.body.anny_export import export_anny_table

    # Anny's skinning backend (warp) prints banners on stdout; keep stdout for our own output.
    with contextlib.redirect_stdout(sys.stderr):
        arrays = export_anny_table()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)
    log.info("mocapgraph: Anny table written to %s", path)
    return path


def interpolation_weights(value: float, anchors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Anny's piecewise-linear anchor weights of one phenotype value and their derivative.

    Values outside the anchors are clamped (derivative 0); at an interior anchor the lower
    segment is used, as Anny does.
    """
    n = len(anchors)
    clamped = min(max(value, anchors[0]), anchors[-1])
    i = int(np.clip(np.searchsorted(anchors, clamped, side="left"), 1, n - 1))
    width = anchors[i] - anchors[i - 1]
    alpha = (clamped - anchors[i - 1]) / width
    w, dw = np.zeros(n), np.zeros(n)
    w[i - 1], w[i] = 1.0 - alpha, alpha
    if anchors[0] <= value <= anchors[-1]:
        dw[i - 1], dw[i] = -1.0 / width, 1.0 / width
    return w, dw


def special_procrustes(M: np.ndarray, dM: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest rotation ``R (N, 3, 3)`` to each ``M`` and its derivative along ``dM (N, 3, 3, S)``.

    With ``M = R P`` (P symmetric), ``dR = R Ω`` where the skew ``Ω`` solves
    ``Ω P + P Ω = Rᵀ dM − dMᵀ R``, diagonal in P's eigenbasis.
    """
    U, sigma, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt))
    sigma = sigma.copy()
    sigma[:, 2] *= d
    U = U.copy()
    U[:, :, 2] *= d[:, None]
    R = U @ Vt
    V = np.swapaxes(Vt, 1, 2)
    X = np.einsum("nji,njks->niks", R, dM)
    X = X - np.swapaxes(X, 1, 2)
    Xt = np.einsum("nji,njks,nkl->nils", V, X, V)
    Om = Xt / (sigma[:, :, None, None] + sigma[:, None, :, None])
    Omega = np.einsum("nij,njks,nlk->nils", V, Om, V)
    dR = np.einsum("nij,njks->niks", R, Omega)
    return R, dR


class AnnyBody(BodyModel):
    """Anny reduced to SMPL-22 joints and COCO-17 + 6 foot keypoints, exact for its phenotypes."""

    name = "anny"

    def __init__(self, table_path: str | Path | None = None):
        path = Path(table_path) if table_path is not None else ensure_anny_table()
        try:
            with np.load(path) as data:
                self._data = {k: data[k] for k in data.files}
        except (OSError, ValueError) as exc:
            raise MocapgraphError(f"cannot read the Anny table {path}: {exc}") from None
        d = self._data
        self.source = str(path)
        self.anny_version = str(d["anny_version"])
        owner = d["bone_owner"]
        self._toe_pairs = d["toe_root"][d["pair_bone"]] >= 0
        # Toe markers also carry a term in the ankle's frame (the toe head's offset from the
        # foot joint, which sits at the mean of the five toe heads).
        ankle = {10: 7, 11: 8}
        self._pair_owner = owner[d["pair_bone"]]
        self._pair_ankle = np.array([ankle.get(int(o), -1) for o in self._pair_owner])

    @property
    def shape_names(self) -> tuple[str, ...]:
        return SHAPE_NAMES

    @property
    def shape_bounds(self) -> np.ndarray:
        d = self._data
        counts = d["anchor_counts"][:6]
        return np.stack([d["anchors"][:6, 0], d["anchors"][np.arange(6), counts - 1]], axis=1)

    @property
    def default_shape(self) -> np.ndarray:
        return np.full(6, 0.5)

    def coefficients(self, shape: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Anny's 136 blendshape coefficients ``c`` for ``shape (6,)`` and ``dc/dβ (136, 6)``."""
        d = self._data
        values = np.concatenate([shape, [0.5, 0.5]])  # cupsize and firmness stay at Anny's default
        weights, d_weights = [], []
        for f, v in enumerate(values):
            w, dw = interpolation_weights(v, d["anchors"][f, : d["anchor_counts"][f]])
            weights.append(w)
            d_weights.append(dw)
        nvar = len(d["variation_feature"])
        phens = np.full(nvar, 1.0 / 3.0)  # race weights: Anny's default, equal thirds
        d_phens = np.zeros((nvar, 6))
        for j, (f, i) in enumerate(zip(d["variation_feature"], d["variation_anchor"])):
            if f >= 0:
                phens[j] = weights[f][i]
                if f < 6:
                    d_phens[j, f] = d_weights[f][i]
        mask = d["blend_mask"]
        factors = phens[None] * mask + (1.0 - mask)  # (624, 26)
        blend = factors.prod(axis=1)
        d_blend = np.zeros((len(blend), 6))
        for j in range(nvar):
            others = np.delete(factors, j, axis=1).prod(axis=1)
            d_blend += (mask[:, j] * others)[:, None] * d_phens[j][None]
        proj = d["blend_projection"]
        return blend @ proj, proj.T @ d_blend

    def _table(self, shape: np.ndarray) -> BodyTable:
        d = self._data
        c, dc = self.coefficients(shape)
        heads = d["head_template"] + np.einsum("i,ibx->bx", c, d["head_blend"])
        d_heads = np.einsum("is,ibx->bxs", dc, d["head_blend"])
        M = d["orient_template"] + np.einsum("i,ibxy->bxy", c, d["orient_blend"])
        dM = np.einsum("is,ibxy->bxys", dc, d["orient_blend"])
        R, dR = special_procrustes(M, dM)
        R[0], dR[0] = np.eye(3), 0.0  # Anny keeps the root's rest orientation at identity
        U = d["reference_orientations"]
        A = np.einsum("bxy,bzy->bxz", U, R)  # U_b R_bᵀ
        dA = np.einsum("bxy,bzys->bxzs", U, dR)
        A[0], dA[0] = np.eye(3), 0.0

        parents = d["bone_parents"]
        child = np.arange(1, len(parents))
        rel, d_rel = heads[child] - heads[parents[child]], d_heads[child] - d_heads[parents[child]]
        steps = np.zeros_like(heads)
        d_steps = np.zeros_like(d_heads)
        steps[child] = np.einsum("bxy,by->bx", A[parents[child]], rel)
        d_steps[child] = np.einsum("bxys,by->bxs", dA[parents[child]], rel) + np.einsum(
            "bxy,bys->bxs", A[parents[child]], d_rel
        )

        # Offsets and keypoint markers in Anny axes and Anny's world-aligned frames.
        offsets = d["step_to_offset"] @ steps
        d_offsets = np.einsum("ce,exs->cxs", d["step_to_offset"], d_steps)
        kb, b, a = d["pair_keypoint"], d["pair_bone"], d["pair_weight"]
        m = d["marker_template"] + np.einsum("i,inx->nx", c, d["marker_blend"])
        dm = np.einsum("is,inx->nxs", dc, d["marker_blend"])
        local = m - a[:, None] * heads[b]
        d_local = dm - a[:, None, None] * d_heads[b]
        own = np.einsum("nxy,ny->nx", A[b], local)  # ℓ_kb = U_b R_bᵀ (m_kb − a_kb h_b)
        d_own = np.einsum("nxys,ny->nxs", dA[b], local) + np.einsum("nxy,nys->nxs", A[b], d_local)
        position = d["step_to_position"][b]  # frozen bone head relative to its owner joint
        own += a[:, None] * (position @ steps)
        d_own += a[:, None, None] * np.einsum("ne,exs->nxs", position, d_steps)

        K = len(BODY_KEYPOINT_NAMES)
        weights = np.zeros((K, NUM_JOINTS))
        markers = np.zeros((K, NUM_JOINTS, 3))
        d_markers = np.zeros((K, NUM_JOINTS, 3, 6))
        owner = self._pair_owner
        np.add.at(weights, (kb, owner), a)
        np.add.at(markers, (kb, owner), own)
        np.add.at(d_markers, (kb, owner), d_own)
        toe = self._toe_pairs
        if np.any(toe):
            toe_bone = d["toe_root"][b[toe]]
            foot = owner[toe]
            lever = np.eye(len(parents))[toe_bone] - d["step_to_offset"][foot]  # s_toe − mean
            np.add.at(markers, (kb[toe], self._pair_ankle[toe]), a[toe, None] * (lever @ steps))
            np.add.at(
                d_markers,
                (kb[toe], self._pair_ankle[toe]),
                a[toe, None, None] * np.einsum("ne,exs->nxs", lever, d_steps),
            )

        # Re-base into SMPL axes with a T-pose at zero: o' = Cᵀ Q_p o, ℓ' = Cᵀ Q_c ℓ.
        frame = np.einsum("yx,cyz->cxz", d["axes"], d["rebase"])  # Cᵀ Q_c
        parent_frame = frame[np.maximum(PARENTS, 0)]
        offsets = np.einsum("cxy,cy->cx", parent_frame, offsets)
        d_offsets = np.einsum("cxy,cys->cxs", parent_frame, d_offsets)
        offsets[0], d_offsets[0] = 0.0, 0.0
        markers = np.einsum("cxy,kcy->kcx", frame, markers)
        d_markers = np.einsum("cxy,kcys->kcxs", frame, d_markers)
        return BodyTable(
            parents=PARENTS.copy(),
            offsets=offsets,
            d_offsets=d_offsets,
            weights=weights,
            markers=markers,
            d_markers=d_markers,
            keypoint_names=BODY_KEYPOINT_NAMES,
            mapped=np.ones(K, dtype=bool),
        )

    def anny_pose(self, root: np.ndarray, pose: np.ndarray) -> dict[str, np.ndarray]:
        """Anny ``local-ref`` delta transforms ``{bone: (T, 4, 4)}`` for our ``root``/``pose``.

        The inverse of the re-basing: ``D_0 = U_0 R Cᵀ`` (translation ``U_0 t``) and
        ``D_c = Q_pᵀ C R_c Cᵀ Q_c``. Used to compare against Anny's own forward pass and to
        skin Anny's mesh for display.
        """
        from mocapgraph.body.anny_export import SMPL_TO_ANNY
        from mocapgraph.body.rotations import rotvec_to_matrix
        from mocapgraph.body.skeleton import JOINT_NAMES

        d = self._data
        C, Q = d["axes"], d["rebase"]
        U0 = d["reference_orientations"][0]
        T = root.shape[0]
        out = {}
        D0 = np.tile(np.eye(4), (T, 1, 1))
        D0[:, :3, :3] = U0 @ root[:, :3, :3] @ C.T
        D0[:, :3, 3] = root[:, :3, 3] @ U0.T
        out["root"] = D0
        local = rotvec_to_matrix(pose)
        for j, name in enumerate(JOINT_NAMES[1:], start=1):
            Dj = np.tile(np.eye(4), (T, 1, 1))
            Dj[:, :3, :3] = Q[PARENTS[j]].T @ C @ local[:, j - 1] @ C.T @ Q[j]
            for bone in SMPL_TO_ANNY[name]:
                out[bone] = Dj
        return out


    def mesh(self, shape) -> SkinnedMesh:
        """Anny's mesh (13,718 vertices) and its 104-bone rig for ``shape``, from one forward pass
        of the anny package (it needs torch and anny; the first model build takes about a minute).

        The bind pose is Anny's rest pose turned into SMPL axes; each bone moves with the joint
        that owns it, the toe bones with the foot about their own heads (see ``mesh``'s docstring).
        """
        import torch

        shape = self.check_shape(shape)
        d = self._data
        model = _anny_model()
        root, pose = np.eye(4)[None], np.zeros((1, NUM_JOINTS - 1, 3))
        deltas = {k: torch.from_numpy(v).to(model.dtype) for k, v in self.anny_pose(root, pose).items()}
        phenotypes = {n: torch.tensor([v], dtype=model.dtype) for n, v in zip(SHAPE_NAMES, shape)}
        with torch.no_grad(), contextlib.redirect_stdout(sys.stderr):  # warp announces its kernels on stdout
            out = {k: v.double().numpy()[0] for k, v in model(pose_parameters=deltas, phenotype_kwargs=phenotypes).items()}
        to_smpl = np.eye(4)
        to_smpl[:3, :3] = d["axes"].T  # Anny's rest frame is Z up; the bind pose stands Y up like the body frame
        neutral = self.rest_joints(shape)
        owner, toe_root = d["bone_owner"], d["toe_root"]
        labels = [str(b) for b in d["bone_labels"]]
        toe = toe_root >= 0
        heads = out["bone_poses"][:, :3, 3]
        return SkinnedMesh(
            bind_vertices=out["rest_vertices"] @ d["axes"],
            faces=model.faces.numpy().astype(np.int64),
            bone_names=tuple(labels),
            bone_parents=d["bone_parents"].astype(np.int64),
            bind_poses=to_smpl @ out["rest_bone_poses"],
            neutral_poses=out["bone_poses"],
            skin_indices=model.vertex_bone_indices.numpy().astype(np.int64),
            skin_weights=model.vertex_bone_weights.double().numpy(),
            bone_driver=owner.astype(np.int64),
            bone_anchor=np.where(toe, PARENTS[owner], owner).astype(np.int64),
            bone_pivot=np.where(toe[:, None], heads[np.maximum(toe_root, 0)], neutral[owner]),
            neutral_joints=neutral,
            joint_bones=tuple(tuple(labels.index(b) for b in SMPL_TO_ANNY[n]) for n in JOINT_NAMES),
        )


@lru_cache(maxsize=1)
def _anny_model():
    """The anny package's model (float64), built once per process; warp's banners go to stderr."""
    from mocapgraph.body.anny_export import load_anny_model

    with contextlib.redirect_stdout(sys.stderr):
        return load_anny_model()


@lru_cache(maxsize=None)
def cached_anny_body() -> AnnyBody:
    """The default Anny body, loaded once per process."""
    return AnnyBody()
