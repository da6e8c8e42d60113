"""``mocapgraph bench``: one module per benchmark, each a function returning a JSON-ready dict
measured in one run (speed ratios within the run). May import anything but ``cli``."""
