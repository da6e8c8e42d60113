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
import time
from collections.abc import Callable

from tqdm.auto import tqdm

ROOT_LOGGER = "mocapgraph"


def progress_bar(iterable=None, *, total: int | None = None, desc: str = "", unit: str = "it") -> tqdm:
    """A tqdm bar on stderr: hidden below INFO (``-q``) and when stderr is not a terminal."""
    quiet = not logging.getLogger(ROOT_LOGGER).isEnabledFor(logging.INFO)
    return tqdm(iterable, total=total, desc=desc, unit=unit, disable=True if quiet else None, leave=False, dynamic_ncols=True)


class LiveLine:
    """One status line that a long loop refreshes (``run online``'s updates/s and latency).

    On a terminal the line is rewritten in place at most every ``every_s`` seconds; otherwise
    (a log file, a pipe, captured output) it goes out as a whole log line at most every
    ``log_every_s`` seconds, so nothing downstream sees carriage returns; below INFO (``-q``)
    nothing is shown. :meth:`due` says whether :meth:`show` would print now, so the caller
    builds the text only then.
    """

    def __init__(self, every_s: float = 0.5, log_every_s: float = 10.0, clock: Callable[[], float] = time.perf_counter):
        self._clock = clock
        self._every_s = every_s if sys.stderr.isatty() else log_every_s
        self._shown_at: float | None = None
        self._open = False

    def due(self) -> bool:
        if not logging.getLogger(ROOT_LOGGER).isEnabledFor(logging.INFO):
            return False
        return self._shown_at is None or self._clock() - self._shown_at >= self._every_s

    def show(self, text: str) -> None:
        if not self.due():
            return
        self._shown_at = self._clock()
        if sys.stderr.isatty():
            print(f"\r{text}", end="", file=sys.stderr, flush=True)
            self._open = True
        else:
            logging.getLogger(ROOT_LOGGER).info(text)

    def close(self) -> None:
        """Ends a line left open on the terminal."""
        if self._open:
            print(file=sys.stderr, flush=True)
            self._open = False


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
