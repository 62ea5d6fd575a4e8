"""Stamp each run of the stored results tables with the commit it was computed at, read from git history.

    python tools/stamp_run_commits.py            # writes the stamps into results/**/*.json (runs without one only)
    python tools/stamp_run_commits.py --check    # print what it would stamp, write nothing

Tables written before issue 30 record one commit per file (``git``), yet a table made with ``--reuse`` holds runs
computed by earlier invocations at other commits, some from dirty trees. The experiment runner now stamps every run
(``run["git"]``) and re-computes, under ``--reuse``, every run that is not from a clean commit; this tool gives the
stored runs the same stamp so that a clean re-run recomputes only the runs that need it.

How a run's commit is found: the oldest committed version of any results JSON in the same folder that holds the
identical run (same key, seed and metrics) was written by the invocation that computed it, so its ``git`` is the
run's commit. One exception: when that version itself reused runs from a file that was never committed (e.g.
``runs/emo_rerun/keep.json``), the run may have come from there and its commit is "unknown". Runs that already carry
a ``git`` are left alone. Each file stamped records this command in ``run_commits_stamped_by``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from dualtalker_lite.provenance import provenance  # noqa: E402


def git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True, check=True).stdout


def run_id(folder: str, run: dict) -> tuple:
    return folder, run["key"], run["seed"], json.dumps(run.get("metrics"), sort_keys=True)


def tables(payload: object) -> bool:
    return isinstance(payload, dict) and isinstance(payload.get("runs"), list) and all(
        isinstance(r, dict) and "key" in r and "seed" in r for r in payload["runs"])


def first_seen() -> dict:
    """{run id: the stamp of the oldest committed table that holds it}."""
    seen: dict = {}
    for line in git("log", "--reverse", "--format=%H", "--", "results").split():
        names = git("show", "--name-only", "--format=", line).split()
        committed = set(git("ls-tree", "-r", "--name-only", line, "--", "results").split())
        for name in (n for n in names if n.startswith("results/") and n.endswith(".json") and n in committed):
            payload = json.loads(git("show", f"{line}:{name}"))
            if not tables(payload):
                continue
            folder = str(Path(name).parent)
            sources = [str(Path(folder) / s.get("table", "")) for s in payload.get("reused_from", [])]
            stamp = payload.get("git") or "unknown"
            if any(s not in committed for s in sources):  # reused from a file that was never committed
                stamp = "unknown"
            for run in payload["runs"]:
                seen.setdefault(run_id(folder, run), stamp)
    return seen


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--check", action="store_true", help="print the stamps, write nothing")
    args = ap.parse_args(argv)
    seen = first_seen()
    stamp = provenance("python tools/stamp_run_commits.py")
    for path in sorted((ROOT / "results").rglob("*.json")):
        payload = json.loads(path.read_text())
        if not tables(payload):
            continue
        folder = str(path.parent.relative_to(ROOT))
        counts: dict = {}
        for run in payload["runs"]:
            if "git" not in run:
                run["git"] = seen.get(run_id(folder, run), "unknown")
                counts[run["git"]] = counts.get(run["git"], 0) + 1
        if not counts:
            continue
        print(f"{path.relative_to(ROOT)}: " + ", ".join(f"{n} run(s) at {c}" for c, n in sorted(counts.items())))
        if not args.check:
            payload["run_commits_stamped_by"] = {k: stamp[k] for k in ("command", "commit", "created")}
            tmp = path.with_suffix(".tmp")
            tmp.write_text(json.dumps(payload, indent=1, ensure_ascii=False) + "\n")
            os.replace(tmp, path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
