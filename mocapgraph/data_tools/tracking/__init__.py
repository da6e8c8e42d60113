"""Finding the person: 2D keypoints in videos (MediaPipe BlazePose, the ``[video]`` extra) and
AirCap's 3D person tracker. May import ``body``, ``errors``, ``progress``,
``data_tools.geometry`` and ``data_tools.io``."""
