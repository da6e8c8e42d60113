"""Data in and out of the factor graphs, by job:

- :mod:`~mocapgraph.data_tools.geometry`: the camera model, triangulation, time matching (arrays only);
- :mod:`~mocapgraph.data_tools.io`: the capture and result formats, importers;
- :mod:`~mocapgraph.data_tools.sim`: synthetic scenes, motion sources, sensors, detector simulation;
- :mod:`~mocapgraph.data_tools.tracking`: detection in videos (MediaPipe) and the person tracker;
- :mod:`~mocapgraph.data_tools.evaluation`: metrics, alignment, ``eval`` and reports.

May import only ``body``, ``errors`` and ``progress`` (and, within it, the parts listed before).
"""
