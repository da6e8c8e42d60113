"""GTSAM factors of the motion-capture graph and the residual kernels behind them.

- :mod:`~mocapgraph.factors.reprojection`: ``reprojection_factor`` (one body state, C cameras,
  refined or fixed, per-keypoint Geman-McClure inside) and ``ShapeTableCache``.
- :mod:`~mocapgraph.factors.robust`: ``RobustScale``, the shared kernel scale a solver anneals.
- :mod:`~mocapgraph.factors.priors`: ``camera_prior_factor`` (robust), ``camera_smoothness_factor``,
  ``root_smoothness_factor``, ``pose_smoothness_factor`` (second order, any time steps),
  ``pose_velocity_factor``, ``shape_prior_factor``, ``pose_regularizer_factor``.
- :mod:`~mocapgraph.factors.reprojection_kernel`: the native residual kernel and its numpy reference.
"""
