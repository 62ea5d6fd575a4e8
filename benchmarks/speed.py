"""Speed figures: training throughput, autoregressive inference with/without the key/value cache,
and CCRL vectorised vs a per-anchor loop. Prints a table; nothing here is a pass/fail test.

    .venv/bin/python benchmarks/speed.py [--threads 2]
"""
import argparse

import torch
import torch.nn.functional as F

from common import Timer, load_sample, tiny_dualtalker
from dualtalker_lite.data.dataset import make_loader
from dualtalker_lite.losses import ccrl_loss, joint_loss, LossWeights, rbf_kernel_weights

ap = argparse.ArgumentParser()
ap.add_argument("--threads", type=int, default=2)
ap.add_argument("--skip-slow", action="store_true", help="skip the uncached 60 s clip (quadratic, minutes)")
args = ap.parse_args()
torch.set_num_threads(args.threads)
corpus, ds = load_sample(("train",))
model = tiny_dualtalker(corpus)
print(f"tiny DualTalker: {model.num_parameters():,} parameters; {args.threads} torch threads")

# --- training throughput (sequences per second, batch 8, full joint loss) ---
opt = torch.optim.Adam(model.parameters(), 1e-3)
batches = list(make_loader(ds["train"], 8, shuffle=True, seed=0))[:12]
model.train()
with Timer() as t:
    for b in batches:
        total, _ = joint_loss(model(b), b, LossWeights())
        opt.zero_grad()
        total.backward()
        opt.step()
n_seq = sum(len(b["name"]) for b in batches)
print(f"training: {n_seq / t.seconds:.1f} sequences/s ({t.seconds / len(batches) * 1000:.0f} ms per batch of 8)")

# --- autoregressive inference, real-time factor (compute time / clip duration) ---
model.eval()
item = ds["train"][0]
for seconds in (4, 20, 60):
    T = 30 * seconds
    audio = item["audio"].repeat((T // len(item["audio"]) + 1, 1))[:T][None]  # (1, T, 160)
    template, speaker = item["template"][None], torch.tensor([0])
    row = []
    for cache in (True, False):
        if not cache and seconds > 20 and args.skip_slow:
            row.append("(skipped with --skip-slow)")
            continue
        with torch.no_grad(), Timer() as t:
            model.generate(audio, template, speaker, use_cache=cache)
        row.append(f"{T / t.seconds:7.0f} frames/s, RTF {t.seconds / seconds:.3f}")
    print(f"inference {seconds:2d} s clip ({T} frames): with cache {row[0]} | without cache {row[1]}")


# --- CCRL: vectorised (package) vs a per-anchor loop ---
def ccrl_per_anchor(x, y, motion):
    """The same loss (default options: kernel-weighted positives of eq. 9, swap second term), one anchor k at a time:
    l_k = log s'_k - sum_j w_kj s^inter_kj / sum_j w_kj, s'_k over the scaled negatives t != k (eq. 10)."""
    mask = torch.ones(x.shape[:2], dtype=torch.bool)
    w = rbf_kernel_weights(motion, None, mask)[0]  # (T, T)
    total = 0.0
    for p, q in ((x[0], y[0]), (y[0], x[0])):
        losses = []
        for k in range(p.shape[0]):
            inter = F.cosine_similarity(p[k:k + 1], q, dim=-1)  # (T,)
            intra = F.cosine_similarity(p[k:k + 1], p, dim=-1)  # (T,)
            neg = torch.arange(p.shape[0]) != k
            logits = torch.cat([(inter * (1 - w[k]))[neg], (intra * (1 - w[k]))[neg]])
            losses.append(torch.logsumexp(logits, 0) - (w[k] * inter).sum() / w[k].sum())
        total = total + torch.stack(losses).mean()
    return total


g = torch.Generator().manual_seed(0)
for T in (60, 120, 300):
    x, y = torch.randn(1, T, 64, generator=g), torch.randn(1, T, 64, generator=g)
    motion = torch.randn(1, T, 4674, generator=g) * 1e-3
    mask = torch.ones(1, T, dtype=torch.bool)
    vec, loop = ccrl_loss(x, y, motion, mask), ccrl_per_anchor(x, y, motion)
    torch.testing.assert_close(vec, loop, rtol=1e-4, atol=1e-4)  # same loss, so the timing comparison is fair
    times = []
    for fn in (lambda: ccrl_loss(x, y, motion, mask), lambda: ccrl_per_anchor(x, y, motion)):
        with Timer() as t:
            for _ in range(3):
                fn()
        times.append(t.seconds / 3 * 1000)
    print(f"CCRL T={T:3d}: vectorised {times[0]:7.2f} ms | per-anchor loop {times[1]:8.2f} ms | x{times[1] / times[0]:.0f}")
