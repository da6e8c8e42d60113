"""mocapgraph: markerless multi-camera human motion capture as GTSAM factor graphs."""

from mocapgraph.errors import MocapgraphError

__version__ = "0.1.0"
__all__ = ["MocapgraphError", "__version__"]
