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


def test_ci_is_make_test_and_make_test_installs_the_test_tools():
    """CI runs exactly what a developer's `make test` runs: the tools' set-up lives in the Makefile's script."""
    ci = [ln for ln in (ROOT / ".ci" / "run").read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    assert ci == ["set -euo pipefail", 'cd "$(dirname "$0")/.."', "make test"]
    makefile = (ROOT / "Makefile").read_text()
    recipe = makefile.split("\ntest: $(STAMP)\n", 1)[1].splitlines()[0].strip()
    assert recipe == ("OMP_NUM_THREADS=1 bash tools/test_tools.sh $(PY) -m pytest tests notebooks --nbval-lax $(XDIST) "
                      "--durations=25")
    assert makefile.split("\nunit: $(STAMP)\n", 1)[1].splitlines()[0].strip() == \
        'OMP_NUM_THREADS=1 $(PY) -m pytest tests -m "not tools" $(XDIST)'
    # one worker per core, a module (a notebook's cells) whole on one worker: pytest-xdist, installed by [dev]
    assert "\nXDIST  := -n $(TEST_JOBS) --dist loadscope\n" in makefile
    assert "\nTEST_JOBS ?= $(shell nproc 2>/dev/null || echo 2)\n" in makefile
    dev = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["dev"]
    assert any(d.startswith("pytest-xdist") for d in dev)
    script = (ROOT / "tools" / "test_tools.sh").read_text()
    for variable in ("DUALTALKER_REQUIRE_EXPORT_TOOLS", "DUALTALKER_REQUIRE_KATEX", "DUALTALKER_REQUIRE_REAL_VOICES"):
        assert f"export {variable}=" in script
    assert script.rstrip().endswith('exec "$@"  # the command\'s exit status is the script\'s (pytest\'s 5, "no tests", '
                                     'included)')


def test_the_tools_marker_is_registered():
    markers = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["markers"]
    assert [m.split(":")[0] for m in markers] == ["tools"]


def test_test_tools_names_each_missing_tool_and_passes_the_exit_status_through(tmp_path):
    """On a machine without node, npm, chromium or apt-get (PATH holds only the shell's basics): one line per missing
    tool with the command that installs it, and the wrapped command's status (pytest's 5 here) unchanged."""
    import os
    import shutil
    import subprocess

    (tmp_path / "repo" / "tools" / "node").mkdir(parents=True)
    (tmp_path / "repo" / "tools" / "katex").mkdir()
    shutil.copy(ROOT / "tools" / "test_tools.sh", tmp_path / "repo" / "tools")
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name in ("bash", "env", "grep", "sort", "tr", "id", "dirname"):
        (bin_dir / name).symlink_to(shutil.which(name))
    env = {"PATH": str(bin_dir), "HOME": str(tmp_path)}
    proc = subprocess.run(["bash", "tools/test_tools.sh", "bash", "-c", "exit 5"], cwd=tmp_path / "repo", env=env,
                          capture_output=True, text=True, timeout=60, executable=bin_dir / "bash")
    assert proc.returncode == 5, proc.stderr
    lines = proc.stdout.splitlines()
    missing = [ln for ln in lines if ln.startswith("test tools: missing ")]
    assert [ln.split(" (")[0] for ln in missing[:3]] == ["test tools: missing the glTF validator and three.js",
                                                         "test tools: missing KaTeX", "test tools: missing chromium"]
    assert "npm ci --prefix tools/node (needs node and npm: sudo apt-get install nodejs npm" in missing[0]
    assert missing[1].endswith("make katex (needs node and npm: sudo apt-get install nodejs npm on Debian)")
    assert "sudo apt-get install chromium" in missing[2]
    recordings = os.path.isdir("/usr/share/asterisk/sounds/en_US_f_Allison")
    assert len(missing) == (3 if recordings else 4)
    assert lines[-1] == ("test tools: required (fail instead of skipping): "
                         + ("DUALTALKER_REQUIRE_REAL_VOICES=1" if recordings else "none"))


def test_readme_examples_write_distinct_folders():
    """README's commands run one after the other as written: no two `generate`s into the same --out (the second
    would be refused), and no command writes the shipped sample."""
    text = (ROOT / "README.md").read_text()
    outs = re.findall(r"dualtalker-lite generate --out (\S+)", text)
    assert len(outs) >= 3 and len(set(outs)) == len(outs), outs
    assert not [o for o in outs if o.startswith("data_samples")]


def test_readme_python_example_runs_as_written_on_the_phonetic_route():
    """README's Python example (issue 30: the phonetic route, the default) runs as written, but for one epoch instead
    of the short recipe's 20 (the recipe `dualtalker-lite train` uses by default, not the tables' tiny one): it
    trains on the corpus's viseme labels and animates a clip through the recogniser's track."""
    import numpy as np
    import pytest

    pytest.importorskip("hama", reason="the [phonetic] extra (hama) is not installed")
    text = (ROOT / "README.md").read_text().split("## Using the package", 1)[1]
    code = text.split("```python\n", 1)[1].split("```", 1)[0]
    assert "VisemeLabels" in code and "build(DEFAULT)" in code and "audio_dim=160" not in code
    assert code.count('TrainConfig.fast("dualtalker")') == 1 and "TrainConfig.tiny" not in code
    namespace: dict = {}
    exec(compile(code.replace('TrainConfig.fast("dualtalker")', 'TrainConfig.fast("dualtalker", epochs=1, '
                                                                'progress=False)'), "README.md", "exec"), namespace)
    model, corpus, verts = namespace["model"], namespace["corpus"], namespace["verts"]
    assert model.cfg.audio_dim == 15  # one-hot over the 15 visemes of face/visemes.py
    assert len(namespace["history"].terms) == 1
    n_frames = int(round(len(corpus.wave("SPK01_s05")) * 30 / 16000))  # 30 fps from 16 kHz audio
    assert verts.shape == (n_frames, 3 * corpus.metadata["n_vertices"]) and np.isfinite(verts).all()
