"""Check and re-point the ``file:line`` anchors of docs/*.md (issue 30, item 5: every number traceable).

The anchor convention of docs/faithfulness.md:

- An anchor is a backticked ``path.py:N`` or ``path.py:N-M`` (a line or a range); paths are under
  ``dualtalker_lite/`` unless they start with ``tests/``, ``benchmarks/`` or ``tools/``. A bare ``:N`` or ``:N-M``
  reuses the last path written before it on the same line (one table row or one prose line).
- Its *key* is the backticked token written right after it (only spaces between): an identifier (``combine``,
  ``paper()``, ``DualFusionLayer.forward``) or a code fragment (``"corrtalk"``). Rule for a keyed anchor:
  if the key names a ``def``/``class`` of that file (for ``A.b``: method ``b`` of class ``A``), the anchor must cite
  its ``def``/``class`` line (a range must contain it); otherwise the key must occur in the cited line, for a range
  in its first line (as a whole word when it is an identifier).
- An anchor with no key cites a docstring passage: every line of it must lie inside one docstring of that file.

``python tools/fix_doc_anchors.py`` rewrites every keyed anchor whose line moved to where its key now is (the
candidate nearest to the old line; a range keeps its length), and, with ``--base REV``, every unkeyed anchor to where
the text it cited at REV now is. ``--check`` only lists the wrong anchors (exit status 1 if any). Run it after a merge
that moved code, then ``pytest tests/test_doc_anchors.py``.
"""
from __future__ import annotations

import argparse
import ast
import re
import subprocess
import sys
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "dualtalker_lite"
TOP_LEVEL = ("tests/", "benchmarks/", "tools/")
TICK = re.compile(r"`([^`\n]+)`")
ANCHOR = re.compile(r"^(?P<path>[\w./-]+\.py)?:(?P<start>\d+)(?:-(?P<end>\d+))?$")
IDENT = re.compile(r"^[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*$")


@dataclass
class Anchor:
    doc: Path
    line: int            # 1-based line of the doc
    span: tuple          # (start, end) character offsets of the backticked anchor text (without the backticks)
    path: str            # as written (relative to the package unless it starts with tests/ ...)
    start: int
    end: int | None      # None for a single line
    key: str | None      # the backticked token right after it, or None

    @property
    def file(self) -> Path:
        return ROOT / self.path if self.path.startswith(TOP_LEVEL) else ROOT / PACKAGE / self.path

    @property
    def where(self) -> str:
        rng = f"{self.start}-{self.end}" if self.end is not None else f"{self.start}"
        return f"{_rel(self.doc)}:{self.line}: `{self.path}:{rng}`" + (f" `{self.key}`" if self.key else "")


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def parse(doc: Path, text: str | None = None) -> list[Anchor]:
    """Every anchor of one Markdown file, in order."""
    text = doc.read_text() if text is None else text
    out = []
    for n, line in enumerate(text.splitlines(), 1):
        path = None
        ticks = list(TICK.finditer(line))
        for i, t in enumerate(ticks):
            m = ANCHOR.match(t.group(1))
            if not m:
                continue
            path = m["path"] or path
            if path is None:
                raise ValueError(f"{doc}:{n}: `{t.group(1)}` has no path before it on its line")
            key = None
            if i + 1 < len(ticks) and line[t.end():ticks[i + 1].start()].strip() == "" \
                    and not ANCHOR.match(ticks[i + 1].group(1)):
                key = ticks[i + 1].group(1)
            end = int(m["end"]) if m["end"] else None
            out.append(Anchor(doc, n, (t.start(1), t.end(1)), path, int(m["start"]), end, key))
    return out


@lru_cache(maxsize=None)
def _source(file: Path) -> tuple[list[str], ast.Module]:
    text = file.read_text()
    return text.splitlines(), ast.parse(text)


def definitions(file: Path, key: str) -> list[int]:
    """Lines of the ``def``/``class`` named by ``key`` (``name``, ``name()`` or ``Class.name``) in ``file``."""
    parts = key.removesuffix("()").split(".")
    _, tree = _source(file)

    def find(nodes, names):
        hits = []
        for node in nodes:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                if node.name == names[0]:
                    hits += [node.lineno] if len(names) == 1 else find(node.body, names[1:])
                if len(names) == len(parts):  # an unqualified name may be a method or a nested def anywhere
                    hits += find(node.body, names) if isinstance(node, ast.ClassDef) or len(names) == 1 else []
        return hits

    return sorted(set(find(tree.body, parts)))


def occurrences(file: Path, key: str) -> list[int]:
    """Lines of ``file`` that hold ``key`` (as a whole word when it is an identifier)."""
    lines, _ = _source(file)
    k = key.removesuffix("()")
    pat = re.compile(rf"(?<!\w){re.escape(k)}(?!\w)" if IDENT.match(k) else re.escape(k))
    return [i for i, s in enumerate(lines, 1) if pat.search(s)]


def docstring_spans(file: Path) -> list[tuple[int, int]]:
    """(first, last) lines of every docstring (a string statement) of ``file``."""
    _, tree = _source(file)
    return [(n.lineno, n.end_lineno) for n in ast.walk(tree)
            if isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant) and isinstance(n.value.value, str)]


def candidates(a: Anchor) -> list[int]:
    """Lines the anchor may start at, by its key (empty for an unkeyed anchor)."""
    if a.key is None:
        return []
    return definitions(a.file, a.key) or occurrences(a.file, a.key)


def problem(a: Anchor) -> str | None:
    """None when the anchor is right, else a sentence saying what is wrong and where the key now is."""
    if not a.file.exists():
        return f"{a.where}: no file {_rel(a.file)}"
    lines, _ = _source(a.file)
    last = a.end if a.end is not None else a.start
    if not 1 <= a.start <= last <= len(lines):
        return f"{a.where}: lines {a.start}-{last} are outside the file ({len(lines)} lines)"
    if a.key is None:
        if any(s <= a.start and last <= e for s, e in docstring_spans(a.file)):
            return None
        return (f"{a.where}: an anchor with no key must cite a docstring passage, but lines {a.start}-{last} are "
                f"not inside one docstring (run tools/fix_doc_anchors.py --base REV, REV the last commit where it "
                f"was right)")
    defs = definitions(a.file, a.key)
    if defs:
        ok = any(a.start <= d <= last for d in defs) if a.end is not None else a.start in defs
        kind = "defined"
    else:
        ok = a.start in occurrences(a.file, a.key)
        kind = "found"
    if ok:
        return None
    now = candidates(a)
    if not now:
        return f"{a.where}: `{a.key}` is nowhere in {a.path}"
    return (f"{a.where}: line {a.start} does not hold `{a.key}`; it is {kind} at {a.path}:"
            + ", ".join(map(str, now)) + f" (nearest: {nearest(now, a.start)})")


def nearest(lines: list[int], old: int) -> int:
    return min(lines, key=lambda x: (abs(x - old), x))


def _text_at(rev: str, a: Anchor) -> list[str] | None:
    rel = a.file.relative_to(ROOT).as_posix()
    try:
        old = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{rel}"], check=True, capture_output=True,
                             text=True).stdout.splitlines()
    except subprocess.CalledProcessError:
        return None
    last = a.end if a.end is not None else a.start
    return [s.strip() for s in old[a.start - 1:last]] if last <= len(old) else None


def relocate(a: Anchor, base: str | None) -> int | None:
    """The new first line of a wrong anchor, or None when it cannot be found."""
    if a.key is not None:
        now = candidates(a)
        return nearest(now, a.start) if now else None
    if base is None:
        return None
    block = _text_at(base, a)
    if not block:
        return None
    lines = [s.strip() for s in _source(a.file)[0]]
    starts = [i + 1 for i in range(len(lines) - len(block) + 1) if lines[i:i + len(block)] == block]
    return nearest(starts, a.start) if starts else None


def fix(doc: Path, base: str | None = None) -> tuple[str, list[str]]:
    """The doc's text with every wrong anchor re-pointed, and what was changed or could not be."""
    text = doc.read_text()
    lines = text.splitlines(keepends=True)
    notes = []
    for a in reversed(parse(doc, text)):  # right to left, so the offsets stay valid
        wrong = problem(a)
        if wrong is None and (a.key is not None or base is None):
            continue  # a docstring range may have moved inside its docstring: with --base it is always looked up
        new = relocate(a, base)
        if new is None:
            if wrong is not None:
                notes.append(f"NOT FIXED {wrong}")
            continue
        if new == a.start:
            continue
        shift = new - a.start
        rng = f"{new}-{a.end + shift}" if a.end is not None else f"{new}"
        written = lines[a.line - 1][a.span[0]:a.span[1]]
        prefix = written[:written.index(":")]
        s, e = a.span
        lines[a.line - 1] = lines[a.line - 1][:s] + f"{prefix}:{rng}" + lines[a.line - 1][e:]
        notes.append(f"fixed {a.where} -> :{rng}")
    return "".join(lines), notes[::-1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("docs", nargs="*", type=Path, help="Markdown files (default: docs/*.md)")
    ap.add_argument("--check", action="store_true", help="list the wrong anchors, change nothing")
    ap.add_argument("--base", help="a commit where the unkeyed (docstring) anchors were right")
    args = ap.parse_args(argv)
    docs = [d.resolve() for d in args.docs] or sorted((ROOT / "docs").glob("*.md"))
    bad = 0
    for doc in docs:
        if args.check:
            for a in parse(doc):
                if (p := problem(a)) is not None:
                    bad += 1
                    print(p)
            continue
        _source.cache_clear()
        text, notes = fix(doc, args.base)
        if text != doc.read_text():
            doc.write_text(text)
        for n in notes:
            bad += n.startswith("NOT FIXED")
            print(n)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
