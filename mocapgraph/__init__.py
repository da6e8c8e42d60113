"""mocapgraph: markerless multi-camera human motion capture as GTSAM factor graphs.

Packages, lowest first (a package imports only those before it; ``tests/test_layers.py`` checks):
``errors`` and ``progress`` (for everyone), ``body``, ``data_tools`` (``geometry``, ``io``,
``sim``, ``tracking``, ``evaluation``), ``factors``, ``priors``, ``graphs``, ``pipelines``, and on
top ``benchmarks`` and ``cli``. This module imports only ``errors``.
"""

from mocapgraph.errors import MocapgraphError

__version__ = "0.1.0"
__all__ = ["MocapgraphError", "__version__"]
