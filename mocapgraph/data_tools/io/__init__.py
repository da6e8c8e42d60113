"""The file formats: captures (what every pipeline reads), results (what every pipeline writes),
validated reading and atomic writing, and importers of other tools' output. May import
``body``, ``errors`` and ``data_tools.geometry``."""
