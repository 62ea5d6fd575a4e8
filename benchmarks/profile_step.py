"""Where the time of one training step goes, and how far it is from the arithmetic lower bound.

    .venv/bin/python benchmarks/profile_step.py [--model dualtalker|faceformer|voca|corrtalk] [--steps 12]
        [--batch-size 8] [--max-frames 90] [--threads 1] [--features visemes|logmel]
        [--out results/profile_step.md]

``--features visemes`` (the default) is the phonetic route as ``dualtalker-lite train`` and
``benchmarks/recipe_curves.py`` train it: the corpus's own viseme labels as a (T, 15) one-hot with up to
``SILENCE_PAD`` frames of silence on each side (``VisemeLabels``), so clips of 32-117 frames, cropped to 90 and
padded; ``logmel`` is the (T, 160) log-mel route of the tables before issue 19 (clips of 32-77 frames, never cropped).

1. Throughput of this machine's matrix multiply (float32 GEMM, torch.mm) at 1 and 2 threads, on the shape of the
   biggest product of a step (B*T frames x V*3 coordinates x d features) and on a square 1024 product.
2. FLOPs of one step (forward + backward, counted by ``torch.utils.flop_counter``: matmuls and convolutions).
3. Step time (process CPU time and wall time, one thread, the recipe's batch), split into data (collate + crop),
   forward, loss, backward, optimiser (clip + Adam), and the profiler's top operators.
4. The ratio measured step time / (FLOPs / GEMM throughput): how many times slower than pure matmul arithmetic.
5. ``train()`` itself for ``--train-steps`` steps with the recipe (PCA-initialised head, lr 6e-3; a fresh model):
   process CPU time per step with everything the loop does (collating, the CCRL kernel cache filling up, logging);
   for DualTalker and FaceFormer-style again with ``basis_space=True`` (the step in the basis's k coordinates).

Measure on a quiet machine if you can; CPU time (``time.process_time``) is less affected by other jobs than wall
time, but a busy machine still slows each core (shared caches, memory bandwidth).
"""
import argparse
import collections
import json
import os
import shlex
import sys
import time
from pathlib import Path

# torch.profiler's CPU tracer (kineto, inside libtorch) logs its own start and stop to stderr ("USDT: ...
# SyncActivityProfilerHandler.cpp:52] profiler_start"); it reads KINETO_LOG_LEVEL once, when torch loads, and 6
# is above its highest level (USDT, 5), so nothing of it reaches `make bench`'s output. Set before importing torch.
os.environ.setdefault("KINETO_LOG_LEVEL", "6")

import torch  # noqa: E402
from torch.profiler import ProfilerActivity, profile, record_function  # noqa: E402
from torch.utils.flop_counter import FlopCounterMode  # noqa: E402

from dualtalker_lite.data.dataset import SILENCE_PAD, VisemeLabels, make_loader  # noqa: E402
from dualtalker_lite.experiments import build_model, load_data, table_specs  # noqa: E402
from dualtalker_lite.files import atomic_write_text  # noqa: E402
from dualtalker_lite.provenance import machine_line, provenance  # noqa: E402
from dualtalker_lite.losses import rbf_kernel_weights  # noqa: E402
from dualtalker_lite.train import TrainConfig, _crop, loss_weights, model_loss, reuse_freed_memory, train  # noqa: E402

ROWS = {"dualtalker": "DualTalker", "faceformer": "FaceFormer-style", "voca": "VOCA-style", "corrtalk": "CorrTalk"}


def gemm_gflops(m: int, k: int, n: int, threads: int, seconds: float = 1.0) -> tuple[float, float]:
    """(GFLOP per CPU second, GFLOP per wall second) of an (m, k) @ (k, n) float32 product, ``threads`` threads.

    The CPU-second rate (``time.process_time``, summed over the threads) is what one core sustains even on a
    busy machine; the wall rate is what this run got."""
    torch.set_num_threads(threads)
    a, b = torch.randn(m, k), torch.randn(k, n)
    torch.mm(a, b)
    reps, t0, c0 = 0, time.perf_counter(), time.process_time()
    while time.process_time() - c0 < seconds * threads:
        torch.mm(a, b)
        reps += 1
    flop = 2 * m * k * n * reps / 1e9
    return flop / (time.process_time() - c0), flop / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default="dualtalker", choices=list(ROWS))
    ap.add_argument("--steps", type=int, default=12)
    ap.add_argument("--batch-size", type=int, default=None, help="default: the recipe's")
    ap.add_argument("--max-frames", type=int, default=None, help="default: the recipe's crop")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", type=Path, default=None, metavar="MD",
                    help="also write the printout to MD (e.g. results/profile_step.md) and its figures to MD's .json, "
                         "with the command, commit and machine")
    ap.add_argument("--train-steps", type=int, default=44,
                    help="5. steps of train() itself, as the recipe runs it (0: skip)")
    ap.add_argument("--features", default="visemes", choices=("visemes", "logmel"),
                    help="the training input: the phonetic route (viseme labels with pauses) or log-mel")
    args = ap.parse_args()
    stamp = provenance("python benchmarks/profile_step.py " + shlex.join(sys.argv[1:]))
    lines: list[str] = []

    def say(*parts) -> None:
        print(*parts, flush=True)
        lines.append(" ".join(map(str, parts)))
    recipe = TrainConfig.tiny()
    bs = args.batch_size or recipe.batch_size
    crop = args.max_frames or recipe.max_frames

    data = load_data()
    spec = next(s for s in table_specs("main", features=args.features) if s.row == ROWS[args.model])
    train_set = data["train"]
    if args.features == "visemes":  # the phonetic route's training clips, as runner._features(training=True) makes
        train_set = VisemeLabels(train_set, pad_silence=SILENCE_PAD)
    audio_dim = int(train_set[0]["audio"].shape[-1])
    torch.manual_seed(0)
    model, _ = build_model(spec, data["n_vertices"], audio_dim, data["n_speakers"])
    weights = loss_weights(model, spec.loss)  # the model's own loss-weight class
    v3 = 3 * data["n_vertices"]

    # 1. GEMM throughput
    rows = bs * crop
    say(f"GEMM float32 throughput (torch.mm), {torch.__version__}:")
    peak = {}  # GFLOP per CPU second
    for threads in (1, 2):
        big, big_wall = gemm_gflops(rows, v3, 64, threads)
        sq, sq_wall = gemm_gflops(1024, 1024, 1024, threads)
        peak[threads] = max(big, sq)
        say(f"  {threads} thread(s): ({rows} x {v3}) @ ({v3} x 64) {big:6.1f} GFLOP per CPU s ({big_wall:6.1f} per "
              f"wall s) | 1024^3 {sq:6.1f} per CPU s ({sq_wall:6.1f} per wall s)")
    torch.set_num_threads(args.threads)

    # 2. FLOPs of one step
    gen = torch.Generator().manual_seed(0)
    loader = make_loader(train_set, bs, shuffle=True, seed=0)
    batches = [_crop(b, crop, gen) for _, b in zip(range(args.steps + 1), loader)]
    frames = sum(int(b["mask"].sum()) for b in batches[1:]) / args.steps
    model.train()
    with FlopCounterMode(display=False) as fc:
        total, _ = model_loss(model, model(batches[0]), batches[0], weights)
        total.backward()
    flops = fc.get_total_flops() * batches[1]["mask"].numel() / batches[0]["mask"].numel()  # ~ per average batch
    n_params = sum(p.numel() for p in model.parameters())
    say(f"\n{ROWS[args.model]} ({args.features}, audio_dim {audio_dim}): {n_params:,} parameters; batch {bs} x up "
          f"to {crop} frames ({frames:.0f} valid frames per step on average), V*3 = {v3}")
    say(f"FLOPs per step (forward + backward, matmul/conv): {flops / 1e9:.2f} GFLOP")

    # 3. step time, split by phase
    reuse_freed_memory()  # as train() does: no page faults on the large per-step tensors
    opt = torch.optim.Adam(model.parameters(), 1e-3, foreach=True)  # as train() steps
    parts = collections.Counter()

    def step(b, timed: bool):
        c = time.process_time()
        with record_function("data (crop)"):
            b = _crop(b, crop, gen)
        c1 = time.process_time()
        with record_function("forward"):
            out = model(b)
        c2 = time.process_time()
        with record_function("loss"):
            total, _ = model_loss(model, out, b, weights)
        c3 = time.process_time()
        opt.zero_grad(set_to_none=True)
        with record_function("backward"):
            total.backward()
        c4 = time.process_time()
        with record_function("optimiser (clip + Adam)"):
            torch.nn.utils.clip_grad_norm_(model.parameters(), recipe.grad_clip or 1e9, foreach=True)
            opt.step()
        c5 = time.process_time()
        if timed:
            for k, a, z in (("data (crop)", c, c1), ("forward", c1, c2), ("loss", c2, c3), ("backward", c3, c4),
                            ("optimiser (clip + Adam)", c4, c5)):
                parts[k] += z - a

    c0 = time.process_time()
    raw = [b for _, b in zip(range(len(loader)), make_loader(train_set, bs, shuffle=True, seed=1))]
    collate_s = (time.process_time() - c0) / len(raw)
    step(raw[0], False)
    if hasattr(model, "kernel_weights") and weights.lambda4:  # per-clip CCRL kernels, as after the first epoch
        c_k = time.process_time()
        for b in raw:
            model.kernel_weights(b, weights)
        say(f"(filling DualTalker's per-clip CCRL kernel cache, once per run: {time.process_time() - c_k:.2f} s CPU)")
    w0, c0 = time.perf_counter(), time.process_time()
    for b in raw[1:args.steps + 1]:
        step(b, True)
    cpu = (time.process_time() - c0) / args.steps
    wall = (time.perf_counter() - w0) / args.steps
    say(f"\nstep time ({args.threads} thread(s)): {cpu * 1e3:.1f} ms CPU, {wall * 1e3:.1f} ms wall "
          f"(+ {collate_s * 1e3:.1f} ms to collate a batch in the loader)")
    for k, v in parts.items():
        say(f"  {k:26s} {v / args.steps * 1e3:7.1f} ms  {100 * v / args.steps / cpu:5.1f} %")
    kern = None
    if getattr(weights, "lambda4", 0):  # the CCRL kernel is rebuilt from the ground truth in the loss, every step
        c0 = time.process_time()
        for b in raw[1:args.steps + 1]:
            rbf_kernel_weights(b["vertices"] - b["template"][:, None], weights.bandwidth, b["mask"],
                               weights.kernel_distance)
        kern = (time.process_time() - c0) / args.steps
        say(f"  {'(CCRL kernel, uncached)':26s} {kern * 1e3:7.1f} ms  {100 * kern / cpu:5.1f} %  "
              "(dense (T x T) Gram over all V*3 ground-truth coordinates: what each step paid before the cache)")
    bound = flops / (peak[1] * 1e9)
    say(f"arithmetic lower bound, FLOPs / the best 1-thread GEMM rate ({peak[1]:.1f} GFLOP/s): {bound * 1e3:.1f} ms "
          f"per step; measured CPU time / bound = {cpu / bound:.1f}x")
    say(f"with 2 threads the GEMM does {peak[2]:.1f} GFLOP per CPU second ({peak[2] / peak[1]:.2f}x the 1-thread "
          f"rate per core): at best a {2 * peak[2] / peak[1]:.2f}x wall-clock speed-up, on 2 otherwise idle cores")

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for b in raw[1:6]:
            step(b, False)
    say("\ntop operators over 5 steps (self CPU time):")
    say(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=14))

    # 5. train() itself, as the recipe runs it: in vertex coordinates, then in the basis's (basis_space)
    if args.train_steps:
        for basis_space in (False, True) if args.model in ("dualtalker", "faceformer") else (False,):
            torch.manual_seed(0)
            fresh, _ = build_model(spec, data["n_vertices"], audio_dim, data["n_speakers"])
            cfg = TrainConfig.tiny(pca_init=64, lr=6e-3, epochs=1000, max_steps=args.train_steps,
                                   threads=args.threads, batch_size=bs, max_frames=crop, progress=False,
                                   weights=weights, basis_space=basis_space)
            c0 = time.process_time()
            hist = train(fresh, make_loader(train_set, bs, shuffle=True, seed=0), cfg)
            setup = time.process_time() - c0 - hist.cpu_seconds[-1]
            say(f"\ntrain(){' with basis_space=True' if basis_space else ''} for {hist.steps[-1]} steps "
                f"({len(hist.steps)} epochs of {len(loader)}): {hist.cpu_seconds[-1] / hist.steps[-1] * 1e3:.1f} ms "
                f"CPU per step, collating and the filling of the CCRL kernel cache included (+ {setup:.2f} s CPU "
                "before the first step: mean and PCA init)")
            if len(hist.steps) > 1:
                later = (hist.cpu_seconds[-1] - hist.cpu_seconds[0]) / (hist.steps[-1] - hist.steps[0])
                say(f"  first epoch {hist.cpu_seconds[0] / hist.steps[0] * 1e3:.1f} ms per step, later epochs "
                    f"{later * 1e3:.1f} ms per step")
    if args.out is not None:
        figures = {"model": ROWS[args.model], "features": args.features, "threads": args.threads,
                   "steps": args.steps, "batch_size": bs, "max_frames": crop, "step_cpu_ms": cpu * 1e3, "step_wall_ms": wall * 1e3,
                   "parts_cpu_ms": {k: v / args.steps * 1e3 for k, v in parts.items()},
                   "ccrl_kernel_uncached_ms": None if kern is None else kern * 1e3, "gflop_per_step": flops / 1e9,
                   "gemm_gflop_per_cpu_s": peak, "arithmetic_bound_ms": bound * 1e3}
        page = ["# Where a training step's time goes", "", f"Command: `{stamp['command']}`; commit {stamp['commit']}; "
                f"{stamp['created']}; {machine_line(stamp['machine'])}. CPU time is the process's own; a busy machine "
                "still slows each core. `benchmarks/profile_step.py`'s docstring says what each part is.", "",
                "```", *"\n".join(lines).splitlines(), "```", ""]
        atomic_write_text(args.out, "\n".join(page))
        atomic_write_text(args.out.with_suffix(".json"), json.dumps({**stamp, "git": stamp["commit"], **figures},
                                                                    indent=1) + "\n")


if __name__ == "__main__":
    main()
