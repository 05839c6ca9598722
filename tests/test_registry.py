"""The model registry is the one source of every fact about a model.

* No file outside a model's own files names a model kind (its registered name as a string, its
  Rust type, its Python class) or downcasts to one: everything else asks the registry.
* The generated Python surface (``btfrs.fit``, the stub's ``_ModelKind``, the docs' option tables)
  is what ``scripts/generate_surface.py`` makes from the registry today.
* The signatures of ``btfrs.fit.<kind>`` are the schema's: names, defaults, and errors that name
  the option, the value and what is allowed.
"""

from __future__ import annotations

import ast
import inspect
import keyword
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import btfrs
from btfrs.exceptions import ArgumentTypeError, InvalidArgumentError

ROOT = Path(__file__).resolve().parent.parent
KINDS = btfrs.model_kinds()

# Each kind's own files: by convention those named after its module in btfrs-fit (its fit file,
# a folder of the same name, its shader), plus what the registry cannot say: the file of a format
# it is written as (relight's web folder holds four kinds and hands NeuralRTI's to its reader),
# the code of an ability only it has (the SH lighting method), a fit file two models share
# (lightfit: PTM and HSH; light_pca and light_bases: RBF and bilinear).
def _module(kind: str) -> str:
    """The model's module in btfrs-fit, from its Rust type (btfrs_fit::lafortune::per_view::...)."""
    return KINDS[kind]["type"].split("::")[1]


RELIGHT = "rust/btfrs-io/src/relight_file.rs"
EXTRA = {
    "ptm": ["rust/btfrs-fit/src/lightfit.rs", "rust/btfrs-io/src/ptm_file.rs", RELIGHT],
    "hsh": ["rust/btfrs-fit/src/lightfit.rs", "rust/btfrs-io/src/rti_file.rs", RELIGHT],
    "sh": ["rust/btfrs-render/src/sh_env.rs"],
    "neural": ["rust/btfrs-io/src/neuralrti_file.rs", RELIGHT],
    # The renderers' formats hold the svbrdf model's maps and nothing else.
    "svbrdf": ["rust/btfrs-io/src/gltf_file.rs", "rust/btfrs-io/src/mitsuba_file.rs"],
    # light_bases.rs: the two by name, for their staged blockwise fit (light_pca names neither).
    "rbf": ["rust/btfrs-fit/src/light_pca.rs", "rust/btfrs-fit/src/light_pca/*", "rust/btfrs-fit/src/light_bases.rs",
            "shaders_wgsl/light_pca.wgsl", RELIGHT],
    "bilinear": ["rust/btfrs-fit/src/light_pca.rs", "rust/btfrs-fit/src/light_pca/*", "rust/btfrs-fit/src/light_bases.rs",
                 "shaders_wgsl/light_pca.wgsl", RELIGHT],
}
OWN = {k: [f"rust/btfrs-fit/src/{_module(k)}.rs", f"rust/btfrs-fit/src/{_module(k)}/*",
           f"shaders_wgsl/{_module(k)}*.wgsl"] + EXTRA.get(k, []) for k in KINDS}
EVERY = ["rust/btfrs-fit/src/registry.rs", "rust/btfrs-fit/src/lib.rs"]
# Rust files where a kind's name is another thing's name: (file, kind) -> what it is.
NOT_KINDS_RUST = {("rust/btfrs-render/src/filter.rs", "bilinear"): "the bilinear texture filter (Filter::Bilinear)",
                  ("rust/btfrs-io/src/mitsuba_file.rs", "bilinear"): "Mitsuba's bilinear bitmap filter"}
# The Rust type of each kind, from the registry.
TYPES = {k: KINDS[k]["type"].split("::")[-1] for k in KINDS}


def _owned(kind: str, rel: str) -> bool:
    return any(Path(rel).match(g) for g in OWN[kind] + EVERY)


def _library_rust() -> list[Path]:
    """The library's Rust sources: not tests, benches or examples (tools, which may pick models)."""
    out = []
    for p in sorted((ROOT / "rust").glob("*/src/**/*.rs")):
        rel = p.relative_to(ROOT).as_posix()
        if "/tests/" in rel or rel.endswith("/tests.rs"):
            continue
        out.append(p)
    return out


def _strip_rust_tests(text: str) -> str:
    """The file without its `#[cfg(test)] mod tests { ... }` (tests fit models by name)."""
    i = text.find("#[cfg(test)]")
    return text if i < 0 else text[:i]


def _strip_rust_comments(text: str) -> str:
    return re.sub(r"//[^\n]*", "", text)


def test_registry_knows_every_kind_with_a_class_and_owned_files():
    assert set(EXTRA) <= set(KINDS)
    for kind in KINDS:
        assert getattr(btfrs, TYPES[kind]) is btfrs.models.class_of(kind), kind
        assert (ROOT / OWN[kind][0]).exists() or list(ROOT.glob(OWN[kind][1])), f"{kind}: no fit file"
        for g in EXTRA.get(kind, []):
            assert list(ROOT.glob(g)), f"{kind}: no file matches {g}"


def test_no_rust_file_outside_a_models_own_files_names_it():
    found = []
    for p in _library_rust():
        rel = p.relative_to(ROOT).as_posix()
        text = _strip_rust_comments(_strip_rust_tests(p.read_text()))
        # The kinds this file may not name, each as one pattern (its string or its type), found
        # once per file instead of once per line (the globs' matching dominated the test's time).
        foreign = [(kind, re.compile(rf'"{kind}"|\b{ty}\b')) for kind, ty in TYPES.items()
                   if not _owned(kind, rel) and (rel, kind) not in NOT_KINDS_RUST]
        for n, line in enumerate(text.splitlines(), 1):
            if "downcast_ref" in line and rel not in ("rust/btfrs-io/src/formats.rs", "rust/btfrs-py/src/errors.rs"):
                found.append(f"{rel}:{n}: downcast: {line.strip()}")
            for kind, named in foreign:
                if named.search(line):
                    found.append(f"{rel}:{n}: names {kind}: {line.strip()}")
    assert not found, "model kinds named outside their own files:\n" + "\n".join(found)


def _python_library() -> list[Path]:
    """The library's Python modules: not the tools, not the generated fit functions, not the
    module that defines the classes and the package's re-exports of them."""
    skip = {"fit.py", "models.py", "__init__.py"}
    return [p for p in sorted((ROOT / "python" / "btfrs").glob("*.py")) if p.name not in skip]


# Strings that are another thing's name and happen to spell a kind, with how often they occur:
# (module, string) -> count.
NOT_KINDS = {
    ("rendering.py", "sh"): 3,  # lighting="sh", the SH lighting method (a model ability's name)
    ("rendering.py", "bilinear"): 1,  # filter="bilinear", four-texel lookups
    ("cli.py", "sh"): 1,  # btfrs tiles --model's default: paper 002 synthesizes tiles of double SH
}


def test_no_python_module_outside_the_models_names_a_kind():
    classes = {TYPES[k] for k in KINDS}
    found = []
    seen: dict = {}
    for p in _python_library():
        tree = ast.parse(p.read_text())
        docstrings = {id(n.body[0].value) for n in ast.walk(tree)
                      if isinstance(n, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
                      and n.body and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
                if node.value in KINDS:
                    key = (p.name, node.value)
                    seen[key] = seen.get(key, 0) + 1
                    if seen[key] > NOT_KINDS.get(key, 0):
                        found.append(f"{p.name}:{node.lineno}: the string {node.value!r}")
            elif isinstance(node, (ast.Name, ast.Attribute)):
                name = node.id if isinstance(node, ast.Name) else node.attr
                if name in classes:
                    found.append(f"{p.name}:{node.lineno}: the class {name}")
            elif isinstance(node, ast.alias) and node.name in classes:
                found.append(f"{p.name}: imports {node.name}")
    assert not found, "model kinds named outside their own files:\n" + "\n".join(found)


def test_the_generated_surface_is_what_the_registry_makes():
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "generate_surface.py"), "--check"],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr


def test_fit_functions_have_the_schemas_signatures():
    for kind, info in KINDS.items():
        f = getattr(btfrs.fit, kind)
        sig = inspect.signature(f)
        names = [n for n in sig.parameters if n not in ("btf", "memory_limit", "progress", "robust", "exclude_bad_images")]
        assert names == [o["name"] + ("_" if keyword.iskeyword(o["name"]) else "") for o in info["options"]], kind
        for o in info["options"]:
            p = sig.parameters[o["name"] + ("_" if keyword.iskeyword(o["name"]) else "")]
            assert p.default == o["default"] and p.kind is inspect.Parameter.KEYWORD_ONLY, (kind, o["name"])
            assert o["doc"].split()[0].lower() in (f.__doc__ or "").lower(), (kind, o["name"])
        assert info["doc"] in (f.__doc__ or ""), kind
    assert set(btfrs.fit.__all__) == {"fit", *KINDS}


@pytest.fixture(scope="module")
def small():
    return btfrs.materials.make("bumps", size=8, seed=3)


@pytest.mark.parametrize("kind", list(KINDS))
def test_every_option_out_of_its_range_is_refused_naming_it(kind, small):
    # One bad value per option, made from the schema itself: above the maximum, below the
    # minimum, outside the choices. Each error names the option and what is allowed.
    for o in KINDS[kind]["options"]:
        bad = []
        if o["type"] in ("int", "optional_int"):
            bad.append(o["min"] - 1)
            if o.get("max") is not None:
                bad.append(o["max"] + 1)
            bad.append(1.5)
        elif o["type"] == "float":
            bad += [o["min"] - 1.0, "x"]
        elif o["type"] in ("choice", "int_choice"):
            bad.append("no-such-choice" if o["type"] == "choice" else 3)
        elif o["type"] == "bool":
            bad.append(1)
        py = o["name"] + ("_" if keyword.iskeyword(o["name"]) else "")  # as Python spells it
        for v in bad:
            with pytest.raises(InvalidArgumentError) as e:
                btfrs.fit.fit(kind, small, **{py: v})
            msg = str(e.value)
            assert msg.startswith(py + ": expected ") and o["allowed"] in msg, msg
            # The same facts as fields, set where the check was made (not read from the message).
            assert (e.value.argument, e.value.value, e.value.allowed) == (py, v, o["allowed"]), msg
            # Through the generated function, spelled as Python spells it.
            with pytest.raises(InvalidArgumentError) as e:
                getattr(btfrs.fit, kind)(small, **{py: v})
            assert (e.value.argument, e.value.value, e.value.allowed) == (py, v, o["allowed"]), str(e.value)
    with pytest.raises(InvalidArgumentError, match="unknown option") as e:
        btfrs.fit.fit(kind, small, no_such_option=1)
    assert (e.value.argument, e.value.value) == ("no_such_option", 1)
    with pytest.raises(InvalidArgumentError, match="finite") as e:
        btfrs.fit.fit(kind, small, memory_limit=None, **{"x": float("nan")})
    assert e.value.argument == "x" and np.isnan(e.value.value) and e.value.allowed == "a finite number"


def test_numpy_scalars_are_options_too(small):
    m = btfrs.fit.hsh(small, order=np.int64(2), lambda_=np.float32(1e-6), bits=np.uint8(32))
    assert m.order == 2 and m.arrays["coeffs"].dtype == np.float32
    # A numpy float for an integer option is a type error, as a Python float is.
    with pytest.raises(ArgumentTypeError) as e:
        btfrs.fit.hsh(small, order=np.float64(2.0))
    assert (e.value.argument, e.value.value) == ("order", 2.0)
    # Values that are no number, string, boolean or None are refused naming the option.
    with pytest.raises(ArgumentTypeError, match="order: expected a number, a string, a boolean or None, got list"):
        btfrs.fit.fit("hsh", small, order=[2])


def test_errors_keep_their_fields_when_pickled(small):
    # A Dask worker's error reaches the client pickled: its fields come with it.
    import pickle

    with pytest.raises(InvalidArgumentError) as e:
        btfrs.fit.hsh(small, lambda_=-1.0)
    back = pickle.loads(pickle.dumps(e.value))
    assert type(back) is type(e.value) and str(back) == str(e.value)
    assert (back.argument, back.value, back.allowed) == ("lambda_", -1.0, "a number >= 0")


def test_every_model_class_is_exported_and_the_cli_lists_every_kind():
    for kind in KINDS:
        assert TYPES[kind] in btfrs.__all__
    r = subprocess.run([sys.executable, "-m", "btfrs.cli", "fit", "--help"], capture_output=True, text=True)
    assert r.returncode == 0
    for kind in KINDS:
        assert kind in r.stdout


def test_the_readme_and_the_docs_list_every_kind():
    readme = (ROOT / "README.md").read_text()
    rows = set(re.findall(r"^\| `([a-z_]+)` \|", readme, re.M))
    assert rows == set(KINDS), "README's model table lists exactly the registered kinds"
    pages = "".join(p.read_text() for p in (ROOT / "docs" / "models").glob("*.md"))
    for kind in KINDS:
        assert f'--8<-- "docs/_generated/{kind}.md"' in pages, f"no docs page includes {kind}'s options"


def test_contributing_lists_every_model_of_the_registry():
    # CONTRIBUTING.md's layout table names the kinds btfrs-fit holds: exactly the registered ones,
    # and each kind's fit file exists where the table's crate says.
    text = (ROOT / "CONTRIBUTING.md").read_text()
    row = next(line for line in text.splitlines() if line.startswith("| `rust/btfrs-fit` |"))
    listed = re.search(r"\(kinds ([^;]*);", row)
    assert listed, "the btfrs-fit row lists its models as '(kinds `a`, `b`, ...;'"
    kinds = re.findall(r"`([a-z_]+)`", listed.group(1))
    assert len(kinds) == len(set(kinds)) and set(kinds) == set(KINDS), (sorted(kinds), sorted(KINDS))
    for kind in KINDS:
        assert list(ROOT.glob(OWN[kind][0])) or list(ROOT.glob(OWN[kind][1])), kind


# Strings of the bench that are another thing's name and spell a kind: string -> what it is.
BENCH_NOT_KINDS = {"sh": "lighting=\"sh\", the SH lighting method (a model ability's name)"}


def test_the_bench_names_no_model():
    # Every model-specific setting of the bench is a registry fact (the models' BENCH settings):
    # no string of it (docstrings and help included) is a kind or holds one as a word, nor a
    # label of the registry's settings (examples, sweeps, bench settings), and no name in it is a
    # model's class or a kind (btfrs.fit.<kind>).
    path = ROOT / "python" / "btfrs" / "tools" / "bench.py"
    tree = ast.parse(path.read_text())
    labels = {lab for info in KINDS.values() for lab in
              [e[0] for e in info["examples"]] + [s[0] for s in info["sweep"]] + [b["label"] for b in info["bench"]]
              if lab}
    classes = {TYPES[k] for k in KINDS}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            text = node.value
            if text in BENCH_NOT_KINDS:
                continue
            for kind in KINDS:
                if re.search(rf"(?<![\w-]){re.escape(kind)}(?![\w-])", text):
                    found.append(f"bench.py:{node.lineno}: the kind {kind!r} in {text[:60]!r}")
            for lab in labels:
                if re.search(rf"(?<![\w-]){re.escape(lab)}(?![\w-])", text):
                    found.append(f"bench.py:{node.lineno}: the setting {lab!r} in {text[:60]!r}")
        elif isinstance(node, (ast.Name, ast.Attribute)):
            name = node.id if isinstance(node, ast.Name) else node.attr
            if name in classes or name in KINDS:
                found.append(f"bench.py:{node.lineno}: the name {name}")
        elif isinstance(node, ast.alias) and node.name in classes:
            found.append(f"bench.py: imports {node.name}")
    assert not found, "the bench names models:\n" + "\n".join(found)


def test_the_fit_crates_module_list_names_every_module():
    # btfrs-fit's crate doc is its guide: every public module is named there as a link ([`x`]),
    # so a new module (a model's file, or a room split off) is described where readers look.
    text = (ROOT / "rust" / "btfrs-fit" / "src" / "lib.rs").read_text()
    doc = "\n".join(line for line in text.splitlines() if line.startswith("//!"))
    modules = re.findall(r"^pub mod (\w+);", text, re.M)
    assert len(modules) >= len(KINDS), modules  # the reader found the declarations
    missing = [m for m in modules if f"[`{m}`]" not in doc]
    assert not missing, f"btfrs-fit's lib.rs doc leaves out {missing}"
