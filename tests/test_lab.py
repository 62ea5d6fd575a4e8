"""`make lab` runs JupyterLab on working copies (tools/lab.py), so running a notebook never rewrites a tracked one:
JupyterLab's autosave rewrote notebooks/08_training_dualtalker.ipynb in a checkout (issue 49)."""
import importlib.util
import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("lab", ROOT / "tools" / "lab.py")
lab = importlib.util.module_from_spec(spec)
spec.loader.exec_module(lab)


def tracked_tree(tmp_path: Path) -> Path:
    src = tmp_path / "notebooks"
    (src / "data" / "real").mkdir(parents=True)
    (src / "data" / "real" / "a.json").write_text("{}")
    (src / "01_a.ipynb").write_text('{"cells": ["a"]}')
    (src / "02_b.ipynb").write_text('{"cells": ["b"]}')
    return src


def snapshot(folder: Path) -> dict:
    return {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.rglob("*")) if p.is_file()}


def test_make_lab_opens_the_working_copies_not_the_tracked_notebooks():
    recipe = re.search(r"^lab:.*\n((?:\t.*\n)+)", (ROOT / "Makefile").read_text(), re.M).group(1)
    assert "tools/lab.py --out runs/notebooks" in recipe and "jupyter lab $(LAB_FLAGS) runs/notebooks/" in recipe
    assert "notebooks/\n" not in recipe.replace("runs/notebooks/\n", "")
    assert "runs/" in (ROOT / ".gitignore").read_text().split()


def test_copies_are_made_refreshed_and_kept_and_the_tracked_files_never_written(tmp_path, capsys):
    src, out = tracked_tree(tmp_path), tmp_path / "runs" / "notebooks"
    before = snapshot(src)
    assert lab.working_copies(src, out) == {"01_a.ipynb": "copied", "02_b.ipynb": "copied"}
    assert (out / "01_a.ipynb").read_text() == '{"cells": ["a"]}'
    assert (out / "data").is_symlink() and (out / "data" / "real" / "a.json").read_text() == "{}"  # data/... resolves
    assert os.readlink(out / "data") == os.path.join("..", "..", "notebooks", "data")
    assert snapshot(src) == before
    # JupyterLab saves a run of 01 (outputs); 02 is left alone; then both tracked notebooks change (a git pull)
    (out / "01_a.ipynb").write_text('{"cells": ["a", "outputs"]}')
    (src / "01_a.ipynb").write_text('{"cells": ["a2"]}')
    (src / "02_b.ipynb").write_text('{"cells": ["b2"]}')
    before = snapshot(src)
    assert lab.working_copies(src, out) == {"01_a.ipynb": "yours, tracked one newer", "02_b.ipynb": "refreshed"}
    assert (out / "01_a.ipynb").read_text() == '{"cells": ["a", "outputs"]}'  # the user's run is kept
    assert (out / "02_b.ipynb").read_text() == '{"cells": ["b2"]}'
    assert f"note: {out / '01_a.ipynb'}: you changed it" in capsys.readouterr().out
    assert lab.working_copies(src, out) == {"01_a.ipynb": "yours, tracked one newer", "02_b.ipynb": "kept"}
    (out / "01_a.ipynb").unlink()  # deleting the copy brings the new tracked one
    assert lab.working_copies(src, out)["01_a.ipynb"] == "copied"
    assert snapshot(src) == before  # nothing under notebooks/ was written, not even its times
