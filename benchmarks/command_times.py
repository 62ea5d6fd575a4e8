"""How long the commands take whose times the README and ``--help`` state: each run as a real process.

    .venv/bin/python benchmarks/command_times.py                    # the quick ones (about four minutes)
    .venv/bin/python benchmarks/command_times.py --only make-unit   # one (or several: --only a --only b)
    .venv/bin/python benchmarks/command_times.py --all              # every one (about an hour on 2 cores)
    .venv/bin/python benchmarks/command_times.py --list             # the names, commands and where each is quoted
    .venv/bin/python benchmarks/command_times.py --note "make-unit=..."  # what a row's numbers cannot say

Each command runs from the repository root as its own process (``subprocess.run``, stdout and stderr into
``runs/command_times/<name>.log``, outputs under ``runs/command_times/``) and gets one row:

- **wall seconds**: ``time.monotonic`` around the process;
- **CPU seconds**: user + system time of the process and all its children (the ``resource.getrusage
  (RUSAGE_CHILDREN)`` difference around it: every process it started and waited for, pytest's workers and
  ffmpeg included), i.e. what the work costs whatever the number of cores;
- the machine: cores (``os.cpu_count``), the 1-minute load average just before it started (above ~1.5 on 2 cores,
  another job was competing and the wall time is too long: measure again when the machine is quiet) and its
  highest value while the command ran, sampled every ~5 s (the command's own busy threads count there too: one
  single-threaded command on a quiet machine approaches 1, ``make unit`` with its two OpenMP threads up to 2;
  much more means company),
  ``OMP_NUM_THREADS`` as the command saw it, the commit (``+dirty`` with uncommitted changes) and the date;
- ``busy_processes``: how many CPU-bound processes (``while True: pass``) ran beside it on purpose (``make-test-busy``:
  one, the "busy machine" case of CI's time limit); their CPU time is not counted.

Rows are kept in ``results/command_times.json`` by name (written when the run ends; ``runs/command_times/
rows_so_far.json`` after each command), so ``--only`` replaces those rows and keeps the others
(each row carries its own machine, load and commit); ``results/command_times.md`` is rewritten from the JSON each
time, with each time as the README and ``--help`` quote it: "about 12 min wall on 2 cores (8 CPU min)".

The ``make`` targets use the virtual environment of the interpreter running this script: when that is not the
checkout's ``.venv`` (a git worktree, another environment), ``make`` is told ``VENV=<it>`` and not to reinstall
(``-o <it>/.installed``). The heavy commands (``heavy`` in ``COMMANDS``: longer than ~3 minutes) run only with
``--all`` or ``--only``.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import resource
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from dualtalker_lite.provenance import provenance  # noqa: E402  (no torch: this parent stays small)
from dualtalker_lite.files import atomic_write_text  # noqa: E402
OUT = ROOT / "runs" / "command_times"
RESULTS = ROOT / "results" / "command_times"
CLI = str(Path(sys.executable).with_name("dualtalker-lite"))


@dataclass(frozen=True)
class Command:
    name: str
    argv: tuple[str, ...]   # "{cli}" is the console script next to this interpreter, "{out}" runs/command_times
    quoted: str             # where the README / --help states its time
    heavy: bool = False     # over ~3 minutes: only with --all or --only
    needs: str | None = None  # a command whose output this one reads (run first when that output is missing)
    makes: str | None = None  # the file this command writes, relative to {out}
    busy: int = 0           # CPU-bound processes (a Python busy loop each) running beside it the whole time


COMMANDS = (
    Command("train-check", ("{cli}", "train", "--model", "voca", "--epochs", "1", "--clips", "16", "--out",
                            "{out}/check.pt", "--overwrite"),
            "README (`train --clips 16 --epochs 1` checks the whole path); train --help example", makes="check.pt"),
    Command("evaluate-check", ("{cli}", "evaluate", "--checkpoint", "{out}/check.pt", "--split", "test_a"),
            "(no time quoted: for scale)", needs="train-check"),
    Command("animate-real-voice", ("{cli}", "animate", "--checkpoint", "{out}/check.pt", "--wav",
                                   "notebooks/data/real/agent-pass.flac", "--speaker", "SPK01", "--out",
                                   "{out}/animation", "--overwrite", "--format", "npy,gltf,html,mp4"),
            "(no time quoted: for scale; the README's animate example, on the quick checkpoint)",
            needs="train-check"),
    Command("train-default", ("{cli}", "train", "--model", "dualtalker", "--out", "{out}/my_model_fast.pt",
                              "--overwrite"),
            "README command block (`train --model dualtalker`: the short recipe, \"about a minute on 2 cores\")",
            makes="my_model_fast.pt"),
    Command("train-faceformer-default", ("{cli}", "train", "--model", "faceformer", "--out",
                                         "{out}/my_faceformer_fast.pt", "--overwrite"),
            "docs/cli.md (the short recipe's FaceFormer-style 60 epochs)", makes="my_faceformer_fast.pt"),
    Command("train-100", ("{cli}", "train", "--model", "dualtalker", "--recipe", "tiny", "--epochs", "100", "--out",
                          "{out}/my_model.pt", "--overwrite"),   # tiny: what it meant before train's default changed
            "README (phonetic route paragraph: the 100-epoch figure)", heavy=True, makes="my_model.pt"),
    Command("train-emoface-12", ("{cli}", "train", "--model", "emoface", "--epochs", "12", "--out",
                                 "{out}/my_emoface.pt", "--overwrite"),
            "README command block; train --help example", heavy=True, makes="my_emoface.pt"),
    Command("make-unit", ("make", "unit"), "README Quick start (`make unit`)", heavy=True),
    Command("make-bench", ("make", "bench"),
            "benchmarks/run_all.py docstring (\"about 12 minutes ... on a busy 2-core machine\")", heavy=True),
    Command("make-test", ("make", "test"), "README Quick start (`make test`, what CI runs)", heavy=True),
    Command("make-test-busy", ("make", "test"), "README Quick start (`make test` beside one CPU-bound process)",
            heavy=True, busy=1),
)
BY_NAME = {c.name: c for c in COMMANDS}


def make_prefix() -> list[str]:
    """``make`` with the environment of this interpreter, never reinstalling it (see the module docstring)."""
    venv = Path(sys.executable).parent.parent
    if venv.resolve() == (ROOT / ".venv").resolve():
        return ["make"]
    return ["make", f"VENV={venv}", "-o", f"{venv}/.installed"]


def command_line(cmd: Command) -> list[str]:
    argv = [a.format(cli=CLI, out=OUT.relative_to(ROOT)) for a in cmd.argv]
    return make_prefix() + argv[1:] if argv[0] == "make" else argv


def shown(cmd: Command) -> str:
    """The command as a reader would type it (``dualtalker-lite ...``, ``make ...``)."""
    return " ".join(shlex.quote(a.format(cli="dualtalker-lite", out="runs/command_times")) for a in cmd.argv)


def _omp_default(cmd: Command) -> str:
    """OMP_NUM_THREADS as the command sees it when this process has none: the Makefile's."""
    if cmd.argv[0] != "make":
        return "unset"
    return f"unset (make {cmd.argv[1]}: 1 per worker)" if cmd.argv[1] in ("test", "unit", "nbval") else "unset (make: 2)"


def measure(cmd: Command) -> dict:
    """Run ``cmd`` once as a process -> its row (wall and CPU seconds, status, machine, commit)."""
    OUT.mkdir(parents=True, exist_ok=True)
    argv = command_line(cmd)
    load, stamp = os.getloadavg()[0], provenance(shown(cmd))  # the code measured: as it was at the start
    print(f"== {cmd.name}: {shlex.join(argv)} (load {load:.2f})", flush=True)
    # the company (``busy``): started first, killed and reaped after the command, outside its CPU figure
    company = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(cmd.busy)]
    try:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.monotonic()
        with open(OUT / f"{cmd.name}.log", "w") as log:
            proc = subprocess.Popen(argv, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
            peak_load = load
            while proc.poll() is None:  # the 1-minute load every ~5 s: its highest includes the command's threads
                peak_load = max(peak_load, os.getloadavg()[0])
                try:
                    proc.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    pass
        wall = time.monotonic() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    finally:
        for p in company:
            p.kill()
            p.wait()
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    lines = (OUT / f"{cmd.name}.log").read_text(errors="replace").strip().splitlines()
    row = {"name": cmd.name, "command": shown(cmd), "quoted": cmd.quoted, "status": proc.returncode,
           "wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "cores": os.cpu_count(),
           "load_1min_at_start": round(load, 2), "load_1min_max": round(peak_load, 2),
           "omp_num_threads": os.environ.get("OMP_NUM_THREADS", _omp_default(cmd)),
           "commit": stamp["commit"], "machine": stamp["machine"],
           "date_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M"),
           "python": platform.python_version(), "last_line": lines[-1][:300] if lines else "",
           "busy_processes": cmd.busy}
    print(f"   {about(row)}, status {proc.returncode}; last line: {row['last_line']}", flush=True)
    return row


def _amount(seconds: float, unit_s: str, unit_min: str) -> str:
    if seconds < 90:
        return f"{seconds:.0f} {unit_s}"
    minutes = seconds / 60
    return f"{minutes:.0f} {unit_min}" if minutes >= 10 else f"{minutes:.1f} {unit_min}".replace(".0 ", " ")


def about(row: dict) -> str:
    """A row as the README quotes it: ``about 12 min wall on 2 cores (8 CPU min)``, seconds below 90 s."""
    return (f"about {_amount(row['wall_s'], 's', 'min')} wall on {row['cores']} cores "
            f"({_amount(row['cpu_s'], 'CPU s', 'CPU min')})")


def _load(row: dict, key: str) -> str:
    return f"{row[key]:.2f}" if isinstance(row.get(key), (int, float)) else "not recorded"


def _busy(row: dict) -> str:
    n = row.get("busy_processes", 0)
    return f" ({n} busy process{'es' if n > 1 else ''} beside it, on purpose)" if n else ""


def write(rows: dict) -> None:
    ordered = [rows[c.name] for c in COMMANDS if c.name in rows]
    RESULTS.with_suffix(".tmp").write_text(json.dumps(ordered, indent=1) + "\n")
    os.replace(RESULTS.with_suffix(".tmp"), RESULTS.with_suffix(".json"))  # atomic: the whole file or the old one
    lines = ["# Command times", "",
             "Written by `benchmarks/command_times.py` (each command a real process from the repository root; CPU = "
             "user + system time of the process and its children). A load above ~1.5 at the start on 2 cores means "
             "another job competed: the wall time is then too long; the highest load while it ran counts its own "
             "threads too.", "",
             "| name | command | as quoted | wall s | CPU s | status | cores | load at start / highest "
             "| OMP_NUM_THREADS | commit | date (UTC) | quoted in |",
             "|---|---|---|---:|---:|---:|---:|---:|---|---|---|---|"]
    for r in ordered:
        m = r.get("machine")  # rows measured before issue 30 name only the cores
        cores = f"{r['cores']} ({m['cpu']}; Python {m['python']}, torch {m['torch']})" if m else r["cores"]
        lines.append(f"| {r['name']} | `{r['command']}` | {about(r)} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | "
                     f"{r['status']} | {cores} | {r['load_1min_at_start']:.2f} / {_load(r, 'load_1min_max')}{_busy(r)} | "
                     f"{r['omp_num_threads']} | "
                     f"{r['commit']} | {r['date_utc']} | {r['quoted']} |")
    notes = [r for r in ordered if r.get("note")]
    if notes:
        lines += ["", "Notes:", ""] + [f"- `{r['name']}`: {r['note']}" for r in notes]
    missing = [c for c in COMMANDS if c.name not in rows]
    if missing:
        lines += ["", "Not measured yet: " + ", ".join(f"`{c.name}` (`{shown(c)}`)" for c in missing) + "."]
    RESULTS.with_suffix(".tmp").write_text("\n".join(lines) + "\n")
    os.replace(RESULTS.with_suffix(".tmp"), RESULTS.with_suffix(".md"))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter,
                                 epilog="names: " + ", ".join(f"{c.name}{' (heavy)' if c.heavy else ''}"
                                                              for c in COMMANDS))
    ap.add_argument("--only", action="append", choices=list(BY_NAME), help="run only this one (repeatable)")
    ap.add_argument("--all", action="store_true", help="run every command, the heavy ones included")
    ap.add_argument("--list", action="store_true", help="print the commands and exit")
    ap.add_argument("--note", action="append", default=[], metavar="NAME=TEXT",
                    help="attach a note to a measured row (what the numbers cannot say: failures, company), "
                         "without running anything")
    args = ap.parse_args(argv)
    if args.list:
        for c in COMMANDS:
            print(f"{c.name:20s} {'heavy' if c.heavy else 'quick':5s} {shown(c)}\n{'':26s} quoted: {c.quoted}")
        return
    if args.note:
        path = RESULTS.with_suffix(".json")
        rows = {r["name"]: r for r in json.loads(path.read_text())} if path.is_file() else {}
        for item in args.note:
            name, _, text = item.partition("=")
            if name not in rows:
                sys.exit(f"--note {item!r}: no measured row {name!r} in {path}")
            rows[name]["note"] = text
        write(rows)
        return
    chosen = [BY_NAME[n] for n in args.only] if args.only else [c for c in COMMANDS if args.all or not c.heavy]
    path = RESULTS.with_suffix(".json")
    rows = {r["name"]: r for r in json.loads(path.read_text())} if path.is_file() else {}
    done: set[str] = set()
    for cmd in chosen:
        need = BY_NAME[cmd.needs] if cmd.needs else None
        if need and need.name not in done and not (OUT / need.makes).is_file():
            rows[need.name] = measure(need)
            done.add(need.name)
        if cmd.name in done:
            continue
        rows[cmd.name] = measure(cmd)
        done.add(cmd.name)
        # after each, into runs/ (a long --all run keeps what it measured if stopped); results/ only at the end:
        # writing it earlier would mark the tree dirty for the next rows' stamps (and fail make unit's provenance test)
        atomic_write_text(OUT / "rows_so_far.json", json.dumps(rows, indent=1) + "\n")
    write(rows)
    failed = [n for n in done if rows[n]["status"] != 0]
    if failed:
        sys.exit(f"failed: {', '.join(failed)} (see {OUT.relative_to(ROOT)}/<name>.log)")


if __name__ == "__main__":
    main()
