"""Every formula in every notebook's markdown renders with a real KaTeX (the npm package, run by node).

JupyterLab shows a formula KaTeX cannot parse as red error text (e.g. "Multiple \\tag"), so a formula that only
*looks* right in the source is not enough. The math is taken from the markdown cells the way JupyterLab finds it
(``$...$``, ``$$...$$``, ``\\begin{env}...\\end{env}``; code spans and fenced code left out) and rendered by
``tools/katex/render_math.js`` with ``throwOnError``. Needs node and ``make katex`` (``npm ci --prefix
tools/katex``); without them the test is skipped with the reason, except where ``DUALTALKER_REQUIRE_KATEX=1``
(``tools/test_tools.sh``, run by ``make test``, sets it where KaTeX is installed), where it fails.
"""
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
KATEX_DIR = ROOT / "tools" / "katex"
NOTEBOOKS = sorted((ROOT / "notebooks").glob("[0-9][0-9]*_*.ipynb"))


def strip_code(text: str) -> str:
    """Fenced code blocks and inline code spans -> spaces (their dollars are not math), same length."""
    blank = lambda m: re.sub(r"[^\n]", " ", m.group(0))  # noqa: E731
    text = re.sub(r"^([ \t]*)(`{3,}|~{3,})[^\n]*\n.*?^\1\2[ \t]*$", blank, text, flags=re.M | re.S)
    return re.sub(r"(`+)(?!`).+?(?<!`)\1(?!`)", blank, text, flags=re.S)


def math_spans(text: str) -> list[tuple[str, bool]]:
    """Markdown -> [(tex, display)] in order. Unterminated ``$$`` or environments come back as
    ``("<unterminated ...>", True)``, which no renderer accepts; a lone ``$`` (a price) is text, as in Jupyter."""
    text, out, i = strip_code(text), [], 0
    while i < len(text):
        if text.startswith("\\begin{", i):
            m = re.match(r"\\begin\{([A-Za-z]+\*?)\}", text[i:])
            end_tag = f"\\end{{{m.group(1)}}}" if m else None
            end = text.find(end_tag, i) if end_tag else -1
            if end < 0:
                out.append((f"<unterminated {text[i:i + 30]!r}>", True))
                break
            out.append((text[i:end + len(end_tag)], True))
            i = end + len(end_tag)
        elif text[i] == "\\":
            i += 2  # an escaped character (\$, \\)
        elif text.startswith("$$", i):
            j = i + 2
            while j < len(text) and not text.startswith("$$", j):
                j += 2 if text[j] == "\\" else 1
            if j >= len(text):
                out.append((f"<unterminated $$ {text[i:i + 30]!r}>", True))
                break
            out.append((text[i + 2:j], True))
            i = j + 2
        elif text[i] == "$":
            j = i + 1
            while j < len(text) and text[j] != "$" and not re.match(r"\n[ \t]*\n", text[j:j + 3]):
                j += 2 if text[j] == "\\" else 1
            if j < len(text) and text[j] == "$" and j > i + 1:
                out.append((text[i + 1:j], False))
                i = j + 1
            else:
                i += 1
        else:
            i += 1
    return out


def notebook_math() -> list[dict]:
    items = []
    for nb in NOTEBOOKS:
        cells = json.loads(nb.read_text())["cells"]
        for k, cell in enumerate(cells):
            if cell["cell_type"] == "markdown":
                source = "".join(cell["source"]) if isinstance(cell["source"], list) else cell["source"]
                for tex, display in math_spans(source):
                    items.append({"where": f"{nb.name} cell {k}", "tex": tex, "display": display})
    return items


def render(items: list[dict]) -> list[dict]:
    node = shutil.which("node")
    if node is None or not (KATEX_DIR / "node_modules" / "katex").is_dir():
        reason = ("node is not installed" if node is None else
                  "KaTeX is not installed: run `make katex` (npm ci --prefix tools/katex)")
        if os.environ.get("DUALTALKER_REQUIRE_KATEX") == "1":
            pytest.fail(f"DUALTALKER_REQUIRE_KATEX=1 but {reason}")
        pytest.skip(reason)
    proc = subprocess.run([node, str(KATEX_DIR / "render_math.js")], input=json.dumps(items), capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_math_is_found_as_jupyter_finds_it():
    text = ("Code `$x$` is not math. Inline $a_t = \\sum_i x_i$ and \\$ escaped.\n\n"
            "$$\ny = Wx \\tag{1}\n$$\n\n```python\nprint('$$ not math $$')\n```\n"
            "\\begin{aligned} a &= b \\tag{2}\\end{aligned} and $$z$$")
    assert math_spans(text) == [("a_t = \\sum_i x_i", False), ("\ny = Wx \\tag{1}\n", True),
                                ("\\begin{aligned} a &= b \\tag{2}\\end{aligned}", True), ("z", True)]
    assert math_spans("a $$ b") == [("<unterminated $$ '$$ b'>", True)]
    assert math_spans("$x\n\ny$") == [] and math_spans("it costs $5.") == []  # a blank line ends inline math


@pytest.mark.tools
def test_the_renderer_fails_on_what_jupyterlab_shows_in_red():
    bad = [{"where": "two tags", "tex": "a \\tag{1} \\\\ b \\tag{2}", "display": True},
           {"where": "underscore in text", "tex": "\\text{lip_dist}", "display": True},
           {"where": "tag inline", "tex": "x \\tag{3}", "display": False},
           {"where": "unknown macro", "tex": "\\foo{x}", "display": False},
           {"where": "good", "tex": "\\begin{aligned} a &= b \\\\ c &= d \\end{aligned} \\tag{4}", "display": True}]
    failed = {f["where"]: f["error"] for f in render(bad)}
    assert set(failed) == {"two tags", "underscore in text", "tag inline", "unknown macro"}
    assert "Multiple \\tag" in failed["two tags"]


@pytest.mark.tools
def test_every_notebook_formula_renders_in_katex():
    items = notebook_math()
    assert len(NOTEBOOKS) >= 16 and len(items) > 300  # the notebooks are full of equations
    failures = render(items)
    report = "\n".join(f"{f['where']}: {f['error']}\n    {f['tex'][:200]!r}" for f in failures)
    assert failures == [], f"{len(failures)} of {len(items)} formulas do not render in KaTeX:\n{report}"


def test_built_notebooks_show_their_sources_markdown():
    """The .ipynb a reader opens carries the text of its source (tools/nb_sync_markdown.py copies text-only edits)."""
    import sys

    sys.path.insert(0, str(ROOT / "tools"))
    from nb_build import parse_percent

    stale = []
    for nb in NOTEBOOKS:
        src = ROOT / "notebooks" / "src" / (nb.stem + ".py")
        fresh = [c.source for c in parse_percent(src.read_text()).cells if c.cell_type == "markdown"]
        built = json.loads(nb.read_text())["cells"]
        built = ["".join(c["source"]) for c in built if c["cell_type"] == "markdown"]
        if fresh != built:
            stale.append(nb.name)
    assert stale == [], f"markdown differs from notebooks/src: {stale} (run tools/nb_sync_markdown.py or nb_build.py)"
