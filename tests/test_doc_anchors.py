"""Every ``file:line`` anchor of docs/*.md cites the line its key names (issue 30, item 5: every number traceable).

The rule (tools/fix_doc_anchors.py's docstring has it in full): an anchor ``path.py:N`` / ``:N`` / ``...:N-M`` is
followed by its key in backticks; a key that names a ``def``/``class`` must be cited at that line (a range must
contain it), any other key must occur in the cited line (a range: its first line); an anchor with no key must lie
inside one docstring. When code moves, the failure names each wrong anchor and where its key is now;
``python tools/fix_doc_anchors.py`` rewrites the line numbers (``--base REV`` also re-points the docstring ranges).
"""
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import fix_doc_anchors as fda  # noqa: E402

DOCS = sorted((ROOT / "docs").glob("*.md"))
FAITH = ROOT / "docs" / "faithfulness.md"
# two real places the synthetic docs below cite (read from the file, not hard-coded, so code moves don't break them)
SPIRAL = ROOT / "dualtalker_lite" / "blocks" / "spiral.py"
K_RINGS = next(i for i, s in enumerate(SPIRAL.read_text().splitlines(), 1) if s.startswith("def k_rings("))


def write(tmp_path, text):
    doc = tmp_path / "doc.md"
    doc.write_text(text)
    return doc


def test_the_parser_reads_paths_bare_lines_ranges_and_keys(tmp_path):
    doc = write(tmp_path, "| eq. 1 | `blocks/spiral.py:10` `k_rings`; `:20-22` `spiral_indices`, `:5` (text) |\n"
                          "prose `tests/test_spiral.py:3` and `not/an.anchor` `x`\n")
    got = [(a.line, a.path, a.start, a.end, a.key) for a in fda.parse(doc)]
    assert got == [(1, "blocks/spiral.py", 10, None, "k_rings"), (1, "blocks/spiral.py", 20, 22, "spiral_indices"),
                   (1, "blocks/spiral.py", 5, None, None), (2, "tests/test_spiral.py", 3, None, None)]
    assert fda.parse(doc)[3].file == ROOT / "tests" / "test_spiral.py"
    assert fda.parse(doc)[0].file == SPIRAL


def test_a_wrong_anchor_is_named_with_where_its_key_is_now(tmp_path):
    doc = write(tmp_path, f"`blocks/spiral.py:{K_RINGS}` `k_rings`, `:{K_RINGS + 3}` `k_rings`, "
                          f"`:{K_RINGS - 2}-{K_RINGS + 1}` `k_rings`, `:{K_RINGS}` `no_such_name`, `:1-3`, "
                          f"`:{K_RINGS}`, `:99999` `k_rings`\n")
    problems = [fda.problem(a) for a in fda.parse(doc)]
    assert problems[0] is None and problems[2] is None  # the def line; a range that contains it
    assert f"line {K_RINGS + 3} does not hold `k_rings`; it is defined at blocks/spiral.py:{K_RINGS}" in problems[1]
    assert "`no_such_name` is nowhere in blocks/spiral.py" in problems[3]
    assert problems[4] is None  # lines 1-3: the module docstring
    assert "must cite a docstring passage" in problems[5]  # a def line is code, not a docstring
    assert "outside the file" in problems[6]


def test_a_non_definition_key_must_be_on_the_cited_line(tmp_path):
    lines = SPIRAL.read_text().splitlines()
    n = next(i for i, s in enumerate(lines, 1) if s.startswith("PAPER_SPIRAL_LENGTH, "))
    doc = write(tmp_path, f"`blocks/spiral.py:{n}` `PAPER_DELTA = 5`, `:{n}` `PAPER_DELTA`, `:{n + 1}` `PAPER_DELTA`\n")
    p = [fda.problem(a) for a in fda.parse(doc)]
    assert "is nowhere" in p[0] and p[1] is None and f"found at blocks/spiral.py:" in p[2] and f"{n}" in p[2]


def test_the_fixer_moves_keyed_anchors_to_their_key_and_keeps_a_range_length(tmp_path):
    doc = write(tmp_path, f"a `blocks/spiral.py:{K_RINGS + 4}` `k_rings` and `:{K_RINGS + 1}-{K_RINGS + 5}` "
                          f"`k_rings` and `:2` `no_such_name`\n")
    text, notes = fda.fix(doc)
    assert text == (f"a `blocks/spiral.py:{K_RINGS}` `k_rings` and `:{K_RINGS}-{K_RINGS + 4}` `k_rings` and `:2` "
                    f"`no_such_name`\n")
    assert sum(n.startswith("fixed") for n in notes) == 2 and sum(n.startswith("NOT FIXED") for n in notes) == 1


def test_the_fixer_moves_a_docstring_range_by_its_text_at_a_base_commit(tmp_path, monkeypatch):
    """An unkeyed anchor is found again from the lines it cited at REV (here faked: the text two lines up)."""
    lines = [s.strip() for s in SPIRAL.read_text().splitlines()]
    monkeypatch.setattr(fda, "_text_at", lambda rev, a: lines[a.start + 1:a.end + 2])
    doc = write(tmp_path, "`blocks/spiral.py:8-10`\n")
    text, _ = fda.fix(doc, base="HEAD")
    assert text == "`blocks/spiral.py:10-12`\n"


def test_faithfulness_has_its_anchors():
    anchors = fda.parse(FAITH)
    assert len(anchors) >= 100, "the parser lost the anchors of docs/faithfulness.md"
    assert sum(a.key is not None for a in anchors) >= 90


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_every_anchor_cites_its_key(doc):
    wrong = [p for a in fda.parse(doc) if (p := fda.problem(a)) is not None]
    assert wrong == [], ("wrong file:line anchors (run `python tools/fix_doc_anchors.py`, then check the diff):\n"
                         + "\n".join(wrong))


TEST_ID = re.compile(r"`(tests/[\w/]+\.py)?::(\w+)`")


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_every_cited_test_exists(doc):
    """A cited test id (`tests/x.py::name`, or `::name` after one on the same line) names a test function that exists:
    a renamed or replaced test must not leave an equation row pointing at nothing."""
    missing = []
    for n, line in enumerate(doc.read_text().splitlines(), 1):
        path = None
        for m in TEST_ID.finditer(line):
            path = m.group(1) or path
            if path is None:
                missing.append(f"{doc.name}:{n}: `::{m.group(2)}` has no test file before it on its line")
                continue
            file = ROOT / path
            if not file.exists() or not re.search(rf"^def {m.group(2)}\(", file.read_text(), re.M):
                missing.append(f"{doc.name}:{n}: {path}::{m.group(2)}")
    assert missing == [], "cited tests that do not exist:\n" + "\n".join(missing)
