"""One-time export of the Anny body model into the numpy table :mod:`anny_backend` evaluates.

Needs ``torch`` and ``anny``; everything at run time afterwards is numpy. The export keeps
Anny's exact phenotype map (piecewise-multilinear blend weights, the compact projection, affine
rest heads, Procrustes rest orientations) and reduces the 104-bone rig to SMPL's 22 joints:
frozen bones fold into their driven ancestor exactly, and SMPL's foot joint drives Anny's five
first toe phalanges with one shared rotation (its position is the mean of their heads).

Anny's frame is Z up, −Y forward, +X left; its zero pose is an A-pose. The exported table is in
SMPL's axes (``v_anny = C · v_smpl``, ``C = R_x(+90°)``) with the arms raised to horizontal, so that
zero rotations are a T-pose as in SMPL (see ``docs/body-model.md``).
"""

from __future__ import annotations

import logging
import os
import time
from importlib.metadata import version

import numpy as np

from mocapgraph.body.rotations import axis_rotation, minimal_rotation
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES, JOINT_NAMES, NUM_JOINTS, PARENTS
from mocapgraph.errors import MocapgraphError

log = logging.getLogger(__name__)

EXPORT_FORMAT = 2

# SMPL joint → Anny bone; the feet drive all five first toe phalanges together.
TOES = tuple(f"toe{i}-1" for i in range(1, 6))
SMPL_TO_ANNY: dict[str, tuple[str, ...]] = {
    "pelvis": ("root",),
    "left_hip": ("upperleg01.L",), "right_hip": ("upperleg01.R",),
    "spine1": ("spine04",),
    "left_knee": ("lowerleg01.L",), "right_knee": ("lowerleg01.R",),
    "spine2": ("spine03",),
    "left_ankle": ("foot.L",), "right_ankle": ("foot.R",),
    "spine3": ("spine02",),
    "left_foot": tuple(t + ".L" for t in TOES), "right_foot": tuple(t + ".R" for t in TOES),
    "neck": ("neck01",),
    "left_collar": ("clavicle.L",), "right_collar": ("clavicle.R",),
    "head": ("head",),
    "left_shoulder": ("upperarm01.L",), "right_shoulder": ("upperarm01.R",),
    "left_elbow": ("lowerarm01.L",), "right_elbow": ("lowerarm01.R",),
    "left_wrist": ("wrist.L",), "right_wrist": ("wrist.R",),
}  # fmt: skip

# Anny axes from SMPL axes: (x, y, z)_anny = (x, -z, y)_smpl.
SMPL_TO_ANNY_AXES = axis_rotation("x", np.pi / 2)


def _np(t) -> np.ndarray:
    """A torch tensor as a float64 numpy array that owns its memory."""
    return t.detach().cpu().double().numpy().copy()


def load_anny_model():
    """Anny's default model (rig ``anny``, default phenotypes), float64, with a progress message."""
    try:
        import anny
    except ImportError as exc:
        raise MocapgraphError(
            f"exporting the Anny body model needs the anny package and torch ({exc}); "
            "install them with `pip install anny torch`"
        ) from None

    cache = os.environ.get("ANNY_CACHE_DIR", "~/.cache/anny")
    log.info("mocapgraph: building the Anny body model (first time ~1 min, cache %s) ...", cache)
    start = time.perf_counter()
    model = anny.Anny()
    log.info("mocapgraph: Anny model ready in %.1f s", time.perf_counter() - start)
    return model


def bone_owners(labels: list[str], bone_parents: list[int]) -> tuple[np.ndarray, dict[int, int]]:
    """Owner SMPL joint of every Anny bone, and which toe bone each first-toe descendant hangs from.

    Returns ``owner (B,)`` (index into JOINT_NAMES) and ``toe_root {bone: first toe bone}``.
    """
    driven = {labels.index(b): j for j, n in enumerate(JOINT_NAMES) for b in SMPL_TO_ANNY[n]}
    owner = np.full(len(labels), -1)
    toe_root: dict[int, int] = {}
    for b in range(len(labels)):  # parents precede children in Anny's bone order
        p = bone_parents[b]
        owner[b] = driven.get(b, owner[p] if p >= 0 else -1)
        if b in driven and labels[b].split(".")[0] in TOES:
            toe_root[b] = b
        elif p >= 0 and p in toe_root:
            toe_root[b] = toe_root[p]
    for j, name in enumerate(JOINT_NAMES[1:], start=1):
        first = labels.index(SMPL_TO_ANNY[name][0])
        if owner[bone_parents[first]] != PARENTS[j]:
            raise RuntimeError(f"Anny rig changed: {name} does not hang below {JOINT_NAMES[PARENTS[j]]}")
    return owner, toe_root


def export_anny_table(model=None) -> dict[str, np.ndarray]:
    """Arrays of the reduced Anny model, as :class:`anny_backend.AnnyBody` evaluates them.

    Steps ``s_e`` and the keypoint bone pairs are explained inline; everything stays in Anny's
    axes except ``rebase`` / ``axes``, which the backend applies last.
    """
    model = model if model is not None else load_anny_model()
    import anny  # importable once the model is loaded
    labels = list(model.bone_labels)
    bone_parents = [int(p) for p in model.bone_parents]
    B = len(labels)
    owner, toe_root = bone_owners(labels, bone_parents)

    # Step vectors s_e = A_par(e) (h_e - h_par(e)) in the frame of e's owner; offsets and frozen
    # chains are sums of them: o_c = Σ_e gamma[c, e] s_e, Δ_b = Σ_e delta[b, e] s_e.
    delta = np.zeros((B, B))  # position of bone b relative to its owner joint
    for b in range(1, B):
        p = bone_parents[b]
        if owner[b] == owner[p]:  # frozen bone: rigidly attached to its owner's frame
            delta[b] = delta[p] + np.eye(B)[b]
    gamma = np.zeros((NUM_JOINTS, B))
    for j, name in enumerate(JOINT_NAMES[1:], start=1):
        bones = [labels.index(b) for b in SMPL_TO_ANNY[name]]
        for b in bones:
            gamma[j] += (delta[bone_parents[b]] + np.eye(B)[b]) / len(bones)

    # Keypoints: vertex weights r_kv times skinning weights w_vb give bone weights a_kb and
    # marker points m_kb = Σ_v r_kv w_vb x_v(β), affine in the blendshape coefficients.
    reg = anny.KeypointsRegressor.coco(model)
    if tuple(reg.labels) != BODY_KEYPOINT_NAMES:
        raise RuntimeError(f"Anny keypoint labels changed: {reg.labels}")
    r = _np(reg.regression_weights)  # (K, V)
    V = r.shape[1]
    w = np.zeros((V, B))
    np.add.at(
        w,
        (np.repeat(np.arange(V), model.vertex_bone_indices.shape[1]), _np(model.vertex_bone_indices).astype(int).ravel()),
        _np(model.vertex_bone_weights).ravel(),
    )
    a_kb = r @ w  # (K, B)
    pairs = np.argwhere(a_kb != 0)  # (N, 2) of (k, b)
    rk = r[pairs[:, 0]] * w[:, pairs[:, 1]].T  # (N, V)
    template = _np(model.template_vertices)
    blend = _np(model.blendshapes)  # (NC, V, 3)
    marker_template = rk @ template
    marker_blend = np.einsum("nv,cvx->cnx", rk, blend)

    # Arms: Anny's zero pose is an A-pose with bent elbows; for the default phenotype, turn each
    # upper arm onto the ±X axis and straighten the forearm along it, so that zero rotations
    # are a T-pose. Q_c are these T-pose world-aligned frames (Anny axes).
    out = model(phenotype_kwargs=None)
    heads = _np(out["bone_poses"])[0, :, :3, 3]
    rebase = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
    for side, prefix in (("L", "left_"), ("R", "right_")):
        shoulder, elbow, wrist = (labels.index(f"{b}.{side}") for b in ("upperarm01", "lowerarm01", "wrist"))
        upper = heads[elbow] - heads[shoulder]
        raise_arm = minimal_rotation(upper, np.array([np.sign(upper[0]), 0.0, 0.0]))
        straighten = minimal_rotation(heads[wrist] - heads[elbow], raise_arm @ upper)
        rebase[JOINT_NAMES.index(prefix + "shoulder")] = raise_arm
        rebase[JOINT_NAMES.index(prefix + "elbow")] = straighten
        rebase[JOINT_NAMES.index(prefix + "wrist")] = straighten

    anchors = {k: _np(v) for k, v in model.anchors.named_buffers()}
    from anny.models.model_data import PHENOTYPE_VARIATIONS

    features = ["gender", "age", "muscle", "weight", "height", "proportions", "cupsize", "firmness"]
    variation_feature, variation_anchor = [], []
    for feature, keys in PHENOTYPE_VARIATIONS.items():
        for i in range(len(keys)):
            variation_feature.append(features.index(feature) if feature in features else -1)
            variation_anchor.append(i)
    if list(model.phenotype_labels) != features[:6]:
        raise RuntimeError(f"Anny phenotype labels changed: {model.phenotype_labels}")

    return {
        "export_format": np.array(EXPORT_FORMAT),
        "anny_version": np.array(version("anny")),
        "feature_names": np.array(features),
        "anchors": np.stack([np.pad(anchors[f], (0, 5 - len(anchors[f])), constant_values=np.nan) for f in features]),
        "anchor_counts": np.array([len(anchors[f]) for f in features]),
        "variation_feature": np.array(variation_feature),
        "variation_anchor": np.array(variation_anchor),
        "blend_mask": _np(model.stacked_phenotype_blend_shapes_mask),
        "blend_projection": _np(model.phenotype_blendshape_projection),
        "head_template": _np(model.template_bone_heads),
        "head_blend": _np(model.bone_heads_blendshapes),
        "orient_template": _np(model.bone_template_orientation_matrices),
        "orient_blend": _np(model.bone_orientation_blendshapes),
        "reference_orientations": _np(model.reference_bone_orientations),
        "bone_parents": np.array(bone_parents),
        "bone_owner": owner,
        "bone_labels": np.array(labels),
        "step_to_offset": gamma,
        "step_to_position": delta,
        "toe_root": np.array([toe_root.get(b, -1) for b in range(B)]),
        "pair_keypoint": pairs[:, 0],
        "pair_bone": pairs[:, 1],
        "pair_weight": a_kb[pairs[:, 0], pairs[:, 1]],
        "marker_template": marker_template,
        "marker_blend": marker_blend,
        "rebase": rebase,
        "axes": SMPL_TO_ANNY_AXES,
    }
