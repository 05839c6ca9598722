"""Every python code block of README.md and docs/**/*.md runs, as a user would run it.

One test per block, named by its page and its first line (``docs/rendering.md:42``). The blocks
of one page run in order in one namespace, in a temporary folder of their own, as a reader
pasting them one after the other into a fresh interpreter would; running one block by itself
(``-k``) first runs the page's earlier blocks. A block that genuinely cannot run here (it needs
a 32 GB file or a download) is fenced as ```` ```python {.skip} ```` (a CSS class for mkdocs,
ignored by GitHub) and is only checked to compile.
"""

from __future__ import annotations

import linecache
import os
import re
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# A fence opens with ``` or ~~~ at any indentation (inside a list item or an admonition) and
# closes with the same fence at the same indentation.
FENCE = re.compile(r"^(?P<indent>[ \t]*)(?P<fence>```|~~~)(?P<info>[^\n]*)\n(?P<body>.*?)^(?P=indent)(?P=fence)[ \t]*$",
                   re.M | re.S)


def pages() -> list[Path]:
    docs = sorted(p for p in (ROOT / "docs").rglob("*.md") if "_generated" not in p.parts)
    return [ROOT / "README.md"] + docs


def blocks(page: Path) -> list[tuple[int, str, bool]]:
    """``(line, code, runs)`` of every python block of ``page``."""
    text = page.read_text(encoding="utf-8")
    out = []
    for m in FENCE.finditer(text):
        info = m.group("info").strip().split()
        if not info or info[0] not in ("python", "py"):
            continue
        line = text.count("\n", 0, m.start()) + 1
        code = textwrap.dedent(m.group("body"))
        out.append((line, code, not any(t.strip("{}") == ".skip" for t in info[1:])))
    return out


CASES = [pytest.param(page, i, id=f"{page.relative_to(ROOT)}:{line}")
         for page in pages() for i, (line, _, _) in enumerate(blocks(page))]


class _Page:
    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.ns: dict = {"__name__": "__main__"}
        self.done = 0
        self.failed: str | None = None


_STATE: dict[Path, _Page] = {}


def _run(page: Path, state: _Page, i: int, line: int, code: str, runs: bool) -> None:
    name = f"{page.relative_to(ROOT)}:{line}"
    linecache.cache[name] = (len(code), None, code.splitlines(True), name)  # tracebacks show the block
    compiled = compile(code, name, "exec")
    if not runs:
        state.done = i + 1
        return
    cwd = os.getcwd()
    os.chdir(state.folder)
    try:
        exec(compiled, state.ns)
    except BaseException:
        state.failed = f"{page.relative_to(ROOT)}:{line}"
        raise
    finally:
        os.chdir(cwd)
        state.done = i + 1


def test_the_pages_have_python_blocks_and_few_skip_any():
    assert len(blocks(ROOT / "README.md")) >= 3
    found = [(p, b) for p in pages() for b in blocks(p)]
    assert len(found) >= 20
    # The marker is for what cannot run here (a 32 GB file, a data set, a cluster); not a way to
    # quiet a block that fails.
    skipped = [f"{p.relative_to(ROOT)}:{line}" for p, (line, _, runs) in found if not runs]
    assert len(skipped) <= 5, skipped
    assert all(runs for _, _, runs in blocks(ROOT / "README.md")), "every README block runs"


@pytest.mark.parametrize("page, index", CASES)
def test_snippet_runs(page: Path, index: int, tmp_path_factory):
    state = _STATE.get(page)
    if state is None:
        state = _STATE[page] = _Page(tmp_path_factory.mktemp(page.stem))
    found = blocks(page)
    for j in range(state.done, index):  # the page's earlier blocks, when this one runs alone
        if state.failed:
            break
        _run(page, state, j, *found[j])
    if state.failed:
        pytest.skip(f"an earlier block of this page failed: {state.failed}")
    _run(page, state, index, *found[index])
    if not found[index][2]:
        pytest.skip("fenced as python {.skip}: compiled, not run")
