"""Left/right labellings of a keypoint format: the swaps 2D detectors make, as permutations.

A detector that confuses the person's sides reports each left point under its right name and
vice versa, for the whole body (seen from behind, or with the face hidden) or for one pair of
limbs (legs crossing in a side view). Each such mistake is a permutation of the format's points;
the simulator applies them (:mod:`mocapgraph.data_tools.sim.detectors`) and the solvers undo them
(:mod:`mocapgraph.factors.reprojection` takes one hypothesis per camera-frame).

Kinds, in the order their integer codes use (``SWAP_KINDS.index(kind)``):

- ``"none"``: the labels as detected;
- ``"body"``: every left/right pair exchanged (face, torso and limbs);
- ``"arms"``: elbows, wrists and hand points exchanged, shoulders kept;
- ``"legs"``: knees, ankles and foot points exchanged, hips kept.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mocapgraph.body.skeleton import left_right_pairs

SWAP_KINDS: tuple[str, ...] = ("none", "body", "arms", "legs")
"""Labelling hypotheses; a swap's integer code is its index here."""

LIMB_PARTS: dict[str, tuple[str, ...]] = {
    "arms": ("elbow", "wrist", "pinky", "index", "thumb", "hand"),
    "legs": ("knee", "ankle", "heel", "big_toe", "small_toe", "foot_index", "toe"),
}
"""The parts (point names without their side) whose labels a limb swap exchanges."""


def part_name(point_name: str) -> str:
    """A point's body part without its side: ``left_wrist`` → ``wrist``, ``mouth_left`` → ``mouth``."""
    for side in ("left_", "right_"):
        if point_name.startswith(side):
            return point_name[len(side) :]
    for side in ("_left", "_right"):
        if point_name.endswith(side):
            return point_name[: -len(side)]
    return point_name


def swap_permutation(names: Sequence[str], kind: str) -> np.ndarray:
    """``(K,)`` index array ``p`` such that ``detections[..., p, :]`` applies (or undoes: every
    swap is its own inverse) the left/right swap ``kind`` on a format with point ``names``."""
    if kind not in SWAP_KINDS:
        raise ValueError(f"unknown swap kind {kind!r}; expected one of {', '.join(SWAP_KINDS)}")
    names = list(names)
    perm = np.arange(len(names))
    if kind == "none":
        return perm
    parts = None if kind == "body" else LIMB_PARTS[kind]
    pairs = list(left_right_pairs(names))
    # BlazePose's mouth_left / mouth_right carry the side as a suffix
    pairs += [(i, names.index(n[:-5] + "_right")) for i, n in enumerate(names) if n.endswith("_left") and n[:-5] + "_right" in names]
    for i, j in pairs:
        if parts is None or part_name(names[i]) in parts:
            perm[i], perm[j] = j, i
    return perm


def swap_permutations(names: Sequence[str]) -> np.ndarray:
    """``(H, K)`` every labelling hypothesis of a format with point ``names``: row ``h`` is
    :func:`swap_permutation` of ``SWAP_KINDS[h]``, so a view's label code indexes it."""
    return np.stack([swap_permutation(names, kind) for kind in SWAP_KINDS])


def then(names: Sequence[str], first: int, second: int) -> int:
    """The code of relabelling by swap ``first`` and then by ``second`` (codes of
    :data:`SWAP_KINDS`), or ``second`` when the two together are no single kind (e.g. the whole
    body and then the legs back: the arms and the trunk alone)."""
    if first <= 0 or second <= 0:
        return max(first, second, 0)
    both = swap_permutation(names, SWAP_KINDS[first])[swap_permutation(names, SWAP_KINDS[second])]
    for code, kind in enumerate(SWAP_KINDS):
        if np.array_equal(both, swap_permutation(names, kind)):
            return code
    return second


__all__ = ["LIMB_PARTS", "SWAP_KINDS", "part_name", "swap_permutation", "then"]
