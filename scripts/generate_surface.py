"""Generate the parts of btfrs that repeat the model registry, from the registry itself.

The Rust registry (``btfrs_fit::registry::describe``, read through ``btfrs._native.model_facts``)
holds every fact of a model: its option schema (name, type, default, allowed values, doc), its
description, renderers, sweep, sampling and export formats. This script writes

* ``python/btfrs/fit.py``: one function per model with a real signature and docstring, so that
  ``help(btfrs.fit.ptm)``, IDE completion and stubtest see them;
* the block of ``python/btfrs/_native.pyi`` between ``# BEGIN GENERATED`` and
  ``# END GENERATED``: the ``_ModelKind`` literal the fit binding takes;
* ``docs/_generated/<kind>.md``: the options table each model's docs page includes.

Run it after changing a model's registry entry: ``.venv/bin/python scripts/generate_surface.py``.
``--check`` writes nothing and exits 1 if any file would change (the test suite runs it).
"""

from __future__ import annotations

import argparse
import json
import keyword
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FIT = ROOT / "python" / "btfrs" / "fit.py"
STUB = ROOT / "python" / "btfrs" / "_native.pyi"
DOCS = ROOT / "docs" / "_generated"


def py_name(name: str) -> str:
    """The Python keyword argument of an option (a Python keyword gets a trailing ``_``)."""
    return name + "_" if keyword.iskeyword(name) else name


def py_type(o: dict) -> str:
    t = o["type"]
    if t == "int":
        return "int"
    if t == "optional_int":
        return "Optional[int]"
    if t == "float":
        return "float"
    if t == "bool":
        return "bool"
    if t in ("choice", "int_choice"):
        return "Literal[" + ", ".join(json.dumps(c) for c in o["choices"]) + "]"
    raise SystemExit(f"unknown option type {t!r} of {o['name']!r}: teach scripts/generate_surface.py")


def py_default(o: dict) -> str:
    d = o["default"]
    if d is None:
        return "None"
    if isinstance(d, bool):
        return "True" if d else "False"
    if isinstance(d, str):
        return json.dumps(d)
    return repr(d)


def wrap(text: str, indent: str, width: int = 100) -> list[str]:
    """Words of ``text`` in lines of at most ``width`` characters after ``indent``."""
    lines, cur = [], ""
    for word in text.split():
        if cur and len(indent) + len(cur) + 1 + len(word) > width:
            lines.append(indent + cur)
            cur = word
        else:
            cur = f"{cur} {word}" if cur else word
    if cur:
        lines.append(indent + cur)
    return lines


def docstring(m: dict) -> list[str]:
    """The function's docstring lines (numpy style), from the registry."""
    out = [f"Fit {m['doc']}."]
    for para in m["about"].split("\n\n"):
        out.append("")
        out += wrap(para.replace("\n", " "), "")
    out += ["", "Parameters", "----------", "btf", "    The BTF (or capture) to fit: only its present pairs are used."]
    for o in m["options"]:
        out.append(f"{py_name(o['name'])}")
        out += wrap(f"{o['doc'][0].upper() + o['doc'][1:]}. Allowed: {o['allowed']}; default {py_default(o)}.", "    ")
    for o in COMMON:
        out.append(f"{py_name(o['name'])}")
        out += wrap(f"{o['doc'][0].upper() + o['doc'][1:]}. Default {py_default(o)}.", "    ")
    out += [
        "memory_limit",
        "    The anonymous memory the fit may allocate besides the model: bytes, or a size such as",
        "    ``\"2GB\"`` (``None``: no limit). A limit below what the fit needs raises",
        "    :class:`~btfrs.exceptions.InvalidArgumentError` naming the least it needs, before any work.",
        "progress",
        "    ``None``, ``True`` for a progress bar, or a callable ``(done, total)``.",
        "",
        "Returns",
        "-------",
        f"{m['class']}",
        "    The fitted model.",
    ]
    return out


def fit_module(facts: list[dict]) -> str:
    kinds = [m["kind"] for m in facts]
    classes = sorted({m["class"] for m in facts})
    lines = [
        '"""Fitting reflectance models to a BTF: ``btfrs.fit.<kind>(btf, **options)``.',
        "",
        "One function per registered model, each fitting only the pairs present in ``btf`` (its mask),",
        "so fitting the train half of a split never sees the held-out pairs; :func:`fit` fits any",
        "registered model by name (``btfrs.fit.fit(\"lpca\", btf, clusters=8)``). The options, their",
        "defaults and allowed values are the model's own (its registry entry): they are checked once, in",
        "Rust, and an error names the option, the value and what is allowed.",
        "",
        "**Out of core.** Every fit reads the values in place, so a memory-mapped BTF",
        "(``btfrs.load(path, mmap=True)``) stays on disk but for the pages being read, and every fit",
        "takes ``memory_limit``: the anonymous memory it may allocate besides the model it returns.",
        "",
        "This file is generated from the model registry by ``scripts/generate_surface.py``; edit the",
        "model's registry entry (``rust/btfrs-fit/src/<model>.rs``), not this file.",
        '"""',
        "",
        "# Generated by scripts/generate_surface.py: do not edit.",
        "",
        "from __future__ import annotations",
        "",
        "from typing import Literal, Optional",
        "",
        "from ._fitting import MemoryLimit, fit, fit_kind",
        "from ._progress import Progress",
        "from .btf import Btf",
        f"from .models import {', '.join(classes)}",
        "",
        "__all__ = " + repr(["fit"] + kinds).replace("'", '"'),
    ]
    for m in facts:
        params = ["btf: Btf", "*"]
        for o in m["options"]:
            params.append(f"{py_name(o['name'])}: {py_type(o)} = {py_default(o)}")
        params += [f"{py_name(o['name'])}: {py_type(o)} = {py_default(o)}" for o in COMMON]
        params += ["memory_limit: MemoryLimit = None", "progress: Progress = None"]
        lines += ["", ""]
        head = f"def {m['kind']}("
        sig = head + ", ".join(params) + f") -> {m['class']}:"
        if len(sig) <= 110:
            lines.append(sig)
        else:
            lines.append(head)
            lines += [f"    {p}," for p in params]
            lines.append(f") -> {m['class']}:")
        doc = docstring(m)
        lines.append('    """' + doc[0])
        lines += [("    " + d) if d else "" for d in doc[1:]]
        lines.append('    """')
        opts = ", ".join(f"{json.dumps(o['name'])}: {py_name(o['name'])}" for o in m["options"])
        lines.append(f"    options: dict[str, object] = {{{opts}}}")
        common = ", ".join(py_name(o["name"]) for o in COMMON)
        lines.append(f"    model = fit_kind({json.dumps(m['kind'])}, btf, options, memory_limit, progress, {common})")
        lines.append(f"    assert isinstance(model, {m['class']})")
        lines.append("    return model")
    return "\n".join(lines) + "\n"


def stub_block(facts: list[dict]) -> str:
    kinds = ", ".join(json.dumps(m["kind"]) for m in facts)
    return f"_ModelKind = Literal[{kinds}]\n"


# The options every fit takes besides its own (robust fitting): btfrs_fit::robust::OPTIONS.
COMMON: list[dict] = []


MIPS = {
    "average": "averages of the texels' parameters (exact: the model is linear in them)",
    "projected": "the block's mean appearance projected on the model's form (least squares)",
    "medoid": "appearance medoids (the texel of each block nearest its mean appearance)",
}


def doc_page(m: dict) -> str:
    rows = ["| option | type | default | allowed | what it does |", "|---|---|---|---|---|"]
    for o in m["options"]:
        rows.append(f"| `{py_name(o['name'])}` | `{py_type(o)}` | `{py_default(o)}` | {o['allowed']} | {o['doc']} |")
    for o in COMMON:
        rows.append(f"| `{py_name(o['name'])}` | `{py_type(o)}` | `{py_default(o)}` | {o['allowed']} | {o['doc']} |")
    rows.append("| `memory_limit` | `int \\| str \\| None` | `None` | bytes, or a size such as `\"2GB\"` | "
                "the memory the fit may allocate besides the model |")
    rows.append("| `progress` | `bool \\| callable \\| None` | `None` | | a progress bar, or a callable `(done, total)` |")
    sweep = ", ".join(f"{s['label']}" + (" (quick)" if s["quick"] else "") for s in m["sweep"])
    sampling = m["sampling"]
    need = (f"a fit per view slot: at least {sampling['min_lights']} lights per view ({sampling['why']})"
            if sampling["per_view"] else sampling["note"])
    facts = [
        f"- **Fit**: `btfrs.fit.{m['kind']}(btf, ...)`, or `btfrs fit CAPTURE --model {m['kind']}`; returns "
        f"`btfrs.{m['class']}`.",
        f"- **Sampling**: {need}.",
        f"- **Renderers**: {', '.join(f'`{r}`' for r in m['renderers'])} (the first is the default).",
        f"- **Mip levels** (`filter=\"trilinear\"`): {MIPS[m['mip']]}.",
        f"- **Evaluated at**: {sweep}.",
        f"- **Other formats**: {', '.join(f'`.{e}`' for e in m['exports']) or 'none'}.",
        f"- **Blockwise (Dask)**: {m['blockwise']}" + (f" ({m['blockwise_note']})" if m["blockwise_note"] else "") + ".",
    ]
    return "\n".join([f"#### `{m['kind']}`: {m['doc']}", "", *facts, "", *rows]) + "\n"


def read_facts() -> list[dict]:
    sys.path.insert(0, str(ROOT / "python"))
    import btfrs  # the built extension and the models' Python classes
    from btfrs.models import class_of

    facts = json.loads(btfrs._native.model_facts())
    COMMON[:] = json.loads(btfrs._native.fit_options())
    for m in facts:
        m["class"] = class_of(m["kind"]).__name__
    return facts


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 if a file would change")
    args = ap.parse_args()
    facts = read_facts()
    outputs: dict[Path, str] = {FIT: fit_module(facts)}
    stub = STUB.read_text()
    a, b = stub.index("# BEGIN GENERATED\n"), stub.index("# END GENERATED")
    outputs[STUB] = stub[: a + len("# BEGIN GENERATED\n")] + stub_block(facts) + stub[b:]
    for m in facts:
        outputs[DOCS / f"{m['kind']}.md"] = doc_page(m)
    stale = [p for p, text in outputs.items() if not p.exists() or p.read_text() != text]
    if args.check:
        for p in stale:
            print(f"{p.relative_to(ROOT)} differs from what the registry generates", file=sys.stderr)
        if stale:
            print("run: .venv/bin/python scripts/generate_surface.py", file=sys.stderr)
        return 1 if stale else 0
    for p in stale:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(outputs[p])
        print(f"wrote {p.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
