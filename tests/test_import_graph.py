"""The import graph of matfit: no cycles, no module importing another's private names, and the
flat public API at the top level; and numpy_ref, the tests' and benchmarks' numpy reference, stays
independent of matfit."""

from __future__ import annotations

import ast
import importlib
import sys
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "matfit"


def _modules():
    out = {}
    for p in PKG.rglob("*.py"):
        parts = p.relative_to(PKG.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = p
    return out


def _imports(mods):
    """``{module: [(imported module, imported name or None, line)]}``, every import statement
    (function-level ones included: a lazy import is still a dependency)."""
    graph = {}
    for name, path in mods.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        found = []
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                found += [(a.name, None, node.lineno) for a in node.names if a.name.startswith("matfit")]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if not target.startswith("matfit"):
                    continue
                for a in node.names:
                    sub = f"{target}.{a.name}"
                    found.append((sub, None, node.lineno) if sub in mods else (target, a.name, node.lineno))
        graph[name] = found
    return graph


def _private(module):
    return any(part.startswith("_") for part in module.split(".")[1:])


def _within(importer, module):
    """A private module may be imported by the package that holds it and by its siblings."""
    holder = module.rpartition(".")[0]
    return importer == holder or importer.startswith(holder + ".")


@pytest.mark.check
def test_no_module_imports_another_modules_private_names():
    mods = _modules()
    bad = []
    for importer, found in _imports(mods).items():
        for module, name, line in found:
            if name is not None and name.startswith("_") and module != importer:
                bad.append(f"{mods[importer].relative_to(PKG.parent)}:{line} imports {module}.{name}")
            if _private(module) and not _within(importer, module):
                bad.append(f"{mods[importer].relative_to(PKG.parent)}:{line} imports the private module {module}")
    assert not bad, "\n".join(bad)


@pytest.mark.check
def test_import_graph_has_no_cycles():
    mods = _modules()
    graph = {m: sorted({t for t, _, _ in found if t in mods and t != m}) for m, found in _imports(mods).items()}
    # a package's __init__ re-exports its modules; the edge from a module to its own package (or
    # an ancestor) is Python's parent import, not a dependency of the code
    graph = {m: [t for t in ts if not m.startswith(t + ".")] for m, ts in graph.items()}
    state, stack, cycles = {}, [], []

    def visit(m):
        state[m] = "open"
        stack.append(m)
        for t in graph[m]:
            if state.get(t) == "open":
                cycles.append(stack[stack.index(t):] + [t])
            elif t not in state:
                visit(t)
        stack.pop()
        state[m] = "done"

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_checker_sees_a_private_import():
    """The walker resolves relative imports and flags a private name (guards against a checker
    that passes because it reads nothing)."""
    mods = _modules()
    found = _imports({"matfit.cli": mods["matfit.cli"]})["matfit.cli"]
    assert any(m == "matfit.demo" for m, _, _ in found)  # cli's lazy `from .demo import run_demo`
    assert _private("matfit.fitting._conductor_guess") and not _private("matfit.fitting.fit")
    assert _within("matfit.fitting.fit", "matfit.fitting._conductor_guess")
    assert not _within("matfit.report", "matfit.io._halfdiff")


@pytest.mark.parametrize("name", ["fit", "fit_batch", "load", "save", "sample_posterior", "compare_models",
                                  "fit_map", "export", "render", "maps", "Table"])
def test_flat_public_api(name):
    import matfit

    obj = getattr(matfit, name)
    assert name in matfit.__all__ and name in dir(matfit)
    if name in ("export", "render", "maps"):
        assert obj is importlib.import_module(f"matfit.{name}")
    else:
        assert callable(obj)


def test_numpy_reference_imports_no_matfit():
    """numpy_ref (the independent numpy references shared by the tests and the benchmarks) imports
    only the standard library, numpy, scipy, colour and its own modules: never matfit."""
    allowed = {"numpy", "scipy", "colour", "numpy_ref"}
    root = PKG.parent / "numpy_ref"
    files = sorted(root.glob("*.py"))
    assert len(files) > 1 and (root / "__init__.py") in files
    bad = []
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = ["numpy_ref"] if node.level else [node.module or ""]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in allowed and top not in sys.stdlib_module_names:
                    bad.append(f"numpy_ref/{path.name}:{node.lineno} imports {name}")
    assert not bad, "\n".join(bad)
