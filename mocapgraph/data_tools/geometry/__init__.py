"""Camera geometry on arrays: the OpenCV camera model with distortion, triangulation of
calibrated views, matching timestamps. The lowest part of ``data_tools``: it may import only
``errors`` (and ``body``); the graphs use it, so it holds no file classes."""
