"""Every pipeline behind one call: load a capture, run, write the result.

:data:`PIPELINES` names each pipeline's options dataclass, its run function
``(capture, options, capture_label) -> Result`` and its summary line; :func:`run_capture` is
the one load → run → write that ``mocapgraph run`` and ``mocapgraph batch`` share. The modules
are imported when a pipeline runs, so that ``--help`` stays quick.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from mocapgraph.data_tools.io.capture import load_capture
from mocapgraph.data_tools.io.files import release_output, reserve_output
from mocapgraph.data_tools.io.result import MANIFEST, Result, write_result
from mocapgraph.errors import MocapgraphError


@dataclass(frozen=True)
class Pipeline:
    """Where a pipeline lives: ``module`` with ``options`` (dataclass), ``run`` and ``summary``."""

    module: str
    options: str
    run: str
    summary: str = "summary"

    def attribute(self, name: str) -> Any:
        return getattr(importlib.import_module(self.module), getattr(self, name))

    def default_options(self):
        return self.attribute("options")()


PIPELINES: dict[str, Pipeline] = {
    "aircap": Pipeline("mocapgraph.pipelines.aircap", "AircapOptions", "run_aircap"),
    "airpose": Pipeline("mocapgraph.pipelines.airpose", "AirposeOptions", "run_airpose"),
    "baseline": Pipeline("mocapgraph.pipelines.baseline", "BaselineOptions", "run_baseline"),
    "smartmocap": Pipeline("mocapgraph.pipelines.smartmocap", "SmartmocapOptions", "run_smartmocap"),
}


def pipeline(name: str) -> Pipeline:
    if name not in PIPELINES:
        raise MocapgraphError(f"pipeline {name!r}: choose one of {', '.join(sorted(PIPELINES))}")
    return PIPELINES[name]


def run_capture(name: str, capture_path: Path, out: Path, options=None, overwrite: bool = False) -> Result:
    """Run pipeline ``name`` (default options unless given) on the capture at ``capture_path``
    and write the result at ``out``, reserved before the run (:func:`reserve_output`: refused when
    it exists, unless ``overwrite`` and it is a result; never the capture itself)."""
    p = pipeline(name)
    reserve_output(out, overwrite, MANIFEST, inputs=[capture_path])
    try:
        run: Callable = p.attribute("run")
        result = run(load_capture(capture_path), options if options is not None else p.default_options(), capture_label=str(capture_path))
        write_result(result, out, overwrite=overwrite)
    finally:
        release_output(out)
    return result


def summary(name: str, result: Result) -> str:
    """The line(s) ``mocapgraph run NAME`` prints about ``result``."""
    return pipeline(name).attribute("summary")(result)
