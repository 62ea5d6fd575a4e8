"""Install torch (the Makefile's pinned version) into this interpreter's environment, the CPU build where possible.

    .venv/bin/python tools/install_torch.py            # what `make env` (and so every make target) runs first

The project runs on the CPU, but on Linux x86-64 PyPI only has the CUDA build of torch: 2.7 GB in 29 files (torch
527 MB plus the nvidia-* CUDA libraries, which `import torch` loads even on a CPU; measured for 2.13.0 with
`pip install --dry-run --report`), against 192 MB for the CPU build. So, in order:

1. torch of the pinned version already installed -> nothing to do;
2. ``TORCH_INDEX`` set (a mirror of the CPU wheel index, or any index) -> install from there;
3. pip's own configuration (``--find-links`` folders, extra indexes) already offers the CPU build -> install it;
4. the CPU wheel index https://download.pytorch.org/whl/cpu answers within 10 s -> install from there;
5. otherwise say so, with the size, and install pip's default build (on a PyPI-only machine: the CUDA one,
   which works on the CPU too; about 4 minutes at 100 Mbit/s). ``TORCH_CPU_ONLY=1`` stops here instead.

numpy is installed just before torch (from pip's own configuration), so that torch finds it the first time it is
imported: torch imported without numpy warns ``Failed to initialize NumPy``.

Exit status: 0 when torch is installed, 2 when it is not (a message says why), pip's status if pip fails.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import urllib.request
from importlib import metadata

VERSION = "2.13.0"
CPU_INDEX = "https://download.pytorch.org/whl/cpu"
NUMPY = "numpy>=1.26"  # pyproject.toml's range: installed before torch, which looks for it when first imported
PYPI_CUDA_GB, CPU_MB = 2.7, 192  # measured for 2.13.0, Linux x86-64, CPython 3.11


def installed_version() -> str | None:
    try:
        return metadata.version("torch")
    except metadata.PackageNotFoundError:
        return None


def reachable(url: str, timeout: float = 10.0) -> bool:
    try:
        with urllib.request.urlopen(url.rstrip("/") + "/torch/", timeout=timeout) as r:
            return r.status == 200
    except Exception:  # DNS failure, refused, timeout, proxy error: all mean "not from here"
        return False


def configured_candidate(pip: list[str]) -> str | None:
    """The torch version pip's own configuration would install (e.g. ``2.13.0+cpu`` from a find-links folder),
    resolved without downloading any wheel; None if pip cannot resolve it."""
    with tempfile.TemporaryDirectory() as tmp:
        report = os.path.join(tmp, "report.json")
        proc = subprocess.run([*pip, "install", "--quiet", "--dry-run", "--ignore-installed", "--no-deps",
                               "--report", report, f"torch=={VERSION}"], capture_output=True, text=True)
        if proc.returncode != 0 or not os.path.exists(report):
            return None
        with open(report) as f:
            items = json.load(f).get("install", [])
    versions = [i["metadata"]["version"] for i in items if i["metadata"]["name"].lower() == "torch"]
    return versions[0] if versions else None


def plan(installed: str | None, torch_index: str | None, candidate, cpu_reachable, cpu_only: bool = False
         ) -> tuple[list[str] | None, str]:
    """-> (extra pip arguments, or None for "install nothing", and the message to print). ``candidate`` and
    ``cpu_reachable`` are callables, so the probes run only when the step before did not decide."""
    if installed is not None and installed.split("+")[0] == VERSION:
        return None, f"torch {installed} already installed"
    if torch_index:
        return ["--index-url", torch_index], f"installing torch {VERSION} from TORCH_INDEX={torch_index}"
    found = candidate()
    if found is not None and found.endswith("+cpu"):
        return [], f"installing torch {found} (the CPU build, offered by pip's configuration)"
    if cpu_reachable():
        return ["--index-url", CPU_INDEX], f"installing torch {VERSION} from {CPU_INDEX} (CPU build, ~{CPU_MB} MB)"
    note = (f"{CPU_INDEX} is not reachable from here and pip's configuration offers no CPU build of torch "
            f"{VERSION}; ")
    if cpu_only:
        return None, note + ("TORCH_CPU_ONLY=1: not installing. Put the CPU wheel in a pip --find-links folder or "
                             "set TORCH_INDEX to a mirror of the CPU index, then run make again")
    return [], note + (f"installing pip's default build instead (from PyPI on Linux x86-64: the CUDA build, "
                       f"~{PYPI_CUDA_GB} GB with the nvidia-* libraries, about 4 minutes at 100 Mbit/s; it runs on "
                       f"the CPU too). To avoid the download: TORCH_INDEX=<CPU index mirror> or TORCH_CPU_ONLY=1")


def main() -> int:
    pip = [sys.executable, "-m", "pip"]
    extra, message = plan(installed_version(), os.environ.get("TORCH_INDEX"), lambda: configured_candidate(pip),
                          lambda: reachable(CPU_INDEX), os.environ.get("TORCH_CPU_ONLY") == "1")
    print(f"install_torch: {message}", file=sys.stderr if extra is None and "not installing" in message
          else sys.stdout, flush=True)
    if extra is None:
        return 2 if "not installing" in message else 0
    status = subprocess.call([*pip, "install", "--quiet", NUMPY])  # before torch (not from a torch-only index)
    if status == 0:
        status = subprocess.call([*pip, "install", "--quiet", *extra, f"torch=={VERSION}"])
    if status == 0:
        import importlib

        torch = importlib.import_module("torch")
        build = "CPU build" if torch.version.cuda is None else f"CUDA {torch.version.cuda} build"
        print(f"install_torch: torch {torch.__version__} installed ({build})", flush=True)
    return status


if __name__ == "__main__":
    sys.exit(main())
