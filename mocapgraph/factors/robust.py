"""A shared, mutable robust-kernel scale, so a solver can anneal L2 → Geman-McClure in place.

Factors that take a :class:`RobustScale` read ``scale.sigma_px`` at every evaluation instead of
copying it when they are built. A staged solver therefore keeps one graph and changes the kernel
between stages::

    scale = RobustScale()            # inf: plain L2 for the first stage (wide basin)
    graph = build_graph(..., scale=scale)
    run_stage(graph, values)         # converge roughly
    scale.sigma_px = 10.0            # per-keypoint Geman-McClure from now on
    run_stage(graph, values)

The Geman-McClure cost of a keypoint with pixel error ``e`` is
``½ w² σ²|e|²/(σ² + |e|²)``: quadratic for ``|e| ≪ σ``, saturating at ``½ w² σ²`` for outliers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mocapgraph.errors import MocapgraphError


@dataclass
class RobustScale:
    """Geman-McClure scale in pixels, shared by reference between factors and the solver.

    Attributes:
        sigma_px: ``> 0``; ``math.inf`` (the default) means plain L2. Assign a new value between
            solver stages; factors pick it up at their next evaluation. Changing it changes the
            cost function, so compare errors only within one stage.
    """

    sigma_px: float = math.inf

    def __setattr__(self, name, value):
        if name == "sigma_px":
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise MocapgraphError(f"RobustScale.sigma_px: expected a number, got {value!r}") from None
            if not value > 0:  # also rejects NaN
                raise MocapgraphError(f"RobustScale.sigma_px must be > 0 (inf = plain L2), got {value!r}")
        super().__setattr__(name, value)

    @property
    def is_robust(self) -> bool:
        """True when Geman-McClure is active (finite ``sigma_px``)."""
        return math.isfinite(self.sigma_px)
