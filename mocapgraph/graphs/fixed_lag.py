"""A fixed-lag smoother on GTSAM's iSAM2, as the online loop drives it.

:class:`FixedLagSmoother`: every key carries a timestamp (seconds); an update marginalises the
keys older than the newest timestamp minus the lag, so the graph, and the cost of an update, stay
bounded however long the stream runs. A key that all times share (a static camera, a camera's GPS
offset) stays in the window by being given the newest timestamp again at every update
(:meth:`FixedLagSmoother.update`'s ``keep``). It does what GTSAM's ``IncrementalFixedLagSmoother``
does, with the elimination order kept in time (the class docstring says why).

Two things the GTSAM performance notes (``notes/gtsam_performance.md`` §3) measured:

- Python ``CustomFactor`` callbacks that receive a C++-owned ``Values`` copy the whole of it on
  every call unless a Python reference to it exists: the wrapper holds
  ``getLinearizationPoint()`` for the smoother's life.
- The latency's p95 comes from iSAM2's relinearisation (every ``skip`` updates, all variables
  whose delta exceeds ``threshold``): :class:`Relinearisation` sets both, and optionally a
  second cheap iSAM2 pass per update (``extra_updates``); ``mocapgraph bench online`` measures
  the choice (``docs/online.md``).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import gtsam
import numpy as np

from mocapgraph.errors import MocapgraphError

log = logging.getLogger(__name__)


# iSAM2's batch-step threshold (0.65, ISAM2.cpp's kBatchThreshold) with a margin either side
_BATCH_MARGIN = (0.6, 0.7)


@dataclass(frozen=True)
class Relinearisation:
    """iSAM2's relinearisation policy.

    Attributes:
        threshold: a variable is relinearised when its delta exceeds this (tangent norm units:
            radians and metres mixed, as iSAM2 compares them).
        skip: relinearisation is considered every ``skip`` updates (1: at every update).
        extra_updates: iSAM2 passes without new factors after each update (each re-solves with
            the relinearisation check; 0: one pass, the smoother's default).
        per_type: thresholds by key character (e.g. ``(("q", 0.3), ("r", 0.05))``) replacing
            ``threshold`` for the variables of that type (iSAM2 compares each tangent component).
        partial_check: iSAM2 checks only the cliques the update touches for relinearisation
            (cheaper; deltas deep in the tree wait until an update reaches them).
        enabled: False: iSAM2 never relinearises; each factor stays linearised where its
            variables started (their prediction, for a new state), the Gauss-Newton step from
            there is the estimate.
    """

    threshold: float = 0.1
    skip: int = 10
    extra_updates: int = 0
    per_type: tuple[tuple[str, float], ...] = ()
    partial_check: bool = False
    enabled: bool = True

    def check(self) -> None:
        if not (np.isfinite(self.threshold) and self.threshold > 0):
            raise MocapgraphError(f"relinearisation.threshold: a finite number > 0, got {self.threshold!r}")
        if not (isinstance(self.skip, int) and self.skip >= 1):
            raise MocapgraphError(f"relinearisation.skip: a whole number of updates >= 1, got {self.skip!r}")
        if not (isinstance(self.extra_updates, int) and 0 <= self.extra_updates <= 5):
            raise MocapgraphError(f"relinearisation.extra_updates: a whole number in [0, 5], got {self.extra_updates!r}")
        if not isinstance(self.enabled, bool):
            raise MocapgraphError(f"relinearisation.enabled: True or False, got {self.enabled!r}")
        for entry in self.per_type:
            if not (len(entry) == 2 and isinstance(entry[0], str) and len(entry[0]) == 1 and np.isfinite(entry[1]) and entry[1] > 0):
                raise MocapgraphError(f"relinearisation.per_type: (key character, threshold > 0) pairs, got {entry!r}")

    def params(self, dims: dict[str, int]) -> gtsam.ISAM2Params:
        """iSAM2's parameters; ``dims`` gives each key character's tangent dimension (with
        ``per_type``, iSAM2 looks every variable's type up, so every type in the graph must be listed)."""
        params = gtsam.ISAM2Params()
        if self.per_type:
            thresholds = gtsam.ISAM2ThresholdMap()
            given = dict(self.per_type)
            for char, dim in dims.items():
                thresholds.insert((char, np.full(dim, given.get(char, self.threshold))))
            params.setRelinearizeThreshold(thresholds)
        else:
            params.setRelinearizeThreshold(self.threshold)
        params.relinearizeSkip = self.skip
        params.enablePartialRelinearizationCheck = self.partial_check
        params.enableRelinearization = self.enabled
        return params


@dataclass
class UpdateReport:
    """What one :meth:`FixedLagSmoother.update` did.

    Attributes:
        seconds: wall time of the iSAM2 update(s).
        relinearised: variables iSAM2 relinearised in the first pass.
        reeliminated: variables iSAM2 eliminated again in the first pass (new ones included).
        batch: whether iSAM2's first pass fell back to a batch step (re-ordered and relinearised
            every factor in the window: more than 65 % of its variables were affected).
        marginalised: keys that left the window (their last estimates are in ``left``).
        left: the estimates of the ``marginalised`` keys from before this update (the smoother
            no longer holds them after it; a key added and marginalised by the same update at
            that update's estimate).
    """

    seconds: float
    relinearised: int
    reeliminated: int
    batch: bool
    marginalised: list[int]
    left: gtsam.Values


class FixedLagSmoother:
    """A fixed-lag smoother of ``lag_s`` seconds on ``gtsam.ISAM2`` with the ``relinearisation``
    policy; ``dims``: the tangent dimension of each key character the graph uses (for ``per_type``).

    GTSAM's ``IncrementalFixedLagSmoother`` constrains iSAM2's elimination order only to put the
    keys leaving the window first; CCOLAMD then placed a state from the middle of the window near
    the Bayes tree's root, and when it left, re-eliminating its subtree touched more than 65 % of
    the variables: iSAM2 fell back to a batch step (every factor linearised again, ~10x an
    update's cost: the latency's p95 on ``rich``). Here every update orders the variables it
    re-eliminates by their timestamps (older first, the leaving ones before all), so the tree is
    a chain with the newest states at its root: a new state re-eliminates only the cliques near
    the root, and the oldest keys are always leaves that ``marginalizeLeaves`` can remove. Keys
    kept at the newest timestamp are re-eliminated at every update so that none stays below a
    leaving key.

    Attributes:
        lag_s: the window, seconds.
        estimate: every key in the window at its current estimate (after the last update).
        timestamps: key → the timestamp the window keeps it by.
    """

    def __init__(self, lag_s: float, relinearisation: Relinearisation = Relinearisation(), dims: dict[str, int] | None = None):
        if not (np.isfinite(lag_s) and lag_s > 0):
            raise MocapgraphError(f"lag_s: a finite number of seconds > 0, got {lag_s!r}")
        relinearisation.check()
        params = relinearisation.params(dims or {})
        # Marginalised factors leave empty slots behind; re-using them keeps the factor graph's
        # size bounded by the window rather than by the stream.
        params.findUnusedFactorSlots = True
        self.lag_s = float(lag_s)
        self.relinearisation = relinearisation
        self.isam = gtsam.ISAM2(params)
        self.estimate = gtsam.Values()
        self.timestamps: dict[int, float] = {}
        self._linearization_point = None  # held: see the module docstring

    @property
    def newest(self) -> float:
        """The newest timestamp in the window (-inf before the first update)."""
        return max(self.timestamps.values(), default=-np.inf)

    def holds(self, key: int) -> bool:
        """Whether ``key`` is in the window."""
        return key in self.timestamps

    def update(self, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, timestamps: dict[int, float], keep: list[int] = ()) -> UpdateReport:
        """Add ``factors`` and the new variables ``values`` (their ``timestamps``, seconds), keep
        the keys ``keep`` in the window at the newest timestamp, and re-solve incrementally.
        When iSAM2 throws (a ``RuntimeError``, e.g. an indeterminant system) the smoother is not
        to be used again: the online loop starts a new one."""
        newest = max(self.newest, max(timestamps.values(), default=-np.inf))
        stamps = {int(k): float(t) for k, t in timestamps.items()}
        kept = [int(k) for k in keep]
        stamps.update({k: newest for k in kept})
        bound = newest - self.lag_s
        self.timestamps.update(stamps)
        leaving = [k for k, t in self.timestamps.items() if t < bound]
        left = _subset(self.estimate, leaving)
        arriving = [k for k in leaving if not self.estimate.exists(k)]
        start = time.perf_counter()
        first = self._step(factors, values, [k for k in kept if self.estimate.exists(k)], set(leaving))
        relinearised, reeliminated, batch = int(first.getVariablesRelinearized()), int(first.getVariablesReeliminated()), bool(first.getBatchReorderTriggered())
        for _ in range(self.relinearisation.extra_updates):
            self._step(gtsam.NonlinearFactorGraph(), gtsam.Values(), [], set(leaving))
        if arriving:
            # new variables already older than the window (the online loop's bootstrap replayed
            # with a lag shorter than the bootstrap) leave in this very update, at its estimate:
            # at their start they were in a frame the update moved the others from
            left.insert(_subset(self.isam.calculateEstimate(), arriving))
        if leaving:
            out = gtsam.KeyList()
            for k in leaving:
                out.push_back(k)
            self.isam.marginalizeLeaves(out)
        seconds = time.perf_counter() - start
        if self._linearization_point is None:
            self._linearization_point = self.isam.getLinearizationPoint()
        for k in leaving:
            del self.timestamps[k]
        self.estimate = self.isam.calculateEstimate()
        return UpdateReport(seconds, relinearised, reeliminated, batch, leaving, left)

    def _step(self, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, reeliminate: list[int], leaving: set[int]) -> gtsam.ISAM2Result:
        """One iSAM2 update with its elimination constrained: the ``leaving`` keys in group 0,
        the others by their timestamps (older first); ``reeliminate``: keys to re-order anyway.

        CCOLAMD reads a group number as an index below the number of variables it orders (a
        larger one corrupts memory), and iSAM2 passes it only those the update affects: the
        groups number the timestamps of the affected keys (iSAM2's prediction) densely. iSAM2
        re-orders the whole window instead (a batch step) when the variables it re-eliminates,
        new ones aside, are 65 % of the window or more; close to that line the whole window is
        marked, so that the step is a batch one for certain and every key is numbered."""
        marked = gtsam.KeyList()
        for k in reeliminate:
            marked.push_back(k)
        params = gtsam.ISAM2UpdateParams()
        params.extraReelimKeys = marked
        # the relinearisation check reads the solution's delta, which iSAM2 back-substitutes only
        # when asked: the prediction read a stale one after an update without an estimate
        self.isam.getDelta()
        affected, _ = self.isam.predictUpdateInfo(factors, values, params)
        new = set(values.keys())
        old = sum(1 for k in affected if k not in new)
        batch = old >= _BATCH_MARGIN[0] * len(self.timestamps)
        if batch and old < _BATCH_MARGIN[1] * len(self.timestamps):
            for k in self.timestamps:
                if k not in new:
                    marked.push_back(k)
        numbered = set(self.timestamps) if batch else {*affected, *new}
        first = 1 if leaving & numbered else 0
        rank = {t: first + r for r, t in enumerate(sorted({self.timestamps[k] for k in numbered if k not in leaving}))}
        groups = gtsam.KeyGroupMap()
        # the keys not numbered: dropped by iSAM2 in an incremental step; in a batch step that
        # was not foreseen, after the leaving ones at least
        for k, t in self.timestamps.items():
            groups.insert2(k, 0 if k in leaving else rank[t] if k in numbered else 1)
        result = self.isam.update(factors, values, [], groups, None, marked, False)
        if result.getBatchReorderTriggered() != batch:
            log.warning("fixed-lag smoother: iSAM2 %s a batch step, not as foreseen (%d keys in the window)", "took" if not batch else "did not take", len(self.timestamps))
        return result

    def marginal_covariance(self, key: int) -> np.ndarray:
        """The marginal covariance of ``key`` in the window, in its tangent space."""
        if key not in self.timestamps:
            raise MocapgraphError(f"key {gtsam.DefaultKeyFormatter(key)} is not in the smoother's window")
        return np.asarray(self.isam.marginalCovariance(key))


def _subset(values: gtsam.Values, keys: list[int]) -> gtsam.Values:
    """A copy of ``values`` with only ``keys`` (those it has)."""
    if not keys:
        return gtsam.Values()
    out = gtsam.Values(values)
    wanted = set(keys)
    for k in list(out.keys()):
        if k not in wanted:
            out.erase(k)
    return out
