"""What a reader sees in JupyterLab: no figure so wide that it is shrunk until its labels cannot be read, and no
results table with more columns than the page holds (checked on the committed notebooks' outputs).

JupyterLab shows an image at its natural width up to the width of the output area (about 1000-1300 px on a laptop
screen) and shrinks a wider one; a 16 x 4 in figure at 100 dpi came out at 60 % with 6-point labels. Markdown
tables wrap their cells but never drop a column, so 17 columns of "12.10 ± 0.58" ran off the page."""
import base64
import io
import json
import re
from pathlib import Path

import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("[0-9][0-9]*_*.ipynb"))
MAX_WIDTH_PX = 1320      # 13 in at the inline backend's 100 dpi (+ the bbox margin)
MAX_TABLE_COLUMNS = 12


def outputs(nb: Path):
    for k, cell in enumerate(json.loads(nb.read_text())["cells"]):
        for out in cell.get("outputs", []):
            yield k, out.get("data", {})


def table_columns(markdown: str) -> list[int]:
    """Column counts of the Markdown tables in a text (from their header separator rows)."""
    return [line.count("|") - 1 for line in markdown.splitlines() if re.fullmatch(r"\|(\s*:?-+:?\s*\|)+", line.strip())]


def test_table_columns_are_counted():
    assert table_columns("| a | b |\n|---|---|\n| 1 | 2 |\n\n| x |\n|:-:|\n") == [2, 1]


@pytest.mark.parametrize("nb", NOTEBOOKS, ids=lambda p: p.stem.split("_")[0])
def test_figures_and_tables_fit_the_page(nb):
    wide, tables = [], []
    for k, data in outputs(nb):
        if "image/png" in data:
            width = Image.open(io.BytesIO(base64.b64decode(data["image/png"]))).size[0]
            if width > MAX_WIDTH_PX:
                wide.append((k, width))
        if "text/markdown" in data:
            text = "".join(data["text/markdown"])
            tables += [(k, n) for n in table_columns(text) if n > MAX_TABLE_COLUMNS]
    assert wide == [], f"{nb.name}: figures wider than {MAX_WIDTH_PX} px (cell, px): {wide}; use figsize <= 12 in"
    assert tables == [], (f"{nb.name}: tables with more than {MAX_TABLE_COLUMNS} columns (cell, columns): {tables}; "
                          f"show the metrics the text discusses: table_markdown(..., metrics=[...])")


def test_the_overview_map_lists_every_notebook():
    """Notebook 00's map names every notebook of the series (02a and CorrTalk's and EmoFace's 10-15 included) and
    nothing that is not one."""
    cells = json.loads((ROOT / "notebooks" / "00_overview.ipynb").read_text())["cells"]
    section = next("".join(c["source"]) for c in cells
                   if c["cell_type"] == "markdown" and "".join(c["source"]).startswith("## 4. The map of this series"))
    mapped = re.findall(r"^\| \*\*(\d\d[a-z]?)\*\* ", section, re.MULTILINE)
    assert mapped == [nb.name.split("_", 1)[0] for nb in NOTEBOOKS]


def test_notebook_08_warns_about_8_khz_audio_in_words_for_its_viseme_model():
    """Its model reads the recogniser's viseme track: the telephone-band warning speaks of the recogniser, not of
    log-mel models (it did, under the model that reads visemes)."""
    texts = ["".join(out.get("text", "")) for cell in json.loads((ROOT / "notebooks" / "08_training_dualtalker.ipynb")
                                                             .read_text())["cells"] for out in cell.get("outputs", [])]
    warnings = [line for text in texts for line in text.splitlines() if "sampled at 8000 Hz" in line]
    assert len(warnings) == 2 and all("phoneme recogniser copes with telephone-band speech" in w for w in warnings)
    assert not any("log-mel models" in w for w in warnings)
