"""mocapgraph: markerless multi-camera human motion capture as GTSAM factor graphs.

Packages, lowest first (a package imports only those before it; ``tests/test_layers.py`` checks):
``errors`` and ``progress`` (for everyone), ``body``, ``data_tools`` (``geometry``, ``io``,
``sim``, ``tracking``, ``evaluation``), ``factors``, ``priors``, ``graphs``, ``pipelines``, and on
top ``benchmarks`` and ``cli``. This module imports only ``errors``.
"""

import os

# OpenMP threads (torch's intra-op pool) spin while they wait by default: beside another busy
# process on the same cores, spinning threads take each other's turns and a Jacobian measured
# at 22 ms asleep took 215 ms spinning (README, "Reliability"). Set before torch loads; a
# user's own setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from mocapgraph.errors import MocapgraphError  # noqa: E402

__version__ = "0.1.0"
__all__ = ["MocapgraphError", "__version__"]
