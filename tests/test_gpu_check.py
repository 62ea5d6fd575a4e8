"""benchmarks/gpu.py, the one-command GPU check (issue 45 item 3): one line and exit 0 without CUDA; its harness on
the CPU (tiny sizes, a few steps) writes the report; bad arguments exit 2 and write nothing."""
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "benchmarks" / "gpu.py"


def run(*argv, timeout=240) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, argv)], capture_output=True, text=True, cwd=ROOT,
                          timeout=timeout)


def load_gpu_module():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import gpu
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    return gpu


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA: the check would run")
def test_without_cuda_it_says_so_in_one_line_and_exits_0(tmp_path):
    proc = run("--out", tmp_path / "gpu.md")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == ("gpu check: no CUDA device here (torch.cuda.is_available() is False): nothing to "
                           "measure\n")
    assert proc.stderr == "" and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, message", [
    (["--steps", "0"], "--steps must be at least 1"),
    (["--steps", "5", "--warmup", "5"], "--warmup must be in 0..4"),
    (["--hour-s", "0"], "--hour-s must be positive"),
    (["--models", "voca"], "invalid choice: 'voca'"),
])
def test_bad_arguments_exit_2_with_one_line_and_write_nothing(tmp_path, argv, message):
    proc = run(*argv, "--out", tmp_path / "gpu.md")
    assert proc.returncode == 2 and message in proc.stderr.splitlines()[-1], proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_relative_gap_hand_computed():
    gpu = load_gpu_module()
    # |2 - 2.002| / 2.002 = 9.99e-4; |-1 - -1| = 0; |0 - 1e-13| / 1e-12 = 0.1 (the floor keeps 0 finite)
    assert gpu.relative_gap([2.0, -1.0], [2.002, -1.0]) == pytest.approx(0.002 / 2.002)
    assert gpu.relative_gap([0.0], [1e-13]) == pytest.approx(0.1)


def test_the_harness_runs_on_the_cpu_and_writes_the_report(tmp_path):
    """The whole path but the GPU: tiny sizes, 2 steps, the loss on "the device" (the CPU again) equal to the
    CPU's, 2 s of audio animated (60 frames), the report and its strict JSON."""
    out = tmp_path / "gpu.md"
    proc = run("--device", "cpu", "--sizes", "tiny", "--models", "dualtalker", "--steps", "2", "--warmup", "1",
               "--agree-steps", "2", "--hour-s", "2", "--out", out)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.splitlines()[-1] == f"report -> {out}"
    data = json.loads(out.with_suffix(".json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert data["device"] == "cpu" and data["tests"] is None and data["sizes"] == "tiny"
    [row] = data["training"]
    assert (row["model"], row["amp"], row["steps"], row["ok"]) == ("dualtalker", False, 2, True)
    assert row["loss_gap"] <= 1e-3 and len(row["cpu_losses"]) == len(row["device_losses"]) == 2
    [anim] = data["animate"]
    assert anim["frames"] == 60 and anim["ok"] and anim["peak_mb"] is None
    md = out.read_text()
    assert "Command: `python benchmarks/gpu.py --device cpu" in md and "| dualtalker | no |" in md
    assert "CUDA tests: not run (no CUDA device: cpu)" in md
