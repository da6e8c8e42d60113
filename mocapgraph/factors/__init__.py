"""GTSAM factors of the motion-capture graph, the residual kernels behind them, and their keys.

- :mod:`~mocapgraph.factors.keys`: the one key scheme of every graph;
- :mod:`~mocapgraph.factors.reprojection` (+ ``reprojection_kernel``, ``robust``,
  ``interpolation``): one body state seen by C cameras, per-keypoint Geman-McClure inside;
- :mod:`~mocapgraph.factors.smoothness`: root, camera, joint-rotation and 3D joint smoothness;
- :mod:`~mocapgraph.factors.camera_priors` and :mod:`~mocapgraph.factors.body_priors`: priors
  on camera poses (GPS/IMU), the shape and the joint rotations;
- :mod:`~mocapgraph.factors.ground`: ground penetration of joints and cameras;
- :mod:`~mocapgraph.factors.navigation`: GPS/barometer fixes, sensor offsets, IMU parameters;
- :mod:`~mocapgraph.factors.noise`, :mod:`~mocapgraph.factors.linear`: checked noise models and
  linear factors with constant Jacobians.

May import only ``body``, ``errors`` and the native kernels.
"""
