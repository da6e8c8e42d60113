"""The factor graphs: the one state model every pipeline builds from, and how it is solved.

- :mod:`~mocapgraph.graphs.state_model`: observations (undistorted once), body states, camera
  variables, the picklable :class:`~mocapgraph.graphs.state_model.Estimate`;
- :mod:`~mocapgraph.graphs.sync`: which camera frames share a body state (grid, states, closest);
- :mod:`~mocapgraph.graphs.body_graph`: the factors of a state model, initial values, elimination
  order, covariances;
- :mod:`~mocapgraph.graphs.initialisation`: initial values of uncalibrated rigs;
- :mod:`~mocapgraph.graphs.solver`: Python-driven Levenberg-Marquardt, staged annealing, holds;
- :mod:`~mocapgraph.graphs.uncertainty`: joint covariances from marginals;
- :mod:`~mocapgraph.graphs.navigation`: the GPS/IMU navigation graph of a vehicle.

Takes arrays and observations, never file classes: it may import ``body``, ``factors``, ``priors``,
``data_tools.geometry`` and ``errors``/``progress``.
"""
