"""The command line: one module per command group (``run``, ``bench``, ``capture``, …) and
:mod:`~mocapgraph.cli.main`, the entry point. Every pipeline flag's default is read from the
pipeline's options dataclass, every benchmark's and trainer's from its function's signature.

May import anything below it (pipelines, benchmarks, priors, data_tools, body); nothing imports it.
"""
