"""The package's layers: every module imports only from its own layer or lower ones, at module top,
and ``import btfrs`` loads neither the tools (btfrs.tools) nor matplotlib.

Read from the source with ``ast`` (no import needed) except the last check, which imports btfrs in
a fresh interpreter.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path
from typing import Dict, Iterator, List, Set, Tuple

PACKAGE = Path(__file__).resolve().parents[1] / "python" / "btfrs"

#: 1 data and models, 2 rendering, 3 synthesis and tiles, 4 analysis (and the package's
#: namespace, which re-exports layers 1-4), 5 the tools and the command line.
LAYERS: Dict[str, int] = {
    **{f"btfrs.{m}": 1 for m in ("exceptions", "_checks", "_progress", "_native", "directions", "hemimap", "btf",
                                 "io", "materials", "photometric", "calibration", "models", "_fitting", "fit", "dask")},
    **{f"btfrs.{m}": 2 for m in ("environment", "rendering")},
    **{f"btfrs.{m}": 3 for m in ("synth", "graphcut", "tiles", "web")},
    **{f"btfrs.{m}": 4 for m in ("evaluation", "stability", "choosing")},
    "btfrs": 4,
    "btfrs.cli": 5,
    "btfrs.tools": 5,
    **{f"btfrs.tools.{m}": 5 for m in ("bench", "demo", "groundtruth", "memprobe", "baselines")},
}

#: Imports that break the rules in modules being rewritten elsewhere (only their import lines may
#: change here), each with its way out. An entry that no longer occurs must be removed.
PENDING: Set[Tuple[str, str]] = set()

#: Third-party packages a function may import: optional extras, or heavy ones that would slow
#: ``import btfrs`` down (matplotlib).
OPTIONAL = {"matplotlib", "dask", "distributed", "zarr", "tqdm", "mitsuba", "drjit", "scipy", "sklearn", "PIL",
            "playwright"}


def modules() -> Iterator[Tuple[str, Path]]:
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        yield ".".join(parts[:-1] if parts[-1] == "__init__" else parts), path


def _is_package(name: str) -> bool:
    return (PACKAGE.parent / name.replace(".", "/") / "__init__.py").exists()


def _exists(name: str) -> bool:
    base = PACKAGE.parent / name.replace(".", "/")
    return _is_package(name) or base.with_suffix(".py").exists() or base.with_suffix(".pyi").exists()


def imports(name: str, path: Path) -> Iterator[Tuple[str, ast.stmt, bool]]:
    """(imported btfrs module, the statement, whether it sits inside a function) for each
    btfrs module ``name`` imports."""
    package = name if _is_package(name) else name.rpartition(".")[0]
    tree = ast.parse(path.read_text(), str(path))

    def walk(node: ast.AST, in_function: bool) -> Iterator[Tuple[str, ast.stmt, bool]]:
        for child in ast.iter_child_nodes(node):
            inside = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                for a in child.names:
                    if a.name == "btfrs" or a.name.startswith("btfrs."):
                        yield a.name, child, in_function
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = package
                    for _ in range(child.level - 1):
                        base = base.rpartition(".")[0]
                    module = f"{base}.{child.module}" if child.module else base
                else:
                    module = child.module or ""
                if module != "btfrs" and not module.startswith("btfrs."):
                    continue
                # `from . import io` imports the module btfrs.io; `from .io import load` imports btfrs.io.
                targets = {f"{module}.{a.name}" if _exists(f"{module}.{a.name}") else module for a in child.names}
                for target in sorted(targets):
                    yield target, child, in_function
            yield from walk(child, inside)

    yield from walk(tree, False)


def third_party_function_imports(path: Path) -> Iterator[Tuple[str, int]]:
    tree = ast.parse(path.read_text(), str(path))
    for fn in ast.walk(tree):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(fn):
            if isinstance(node, ast.Import):
                for a in node.names:
                    yield a.name, node.lineno
            elif isinstance(node, ast.ImportFrom) and not node.level:
                yield node.module or "", node.lineno


def test_every_module_has_a_layer():
    found = {name for name, _ in modules()}
    assert found - set(LAYERS) == set(), "give the new modules a layer in LAYERS"
    assert {m for m in LAYERS if not _exists(m)} == set(), "LAYERS names modules that are gone"


def test_each_module_imports_only_its_own_layer_or_lower_ones():
    bad: List[str] = []
    seen: Set[Tuple[str, str]] = set()
    for name, path in modules():
        for target, node, _ in imports(name, path):
            assert target in LAYERS, f"{name}:{node.lineno} imports {target}, which has no layer"
            if LAYERS[target] > LAYERS[name]:
                seen.add((name, target))
                if (name, target) not in PENDING:
                    bad.append(f"{name}:{node.lineno} (layer {LAYERS[name]}) imports {target} (layer {LAYERS[target]})")
    assert bad == []
    # Same-layer PENDING entries are checked by the next test.
    stale = {p for p in PENDING if LAYERS[p[1]] > LAYERS[p[0]]} - seen
    assert stale == set(), f"fixed: remove from PENDING {sorted(stale)}"


def test_no_function_imports_a_btfrs_module():
    found: Set[Tuple[str, str]] = set()
    bad: List[str] = []
    for name, path in modules():
        for target, node, in_function in imports(name, path):
            if in_function:
                found.add((name, target))
                if (name, target) not in PENDING:
                    bad.append(f"{name}:{node.lineno} imports {target} inside a function")
    assert bad == [], "import it at the module's top (a cycle means a layer is wrong)"
    assert PENDING - found == set(), f"fixed: remove from PENDING {sorted(PENDING - found)}"


def test_functions_import_only_optional_or_heavy_dependencies():
    bad = []
    for name, path in modules():
        for module, line in third_party_function_imports(path):
            if module != "btfrs" and not module.startswith("btfrs.") and module.split(".")[0] not in OPTIONAL:
                bad.append(f"{name}:{line} imports {module} inside a function")
    assert bad == [], "only optional or heavy dependencies may wait for the function that needs them"


def test_importing_btfrs_loads_no_tool_and_no_matplotlib():
    code = "import btfrs, sys, json; print(json.dumps(sorted(sys.modules)))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = json.loads(r.stdout.strip().splitlines()[-1])
    assert [m for m in loaded if m == "btfrs.tools" or m.startswith("btfrs.tools.")] == []
    assert [m for m in loaded if m == "matplotlib" or m.startswith("matplotlib.")] == []
    assert "btfrs.cli" not in loaded


def test_the_suite_reads_the_ci_switch_in_one_place():
    # One meaning of "running in CI" for every test (conftest.in_ci): no test reads CI itself.
    tests = Path(__file__).resolve().parent
    found = [f"{p.name}:{n}: {line.strip()}" for p in sorted(tests.glob("*.py")) if p.name not in ("conftest.py", Path(__file__).name)
             for n, line in enumerate(p.read_text().splitlines(), 1)
             if ("environ" in line or "getenv" in line) and ('"CI"' in line or "'CI'" in line)]
    assert not found, "read conftest.in_ci() instead:\n" + "\n".join(found)
    assert "def in_ci(" in (tests / "conftest.py").read_text()
