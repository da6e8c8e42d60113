"""Synthetic captures with ground truth: motion sources (procedural, CMU retargeted), camera
rigs of the scenario presets, vehicle sensors, detector simulation with realistic faults.
May import ``body``, ``errors``, ``progress``, ``data_tools.geometry`` and ``data_tools.io``."""
