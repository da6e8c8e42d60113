"""A body state between two states of a time grid, with the Jacobians of the interpolation.

Body graphs may place their states on a regular grid and explain each detection at its own
timestamp by the state a fraction ``a ∈ [0, 1]`` of the way from state ``k`` to state ``k + 1``:

- root pose: rotation by geodesic interpolation (slerp), ``R_a = R₀ Exp(a Log(R₀ᵀ R₁))``;
  translation (the pelvis) linearly, ``t_a = (1 − a) t₀ + a t₁``;
- joint rotations: the axis-angle vectors linearly, ``θ_a = (1 − a) θ₀ + a θ₁`` (exact in
  ``θ``; on a grid of 30 Hz a joint turns by a few degrees between states, where the axis-angle
  chord and the geodesic differ by well under a millimetre at the hand).

Tangent conventions are GTSAM's for ``Pose3``: ``[ω, v]``, rotation first, both in the body
frame (``R → R Exp(ω)``, ``t → t + R v`` to first order).
"""

from __future__ import annotations

import gtsam
import numpy as np

from mocapgraph.body.native import native_module


def interpolate_root(first: np.ndarray, second: np.ndarray, fraction: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The root pose a ``fraction ∈ [0, 1]`` of the way from ``first`` to ``second`` (``(4, 4)``
    world_T_root each), by the native kernel (about 5 µs a call).

    Returns ``(T_a (4, 4) world_T_root, A₀ (6, 6), A₁ (6, 6))`` where ``A_i = ∂ξ_a / ∂ξ_i`` maps a
    tangent perturbation of the first (second) pose to the interpolated pose's tangent. With
    ``Δ = Log(R₀ᵀR₁)`` and ``J = Jr(aΔ) Jr⁻¹(Δ)``:

        ∂ω_a/∂ω₀ = Exp(aΔ)ᵀ − a J R₁ᵀR₀     ∂ω_a/∂ω₁ = a J
        ∂v_a/∂v₀ = (1 − a) R_aᵀR₀           ∂v_a/∂v₁ = a R_aᵀR₁

    and the translation does not depend on the rotations. Log takes the shorter way round, so
    the two rotations should be less than π apart, which a time grid guarantees.
    """
    return native_module().interpolate_pose(
        np.ascontiguousarray(first, dtype=float), np.ascontiguousarray(second, dtype=float), float(fraction)
    )


def interpolate_root_reference(first: gtsam.Pose3, second: gtsam.Pose3, fraction: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`interpolate_root` from GTSAM's ``Rot3`` maps (about 35 µs): the independent
    reference the native kernel is tested against."""
    a = float(fraction)
    R0, R1 = first.rotation(), second.rotation()
    relative = R0.between(R1)
    delta = gtsam.Rot3.Logmap(relative)
    partial = gtsam.Rot3.Expmap(a * delta)
    Ra = R0.compose(partial).matrix()
    J = gtsam.Rot3.ExpmapDerivative(a * delta) @ gtsam.Rot3.LogmapDerivative(delta)
    R0m, R1m = R0.matrix(), R1.matrix()
    T = np.eye(4)
    T[:3, :3] = Ra
    T[:3, 3] = (1.0 - a) * first.translation() + a * second.translation()
    A0 = np.zeros((6, 6))
    A1 = np.zeros((6, 6))
    A0[:3, :3] = partial.matrix().T - a * J @ relative.matrix().T
    A1[:3, :3] = a * J
    A0[3:, 3:] = (1.0 - a) * Ra.T @ R0m
    A1[3:, 3:] = a * Ra.T @ R1m
    return T, A0, A1
