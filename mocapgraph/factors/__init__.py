"""GTSAM factors of the motion-capture graph and the residual kernels behind them."""
