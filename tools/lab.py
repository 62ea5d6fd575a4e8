"""`make lab`'s working copies: JupyterLab opens runs/notebooks/, never the tracked notebooks/ (issue 49).

JupyterLab saves the notebook it runs (autosave every two minutes, outputs and kernel metadata included), so running
notebooks/NN_*.ipynb in place rewrote tracked files. `make lab` first runs this script, which copies every tracked
notebook to runs/notebooks/ (gitignored, like all of runs/) and links runs/notebooks/data to notebooks/data (the
notebooks read data/... relative to where they run); JupyterLab then opens runs/notebooks/. Nothing here ever writes
under notebooks/.

A copy is (re)made when it is missing, or when the tracked notebook changed (a `git pull`, a rebuild) and the copy is
still as this script made it; a copy you changed is kept, with one line saying the tracked notebook is newer (delete
the copy to get it). runs/notebooks/.copies.json records, per notebook, the hashes of the tracked file and of the copy
when it was made. Usage: python tools/lab.py [--out runs/notebooks]
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECORD = ".copies.json"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def working_copies(src: Path, out: Path) -> dict[str, str]:
    """Copy ``src``'s notebooks to ``out`` by the rules above and link ``out/data`` to ``src/data`` -> {notebook name:
    "copied" | "refreshed" | "kept" | "yours, tracked one newer"}; only ``out`` is written."""
    out.mkdir(parents=True, exist_ok=True)
    record_path = out / RECORD
    record = json.loads(record_path.read_text()) if record_path.is_file() else {}
    done = {}
    for nb in sorted(src.glob("*.ipynb")):
        copy, tracked = out / nb.name, _sha(nb)
        seen = record.get(nb.name)
        if not copy.exists():
            state = "copied"
        elif seen is None or seen["tracked"] == tracked:
            state = "kept"
        elif _sha(copy) == seen["copy"]:
            state = "refreshed"
        else:
            state = "yours, tracked one newer"
            print(f"note: {copy}: you changed it and {nb} changed since; kept yours (delete it to get the new one)")
        if state in ("copied", "refreshed"):
            shutil.copyfile(nb, copy)
            record[nb.name] = {"tracked": tracked, "copy": _sha(copy)}
        done[nb.name] = state
    link = out / "data"
    if not link.exists() and (src / "data").is_dir():
        link.symlink_to(os.path.relpath(src / "data", out))
    record_path.write_text(json.dumps(record, indent=1) + "\n")
    return done


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python tools/lab.py", description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "runs" / "notebooks", help="where the working copies go")
    args = ap.parse_args(argv)
    done = working_copies(ROOT / "notebooks", args.out)
    made = sum(state in ("copied", "refreshed") for state in done.values())
    print(f"JupyterLab opens {args.out}: working copies of the {len(done)} notebooks ({made} copied now); running "
          f"them never changes notebooks/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
