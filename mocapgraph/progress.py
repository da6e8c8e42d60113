"""Progress bars and messages for long work, one switch for all: the ``mocapgraph`` logger's level.

Library code reports through ``logging.getLogger(__name__)`` (under ``mocapgraph``) and shows
progress with :func:`progress_bar` (tqdm, on stderr). The command line sets the level
(``-q``: warnings only, no bars; ``-v``: debug, e.g. every solver iteration); a program that
imports mocapgraph sets it as it likes. Bars show only on a terminal, so logs and captured
output stay free of carriage returns.
"""

from __future__ import annotations

import contextlib
import logging
import sys

from tqdm.auto import tqdm

ROOT_LOGGER = "mocapgraph"


def progress_bar(iterable=None, *, total: int | None = None, desc: str = "", unit: str = "it") -> tqdm:
    """A tqdm bar on stderr: hidden below INFO (``-q``) and when stderr is not a terminal."""
    quiet = not logging.getLogger(ROOT_LOGGER).isEnabledFor(logging.INFO)
    return tqdm(iterable, total=total, desc=desc, unit=unit, disable=True if quiet else None, leave=False, dynamic_ncols=True)


class _StderrHandler(logging.StreamHandler):
    """Writes to whatever ``sys.stderr`` is when a message comes (tests and tools swap it)."""

    def __init__(self):
        super().__init__(sys.stderr)

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):
        pass


def configure_logging(verbosity: int = 0) -> None:
    """Messages of the ``mocapgraph`` loggers on stderr: ``verbosity`` -1 warnings only, 0 info,
    1 and more debug. Called once by the command line."""
    level = logging.WARNING if verbosity < 0 else logging.INFO if verbosity == 0 else logging.DEBUG
    logger = logging.getLogger(ROOT_LOGGER)
    logger.setLevel(level)
    if not logger.handlers:
        handler = _StderrHandler()
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
    logger.propagate = False


@contextlib.contextmanager
def log_level(level: int):
    """The ``mocapgraph`` loggers at ``level`` for the duration (e.g. WARNING in a batch task)."""
    logger = logging.getLogger(ROOT_LOGGER)
    before = logger.level
    logger.setLevel(level)
    try:
        yield
    finally:
        logger.setLevel(before)
