"""The pipelines: a capture in, a result out, as library calls.

``aircap``, ``airpose``, ``smartmocap`` and the triangulation ``baseline``; the shared road from a
capture to the state model (:mod:`~mocapgraph.pipelines.observations`) and back to a result
(:mod:`~mocapgraph.pipelines.results`); the GPS/IMU camera priors of a capture
(:mod:`~mocapgraph.pipelines.camera_priors`); one load → run → write for every pipeline
(:mod:`~mocapgraph.pipelines.runner`); executors and ``batch``.

May import ``graphs``, ``priors``, ``factors``, ``data_tools`` and ``body``; only ``benchmarks``
and ``cli`` import it.
"""
