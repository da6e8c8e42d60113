"""Scoring results: metrics with their units, similarity and Procrustes alignment, ``eval``
against a capture's ground truth, HTML reports. May import ``body``, ``errors``,
``data_tools.geometry`` and ``data_tools.io``."""
