"""Provenance of a results file (issue 30): the command that made it, the commit it was made from ("+dirty" when
tracked files had uncommitted changes) and the machine (CPU model, cores, Python and torch versions).

One home for the stamp: the experiment runner (``experiments.command``, its pages through ``experiments.report``)
and every ``benchmarks/*.py`` that writes into ``results/`` call :func:`provenance`; ``tests/test_provenance.py``
refuses a results file whose stamp names a dirty tree, lacks a command or commit, or names a run file not in the
repository. A foundation module without torch: a benchmark that measures its own process's memory may import it.
"""
from __future__ import annotations

import datetime as _dt
import os
import platform
import re
import subprocess
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent  # the checkout (files.repo_root, without importing torch)


def _git() -> str:
    """The commit of the working tree, short, with "+dirty" when tracked files have uncommitted changes (a results
    file stamped "+dirty" cannot be re-made from its commit: ``tests/test_provenance.py`` refuses it)."""
    try:
        run = lambda *a: subprocess.run(["git", "-C", str(ROOT), *a], capture_output=True,  # noqa: E731
                                        text=True, timeout=10).stdout.strip()
        head = run("rev-parse", "--short", "HEAD")
        return f"{head}{'+dirty' if run('status', '--porcelain', '--untracked-files=no') else ''}" or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _cpu_model() -> str:
    """The CPU's model name (Linux: /proc/cpuinfo; elsewhere what :mod:`platform` knows)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def machine() -> dict:
    """The machine a results file was made on: CPU model, logical cores, Python and torch versions."""
    return {"cpu": _cpu_model(), "cores": os.cpu_count(), "python": platform.python_version(),
            "torch": _version("torch")}


def _version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "not installed"


def machine_line(info: dict) -> str:
    """:func:`machine`'s record as one line of a results page: 'Intel Xeon ..., 16 logical CPUs; Python 3.12.3,
    torch 2.5.1'."""
    return (f"{info.get('cpu', '?')}, {info.get('cores', '?')} logical CPUs; Python {info.get('python', '?')}, "
            f"torch {info.get('torch', '?')}")


def provenance(command: str) -> dict:
    """What every results file records (issue 30): the command that made it, the commit (:func:`_git`, "+dirty"
    with uncommitted changes), the machine (:func:`machine`) and the time. The runner, ``benchmarks/*.py`` writers
    and their pages all take it from here."""
    return {"command": command, "commit": _git(), "machine": machine(),
            "created": _dt.datetime.now().isoformat(timespec="seconds")}


def is_clean_commit(commit: object) -> bool:
    """True for a commit stamp a results file may carry: a hexadecimal id with no dirty mark."""
    return isinstance(commit, str) and re.fullmatch(r"[0-9a-f]{7,40}", commit) is not None
