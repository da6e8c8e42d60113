"""The live status line: rewritten in place on a terminal, whole log lines elsewhere, silent at ``-q``."""

from __future__ import annotations

import io
import logging

from mocapgraph.progress import LiveLine, configure_logging, log_level


class _Stream(io.StringIO):
    def __init__(self, tty: bool):
        super().__init__()
        self._tty = tty

    def isatty(self) -> bool:
        return self._tty


class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _run(monkeypatch, tty: bool, level: int = logging.INFO) -> str:
    stream = _Stream(tty)
    monkeypatch.setattr("sys.stderr", stream)
    configure_logging(0)
    clock = _Clock()
    with log_level(level):
        line = LiveLine(every_s=0.5, log_every_s=10.0, clock=clock)
        for step in range(41):  # 20 s of updates every 0.5 s, and one 0.25 s after each
            clock.t = 0.5 * step
            line.show(f"t {clock.t:.2f}")
            clock.t += 0.25
            line.show(f"t {clock.t:.2f}")
        line.close()
    return stream.getvalue()


def test_terminal_rewrites_one_line_at_most_every_half_second(monkeypatch):
    out = _run(monkeypatch, tty=True)
    shown = out.split("\r")[1:]
    assert [s.strip() for s in shown] == [f"t {0.5 * k:.2f}" for k in range(41)]
    assert out.endswith("\n") and out.count("\n") == 1


def test_elsewhere_whole_log_lines_every_ten_seconds(monkeypatch):
    out = _run(monkeypatch, tty=False)
    assert "\r" not in out
    assert out.splitlines() == ["t 0.00", "t 10.00", "t 20.00"]


def test_quiet_shows_nothing(monkeypatch):
    assert _run(monkeypatch, tty=True, level=logging.WARNING) == ""
    assert _run(monkeypatch, tty=False, level=logging.WARNING) == ""
