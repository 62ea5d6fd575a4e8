"""The real-voice benchmarks stop with one line, before training anything or writing a file, when their frozen
inputs (made once by ``benchmarks/recipe_curves.py inputs``) are missing."""
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("args", [
    ["benchmarks/demo_load.py", "--seeds", "0", "--out", "{tmp}/out", "--report", "{tmp}/out/demo_load.md"],
    ["benchmarks/recipe_curves.py", "run", "--models", "dualtalker", "--seeds", "0", "--out", "{tmp}/out"],
])
def test_missing_frozen_inputs_fail_with_one_line_and_write_nothing(tmp_path, args):
    missing = tmp_path / "nope" / "inputs.pth"
    cmd = [sys.executable, *[a.format(tmp=tmp_path) for a in args], "--inputs", str(missing)]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert lines == [f"{missing}: no such file; make it first with `python benchmarks/recipe_curves.py inputs` "
                     "(needs real_voices.py's recordings, pocketsphinx and the recogniser)"]
    assert not (tmp_path / "out").exists()
