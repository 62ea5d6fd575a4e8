"""The conda environment installs the same thing as pyproject.toml; the Quick start stays two commands."""
import re
import tomllib
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def _name(req: str) -> str:
    return re.split(r"[<>=!~\[; ]", req.strip(), maxsplit=1)[0].lower().replace("_", "-")


def _pyproject_requirements() -> set[str]:
    proj = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    reqs = list(proj["dependencies"])
    for extra in proj["optional-dependencies"].values():
        reqs += extra
    return {_name(r) for r in reqs}


def test_environment_yml_parses_and_matches_pyproject():
    env = yaml.safe_load((ROOT / "environment.yml").read_text())
    assert "python=3.11" in env["dependencies"]
    pip_block = next(d for d in env["dependencies"] if isinstance(d, dict))["pip"]
    pip_names = {_name(r) for r in pip_block if not r.startswith("-e")}
    assert "-e ." in pip_block, "environment.yml must install the package itself"
    assert pip_names == _pyproject_requirements()


def test_torch_is_pinned_to_the_cpu_wheel_before_the_package():
    env = yaml.safe_load((ROOT / "environment.yml").read_text())
    pip_block = next(d for d in env["dependencies"] if isinstance(d, dict))["pip"]
    assert pip_block[0] == "torch==2.13.0"
    makefile = (ROOT / "Makefile").read_text()  # torch first (the CPU build where possible), then the package
    assert makefile.index("tools/install_torch.py") < makefile.index('-e ".[')
    assert 'VERSION = "2.13.0"' in (ROOT / "tools" / "install_torch.py").read_text()


def test_no_torchaudio_or_torchvision_dependency():
    names = _pyproject_requirements()
    assert not names & {"torchaudio", "torchvision"}


def test_readme_quick_start_has_exactly_two_commands():
    text = (ROOT / "README.md").read_text()
    block = text.split("## Quick start", 1)[1].split("```", 2)[1]
    commands = [ln for ln in block.splitlines()[1:] if ln.strip() and not ln.strip().startswith("#")]
    assert commands == ["make lab", "make test"], commands


def test_ci_runs_the_readme_test_command():
    assert "make test" in (ROOT / ".ci" / "run").read_text()
