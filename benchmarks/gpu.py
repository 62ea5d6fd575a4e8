"""The GPU check: what anyone with an NVIDIA GPU runs in one command (``make gpu-check`` runs this script).

    .venv/bin/python benchmarks/gpu.py                     # everything below -> results/gpu.md (+ .json)
    .venv/bin/python benchmarks/gpu.py --steps 100 --hour-s 600 --out runs/gpu.md   # a shorter run
    .venv/bin/python benchmarks/gpu.py --device cpu --sizes tiny --steps 3 ...      # the harness itself, no GPU

On a machine without CUDA (and without ``--device cpu``) it prints one line saying so and exits 0: CI and the
laptops this project is written on have no GPU, and that is not a failure.

With CUDA it measures, on the shipped corpus (``data_samples/``, log-mel input: the papers' acoustic front end, so
no recogniser runs):

1. **The CUDA tests**: ``pytest tests -k cuda`` as a process (``tests/test_inference.py::test_cuda_matches_cpu``
   and every other test whose name says cuda); its status and summary line.
2. **Training steps at the papers' sizes**: DualTalker, FaceFormer-style, CorrTalk and EmoFace built with their
   config's ``paper()`` preset (the dataclass defaults: d=128, FF 2048 and so on; EmoFace on its emotional
   pseudo-pairs), the training step of :func:`dualtalker_lite.train.train` (forward, the model's own loss, backward,
   gradient clipping, Adam with ``foreach``), batch 8 of the recipe's crops, for ``--steps`` steps in float32 and
   again with ``--amp`` (``torch.autocast`` in bfloat16; the weights and Adam stay float32). Per row: median step
   time after ``--warmup`` steps, peak GPU memory (``torch.cuda.max_memory_allocated``), the last loss.
3. **Loss agreement with the CPU**: the first ``--agree-steps`` steps from the same initial weights on the same
   batches, on the CPU and on the GPU (float32, TF32 off): the largest relative difference of the loss per step must
   stay under ``--rtol`` (default 1e-3: float sums in another order, compounded over a few Adam steps); with
   ``--amp`` the same comparison is reported against ``--amp-rtol`` (5e-2: bfloat16 keeps 8 bits of mantissa).
4. **``animate --device cuda`` of an hour of audio** (``--hour-s`` seconds of a synthetic speech-like signal; the
   command in this process, so its peak GPU memory can be read): frames per second of wall time and peak GPU memory,
   with and without ``--amp``, on an untrained log-mel DualTalker at the paper's sizes (the speed does not depend on
   the weights).

``results/gpu.md`` and ``results/gpu.json`` record the command, the commit (``dualtalker_lite.provenance``) and
the device's name. Exit status: 0 when every check passed, 1 when one failed (the report says which), 2 for bad
arguments.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

MODELS = ("dualtalker", "faceformer", "corrtalk", "emoface")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cuda", help="cuda or cuda:N; cpu runs the harness alone (its own check)")
    ap.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS)
    ap.add_argument("--sizes", choices=("paper", "tiny"), default="paper", help="the configs' preset")
    ap.add_argument("--steps", type=int, default=300, help="timed training steps per model and precision")
    ap.add_argument("--warmup", type=int, default=20, help="steps left out of the median (allocator, kernels)")
    ap.add_argument("--agree-steps", type=int, default=5, help="steps compared with the CPU")
    ap.add_argument("--rtol", type=float, default=1e-3, help="largest relative loss difference, float32")
    ap.add_argument("--amp-rtol", type=float, default=5e-2, help="largest relative loss difference, --amp")
    ap.add_argument("--hour-s", type=float, default=3600.0, help="seconds of audio for the animate check")
    ap.add_argument("--no-tests", action="store_true", help="skip the CUDA tests (pytest)")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "gpu.md", help="the report (.md; .json beside)")
    args = ap.parse_args(argv)
    for name in ("steps", "agree_steps"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be at least 1")
    if args.warmup < 0 or args.warmup >= args.steps:
        ap.error(f"--warmup must be in 0..{args.steps - 1} (below --steps)")
    if not args.hour_s > 0:
        ap.error("--hour-s must be positive")
    return args


# ------------------------------------------------------------------------------------------------ set-up
def training_setup(name: str, sizes: str, seed: int = 0):
    """(model, loader, weights) of ``--model name`` on the shipped corpus at ``sizes``: the clips and loss weights
    of ``dualtalker-lite train --features logmel``, the model rebuilt with its config's ``paper()`` preset."""
    from dualtalker_lite.commands import model_specs, pair_dataset
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus
    from dualtalker_lite.data.dataset import TalkingFaceDataset
    from dualtalker_lite.experiments.assembly import assemble_training
    from dualtalker_lite.models import registry
    from dualtalker_lite.seeding import set_seed

    corpus = Corpus(sample_path())
    spec = dataclasses.replace(model_specs()[name], features="logmel")
    paired = spec.data == "pairs"
    clips = pair_dataset(corpus, seed) if paired else TalkingFaceDataset(corpus, "train")
    a = assemble_training(spec, clips, corpus, paired=paired, seed=seed, recipe="fast" if name != "emoface" else "tiny")
    model = a.model
    if sizes == "paper":
        entry = registry.get(name)
        keep = ("n_vertices", "audio_dim", "n_speakers", "n_emotions", "content_dims")
        given = {k: getattr(a.model_config, k) for k in keep if hasattr(a.model_config, k)}
        set_seed(seed)
        cfg = entry.config_cls.paper(**given)
        model = entry.model_cls(cfg, faces=corpus.faces) if name == "emoface" else entry.model_cls(cfg)
    return model, a.loader, a.train_config


def batches(loader, n: int, max_frames: int | None, seed: int = 0) -> list[dict]:
    """The first ``n`` batches of ``loader`` (cycled), cropped as ``train`` crops them, on the CPU."""
    import torch

    from dualtalker_lite.train import _crop

    gen = torch.Generator().manual_seed(seed)
    out: list[dict] = []
    while len(out) < n:
        for batch in loader:
            out.append(_crop(batch, max_frames, gen))
            if len(out) == n:
                break
    return out


def run_steps(model, batch_list: list[dict], weights, device: str, amp: bool, lr: float = 1e-4,
              grad_clip: float = 1.0) -> tuple[list[float], list[float]]:
    """``train``'s step on each batch -> (losses, seconds per step); CUDA steps are timed to the end of the
    step (``torch.cuda.synchronize``)."""
    import torch

    from dualtalker_lite.train import _to_device, model_loss

    model.to(device).train()
    opt = torch.optim.Adam(model.parameters(), lr=lr, foreach=True)
    cuda = device.startswith("cuda")
    losses, seconds = [], []
    for batch in batch_list:
        t0 = time.perf_counter()
        batch = _to_device(batch, torch.device(device))
        with torch.autocast("cuda", dtype=torch.bfloat16, enabled=amp and cuda):
            out = model(batch)
            total, _ = model_loss(model, out, batch, weights)
        opt.zero_grad(set_to_none=True)
        total.float().backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), grad_clip, foreach=True)
        opt.step()
        if cuda:
            torch.cuda.synchronize(device)
        seconds.append(time.perf_counter() - t0)
        losses.append(float(total.detach()))
    return losses, seconds


def relative_gap(a: list[float], b: list[float]) -> float:
    """The largest |a - b| / max(|a|, |b|, 1e-12) over the steps."""
    return max(abs(x - y) / max(abs(x), abs(y), 1e-12) for x, y in zip(a, b))


def training_rows(args, device: str) -> list[dict]:
    import copy

    import torch

    rows = []
    for name in args.models:
        model, loader, tc = training_setup(name, args.sizes)
        n_params = sum(p.numel() for p in model.parameters() if p.requires_grad)
        timed = batches(loader, args.steps, tc.max_frames)
        first = timed[:args.agree_steps]
        cpu_losses, _ = run_steps(copy.deepcopy(model), first, tc.weights, "cpu", amp=False)
        for amp in (False, True) if device.startswith("cuda") else (False,):  # autocast here is CUDA's
            if device.startswith("cuda"):
                torch.backends.cuda.matmul.allow_tf32 = False
                torch.backends.cudnn.allow_tf32 = False
                torch.cuda.reset_peak_memory_stats(device)
            dev_losses, _ = run_steps(copy.deepcopy(model), first, tc.weights, device, amp=amp)
            gap = relative_gap(cpu_losses, dev_losses)
            tol = args.amp_rtol if amp else args.rtol
            if device.startswith("cuda"):
                torch.backends.cuda.matmul.allow_tf32 = True  # the timed run: the GPU's fast float32 path
                torch.cuda.reset_peak_memory_stats(device)
            losses, seconds = run_steps(copy.deepcopy(model), timed, tc.weights, device, amp=amp)
            peak = torch.cuda.max_memory_allocated(device) / 2**20 if device.startswith("cuda") else None
            rows.append({"model": name, "amp": amp, "parameters": n_params, "steps": len(timed),
                         "step_ms": 1000 * statistics.median(seconds[args.warmup:]), "peak_mb": peak,
                         "last_loss": losses[-1], "finite": all(map(math.isfinite, losses)),
                         "cpu_losses": cpu_losses, "device_losses": dev_losses, "loss_gap": gap, "tolerance": tol,
                         "ok": gap <= tol and all(map(math.isfinite, losses))})
            r = rows[-1]
            print(f"{name:10s} amp={amp!s:5s} {r['step_ms']:8.1f} ms/step  peak {_mb(r['peak_mb']):>6s} MB  "
                  f"loss gap vs CPU {gap:.2e} (<= {tol:g}: {'ok' if r['ok'] else 'FAILED'})", flush=True)
        del model, loader, timed
    return rows


def speech_like_wav(path: Path, seconds: float, rate: int = 16000) -> Path:
    """A speech-like signal (a voiced tone gliding in pitch, switched on and off at syllable rate, with noise) of
    ``seconds``, written block by block as 16-bit PCM (an hour is 115 MB)."""
    import numpy as np
    import soundfile as sf

    rng = np.random.default_rng(0)
    block = 60 * rate
    with sf.SoundFile(path, "w", samplerate=rate, channels=1, subtype="PCM_16") as f:
        for start in range(0, int(seconds * rate), block):
            n = min(block, int(seconds * rate) - start)
            t = (start + np.arange(n)) / rate
            wave = 0.3 * np.sin(2 * np.pi * (150 + 50 * np.sin(2 * t)) * t) * (np.sin(2 * np.pi * 3 * t) > 0)
            f.write((wave + 0.01 * rng.standard_normal(n)).astype(np.float32))
    return path


def animate_rows(args, device: str, work: Path) -> list[dict]:
    """``dualtalker-lite animate --device DEVICE [--amp]`` of ``--hour-s`` seconds, in this process."""
    import numpy as np
    import torch

    from dualtalker_lite.checkpoints import save_checkpoint
    from dualtalker_lite.cli import main as cli_main
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus
    from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig

    corpus = Corpus(sample_path())
    preset = DualTalkerConfig.paper if args.sizes == "paper" else DualTalkerConfig.tiny
    torch.manual_seed(0)
    cfg = preset(n_vertices=corpus.metadata["n_vertices"], audio_dim=160, n_speakers=len(corpus.train_speakers))
    save_checkpoint(work / "m.pt", DualTalker(cfg).eval(), cfg, speakers=corpus.train_speakers, faces=corpus.faces)
    wav = speech_like_wav(work / "speech.wav", args.hour_s)
    rows = []
    for amp in (False, True):
        if amp and not device.startswith("cuda"):
            continue  # --amp is refused without CUDA
        out = work / f"out_amp{int(amp)}"
        if device.startswith("cuda"):
            torch.cuda.reset_peak_memory_stats(device)
        t0 = time.perf_counter()
        status = cli_main(["animate", "--checkpoint", str(work / "m.pt"), "--wav", str(wav), "--out", str(out),
                           "--format", "npy", "--device", device, "--quiet", *(["--amp"] if amp else [])])
        wall = time.perf_counter() - t0
        frames = np.load(out / "vertices.npy", mmap_mode="r").shape[0]
        peak = torch.cuda.max_memory_allocated(device) / 2**20 if device.startswith("cuda") else None
        rows.append({"amp": amp, "audio_s": args.hour_s, "frames": int(frames), "wall_s": wall,
                     "frames_per_s": frames / wall, "realtime_x": args.hour_s / wall, "peak_mb": peak,
                     "ok": status == 0 and frames == round(args.hour_s * corpus.fps)})
        r = rows[-1]
        print(f"animate {args.hour_s:.0f} s amp={amp!s:5s} {r['frames_per_s']:8.0f} frames/s "
              f"({r['realtime_x']:.0f}x real time), peak {_mb(r['peak_mb'])} MB: {'ok' if r['ok'] else 'FAILED'}",
              flush=True)
    return rows


def cuda_tests() -> dict:
    proc = subprocess.run([sys.executable, "-m", "pytest", "tests", "-k", "cuda", "-q", "-p", "no:cacheprovider"],
                          cwd=ROOT, capture_output=True, text=True)
    lines = proc.stdout.strip().splitlines()
    return {"status": proc.returncode, "summary": lines[-1] if lines else proc.stderr.strip()[-300:],
            "ok": proc.returncode == 0}


# ------------------------------------------------------------------------------------------------ report
def _mb(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.0f}"


def report(args, device: str, device_name: str, tests: dict | None, train: list[dict], animate: list[dict],
           command: str) -> tuple[str, dict]:
    from dualtalker_lite.provenance import provenance

    stamp = provenance(command)
    data = {**stamp, "device": device, "device_name": device_name, "sizes": args.sizes, "tests": tests,
            "training": train, "animate": animate}
    lines = ["# GPU check", "", f"Command: `{command}`", "",
             f"Commit {stamp['commit']}, {stamp['created']}; device: {device_name} ({device}); model sizes: "
             f"`{args.sizes}()`; written by `benchmarks/gpu.py` (its docstring says what each figure is).", ""]
    if tests is None:
        lines += ["CUDA tests: not run" + (" (--no-tests)" if args.no_tests else f" (no CUDA device: {device})"), ""]
    else:
        lines += [f"CUDA tests (`pytest tests -k cuda`): status {tests['status']}, {tests['summary']}", ""]
    lines += ["## Training steps (batch 8, the recipe's crops; loss gap: the first steps against the CPU's)", "",
              "| model | --amp | parameters | ms / step (median) | peak GPU MB | last loss | loss gap vs CPU "
              "| tolerance | ok |", "|---|---|---:|---:|---:|---:|---:|---:|---|"]
    for r in train:
        lines.append(f"| {r['model']} | {'yes' if r['amp'] else 'no'} | {r['parameters']:,} | {r['step_ms']:.1f} | "
                     f"{_mb(r['peak_mb'])} | {r['last_loss']:.4g} | {r['loss_gap']:.2e} | {r['tolerance']:g} | "
                     f"{'yes' if r['ok'] else '**no**'} |")
    lines += ["", f"## `animate --device {device}` of {args.hour_s:.0f} s of audio (log-mel DualTalker, "
              f"`{args.sizes}()` sizes, untrained)", "",
              "| --amp | frames | wall s | frames / s | x real time | peak GPU MB | ok |",
              "|---|---:|---:|---:|---:|---:|---|"]
    for r in animate:
        lines.append(f"| {'yes' if r['amp'] else 'no'} | {r['frames']:,} | {r['wall_s']:.1f} | "
                     f"{r['frames_per_s']:.0f} | {r['realtime_x']:.0f} | {_mb(r['peak_mb'])} | "
                     f"{'yes' if r['ok'] else '**no**'} |")
    return "\n".join(lines) + "\n", data


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    import torch

    device = args.device
    if device.startswith("cuda") and not torch.cuda.is_available():
        print("gpu check: no CUDA device here (torch.cuda.is_available() is False): nothing to measure")
        return 0
    from dualtalker_lite.files import atomic_write_text

    device_name = torch.cuda.get_device_name(device) if device.startswith("cuda") else "CPU (harness check)"
    command = shlex.join(["python", "benchmarks/gpu.py", *(argv if argv is not None else sys.argv[1:])])
    print(f"gpu check on {device_name}: {command}", flush=True)
    tests = None if args.no_tests or not device.startswith("cuda") else cuda_tests()
    if tests is not None:
        print(f"CUDA tests: {tests['summary']}", flush=True)
    train = training_rows(args, device)
    with tempfile.TemporaryDirectory(prefix="dualtalker-gpu-") as tmp:
        animate = animate_rows(args, device, Path(tmp))
    text, data = report(args, device, device_name, tests, train, animate, command)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, text)
    atomic_write_text(args.out.with_suffix(".json"), json.dumps(data, indent=1) + "\n")
    failed = [f"{r['model']} amp={r['amp']}" for r in train if not r["ok"]]
    failed += [f"animate amp={r['amp']}" for r in animate if not r["ok"]]
    if tests is not None and not tests["ok"]:
        failed.append("the CUDA tests")
    print(f"report -> {args.out}" + (f"; FAILED: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
