# %% [markdown]
# # 04 · The speaker-aware gate (eq. 5)
#
# Different people move their faces differently for the same sound: one speaker opens the jaw wide, another
# mostly rounds the lips. DualTalker lets the style embedding $S_n$ of speaker $n$ rescale the channels of the
# attended motion features with a *speaker-aware module* (Fig. 2, lower right), a Squeeze-and-Excitation gate
# whose excitation also sees the speaker. This notebook takes the gate apart: what SE does, eq. 5 checked
# against a from-scratch formula, how the gate differs between speakers, what the reduction ratio $r$ costs
# and buys, and a tiny experiment in which a gate learns two speakers' channel scalings.
#
# **We will cover**
#
# 1. Squeeze-and-Excitation, and why DualTalker's gate does not squeeze over time.
# 2. Eq. 5: `SpeakerAwareGate` against the formula written out.
# 3. How the gate differs per speaker: gate values per speaker x channel, and their distribution.
# 4. The reduction ratio $r$: parameter count and the rank of the gate.
# 5. A tiny experiment: a gate + linear head learns two speakers' channel scalings; a head alone cannot.
# 6. $r$ against the number of speakers: a narrow bottleneck cannot tell many speakers apart.
#
# | paper symbol | code name | shape |
# |---|---|---|
# | $\check{Y}_{1:T}$ (attended motion features, output of eqs. 3-4) | `features` | (B, T, d) |
# | $S_n$ (style embedding of speaker $n$) | `style` | (B, d) |
# | $\mathrm{Concat}(S_n, \check{Y}_t)$ | `torch.cat([style, features_t])` | (B, T, 2d) |
# | FC 1 ($2d \to 2d/r$) | `gate.fc1` | weight (2d/r, 2d) |
# | FC 2 ($2d/r \to d$) | `gate.fc2` | weight (d, 2d/r) |
# | $\mathrm{MLP}(\cdot)$ (gate values in (0, 1)) | `gate.gate(features, style)` | (B, T, d) |
# | $\bar{Y}_{1:T}$ (speaker-specific features) | `gated` = `gate(features, style)` | (B, T, d) |
# | $r$ (channel compression ratio) | `reduction` | int (16 in the paper) |
# | $d$ (model width; $d_k$ in the paper's text) | `d` | int (128 for VOCASET) |

# %%
%matplotlib inline
import matplotlib.pyplot as plt
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from dualtalker_lite.blocks import SpeakerAwareGate
from dualtalker_lite.data import sample_path  # the shipped corpus (not needed here: everything is synthetic)
from dualtalker_lite.checks import check_shape
from dualtalker_lite.seeding import set_seed

torch.set_num_threads(2)
gen = set_seed(0)  # seeds Python/NumPy/torch; `gen` draws every random tensor below

# %% [markdown]
# ## 1. Squeeze-and-Excitation, and why DualTalker does not squeeze over time
#
# SE (Hu et al., 2018) recalibrates the $C$ channels of a feature map $U$ in three steps: **squeeze** the
# spatial (here: temporal) axis by averaging, **excite** with a small bottleneck MLP ending in a sigmoid, and
# **scale** each channel by its gate:
#
# $$z = \frac{1}{T}\sum_{t=1}^{T} u_t, \qquad s = \sigma\big(W_2\,\mathrm{ReLU}(W_1 z)\big), \qquad \tilde{u}_t = s \odot u_t,
# \qquad W_1 \in \mathbb{R}^{\frac{C}{r}\times C},\ W_2 \in \mathbb{R}^{C\times\frac{C}{r}}$$
#
# DualTalker keeps the excitation and the scaling but changes the input of the MLP: instead of the squeezed
# summary $z$ it receives the speaker's style $S_n$ concatenated with the features *of each frame*. A squeeze over
# time would not work in an autoregressive decoder: the gate of frame $t$ would depend on frames after $t$,
# which do not exist yet at inference. Below, the SE-style variant (the package's gate fed the time-average of
# the features) changes the past when the future changes; the package's per-frame gate does not.

# %%
d, T, B = 32, 20, 2
torch.manual_seed(1)
gate = SpeakerAwareGate(d, reduction=4)
features = torch.randn(B, T, d, generator=gen)  # (B, T, d) Y̌
style = torch.randn(B, d, generator=gen)  # (B, d) S_n


def se_style(feats: torch.Tensor) -> torch.Tensor:
    """The gate fed the squeezed (time-averaged) features, as in SE: one gate per clip, not per frame."""
    squeezed = feats.mean(dim=1, keepdim=True).expand_as(feats)  # (B, T, d) z broadcast over frames
    return gate.gate(squeezed, style) * feats  # (B, T, d)


future_changed = features.clone()
future_changed[:, 10:] = torch.randn(B, T - 10, d, generator=gen)  # rewrite frames 10..19
torch.testing.assert_close(gate(features, style)[:, :10], gate(future_changed, style)[:, :10])  # causal
assert not torch.allclose(se_style(features)[:, :10], se_style(future_changed)[:, :10])  # SE leaks the future
g_se = se_style(features) / features
torch.testing.assert_close(g_se, g_se[:, :1].expand_as(g_se))  # SE: the same gate for every frame
print("per-frame gate (eq. 5): causal; SE squeeze over time: one gate per clip, depends on future frames")

# %% [markdown]
# ## 2. Eq. 5: the speaker-aware gate
#
# $$\bar{Y}_{1:T} = \mathrm{MLP}\big(\mathrm{Concat}(S_n, \check{Y}_{1:T})\big) \cdot \check{Y}_{1:T} \tag{5}$$
#
# with $\mathrm{MLP} = \mathrm{FC}(2d \to 2d/r) \to \mathrm{ReLU} \to \mathrm{FC}(2d/r \to d) \to \mathrm{Sigmoid}$.
# $S_n$ is broadcast over the $T$ frames, and "$\cdot$" is the element-wise product (the gate has one value per
# channel and frame). The paper sizes the first FC as "$2 \times d_k / r$" outputs with $r = 16$ (supplementary
# A writes "d to 2d/16"); its input is the $2d$-channel concatenation, and the second FC must return $d$ channels
# to multiply $\check{Y}$. Written out for one frame:
#
# $$g_t = \sigma\big(W_2\, \mathrm{ReLU}(W_1 [S_n; \check{Y}_t] + b_1) + b_2\big) \in (0, 1)^d, \qquad \bar{Y}_t = g_t \odot \check{Y}_t$$

# %%
concat = torch.cat([style[:, None, :].expand(B, T, d), features], dim=-1)  # (B, T, 2d) [S_n; Y̌_t]
g_scratch = torch.sigmoid(F.linear(torch.relu(F.linear(concat, gate.fc1.weight, gate.fc1.bias)),
                                   gate.fc2.weight, gate.fc2.bias))  # (B, T, d)
gated = gate(features, style)  # Ȳ

check_shape(gate.fc1.weight, (2 * d // 4, 2 * d), "W_1")
check_shape(gate.fc2.weight, (d, 2 * d // 4), "W_2")
check_shape(gated, (B, T, d), "gated features")
torch.testing.assert_close(gate.gate(features, style), g_scratch)
torch.testing.assert_close(gated, g_scratch * features)
g = gate.gate(features, style)
assert ((g > 0) & (g < 1)).all()  # a sigmoid: the gate only attenuates ...
assert (gated.abs() <= features.abs()).all()  # ... so |Ȳ| <= |Y̌| channel by channel
print(f"eq. 5: package == from scratch; gate values in [{g.min():.2f}, {g.max():.2f}]")

# %% [markdown]
# ## 3. How the gate differs per speaker
#
# Feed the *same* features with the style embeddings of six speakers (random, as the model's `nn.Embedding` is
# at initialisation) and average the gate over the frames: each speaker gets its own channel profile. At
# initialisation the gates sit near 0.5 (the sigmoid of a small number), so the module starts by roughly
# halving every channel; training (section 5) spreads them out.

# %%
n_speakers, T3 = 6, 50
torch.manual_seed(3)
style_table = nn.Embedding(n_speakers, d)  # S_1..S_6, N(0, 1) like the model's style embedding at init
shared = torch.randn(1, T3, d, generator=gen).expand(n_speakers, T3, d)  # (6, T, d) the same Y̌ for all
with torch.no_grad():
    g_spk = gate.gate(shared, style_table(torch.arange(n_speakers)))  # (6, T, d)
check_shape(g_spk, (n_speakers, T3, d), "gates per speaker")
profile = g_spk.mean(dim=1)  # (6, d) mean gate per speaker and channel

between = profile.std(dim=0).mean().item()  # how much speakers differ (per channel, averaged)
within = g_spk.std(dim=1).mean().item()  # how much a speaker's gate moves over the frames
assert not torch.allclose(profile[0], profile[1], atol=1e-3)
print(f"spread of the gate across speakers: {between:.3f}; across the frames of one speaker: {within:.3f}")

# %%
fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(13, 3.6), layout="constrained", width_ratios=[1.6, 1])
im = ax0.imshow(profile, aspect="auto", cmap="viridis")
ax0.set_xlabel("channel k of the features")
ax0.set_ylabel("speaker n")
ax0.set_title("Mean gate per speaker and channel (untrained gate, same features)")
fig.colorbar(im, ax=ax0, label="gate value (mean over frames)")
bins = np.linspace(g_spk.min().item(), g_spk.max().item(), 40)
for n in range(3):
    ax1.hist(g_spk[n].flatten(), bins=bins, histtype="step", lw=1.5, label=f"speaker {n}")
ax1.set_xlabel("gate value (all frames and channels)")
ax1.set_ylabel("count")
ax1.set_title("Gate distribution per speaker")
ax1.legend(fontsize=8)
plt.show()

# %% [markdown]
# ## 4. The reduction ratio $r$
#
# The hidden layer has $h = 2d/r$ units, so the MLP has $2d \cdot h + h$ (FC 1) $+\ h \cdot d + d$ (FC 2)
# parameters, about $6d^2/r$. At the paper's VOCASET width $d = 128$ with $r = 16$ that is about 6 k parameters,
# next to 66 k for one multi-head attention ($4(d^2 + d)$).

# %%
# NBVAL_CHECK_OUTPUT
d_paper = 128
table = [f"{'r':>4} {'hidden 2d/r':>11} {'FC1 params':>10} {'FC2 params':>10} {'total':>7} {'vs r=1':>7}"]
counts = {}
for r in (1, 2, 4, 8, 16, 32, 64, 256):
    m = SpeakerAwareGate(d_paper, reduction=r)
    h = m.fc1.out_features
    n_fc1, n_fc2 = sum(p.numel() for p in m.fc1.parameters()), sum(p.numel() for p in m.fc2.parameters())
    assert h == max(1, 2 * d_paper // r)
    assert (n_fc1, n_fc2) == (2 * d_paper * h + h, h * d_paper + d_paper)  # the formula above
    counts[r] = n_fc1 + n_fc2
    table.append(f"{r:>4} {h:>11} {n_fc1:>10} {n_fc2:>10} {counts[r]:>7} {counts[r] / counts[1]:>7.3f}")
print("\n".join(table))

# %% [markdown]
# What does the bottleneck cost in expressiveness? Before the sigmoid, the gate's logits are
# $W_2\,\mathrm{ReLU}(\cdot) + b_2$: whatever the speaker and the frame, the logit vector minus $b_2$ lies in the
# column space of $W_2$, a subspace of dimension at most $h = 2d/r$ of the $d$ channels. Stack the logits of many
# (speaker, frame) inputs and count the non-zero singular values: the rank is exactly $\min(h, d)$. With $r = 16$
# the 128 channel gates of VOCASET move in a 16-dimensional family.

# %%
z = torch.randn(1024, 2 * d_paper, generator=gen)  # 1024 random inputs [S_n; Y̌_t]
spectra, report = {}, []
for r in (1, 4, 16, 64):
    torch.manual_seed(4)
    m = SpeakerAwareGate(d_paper, reduction=r)
    with torch.no_grad():
        logits = m.fc2(torch.relu(m.fc1(z))) - m.fc2.bias  # (1024, d) pre-sigmoid gate, minus the bias
    h = m.fc1.out_features
    assert torch.linalg.matrix_rank(logits).item() == min(h, d_paper)
    spectra[r] = torch.linalg.svdvals(logits)
    report.append(f"r = {r:>2}: hidden h = {h:>3}, rank of the gate logits = {torch.linalg.matrix_rank(logits).item()}")
print("\n".join(report))

fig, ax = plt.subplots(figsize=(7, 3.6))
for r, s in spectra.items():
    ax.semilogy(np.arange(1, d_paper + 1), (s / s[0]).clamp(min=1e-10), label=f"r = {r} (h = {2 * d_paper // r})")
ax.set_xlabel("singular value index")
ax.set_ylabel("singular value / largest")
ax.set_title("Gate logits over 1024 inputs (d = 128): rank = min(2d/r, d)")
ax.legend(fontsize=8)
plt.show()

# %% [markdown]
# ## 5. A tiny experiment: two speakers who need different channel scalings
#
# Task: the input is a random feature sequence $\check{Y}$ ($d = 16$ channels) and a speaker $n \in \{0, 1\}$;
# the target is $c_n \odot \check{Y}_t$, where speaker 0 keeps the first 8 channels (x0.9) and damps the last 8
# (x0.2), and speaker 1 does the opposite. The style embeddings are fixed random vectors; we train only a
# `SpeakerAwareGate` (r = 4) followed by a linear head, with Adam, for 400 steps. A linear head alone (no gate)
# is the control: it cannot depend on the speaker, so its best possible answer is the average scaling
# 0.55 in every channel, i.e. a mean squared error of $0.35^2 \approx 0.1225$.

# %%
d5, n_spk, T5, B5, steps = 16, 2, 8, 64, 400
c_target = torch.tensor([[0.9] * 8 + [0.2] * 8, [0.2] * 8 + [0.9] * 8])  # (2, d) c_n
style5 = torch.randn(n_spk, d5, generator=gen)  # (2, d) fixed S_n


def batch(g: torch.Generator, c: torch.Tensor, styles: torch.Tensor):
    """Random features, speakers and targets c_n * Y̌ -> (features (B, T, d), style (B, d), target, speaker)."""
    feats = torch.randn(B5, T5, c.shape[1], generator=g)
    spk = torch.randint(len(c), (B5,), generator=g)
    return feats, styles[spk], c[spk][:, None, :] * feats, spk


# %%
def train(model_fn, params, c, styles, seed=0, n_steps=steps, lr=1e-2):
    """Adam on the mean squared error; returns the loss of every step."""
    g, opt, losses = torch.Generator().manual_seed(seed), torch.optim.Adam(params, lr=lr), []
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tensors this small: a second thread only adds synchronisation (30x slower on a busy CPU)
    try:
        for _ in range(n_steps):
            feats, s, target, _ = batch(g, c, styles)
            loss = F.mse_loss(model_fn(feats, s), target)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(loss.item())
    finally:
        torch.set_num_threads(threads)
    return np.array(losses)


# %% [markdown]
# Train the gate + head and the head-only control on the same batches (same seed), and compare their final losses.

# %%
torch.manual_seed(5)
gate5, head5 = SpeakerAwareGate(d5, reduction=4), nn.Linear(d5, d5)
loss_gate = train(lambda f, s: head5(gate5(f, s)), [*gate5.parameters(), *head5.parameters()], c_target, style5)
torch.manual_seed(5)
head_only = nn.Linear(d5, d5)
loss_head = train(lambda f, s: head_only(f), list(head_only.parameters()), c_target, style5)

final_gate, final_head = loss_gate[-20:].mean(), loss_head[-20:].mean()
print(f"MSE, first step -> mean of the last 20: gate + head {loss_gate[0]:.3f} -> {final_gate:.1e}; "
      f"head only {loss_head[0]:.3f} -> {final_head:.4f}")
assert final_gate < 0.05 * loss_gate[0]  # the loss falls
assert final_gate < 0.1 * final_head  # and far below what any speaker-agnostic model can reach
assert abs(final_head - 0.35 ** 2) < 0.02  # the control sits at its analytic optimum

# %% [markdown]
# Did the gate learn *the speakers' scalings*? Measure, on fresh data, the effective per-channel gain of each
# speaker, $\hat{c}_{n,k} = \sum_t \hat{y}_{t,k}\, \check{y}_{t,k} / \sum_t \check{y}_{t,k}^2$, and look at the mean
# gate itself: the two speakers open opposite halves of the channels.

# %%
with torch.no_grad():
    feats, s, target, spk = batch(torch.Generator().manual_seed(99), c_target, style5)
    pred = head5(gate5(feats, s))  # (B, T, d)
    gains = (pred * feats).sum(1) / feats.pow(2).sum(1)  # (B, d) effective gain per clip and channel
    c_hat = torch.stack([gains[spk == n].mean(0) for n in range(n_spk)])  # (2, d)
    g_learned = torch.stack([gate5.gate(feats[spk == n], s[spk == n]).mean((0, 1)) for n in range(n_spk)])
check_shape(c_hat, (n_spk, d5), "learned gains")
assert (c_hat - c_target).abs().max() < 0.1
# The gate itself separates the halves: speaker 0 opens channels 0-7 more than speaker 1 does, and vice versa.
assert (g_learned[0, :8] > g_learned[1, :8]).all() and (g_learned[1, 8:] > g_learned[0, 8:]).all()
print(f"max |ĉ - c| = {(c_hat - c_target).abs().max().item():.1e}")

# %%
fig = plt.figure(figsize=(13, 4.2), layout="constrained")
ax0, ax1, ax2 = fig.subplots(1, 3, width_ratios=[1.1, 1, 1])
ax0.semilogy(loss_gate, label="gate + linear head")
ax0.semilogy(loss_head, label="linear head only")
ax0.axhline(0.35 ** 2, color="gray", ls=":", label="best speaker-agnostic MSE")
ax0.set_xlabel("training step")
ax0.set_ylabel("mean squared error (a.u.)")
ax0.set_title("Training loss")
ax0.legend(fontsize=8)
for ax, mat, title in ((ax1, torch.cat([c_target, c_hat]), "target $c_n$ (rows 0-1) vs learned $\\hat{c}_n$ (rows 2-3)"),
                       (ax2, g_learned, "mean learned gate per speaker")):
    im = ax.imshow(mat, aspect="auto", cmap="viridis", vmin=0, vmax=1)
    ax.set_xlabel("channel")
    ax.set_title(title, fontsize=10)
    fig.colorbar(im, ax=ax, label="gain" if ax is ax1 else "gate value")
ax1.set_yticks(range(4), ["c, spk 0", "c, spk 1", "ĉ, spk 0", "ĉ, spk 1"])
ax2.set_yticks(range(2), ["speaker 0", "speaker 1"])
plt.show()

# %% [markdown]
# ## 6. $r$ against the number of speakers
#
# Section 4 showed that the gate logits live in an $h = 2d/r$-dimensional family (plus the bias $b_2$). With $N$
# speakers whose target scalings are generic, the $N$ per-speaker gate vectors span an $(N-1)$-dimensional affine
# family, so, roughly, a bottleneck with $h < N - 1$ cannot fit them all (the shared head cannot help: it is the
# same for every speaker). Same task with $N = 8$ speakers and random scalings in $[0.1, 0.9]$, $d = 16$, for
# three ratios ($h = 2, 8, 32$), 400 steps each.

# %%
n_many = 8
c_many = 0.1 + 0.8 * torch.rand(n_many, d5, generator=gen)  # (8, d) random target scalings
style_many = torch.randn(n_many, d5, generator=gen)
final, report = {}, []
for r in (16, 4, 1):
    torch.manual_seed(6)
    g_r, h_r = SpeakerAwareGate(d5, reduction=r), nn.Linear(d5, d5)
    losses = train(lambda f, s: h_r(g_r(f, s)), [*g_r.parameters(), *h_r.parameters()], c_many, style_many, seed=1)
    final[r] = losses[-20:].mean()
    report.append(f"r = {r:>2} (hidden h = {g_r.fc1.out_features:>2}): final MSE {final[r]:.4f}")
print("\n".join(report))
assert final[16] > 3 * final[4] and final[16] > 3 * final[1]  # h = 2 < N - 1 = 7: cannot separate 8 speakers

fig, ax = plt.subplots(figsize=(6, 3.5))
ax.bar([f"r={r}\nh={2 * d5 // r}" for r in final], list(final.values()))
ax.set_yscale("log")
ax.set_ylabel("final mean squared error (a.u.)")
ax.set_title("8 speakers, d = 16: a 2-unit bottleneck is too narrow")
plt.show()

# %% [markdown]
# ## Summary
#
# - SE recalibrates channels with a bottleneck MLP and a sigmoid. DualTalker's speaker-aware module replaces
#   SE's squeeze over time by the style $S_n$ concatenated to each frame, which keeps the gate causal.
# - Eq. 5, $\bar{Y} = \sigma(W_2\,\mathrm{ReLU}(W_1[S_n;\check{Y}]))\odot\check{Y}$, is exactly what
#   `SpeakerAwareGate` computes; the gate only attenuates ($0 < g < 1$).
# - Different style embeddings give different channel profiles for the same features; an untrained gate sits
#   near 0.5.
# - $r$ trades parameters ($\approx 6d^2/r$) for expressiveness: the gate logits have rank $2d/r$, and a gate
#   too narrow for the number of speakers cannot fit their scalings. A gate + shared linear head learns two
#   speakers' opposite scalings in a few hundred steps, where a speaker-agnostic head is stuck at the average.
#
# ## Exercises
#
# 1. Remove $S_n$ from the concatenation (feed zeros as the style) in section 5. What loss does the gate + head
#    reach, and why is it the same as the head alone?
# 2. Make speaker 1's target scaling 1.5 instead of 0.9 on its strong channels. The gate cannot exceed 1: which
#    parameters take up the slack, and does the loss still fall?
# 3. In section 6, find the smallest hidden size $h$ that fits $N = 8$ speakers (try $r = 8, 6, 5$). Does it
#    match the $h \ge N - 1$ argument?
# 4. Replace the per-frame gate by the SE-style clip gate of section 1 in the experiment of section 5. It learns
#    the task too: why is it nevertheless unusable in DualTalker's autoregressive decoder?
