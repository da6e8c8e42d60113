"""The package's layers, as ``../shared/DESIGN.md`` draws them, read from the source's imports.

``body`` ← ``factors`` ← ``graphs`` ← ``pipelines`` ← ``cli`` / ``benchmarks``; ``priors`` may
use ``body``, ``factors`` and ``data_tools`` (training data); ``data_tools`` uses only ``body``
and ``errors``, its parts in the order below; ``errors`` and ``progress`` are for everyone. No
module imports one that imports it back, directly or through others. Every import counts, also
one inside a function: a deferred import is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "mocapgraph"
BASE = {"root", "errors", "progress"}
DATA = {"data_tools.geometry", "data_tools.io", "data_tools.sim", "data_tools.tracking", "data_tools.evaluation"}
ALLOWED = {
    "root": BASE,
    "errors": set(),
    "progress": set(),
    "_native": set(),
    "body": BASE | {"_native"},
    "data_tools": BASE,
    "data_tools.geometry": BASE | {"body"},
    "data_tools.io": BASE | {"body", "data_tools.geometry"},
    "data_tools.sim": BASE | {"body", "data_tools.geometry", "data_tools.io"},
    "data_tools.tracking": BASE | {"body", "data_tools.geometry", "data_tools.io"},
    "data_tools.evaluation": BASE | {"body", "data_tools.geometry", "data_tools.io"},
    "factors": BASE | {"body", "_native"},
    "priors": BASE | {"body", "factors"} | DATA,
    # The graphs take arrays and observations: of data_tools only the array geometry, no file classes.
    "graphs": BASE | {"body", "factors", "priors", "data_tools.geometry"},
    "pipelines": BASE | {"body", "factors", "priors", "graphs"} | DATA,
    "benchmarks": BASE | {"body", "factors", "priors", "graphs", "pipelines"} | DATA,
    "cli": BASE | {"body", "factors", "priors", "graphs", "pipelines", "benchmarks"} | DATA,
}

def module_name(path: Path) -> str:
    parts = ["mocapgraph", *path.relative_to(PACKAGE).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer(module: str) -> str:
    parts = module.split(".")
    if len(parts) == 1:
        return "root"
    if parts[1] == "data_tools" and len(parts) > 2:
        return f"data_tools.{parts[2]}"
    return parts[1]


def imports(path: Path) -> list[tuple[int, str]]:
    """``(line, module)`` of every mocapgraph module ``path`` imports (``from a import b`` counts
    ``a.b`` when that is a module of its own)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names if a.name.startswith("mocapgraph")]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and node.module.startswith("mocapgraph"):
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"
                out.append((node.lineno, sub if sub in MODULES else node.module))
    return out


SOURCES = sorted(PACKAGE.rglob("*.py"))
MODULES = {module_name(p) for p in SOURCES} | {"mocapgraph._native"}


def test_every_module_has_a_layer():
    assert {layer(module_name(p)) for p in SOURCES} <= set(ALLOWED)


def test_no_layer_imports_one_above_it():
    offences = []
    for path in SOURCES:
        source = layer(module_name(path))
        for line, target in imports(path):
            if layer(target) != source and layer(target) not in ALLOWED[source]:
                offences.append(f"{path.relative_to(PACKAGE.parent)}:{line}: {source} imports {target} ({layer(target)})")
    assert not offences, "imports against the layers:\n" + "\n".join(offences)


def test_no_import_cycles():
    graph = {module_name(p): {t for _, t in imports(p) if t in MODULES} for p in SOURCES}
    # A package's __init__ re-exporting its modules is not a cycle of meaning; the modules are.
    graph = {m: {t for t in ts if not m.startswith(t + ".")} for m, ts in graph.items()}
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for t in sorted(graph.get(m, ())):
            if state.get(t) == 1:
                return stack[stack.index(t) :] + [t]
            if t not in state and (cycle := visit(t)):
                return cycle
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (cycle := visit(m)):
            pytest.fail("import cycle: " + " -> ".join(cycle))


def test_each_package_says_what_it_holds_and_may_import():
    for init in sorted(PACKAGE.rglob("__init__.py")):
        doc = ast.get_docstring(ast.parse(init.read_text(encoding="utf-8"))) or ""
        assert len(doc) > 40 and "import" in doc, f"{init.relative_to(PACKAGE.parent)}: needs a docstring saying what it holds and may import"


def test_the_layer_test_catches_an_offence(tmp_path):
    """The checks above read real imports: a graphs module importing a file class is caught."""
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from mocapgraph.data_tools.io.capture import Capture\n")
    ((line, target),) = imports(bad)
    assert (line, target) == (2, "mocapgraph.data_tools.io.capture")
    assert layer(target) not in ALLOWED["graphs"]
