"""tools/install_torch.py (run by `make env`): which torch build it installs where, and what it says about it."""
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import install_torch as it  # noqa: E402


def never():
    raise AssertionError("this probe must not run")


def test_an_installed_torch_of_the_pinned_version_is_kept():
    assert it.plan(f"{it.VERSION}+cpu", None, never, never) == (None, f"torch {it.VERSION}+cpu already installed")
    args, message = it.plan("2.2.0", None, lambda: f"{it.VERSION}+cpu", never)  # another version: replaced
    assert args == [] and "CPU build" in message


def test_torch_index_wins_without_probing():
    args, message = it.plan(None, "https://mirror.example/cpu", never, never)
    assert args == ["--index-url", "https://mirror.example/cpu"] and "TORCH_INDEX" in message


def test_cpu_index_when_reachable_and_the_configuration_has_no_cpu_build():
    args, message = it.plan(None, None, lambda: it.VERSION, lambda: True)
    assert args == ["--index-url", "https://download.pytorch.org/whl/cpu"] and "192 MB" in message


@pytest.mark.parametrize("candidate", [it.VERSION, None])
def test_pypi_only_machine_says_what_it_downloads(candidate):
    args, message = it.plan(None, None, lambda: candidate, lambda: False)
    assert args == [] and "not reachable" in message and "2.7 GB" in message and "CUDA" in message
    args, message = it.plan(None, None, lambda: candidate, lambda: False, cpu_only=True)
    assert args is None and "TORCH_CPU_ONLY=1: not installing" in message


def test_unreachable_url_is_refused_fast():
    assert it.reachable("http://127.0.0.1:9/whl/cpu", timeout=2) is False


def test_this_environment_is_kept_as_it_is():
    """The script on the project's own venv (torch already there): exit 0, nothing installed."""
    proc = subprocess.run([sys.executable, str(Path(it.__file__))], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and proc.stdout.startswith("install_torch: torch 2.13.0") and proc.stderr == ""


def test_numpy_is_installed_before_torch(monkeypatch, capsys):
    """torch imported without numpy warns 'Failed to initialize NumPy': main() installs numpy first, and only then
    torch (with the plan's index arguments, which must not apply to numpy)."""
    calls = []
    monkeypatch.setattr(it, "installed_version", lambda: None)
    monkeypatch.setattr(it, "plan", lambda *a: (["--index-url", "https://mirror.example/cpu"], "installing"))
    monkeypatch.setattr(it.subprocess, "call", lambda cmd: calls.append(cmd[3:]) or 1)  # fails: stops after numpy
    assert it.main() == 1 and calls == [["install", "--quiet", "numpy>=1.26"]]
    calls.clear()
    monkeypatch.setattr(it.subprocess, "call", lambda cmd: calls.append(cmd[3:]) or 0)
    assert it.main() == 0
    assert calls == [["install", "--quiet", "numpy>=1.26"],
                     ["install", "--quiet", "--index-url", "https://mirror.example/cpu", "torch==2.13.0"]]
