"""Copy the markdown cells of notebook sources into their built notebooks WITHOUT executing anything.

For text-only edits of ``notebooks/src/NN_name.py`` (a typo, an equation that KaTeX cannot render): the built
``notebooks/NN_name.ipynb`` keeps its outputs, and only its markdown cells are replaced, in order, by the
source's. Refused (use ``tools/nb_build.py NN``) when the cell structure or any code cell differs, because then
the outputs would no longer belong to the code. ``--imports`` also copies code cells that differ only in their
import statements (a module moved; an import prints nothing, so the outputs still belong to the code). Usage:

    .venv/bin/python tools/nb_sync_markdown.py 11 14      # notebooks whose name starts with 11 or 14
    .venv/bin/python tools/nb_sync_markdown.py --imports 03   # also import-only code changes
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

import nbformat

sys.path.insert(0, str(Path(__file__).resolve().parent))
from nb_build import OUT, SRC, parse_percent  # noqa: E402


def _without_imports(code: str) -> list[str]:
    """The lines of ``code`` that are not part of an import statement (None if it does not parse)."""
    python = "\n".join("#" + line if line.lstrip().startswith(("%", "!")) else line for line in code.splitlines())
    try:
        tree = ast.parse(python)  # IPython magics (%, !) read as comments
    except SyntaxError:
        return None
    drop = {n for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))
            for n in range(node.lineno, node.end_lineno + 1)}
    return [line for i, line in enumerate(code.splitlines(), 1) if i not in drop]


def sync(src: Path, imports: bool = False) -> int:
    """-> the number of cells changed; raises ValueError if code (beyond imports, with ``imports``) or structure
    differ."""
    fresh = parse_percent(src.read_text())
    path = OUT / (src.stem + ".ipynb")
    built = nbformat.read(path, as_version=4)
    kinds = ([c.cell_type for c in fresh.cells], [c.cell_type for c in built.cells])
    if kinds[0] != kinds[1]:
        raise ValueError(f"{path.name}: cells differ from {src.name} in number or kind; rebuild with nb_build.py")
    changed = 0
    for new, old in zip(fresh.cells, built.cells):
        if new.cell_type == "code" and new.source != old.source:
            rest = _without_imports(new.source)
            if not (imports and rest is not None and rest == _without_imports(old.source)):
                raise ValueError(f"{path.name}: a code cell differs from {src.name}; rebuild with nb_build.py")
            old.source = new.source
            changed += 1
        if new.cell_type == "markdown" and new.source != old.source:
            old.source = new.source
            changed += 1
    if changed:
        nbformat.write(built, path)
    return changed


if __name__ == "__main__":
    imports = "--imports" in sys.argv[1:]
    prefixes = [a for a in sys.argv[1:] if a != "--imports"]
    if not prefixes:
        sys.exit("usage: nb_sync_markdown.py [--imports] NN [NN ...]")
    for src in sorted(SRC.glob("*.py")):
        if any(src.stem.startswith(p) for p in prefixes):
            print(f"{src.stem}: {sync(src, imports)} cell(s) updated")
