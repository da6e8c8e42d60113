"""Batch nonlinear least squares on a GTSAM factor graph, driven from Python.

Why not ``gtsam.LevenbergMarquardtOptimizer``: when the optimiser (C++) calls a Python
``CustomFactor``, pybind11 copies the whole C++-owned ``Values`` for every callback, so one
iteration costs O(N²) in the number of variables. Here every ``graph.linearize(values)`` and
``graph.error(values)`` call receives a ``Values`` that Python owns, so the callbacks see it
without a copy and an iteration stays O(N). GTSAM still does everything heavy: linearisation,
the sparse multifrontal solve (``GaussianFactorGraph.optimize(ordering)``) and the retraction
(``Values.retract``).

The module knows nothing about bodies or cameras; it works on any ``NonlinearFactorGraph``.

- :func:`levenberg_marquardt`: one LM (or Gauss-Newton) solve. Damping is ``λ·I`` on every
  variable, added as one ``JacobianFactor(key, √λ·I, 0)`` per variable; λ lives on a geometric
  grid (10 points per decade) so the damping graphs of recently used λ are cached. λ follows
  Nielsen's gain-ratio rule by default (``lambda_policy="nielsen"``), or GTSAM's fixed ×10 / ÷10
  (``"fixed"``).
- :func:`solve_staged`: several LM solves in a row, each after a setup callable (for example an
  annealed robust scale); the logs are concatenated.
- :func:`marginal_covariances`: marginal covariances at a solution from one linearisation on
  Python-owned values (``gtsam.Marginals`` on the ``GaussianFactorGraph``).

docs/solver.md describes the loop, the λ policy, the stopping rules and measured speeds.
"""

from __future__ import annotations

import logging
import math
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field

import gtsam
import numpy as np

from mocapgraph.errors import MocapgraphError
from mocapgraph.progress import progress_bar

log = logging.getLogger(__name__)

__all__ = [
    "SolverOptions",
    "SolveLog",
    "SolveResult",
    "levenberg_marquardt",
    "solve_staged",
    "marginal_covariances",
]

_GRID_PER_DECADE = 10
"""λ is always ``10 ** (k / _GRID_PER_DECADE)`` for an integer k, so damping graphs can be cached by k."""

_DAMPING_CACHE_SIZE = 16
_ORDERINGS = ("colamd", "time", "natural", "metis")
_ACTIVE_SET_ROUNDS = 3
_HOLD_WEIGHT = 1e8
"""Whitened weight of a row holding a clamped component: it moves by ~1e-15 of its target. Hard
``noiseModel.Constrained`` rows force QR in their clique, which fails (``IndeterminateSystemException``)
when a child clique passes up a semi-definite Hessian, as the body-and-camera graphs do."""
_MAX_STREAK = 4
_CURVATURE_JUMP = 1.0
"""After a rejected step, λ ≥ this × the curvature along the step (about halving that step)."""
_POLICIES = ("nielsen", "fixed")

CONVERGED_REASONS = frozenset(
    {"error_tolerance", "absolute_decrease", "relative_decrease", "small_step", "no_decrease"}
)
"""Stop reasons that count as convergence; the others are ``max_iterations``,
``lambda_upper_bound``, ``cost_increase`` and ``linear_solve_failed`` (the last two: Gauss-Newton only)."""


@dataclass(frozen=True)
class SolverOptions:
    """Settings of one LM (or Gauss-Newton) solve; in :func:`solve_staged`, of one stage.

    Tolerances are on the GTSAM cost ``½ Σ ‖whitened residual‖²`` (``graph.error``).
    """

    max_iterations: int = 100
    """Outer iterations (linearisations) at most; rejected LM tries do not count."""
    initial_lambda: float = 1e-5
    """Initial damping λ (absolute: the damping adds ``λ ‖δ‖²`` to the linear model); snapped to the λ grid."""
    lambda_lower_bound: float = 1e-10
    lambda_upper_bound: float = 1e10
    """LM gives up (``reason="lambda_upper_bound"``, not converged) when λ must rise above this."""
    relative_tolerance: float = 1e-5
    """Converged when an accepted step lowers the cost by at most this fraction of it."""
    absolute_tolerance: float = 1e-5
    """Converged when an accepted step lowers the cost by at most this much."""
    error_tolerance: float = 0.0
    """Converged when the cost is at most this."""
    step_tolerance: float = 1e-10
    """Converged when the tangent step ``‖δ‖₂`` is at most this."""
    min_model_fidelity: float = 1e-3
    """A step is accepted when actual / predicted cost decrease exceeds this (and the cost drops)."""
    lambda_policy: str = "nielsen"
    """``"nielsen"``: gain-ratio rule; ``"fixed"``: ÷ ``lambda_factor`` on accept, × on reject (GTSAM's default)."""
    lambda_factor: float = 10.0
    """Step factor of the ``"fixed"`` policy."""
    gauss_newton: bool = False
    """No damping. A step is taken when it does not raise the cost; otherwise the solve stops (``cost_increase``)."""
    ordering: str | Sequence[int] | gtsam.Ordering = "colamd"
    """Elimination order: ``"colamd"``; ``"time"`` (keys in order of first appearance in the graph's
    factors, i.e. the order they were inserted, then any key only in the values); ``"natural"``
    (sorted keys); ``"metis"``; or an explicit key sequence / ``gtsam.Ordering``. Computed once per solve."""

    def __post_init__(self) -> None:
        if self.max_iterations < 0:
            raise MocapgraphError(f"max_iterations: must be ≥ 0, got {self.max_iterations}")
        if not 0.0 < self.lambda_lower_bound <= self.lambda_upper_bound:
            raise MocapgraphError(
                "lambda bounds: need 0 < lambda_lower_bound ≤ lambda_upper_bound, got "
                f"{self.lambda_lower_bound}, {self.lambda_upper_bound}"
            )
        if not self.initial_lambda > 0.0:
            raise MocapgraphError(f"initial_lambda: must be > 0, got {self.initial_lambda}")
        if self.lambda_policy not in _POLICIES:
            raise MocapgraphError(f"lambda_policy: one of {_POLICIES}, got {self.lambda_policy!r}")
        if not self.lambda_factor > 1.0:
            raise MocapgraphError(f"lambda_factor: must be > 1, got {self.lambda_factor}")
        if isinstance(self.ordering, str) and self.ordering not in _ORDERINGS:
            raise MocapgraphError(f"ordering: one of {_ORDERINGS} or a key sequence, got {self.ordering!r}")


@dataclass
class SolveLog:
    """One linear solve (an LM try) of a solve; ``SolveResult.log`` holds these as dicts."""

    stage: str
    """Stage name (``""`` outside :func:`solve_staged`)."""
    iteration: int
    """Outer iteration in the stage, from 1; all tries of one iteration share its linearisation."""
    attempt: int
    """Try within the iteration, from 1 (LM re-solves with larger λ after a rejected step)."""
    cost_before: float
    cost_after: float
    """Cost at the tried point, after ``project``; ``inf`` when the linear solve failed."""
    predicted_decrease: float
    """Decrease of the undamped linear model along the step taken (after ``project``), ``L(0) − L(δ)``."""
    gain: float
    """``(cost_before − cost_after) / predicted_decrease`` (NaN when the prediction is ~0)."""
    lambda_: float
    """Damping used for this try (0 for Gauss-Newton)."""
    accepted: bool
    step_norm: float
    """``‖δ‖₂`` of the tangent step taken (after ``project``; NaN when the linear solve failed)."""
    seconds: float
    """Wall time of this try, including the iteration's linearisation on the first try."""
    linearize_seconds: float
    solve_seconds: float
    """Damping, linear solve(s), retraction and ``project``."""
    error_seconds: float
    """The cost evaluation at the tried point."""
    active_set_solves: int = 0
    """Extra linear solves with clamped components held (only with ``project``; see :func:`levenberg_marquardt`)."""

    def as_row(self) -> dict:
        return asdict(self)


@dataclass
class SolveResult:
    values: gtsam.Values
    """The solution (a new, Python-owned ``Values``)."""
    log: list[dict]
    """One :class:`SolveLog` row (as a dict) per linear solve, all stages concatenated."""
    iterations: int
    """Outer iterations (linearisations), summed over stages."""
    error: float
    """Final cost ``graph.error(values)``."""
    converged: bool
    """The (last) stage stopped on a tolerance, not on a limit; see ``CONVERGED_REASONS``."""
    seconds: float
    reason: str = ""
    """Why the (last) stage stopped."""
    initial_error: float = math.nan
    final_lambda: float = math.nan
    """λ at the end (of the last stage): a warm start for a follow-up solve."""
    stage_reasons: dict[str, str] = field(default_factory=dict)
    """Stop reason per stage name (one entry for a single solve)."""


class _LambdaGrid:
    """λ = 10^(k/10) with an integer k, clamped to the bounds, and Nielsen's ν for rejections."""

    def __init__(self, options: SolverOptions, initial: float | None = None) -> None:
        self.k_min = math.ceil(_GRID_PER_DECADE * math.log10(options.lambda_lower_bound) - 1e-9)
        self.k_max = math.floor(_GRID_PER_DECADE * math.log10(options.lambda_upper_bound) + 1e-9)
        start = options.initial_lambda if initial is None else initial
        self.k = min(max(round(_GRID_PER_DECADE * math.log10(start)), self.k_min), self.k_max)
        self.policy = options.lambda_policy
        self.fixed_steps = max(1, round(_GRID_PER_DECADE * math.log10(options.lambda_factor)))
        self.nu = 2.0
        self.streak = 0

    @property
    def value(self) -> float:
        return 10.0 ** (self.k / _GRID_PER_DECADE)

    def accepted(self, gain: float) -> None:
        if self.policy == "fixed":
            steps = -self.fixed_steps
        else:
            # Nielsen: λ ← λ · max(1/3, 1 − (2ρ − 1)³): strong decrease for ρ ≈ 1, slight increase
            # for ρ < ½. A run of steps at the 1/3 floor (model near-exact) decreases λ 3×, 9×,
            # 27×, …: the mirror image of ν doubling on rejections.
            factor = 1.0 / 3.0 if not math.isfinite(gain) else 1.0 - (2.0 * gain - 1.0) ** 3
            if factor <= 1.0 / 3.0:
                self.streak += 1
                factor = (1.0 / 3.0) ** min(self.streak, _MAX_STREAK)
            else:
                self.streak = 0
            steps = round(_GRID_PER_DECADE * math.log10(factor))
            self.nu = 2.0
        self.k = max(self.k + steps, self.k_min)

    def rejected(self, curvature: float = math.nan) -> bool:
        """Raise λ; False when it would pass the upper bound.

        ``curvature`` is the model's curvature along the rejected step, ``δᵀHδ / ‖δ‖²``. Under
        the Nielsen policy λ jumps to at least ``_CURVATURE_JUMP × curvature`` at once: a λ far
        below it barely shortens the step, so doubling from there only wastes solves.
        """
        if self.policy == "fixed":
            steps = self.fixed_steps
        else:
            steps = max(1, round(_GRID_PER_DECADE * math.log10(self.nu)))
            self.nu *= 2.0
            self.streak = 0
            if curvature > 0.0 and math.isfinite(curvature):
                jump = math.ceil(_GRID_PER_DECADE * math.log10(_CURVATURE_JUMP * curvature)) - self.k
                steps = max(steps, jump)
        if self.k + steps > self.k_max:
            return False
        self.k += steps
        return True


class _Damping:
    """Cached graphs of ``JacobianFactor(key, √λ·I, 0)`` over every variable, one per grid λ."""

    def __init__(self, dims: dict[int, int]) -> None:
        self.dims = dims
        self.cache: OrderedDict[int, gtsam.GaussianFactorGraph] = OrderedDict()
        self.noise = {d: gtsam.noiseModel.Unit.Create(d) for d in set(dims.values())}
        self.zeros = {d: np.zeros(d) for d in self.noise}

    def graph(self, k: int, lam: float) -> gtsam.GaussianFactorGraph:
        cached = self.cache.get(k)
        if cached is not None:
            self.cache.move_to_end(k)
            return cached
        root = math.sqrt(lam)
        blocks = {d: np.asfortranarray(root * np.eye(d)) for d in self.noise}  # F order: ~25 % faster to wrap
        damping = gtsam.GaussianFactorGraph()
        for key, d in self.dims.items():
            damping.push_back(gtsam.JacobianFactor(key, blocks[d], self.zeros[d], self.noise[d]))
        self.cache[k] = damping
        if len(self.cache) > _DAMPING_CACHE_SIZE:
            self.cache.popitem(last=False)
        return damping


def _keys_in_insertion_order(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> list[int]:
    seen: dict[int, None] = {}
    for i in range(graph.size()):
        factor = graph.at(i)
        if factor is not None:
            for key in factor.keys():
                seen.setdefault(key, None)
    present = set(values.keys())
    ordered = [key for key in seen if key in present]
    ordered += sorted(present.difference(seen))
    return ordered


def _make_ordering(
    choice, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, system: gtsam.GaussianFactorGraph
) -> gtsam.Ordering:
    if isinstance(choice, gtsam.Ordering):
        return choice
    if isinstance(choice, str):
        if choice == "colamd":
            return gtsam.Ordering.ColamdGaussianFactorGraph(system)
        if choice == "metis":
            return gtsam.Ordering.MetisGaussianFactorGraph(system)
        if choice == "natural":
            return gtsam.Ordering(sorted(values.keys()))
        return gtsam.Ordering(_keys_in_insertion_order(graph, values))
    return gtsam.Ordering([int(key) for key in choice])


def _combined(linear: gtsam.GaussianFactorGraph, damping: gtsam.GaussianFactorGraph | None):
    if damping is None:
        return linear
    system = gtsam.GaussianFactorGraph()
    system.push_back(linear)
    system.push_back(damping)
    return system


def _solve(system: gtsam.GaussianFactorGraph, ordering: gtsam.Ordering) -> gtsam.VectorValues | None:
    try:
        return system.optimize(ordering)  # multifrontal, Cholesky where possible
    except RuntimeError:  # indeterminate (singular) system
        return None


class _Projection:
    """The ``project`` hook, with an active set so that clamping does not stall LM.

    A plain "step, then clamp" stalls at a bound: the step of the other variables was solved
    assuming the clamped components move, so the clamped point gains little and LM keeps raising
    λ. Here the components the hook changed are held at their projected values (stiff rows of
    weight ``_HOLD_WEIGHT`` on just those components) and the damped system is solved again, so
    the free variables take their best step given the clamp. Which components moved is read
    from the tangent step ``localCoordinates(projected) − δ``, so the hook stays free to act on
    any variable.

    The active set is kept from one try to the next: a component that sat at a bound after the
    last accepted step is held there from the first solve of the next try, which saves a solve
    per try while a bound stays active (every try of a long fit, when a shape parameter rests on
    its limit). A held component is released when the damped model's gradient at the solution
    points into the feasible set (the hook leaves a small move that way alone). Up to
    ``_ACTIVE_SET_ROUNDS`` extra solves per try add or release components.
    """

    def __init__(self, project: Callable[[gtsam.Values], gtsam.Values | None], values: gtsam.Values) -> None:
        self.project = project
        dims = values.dims()
        self.keys = sorted(dims)
        sizes = np.array([dims[key] for key in self.keys], dtype=int)
        self.offsets = np.concatenate(([0], np.cumsum(sizes)))
        self.owner = np.repeat(np.arange(len(self.keys)), sizes)
        self.units: dict[int, gtsam.noiseModel.Base] = {}
        self.held: dict[int, float] = {}  # flat index -> tangent value it is held at, from `base`
        self.base: gtsam.Values | None = None

    def apply(self, values: gtsam.Values, delta: gtsam.VectorValues) -> tuple[gtsam.Values, gtsam.VectorValues]:
        candidate = values.retract(delta)
        projected = self.project(candidate)
        candidate = candidate if projected is None else projected
        return candidate, values.localCoordinates(candidate)

    def flat(self, vector: gtsam.VectorValues) -> np.ndarray | None:
        try:
            return vector.vector(self.keys)
        except (RuntimeError, IndexError, ValueError):  # lacks a key (Gauss-Newton, unused key)
            return None

    def moved(self, delta: gtsam.VectorValues, step: gtsam.VectorValues) -> np.ndarray:
        """Flat indices (in sorted-key layout) of the tangent components the hook changed."""
        wanted, taken = self.flat(delta), self.flat(step)
        if wanted is None or taken is None:
            return np.zeros(0, dtype=int)
        return np.flatnonzero(np.abs(taken - wanted) > 1e-9 * (1.0 + np.abs(wanted)))

    def unit(self, dim: int) -> gtsam.noiseModel.Base:
        if dim not in self.units:
            self.units[dim] = gtsam.noiseModel.Unit.Create(dim)
        return self.units[dim]

    def with_holds(self, system: gtsam.GaussianFactorGraph, held: dict[int, float]) -> gtsam.GaussianFactorGraph:
        if not held:
            return system
        constrained = gtsam.GaussianFactorGraph()
        constrained.push_back(system)  # Cholesky handles a stiff diagonal row: it is invariant to diagonal scaling
        indices = np.array(sorted(held))
        for owner in np.unique(self.owner[indices]):
            rows = indices[self.owner[indices] == owner]
            key, dim = self.keys[owner], int(self.offsets[owner + 1] - self.offsets[owner])
            select = np.eye(dim)[rows - self.offsets[owner]]
            target = np.array([held[int(i)] for i in rows])
            constrained.push_back(gtsam.JacobianFactor(key, _HOLD_WEIGHT * select, _HOLD_WEIGHT * target, self.unit(len(rows))))
        return constrained

    def releasable(self, values, system, delta, held) -> list[int]:
        """Held components whose model gradient at ``delta`` points into the feasible set."""
        gradient, flat = self.flat(system.gradient(delta)), self.flat(delta)
        if gradient is None or flat is None:
            return []
        indices = np.array(sorted(held))
        probe = flat.copy()
        probe[indices] -= 1e-6 * (1.0 + np.abs(flat[indices])) * np.sign(gradient[indices])
        moved = gtsam.VectorValues()  # only the variables owning held components differ from delta
        for owner in np.unique(self.owner[indices]):
            moved.insert(self.keys[owner], probe[self.offsets[owner] : self.offsets[owner + 1]])
        probe_delta = gtsam.VectorValues(delta)
        probe_delta.update(moved)
        clamped = set(self.moved(probe_delta, self.apply(values, probe_delta)[1]).tolist())
        return [int(i) for i in indices if gradient[i] != 0.0 and i not in clamped]

    def solve(self, values, system, ordering) -> tuple[gtsam.Values | None, gtsam.VectorValues | None, int, bool]:
        """(projected candidate, its tangent step, linear solves, whether components were held);
        a None candidate when a linear solve failed."""
        if values is not self.base:  # a step was accepted: the held components now sit at their bounds
            self.held = {i: 0.0 for i in self.held}
            self.base = values
        held = dict(self.held)
        candidate = step = None
        solves = 0
        for _ in range(_ACTIVE_SET_ROUNDS + 1):
            delta = _solve(self.with_holds(system, held), ordering)
            solves += 1
            if delta is None:
                return None, None, solves, bool(held)
            candidate, step = self.apply(values, delta)
            new = [int(i) for i in self.moved(delta, step) if int(i) not in held]
            released = self.releasable(values, system, delta, held) if held else []
            if not new and not released:
                break
            flat = self.flat(step)
            held.update((i, float(flat[i])) for i in new)
            for i in released:
                del held[i]
        self.held = held
        return candidate, step, solves, bool(held)


def _stop_after_step(opts: SolverOptions, cost: float, decrease: float, step_norm: float) -> str:
    """The convergence reason after an accepted step that lowered the cost to ``cost`` by ``decrease``, or ""."""
    if cost <= opts.error_tolerance:
        return "error_tolerance"
    if decrease <= opts.absolute_tolerance:
        return "absolute_decrease"
    if decrease <= opts.relative_tolerance * (cost + decrease):
        return "relative_decrease"
    if step_norm <= opts.step_tolerance:
        return "small_step"
    return ""


def _log_row(row: SolveLog) -> None:
    log.debug(
        "[lm %s] it %3d.%-2d cost %.6g -> %.6g pred %.3g gain %.3g lambda %.3g %s |step| %.3g %.1f ms",
        row.stage or "-", row.iteration, row.attempt, row.cost_before, row.cost_after, row.predicted_decrease, row.gain,
        row.lambda_, "accept" if row.accepted else "reject", row.step_norm, row.seconds * 1e3,
    )  # fmt: skip


def levenberg_marquardt(
    graph: gtsam.NonlinearFactorGraph,
    initial: gtsam.Values,
    options: SolverOptions | None = None,
    *,
    project: Callable[[gtsam.Values], gtsam.Values | None] | None = None,
    on_iteration: Callable[[dict], None] | None = None,
    stage: str = "",
    initial_lambda: float | None = None,
) -> SolveResult:
    """Minimise ``graph.error`` from ``initial`` by Levenberg-Marquardt (or Gauss-Newton) in Python.

    Each outer iteration linearises once; a rejected step is re-solved on the same linearisation
    with a larger λ.

    ``project(values)`` (optional) maps every tried point back into the feasible set (e.g. clamps
    a bounded vector) and returns the projected values, or None after changing them in place. It
    must not add or remove keys. The cost is evaluated *after* projecting and decides acceptance,
    so the cost never rises. When the hook changes some tangent components, they are held at
    their projected values and the damped system is solved again (an active set; up to 3 extra
    solves per try, logged as ``active_set_solves``), so the free variables do not stall at a bound.

    ``on_iteration(row)`` receives each log row (one per LM try) as it is made.
    ``stage`` labels the log rows; ``initial_lambda`` overrides ``options.initial_lambda``.
    ``initial`` is not modified.
    """
    opts = options if options is not None else SolverOptions()
    start = time.perf_counter()
    values = gtsam.Values(initial)  # Python-owned: factor callbacks see it without a copy
    cost = graph.error(values)
    initial_error = cost
    grid = _LambdaGrid(opts, initial_lambda)
    damping = None if opts.gauss_newton else _Damping(values.dims())
    projection = project if isinstance(project, _Projection) or project is None else _Projection(project, values)
    ordering: gtsam.Ordering | None = None
    rows: list[dict] = []
    iterations = 0
    reason = "error_tolerance" if cost <= opts.error_tolerance else ""

    while not reason:
        if iterations >= opts.max_iterations:
            reason = "max_iterations"
            break
        iterations += 1
        t_lin = time.perf_counter()
        linear = graph.linearize(values)
        model_at_zero = linear.error(values.zeroVectors())
        linearize_seconds = time.perf_counter() - t_lin
        attempt = 0
        while True:
            attempt += 1
            t_try = time.perf_counter()
            lam = 0.0 if damping is None else grid.value
            system = _combined(linear, None if damping is None else damping.graph(grid.k, lam))
            if ordering is None:
                ordering = _make_ordering(opts.ordering, graph, values, system)
            if projection is None:
                step = _solve(system, ordering)
                candidate, extra_solves, held = None if step is None else values.retract(step), 0, False
            else:
                candidate, step, solves, held = projection.solve(values, system, ordering)
                extra_solves = solves - 1
            t_solved = time.perf_counter()
            if candidate is None:
                predicted, step_norm, new_cost = math.nan, math.nan, math.inf
            else:
                predicted = model_at_zero - linear.error(step)
                step_norm = step.norm()
                new_cost = graph.error(candidate)
                if not math.isfinite(new_cost):  # NaN or overflow at the tried point: reject it
                    new_cost = math.inf
            actual = cost - new_cost
            tiny_prediction = not predicted > 1e-15 * max(model_at_zero, cost)
            gain = math.nan if tiny_prediction else actual / predicted
            if candidate is None:
                accepted = False
            elif damping is None:
                accepted = actual >= 0.0
            else:
                accepted = actual > 0.0 and (tiny_prediction or gain > opts.min_model_fidelity)
            t_end = time.perf_counter()
            row = SolveLog(
                stage=stage,
                iteration=iterations,
                attempt=attempt,
                cost_before=cost,
                cost_after=new_cost,
                predicted_decrease=predicted,
                gain=gain,
                lambda_=lam,
                accepted=accepted,
                step_norm=step_norm,
                seconds=t_end - t_try + (linearize_seconds if attempt == 1 else 0.0),
                linearize_seconds=linearize_seconds if attempt == 1 else 0.0,
                solve_seconds=t_solved - t_try,
                error_seconds=t_end - t_solved,
                active_set_solves=extra_solves,
            )
            _log_row(row)
            rows.append(row.as_row())
            if on_iteration is not None:
                on_iteration(rows[-1])

            if accepted:
                values, cost = candidate, new_cost
                if damping is not None:
                    grid.accepted(gain)
                reason = _stop_after_step(opts, cost, actual, step_norm)
                break
            if damping is None:
                reason = "linear_solve_failed" if candidate is None else "cost_increase"
                break
            # Rejected LM step. Stop when even the model promises no significant decrease and the
            # actual change is as small (we are at a minimum up to rounding), or the step is tiny.
            negligible = max(opts.absolute_tolerance, opts.relative_tolerance * cost)
            if candidate is not None and predicted <= negligible and abs(actual) <= negligible:
                reason = "no_decrease"
                break
            if candidate is not None and step_norm <= opts.step_tolerance:
                reason = "small_step"
                break
            curvature = math.nan
            if not held and candidate is not None and step_norm > 0.0:
                # For the exact LM step, L(0) − L(δ) = ½ δᵀHδ + λ‖δ‖².
                curvature = 2.0 * (predicted - lam * step_norm**2) / step_norm**2
            if not grid.rejected(curvature):
                reason = "lambda_upper_bound"
                break

    return SolveResult(
        values=values,
        log=rows,
        iterations=iterations,
        error=cost,
        converged=reason in CONVERGED_REASONS,
        seconds=time.perf_counter() - start,
        reason=reason,
        initial_error=initial_error,
        final_lambda=0.0 if damping is None else grid.value,
        stage_reasons={stage: reason},
    )


def solve_staged(
    graph: gtsam.NonlinearFactorGraph,
    initial: gtsam.Values,
    stages: Sequence[tuple[str, Callable[[], None] | None, SolverOptions | None]],
    progress: str = "",
    **kw,
) -> SolveResult:
    """Run :func:`levenberg_marquardt` once per stage, each from the previous stage's solution.

    Before stage ``(name, setup, options)`` runs, ``setup()`` is called (e.g. to change a robust
    scale that the graph's factors share; ``None`` skips it). Each stage re-evaluates the cost,
    so the setup may change the objective. ``kw`` (``project``, ``on_iteration``) is passed to
    every stage; the active set of ``project`` carries over from one stage to the next (a
    bound reached in one stage is held from the next stage's first solve). The result's log
    concatenates the stages (column ``stage``), ``iterations`` sums them, and ``converged`` /
    ``reason`` are the last stage's. ``progress`` labels a bar of the iterations (their most:
    every stage's ``max_iterations``), for solves long enough to wait for.
    """
    if not stages:
        raise MocapgraphError("stages: need at least one (name, setup, options) stage")
    if "stage" in kw or "initial_lambda" in kw:
        raise MocapgraphError("solve_staged: 'stage' and 'initial_lambda' are set per stage")
    start = time.perf_counter()
    values = initial
    if kw.get("project") is not None:
        kw["project"] = _Projection(kw["project"], initial)
    rows: list[dict] = []
    iterations = 0
    initial_error = math.nan
    stage_reasons: dict[str, str] = {}
    result: SolveResult | None = None
    bar = progress_bar(total=sum((o or SolverOptions()).max_iterations for _, _, o in stages), desc=progress, unit="it") if progress else None
    if bar is not None:
        given = kw.get("on_iteration")

        def on_iteration(row: dict) -> None:
            if row["attempt"] == 1:
                bar.update()
            if given is not None:
                given(row)

        kw["on_iteration"] = on_iteration
    for name, setup, options in stages:
        if setup is not None:
            setup()
        result = levenberg_marquardt(graph, values, options, stage=name, **kw)
        if math.isnan(initial_error):
            initial_error = result.initial_error
        values = result.values
        rows.extend(result.log)
        iterations += result.iterations
        stage_reasons[name] = result.reason
    if bar is not None:
        bar.close()
    assert result is not None
    return SolveResult(
        values=values,
        log=rows,
        iterations=iterations,
        error=result.error,
        converged=result.converged,
        seconds=time.perf_counter() - start,
        reason=result.reason,
        initial_error=initial_error,
        final_lambda=result.final_lambda,
        stage_reasons=stage_reasons,
    )


def annealed_stages(scale, sigma_px: float, iterations: int, ordering: str | Sequence[int] = "colamd") -> list:
    """Stages for :func:`solve_staged`: L2 until the cost settles (relative tolerance 1e-2), then
    the robust kernel at ``sigma_px`` (1e-3), by setting ``scale.sigma_px`` (a shared
    :class:`~mocapgraph.factors.robust.RobustScale`) before each. Robust costs from a poor start stall.

    λ starts at 1: a body's rotations make the first steps far from linear, and a small initial
    damping spent most solves on rejected steps (39 solves against 19, measured on AirCap).
    """

    def stage(rel_tol: float) -> SolverOptions:
        return SolverOptions(max_iterations=iterations, relative_tolerance=rel_tol, initial_lambda=1.0, ordering=ordering)

    return [
        ("l2", lambda: setattr(scale, "sigma_px", math.inf), stage(1e-2)),
        ("geman-mcclure", lambda: setattr(scale, "sigma_px", sigma_px), stage(1e-3)),
    ]


def marginal_covariances(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys: Iterable[int]
) -> dict[int, np.ndarray]:
    """Marginal covariance of each key at ``values`` (normally the solution), in its tangent space.

    Linearises once from Python (no per-callback ``Values`` copy with CustomFactors, unlike
    ``gtsam.Marginals(graph, values)``) and runs ``gtsam.Marginals`` on the Gaussian factor graph.
    Each matrix is ``dim × dim`` in the variable's local coordinates, the coordinates of
    ``Values.retract``: for a ``Pose3`` the rotation first, then the translation,
    ``[ωx, ωy, ωz, tx, ty, tz]``, both in the body frame (``x ⊕ ξ = x · Exp(ξ)``); for a vector
    its own entries. Covariances are in the units of the whitened residuals' inverse, i.e. the
    noise models' sigmas.
    """
    wanted = [int(key) for key in keys]
    missing = [key for key in wanted if not values.exists(key)]
    if missing:
        raise MocapgraphError(f"keys: not in values: {[gtsam.DefaultKeyFormatter(k) for k in missing]}")
    linear = graph.linearize(values)
    marginals = gtsam.Marginals(linear, values)
    return {key: np.array(marginals.marginalCovariance(key)) for key in wanted}


HOLD_SIGMA = 1e-5
"""σ (rad, m) of the priors that hold a variable at its value during a phase of a solve."""


def held(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys: Iterable[int]) -> gtsam.NonlinearFactorGraph:
    """A copy of ``graph`` with every key of ``keys`` (those in ``values``) held at its value by a
    stiff prior. Stiff rows rather than removing the variables: the graph's structure and its
    elimination order stay as they are, and the same graph gives the covariances with them free."""
    out = gtsam.NonlinearFactorGraph(graph)
    for key in keys:
        if not values.exists(key):
            continue
        try:
            pose = values.atPose3(key)
        except RuntimeError:
            vec = values.atVector(key)
            out.add(gtsam.PriorFactorVector(key, vec, gtsam.noiseModel.Isotropic.Sigma(len(vec), HOLD_SIGMA)))
        else:
            out.add(gtsam.PriorFactorPose3(key, pose, gtsam.noiseModel.Isotropic.Sigma(6, HOLD_SIGMA)))
    return out
