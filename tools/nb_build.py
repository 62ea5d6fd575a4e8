"""Build the notebooks from their percent-format sources, execute them, and strip noise.

Sources live in ``notebooks/src/NN_name.py`` ("# %%" starts a code cell, "# %% [markdown]" a markdown cell
whose lines are comments). This script writes ``notebooks/NN_name.ipynb``, executes it top to bottom with
a fresh kernel (cwd = notebooks/), prints each notebook's run time, and removes execution metadata
(timestamps, kernel session ids) so diffs show only real changes. Usage:

    python tools/nb_build.py                 # all notebooks
    python tools/nb_build.py 03 07           # only those whose name starts with 03 or 07
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parents[1]
# What JupyterLab stores for the default ipykernel: with anything else, opening a notebook marks it modified.
KERNELSPEC = {"display_name": "Python 3 (ipykernel)", "language": "python", "name": "python3"}
SRC, OUT = ROOT / "notebooks" / "src", ROOT / "notebooks"


def parse_percent(text: str) -> nbformat.NotebookNode:
    nb = nbformat.v4.new_notebook()
    cells: list[tuple[str, list[str]]] = []
    for line in text.splitlines():
        if line.startswith("# %%"):
            kind = "markdown" if "[markdown]" in line else "code"
            cells.append((kind, []))
        elif cells:
            cells[-1][1].append(line)
    for kind, lines in cells:
        while lines and not lines[-1].strip():
            lines.pop()
        while lines and not lines[0].strip():
            lines.pop(0)
        if kind == "markdown":
            body = "\n".join(ln[2:] if ln.startswith("# ") else ln.lstrip("#") for ln in lines)
            nb.cells.append(nbformat.v4.new_markdown_cell(body))
        else:
            nb.cells.append(nbformat.v4.new_code_cell("\n".join(lines)))
    nb.metadata = {"kernelspec": dict(KERNELSPEC), "language_info": {"name": "python"}}
    return nb


def _merge_streams(outputs: list) -> list:
    """Join consecutive stdout/stderr pieces: how a print is split into messages varies between runs."""
    merged: list = []
    for o in outputs:
        if o.get("output_type") == "stream" and merged and merged[-1].get("output_type") == "stream" \
                and merged[-1]["name"] == o["name"]:
            merged[-1]["text"] += o["text"]
        else:
            merged.append(o)
    return merged


def strip(nb: nbformat.NotebookNode) -> None:
    """Drop timestamps and session noise; number code cells 1, 2, ... (nbval needs counts on cells with outputs)."""
    n = 0
    for i, cell in enumerate(nb.cells):
        cell.metadata = {k: v for k, v in cell.metadata.items() if k in ("tags",)}
        cell["id"] = f"c{i:02d}"
        if cell.cell_type == "code":
            n += 1
            cell.execution_count = n
            cell.outputs = _merge_streams(cell.outputs)
            for o in cell.outputs:
                if "execution_count" in o:
                    o["execution_count"] = n
                o.get("metadata", {}).pop("execution", None)
    nb.metadata.pop("widgets", None)
    nb.metadata["kernelspec"] = dict(KERNELSPEC)  # whatever the executing kernel reported


def build(src: Path) -> float:
    nb = parse_percent(src.read_text())
    t0 = time.perf_counter()
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(OUT)}}).execute()
    seconds = time.perf_counter() - t0
    strip(nb)
    nbformat.write(nb, OUT / (src.stem + ".ipynb"))
    return seconds


if __name__ == "__main__":
    prefixes = sys.argv[1:]
    for src in sorted(SRC.glob("*.py")):
        if prefixes and not any(src.stem.startswith(p) for p in prefixes):
            continue
        print(f"{src.stem}: {build(src):.1f} s", flush=True)
