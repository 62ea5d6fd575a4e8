# %% [markdown]
# # 03 · Attention: scaled dot-product, multi-head, FaceFormer's biases and the alignment mask
#
# DualTalker's cross-modal fusion (Fig. 2 of the paper) is built from one operation, the scaled dot-product
# attention of eq. 3, used three times: the *motion-attentive* self-attention over past motion (with
# FaceFormer's temporal bias), and the *audio-visual integration* between the audio features and the gated
# motion features (with an alignment mask). This notebook builds that operation up from a single matrix
# product and checks every step against the package (`dualtalker_lite.blocks`).
#
# **We will cover**
#
# 1. Scaled dot-product attention (eq. 3), re-derived from scratch and checked against the package and PyTorch.
# 2. Multi-head attention (eq. 4): heads are slices of the projection matrices.
# 3. FaceFormer's causal ALiBi bias with a period: the bias matrix and the attention maps it produces.
# 4. The periodic positional encoding (PPE): position modulo 30 frames.
# 5. No maximum length: bias, PPE and attention are built for any sequence length, and stay causal.
# 6. The audio-motion alignment mask: DualTalker's causal window and FaceFormer's diagonal.
# 7. Why `window=1` gives W_Q and W_K no gradient at all.
#
# | paper symbol | code name | shape |
# |---|---|---|
# | $\hat{Y}_{1:T}$ (temporally encoded motion stream) | `y_hat` | (B, T, d) |
# | $X_{1:T}$ (audio features) | `x` | (B, T, d) |
# | $Q, K, V$ (one head) | `q`, `k`, `v` | (B, H, T, d_h) |
# | $d_k$ (per-head width) | `d_h` = d / H | int |
# | $H$ (number of heads) | `n_heads` | int |
# | $W^Q, W^K, W^V$ (all heads stacked) | `mha.q_proj`, `mha.k_proj`, `mha.v_proj` | (d, d) |
# | $W^{\hat{Y}}$ (output projection, usually $W^O$) | `mha.out_proj` | (d, d) |
# | $\mathrm{softmax}(\cdot)$ (attention weights) | `weights` | (B, H, T_q, T_k) |
# | $m_h$ (ALiBi slope of head $h$) | `alibi_slopes(n_heads)` | (H,) |
# | $p$ (period, frames) | `period` | int (30) |
# | $B_h(i, j)$ (temporal bias) | `bias` | (1, H, T_q, T_k) |
# | alignment between modalities | `mask` (True = may attend) | (T_q, T_k) bool |

# %%
%matplotlib inline
import math

import matplotlib.pyplot as plt
from matplotlib.colors import LogNorm
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from dualtalker_lite.blocks import (DualIntegration, MultiHeadAttention, PeriodicPositionalEncoding,
                                    alibi_causal_bias, alibi_slopes, alignment_mask, scaled_dot_product_attention)
from dualtalker_lite.data import sample_path  # the shipped corpus (only used in the optional last cell)
from dualtalker_lite.checks import check_shape
from dualtalker_lite.seeding import set_seed

torch.set_num_threads(2)
gen = set_seed(0)  # seeds Python/NumPy/torch; `gen` draws every random tensor below
FPS = 30  # mesh frames per second (docs/design.md)

# %% [markdown]
# ## 1. Scaled dot-product attention (eq. 3)
#
# Every query vector is compared with every key vector by a dot product; a softmax over the keys turns the
# scores into weights that sum to one, and the output is the weighted average of the value vectors:
#
# $$\mathrm{Att}(Q^{\hat{Y}}, K^{\hat{Y}}, V^{\hat{Y}}) = \mathrm{softmax}\!\left(\frac{Q^{\hat{Y}} (K^{\hat{Y}})^{\top}}{\sqrt{d_k}}\right) V^{\hat{Y}} \tag{3}$$
#
# The package writes it out in `scaled_dot_product_attention(q, k, v, bias=None, mask=None)`, which also returns
# the weights (PyTorch's fused kernel does not). Below we re-derive it in one line and check it against both.

# %%
B, H, T, d_h = 2, 4, 12, 8
q, k, v = (torch.randn(B, H, T, d_h, generator=gen) for _ in range(3))  # (B, H, T, d_h)

weights_scratch = torch.softmax(q @ k.transpose(-2, -1) / math.sqrt(d_h), dim=-1)  # (B, H, T, T)
out_scratch = weights_scratch @ v  # (B, H, T, d_h)

out, weights = scaled_dot_product_attention(q, k, v)
check_shape(out, (B, H, T, d_h), "out")
check_shape(weights, (B, H, T, T), "weights")
torch.testing.assert_close(out, out_scratch)
torch.testing.assert_close(weights, weights_scratch)
torch.testing.assert_close(out, F.scaled_dot_product_attention(q, k, v))  # PyTorch's own kernel
torch.testing.assert_close(weights.sum(-1), torch.ones(B, H, T))  # each row is a distribution over keys

# A boolean mask is True where a query MAY attend (same convention as F.scaled_dot_product_attention).
causal = torch.ones(T, T, dtype=torch.bool).tril()  # (T, T)
out_c, weights_c = scaled_dot_product_attention(q, k, v, mask=causal)
torch.testing.assert_close(out_c, F.scaled_dot_product_attention(q, k, v, attn_mask=causal))
torch.testing.assert_close(out_c, F.scaled_dot_product_attention(q, k, v, is_causal=True))
assert (weights_c[..., ~causal] == 0).all()  # masked keys get exactly zero weight
print("eq. 3: package == from scratch == torch.nn.functional.scaled_dot_product_attention")

# %% [markdown]
# **Why divide by $\sqrt{d_k}$?** If the entries of $q$ and $k$ are independent with unit variance, $q\cdot k$
# is a sum of $d_k$ unit-variance terms, so its standard deviation grows like $\sqrt{d_k}$. Without the scale
# the softmax saturates as the heads get wider: each query puts almost all its weight on one key and the
# gradient through the softmax vanishes. Dividing by $\sqrt{d_k}$ keeps the scores at unit scale for any width.

# %%
widths = [4, 16, 64, 256]
rows = []
for dk in widths:
    qq, kk = torch.randn(1, 1, 64, dk, generator=gen), torch.randn(1, 1, 64, dk, generator=gen)
    raw = qq @ kk.transpose(-2, -1)  # (1, 1, 64, 64) unscaled scores
    rows.append((dk, raw.std().item(), (raw / math.sqrt(dk)).std().item(),
                 torch.softmax(raw, -1).max(-1).values.mean().item(),
                 torch.softmax(raw / math.sqrt(dk), -1).max(-1).values.mean().item()))
table = [f"{'d_k':>5} {'std raw':>8} {'std scaled':>10} {'max w raw':>10} {'max w scaled':>12}"]
for dk, s_raw, s_sc, w_raw, w_sc in rows:
    table.append(f"{dk:>5} {s_raw:>8.2f} {s_sc:>10.2f} {w_raw:>10.2f} {w_sc:>12.2f}")
    assert 0.7 < s_sc < 1.3  # scaled scores stay at unit scale
print("\n".join(table))
assert rows[-1][3] > 0.8 and rows[-1][4] < 0.2  # unscaled d_k=256: nearly one-hot; scaled: spread out
assert all(a[3] < b[3] for a, b in zip(rows, rows[1:]))  # saturation grows with the width

# %%
fig, ax = plt.subplots(figsize=(6, 3.5))
ax.plot(widths, [r[3] for r in rows], "o-", label=r"softmax($QK^\top$)")
ax.plot(widths, [r[4] for r in rows], "s-", label=r"softmax($QK^\top/\sqrt{d_k}$) (eq. 3)")
ax.axhline(1 / 64, color="gray", ls=":", label="uniform over 64 keys")
ax.set_xscale("log", base=2)
ax.set_xlabel("per-head width $d_k$ (channels)")
ax.set_ylabel("mean largest weight per query")
ax.set_title("Without the $1/\\sqrt{d_k}$ scale the softmax saturates")
ax.legend(fontsize=8)
plt.show()

# %% [markdown]
# ## 2. Multi-head attention (eq. 4)
#
# Instead of one attention in $d$ dimensions, $H$ attentions run in parallel in $d_k = d/H$-dimensional
# subspaces, each with its own projections, and their outputs are concatenated and projected back:
#
# $$\mathrm{MH}(Q^{\hat{Y}}, K^{\hat{Y}}, V^{\hat{Y}}) = \mathrm{Concat}(\mathrm{head}_1, \dots, \mathrm{head}_H)\, W^{\hat{Y}}, \quad
# \mathrm{head}_h = \mathrm{Att}(Q^{\hat{Y}}_h, K^{\hat{Y}}_h, V^{\hat{Y}}_h) \tag{4}$$
#
# In code the $H$ projections are one `nn.Linear(d, d)` each for Q, K and V: head $h$ uses rows
# $h d_k, \dots, (h+1) d_k - 1$ of the weight matrix. `MultiHeadAttention` (d = 32, H = 4 here; DualTalker uses
# H = 4 with d = 128) does the split with a reshape; the loop below does it by slicing, one head at a time.

# %%
d, n_heads = 32, 4
d_h = d // n_heads
torch.manual_seed(1)
mha = MultiHeadAttention(d, n_heads).eval()
y_hat = torch.randn(B, T, d, generator=gen)  # (B, T, d) a stand-in for the motion stream Ŷ

heads = []
for h in range(n_heads):
    rows_h = slice(h * d_h, (h + 1) * d_h)  # the rows of W^Q, W^K, W^V that belong to head h
    q_h, k_h, v_h = (F.linear(y_hat, p.weight[rows_h], p.bias[rows_h]) for p in (mha.q_proj, mha.k_proj, mha.v_proj))
    heads.append(torch.softmax(q_h @ k_h.transpose(-2, -1) / math.sqrt(d_h), -1) @ v_h)  # (B, T, d_h)
mh_scratch = mha.out_proj(torch.cat(heads, dim=-1))  # Concat(head_1..head_H) W^Ŷ -> (B, T, d)

mh, mh_weights = mha(y_hat, need_weights=True)  # self-attention: key = value = query
check_shape(mh, (B, T, d), "MH output")
check_shape(mh_weights, (B, n_heads, T, T), "per-head weights")
torch.testing.assert_close(mh, mh_scratch)
print("eq. 4: package == per-head loop;", sum(p.numel() for p in mha.parameters()), "parameters = 4 x (d*d + d)")
assert sum(p.numel() for p in mha.parameters()) == 4 * (d * d + d)

# %% [markdown]
# ## 3. FaceFormer's causal ALiBi bias with a period
#
# DualTalker's motion-attentive module is a *biased* self-attention (supplementary A), taken from FaceFormer:
# the motion stream is autoregressive, so frame $i$ may only look at frames $j \le i$, and older frames are
# penalised linearly (ALiBi, Press et al.), one step per period of $p$ frames. The bias is added to the scores
# of eq. 3 before the softmax:
#
# $$B_h(i, j) = \begin{cases} -m_h \left\lfloor \dfrac{i - j}{p} \right\rfloor & j \le i \\ -\infty & j > i \end{cases}
# \qquad \mathrm{softmax}\!\left(\frac{Q K^\top}{\sqrt{d_k}} + B_h\right) V$$
#
# with head slopes $m_h = 2^{-8h/H}$ (for $H = 4$: 1/4, 1/16, 1/64, 1/256) and $p = 30$ frames (one second at
# 30 fps). The paper has no number for this formula; it is FaceFormer's `init_biased_mask`. Each head gets a
# different slope, so some heads focus on the last second and others see the whole past almost uniformly.

# %%
# NBVAL_CHECK_OUTPUT
period, T_long = 30, 90  # three seconds of motion at 30 fps
slopes = alibi_slopes(n_heads)
assert slopes == [1 / 4, 1 / 16, 1 / 64, 1 / 256]

bias = alibi_causal_bias(n_heads, T_long, T_long, period=period)  # (1, H, T, T)
check_shape(bias, (1, n_heads, T_long, T_long), "bias")

# The formula, written out once more and compared with the package.
i, j = torch.arange(T_long)[:, None], torch.arange(T_long)[None, :]  # (T, 1), (1, T)
lag = (i - j).clamp(min=0)
bias_scratch = torch.stack([torch.where(j <= i, -m * (lag // period).float(), -math.inf) for m in slopes])[None]
torch.testing.assert_close(bias, bias_scratch)  # -inf entries must match too
assert (bias[torch.isfinite(bias)] <= 0).all()  # never a bonus, only penalties
assert torch.isinf(bias[0, :, 0, 1:]).all() and (bias[0, :, :, 0][:, :period] == 0).all()
print("head 1, query i=89, keys j = 89, 60, 59, 30, 29, 0:", [v + 0.0 for v in bias[0, 0, 89, [89, 60, 59, 30, 29, 0]].tolist()])

# %%
fig, axes = plt.subplots(1, n_heads, figsize=(13, 3.4), layout="constrained")
cmap = plt.get_cmap("viridis").copy()
cmap.set_bad("lightgray")  # -inf (future frames) drawn in grey
for h, ax in enumerate(axes):
    shown = bias[0, h].masked_fill(torch.isinf(bias[0, h]), float("nan"))
    im = ax.imshow(shown, cmap=cmap, vmin=-2 / 4, vmax=0)
    ax.set_title(f"head {h + 1}: $m_h$ = 1/{round(1 / slopes[h])}")
    ax.set_xlabel("key frame j")
axes[0].set_ylabel("query frame i")
fig.colorbar(im, ax=axes, shrink=0.8, label="bias $B_h(i, j)$ (grey: $-\\infty$)")
fig.suptitle("FaceFormer's causal ALiBi bias, period p = 30 frames (the colour scale is clipped at head 1's range)")
plt.show()

# %% [markdown]
# What does the bias do to the weights? With content-free scores ($QK^\top = 0$) the weights of a query are the
# softmax of its bias row alone: flat within each period and dropping by a factor $e^{-m_h}$ per period. Head 1
# ($m = 1/4$) prefers the last second; head 4 ($m = 1/256$) is almost a uniform average over the past.

# %%
only_bias = torch.softmax(bias[0, :, T_long - 1], dim=-1)  # (H, T) weights of the last query, zero content
fig, ax = plt.subplots(figsize=(7, 3.5))
for h in range(n_heads):
    ax.plot(np.arange(T_long) / FPS, only_bias[h], label=f"head {h + 1}, $m_h$ = 1/{round(1 / slopes[h])}")
ax.set_xlabel("key time j / fps (s); the query is the last frame, t = 2.97 s")
ax.set_ylabel("attention weight")
ax.set_title("Weights from the bias alone ($QK^T = 0$): one step per 30-frame period")
ax.legend(fontsize=8)
plt.show()
ratio = only_bias[0, T_long - 1] / only_bias[0, T_long - 1 - period]
torch.testing.assert_close(ratio, torch.tensor(math.exp(1 / 4)))  # one period older -> weight x e^{-m}

# %% [markdown]
# Now a real causal self-attention: the package's `MultiHeadAttention` on a (random, seeded) motion stream with
# the bias. Each head has its own map; all are lower-triangular (causal). We also check the package against
# `torch.nn.MultiheadAttention` with the same weights — whose float `attn_mask` is exactly such an additive bias
# (careful: its *boolean* masks mean "True = may NOT attend", the opposite of the package's convention).

# %%
y_long = torch.randn(1, T_long, d, generator=gen)  # (1, T, d)
sa, sa_weights = mha(y_long, bias=bias, need_weights=True)
check_shape(sa, (1, T_long, d), "self-attention output")
check_shape(sa_weights, (1, n_heads, T_long, T_long), "self-attention weights")
assert (sa_weights[0][:, ~torch.ones(T_long, T_long, dtype=torch.bool).tril()] == 0).all()  # causal
torch.testing.assert_close(sa_weights.sum(-1), torch.ones(1, n_heads, T_long))

ref = nn.MultiheadAttention(d, n_heads, batch_first=True).eval()
with torch.no_grad():  # copy W^Q, W^K, W^V (stacked as in_proj) and W^O into the reference
    ref.in_proj_weight.copy_(torch.cat([mha.q_proj.weight, mha.k_proj.weight, mha.v_proj.weight]))
    ref.in_proj_bias.copy_(torch.cat([mha.q_proj.bias, mha.k_proj.bias, mha.v_proj.bias]))
    ref.out_proj.weight.copy_(mha.out_proj.weight)
    ref.out_proj.bias.copy_(mha.out_proj.bias)
    ref_out, ref_weights = ref(y_long, y_long, y_long, attn_mask=bias[0], need_weights=True,
                               average_attn_weights=False)  # float (H, T, T) mask: added to the scores
torch.testing.assert_close(sa, ref_out)
torch.testing.assert_close(sa_weights, ref_weights)
print("biased causal self-attention: package == torch.nn.MultiheadAttention")

# %%
# A query at frame i has i + 1 admissible keys; multiplying by i + 1 shows each weight relative to a uniform
# average (1 = uniform), so rows of different lengths share one colour scale.
relative = (sa_weights[0] * torch.arange(1, T_long + 1)[:, None]).detach()  # (H, T, T)
relative = relative.masked_fill(~torch.ones(T_long, T_long, dtype=torch.bool).tril(), float("nan"))
fig, axes = plt.subplots(1, n_heads, figsize=(13, 3.4), layout="constrained")
cmap_rel = plt.get_cmap("RdBu_r").copy()
cmap_rel.set_bad("lightgray")
for h, ax in enumerate(axes):
    im = ax.imshow(relative[h], cmap=cmap_rel, norm=LogNorm(1 / 3, 3))
    ax.set_title(f"head {h + 1}: $m_h$ = 1/{round(1 / slopes[h])}")
    ax.set_xlabel("key frame j")
axes[0].set_ylabel("query frame i")
fig.colorbar(im, ax=axes, shrink=0.8, label="weight x (i + 1)  (1 = uniform; log scale)")
fig.suptitle("Causal self-attention with the ALiBi bias (random weights and input): weights per head, grey = future")
plt.show()

# %% [markdown]
# ## 4. Periodic positional encoding (PPE)
#
# Attention itself is blind to order: permuting the frames permutes the outputs. FaceFormer (and DualTalker's
# "temporally encoded" $\hat{Y}_{1:T}$) therefore adds a sinusoidal encoding of the frame index, but of the
# index *modulo the period* $p$, so the encoding repeats every second and never runs out:
#
# $$\mathrm{PPE}(t, 2i) = \sin\!\left(\frac{t \bmod p}{10000^{2i/d}}\right), \qquad
# \mathrm{PPE}(t, 2i+1) = \cos\!\left(\frac{t \bmod p}{10000^{2i/d}}\right), \qquad \hat{Y}_t = Y_t + \mathrm{PPE}(t)$$
#
# Absolute time beyond one period comes from the bias of section 3, which counts periods.

# %%
ppe = PeriodicPositionalEncoding(d, period=period)
pe = ppe.encoding(4 * period)  # (T, d) for t = 0..119
check_shape(pe, (4 * period, d), "PPE")

t = torch.arange(4 * period, dtype=torch.float32)[:, None] % period  # (T, 1) position mod p
freq = 10000.0 ** (-torch.arange(0, d, 2, dtype=torch.float32) / d)  # (d/2,) 1/10000^{2i/d}
pe_scratch = torch.stack([torch.sin(t * freq), torch.cos(t * freq)], dim=-1).flatten(1)  # interleave sin, cos
torch.testing.assert_close(pe, pe_scratch)
torch.testing.assert_close(pe[period:2 * period], pe[:period])  # periodic with period p
torch.testing.assert_close(ppe(y_long) - y_long, pe[:T_long][None])  # the module adds it to the stream
assert not torch.allclose(pe[1], pe[0])  # but distinct within a period

# %%
fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 3.6), layout="constrained")
im = ax0.imshow(pe.T, aspect="auto", cmap="RdBu_r", vmin=-1, vmax=1)
for s in range(1, 4):
    ax0.axvline(s * period - 0.5, color="k", lw=1)
ax0.set_xlabel("frame t (30 fps); black lines every p = 30 frames")
ax0.set_ylabel("channel")
ax0.set_title("PPE(t): the pattern repeats every period")
fig.colorbar(im, ax=ax0, label="value")
for c in (4, 8, 12):
    ax1.plot(np.arange(4 * period) / FPS, pe[:, c], label=f"channel {c}")
ax1.set_xlabel("time t / fps (s)")
ax1.set_ylabel("PPE value")
ax1.set_title("Slow channels jump back every 1 s (frame 30 = frame 0)")
ax1.legend(fontsize=8)
plt.show()

# %% [markdown]
# ## 5. Any length works: no maximum sequence length
#
# A learned position table, or a bias matrix precomputed up to `max_seq_len` (FaceFormer's code uses 600 frames),
# limits the clip length. The package computes the bias and the encoding for the requested size on the fly, so
# any length works, and a shorter sequence sees exactly the top-left corner of a longer one's bias. The
# attention also stays causal: changing future frames never changes the output of past frames.

# %%
for length in (1, 7, 301, 1250):  # 1250 frames = 41.7 s, far beyond FaceFormer's 600-frame table
    stream = ppe(torch.randn(1, length, d, generator=gen))  # Ŷ = Y + PPE
    b = alibi_causal_bias(n_heads, length, length, period=period)
    o, _ = mha(stream, bias=b)
    check_shape(o, (1, length, d), f"output for T={length}")
    assert torch.isfinite(o).all()
print("self-attention with bias and PPE ran for T = 1, 7, 301 and 1250 frames")

torch.testing.assert_close(alibi_causal_bias(n_heads, 301, 301)[..., :90, :90], bias)  # corner = shorter bias
torch.testing.assert_close(alibi_causal_bias(n_heads, 1, 90, offset=89)[0, :, 0], bias[0, :, 89])  # one step

future_changed = y_long.clone()
future_changed[:, 60:] = torch.randn(1, T_long - 60, d, generator=gen)  # rewrite frames 60..89
o_a, _ = mha(y_long, bias=bias)
o_b, _ = mha(future_changed, bias=bias)
torch.testing.assert_close(o_a[:, :60], o_b[:, :60])  # frames 0..59 did not notice
assert not torch.allclose(o_a[:, 60:], o_b[:, 60:])
print("causal: outputs of frames 0..59 unchanged when frames 60..89 change")

# %% [markdown]
# ## 6. The audio-motion alignment mask
#
# The audio-visual integration (eq. 6) is a *cross*-attention between the audio features $X_{1:T}$ and the
# speaker-gated motion features $\bar{Y}_{1:T}$:
#
# $$\mathrm{Att}(Q^X, K^{\bar{Y}}, V^{\bar{Y}}) = \mathrm{softmax}\!\left(\frac{Q^X (K^{\bar{Y}})^\top}{\sqrt{d_k}}\right) V^{\bar{Y}} \tag{6}$$
#
# Which audio frame may talk to which motion frame is set by a boolean alignment mask (True = may attend):
#
# - **DualTalker, as the paper reads** (`mode="causal"`, the package default with `window=2`): queries come from
#   the audio $X$, keys/values from the autoregressive $\bar{Y}$. $\bar{Y}_j$ is built from motion frames
#   before $j$, so audio frame $i$ may read $\bar{Y}_j$ for $j \in [i - w + 1, i]$ — a causal window of $w$ frames.
# - **FaceFormer** (VOCASET): the diagonal, frame $i$ with frame $i$ only (`window=1`, identical in both modes).
# - FaceFormer's direction with a wider window (`mode="centred"`): keys come from the fully known modality,
#   so the window may look ahead, $j - i \in [-\lfloor (w-1)/2 \rfloor, \lfloor w/2 \rfloor]$.

# %%
T_a = 10
masks = {"FaceFormer diagonal\n(window=1)": alignment_mask(T_a, T_a, 1),
         "DualTalker causal\n(window=2, default)": alignment_mask(T_a, T_a, 2, mode="causal"),
         "causal, window=4": alignment_mask(T_a, T_a, 4, mode="causal"),
         "centred, window=3\n(FaceFormer direction)": alignment_mask(T_a, T_a, 3, mode="centred")}
for m in masks.values():
    check_shape(m, (T_a, T_a), "alignment mask")
    assert m.dtype == torch.bool
assert torch.equal(masks["FaceFormer diagonal\n(window=1)"], torch.eye(T_a, dtype=torch.bool))
causal2 = masks["DualTalker causal\n(window=2, default)"]
assert causal2.sum(1).tolist() == [1] + [2] * (T_a - 1)  # frame 0 has only itself, others {i-1, i}
assert not causal2.triu(1).any()  # never a future motion frame
assert torch.equal(DualIntegration(d, n_heads).alignment(T_a, T_a), causal2)  # what the model uses

fig, axes = plt.subplots(1, 4, figsize=(13, 3.6), layout="constrained")
for ax, (name, m) in zip(axes, masks.items()):
    ax.imshow(m, cmap="Greys", vmin=0, vmax=1)
    ax.set_title(name, fontsize=10)
    ax.set_xlabel("key frame j (motion $\\bar{Y}$)")
axes[0].set_ylabel("query frame i (audio $X$)")
fig.suptitle("Alignment masks (black = may attend)")
plt.show()

# %% [markdown]
# ## 7. Why `window=1` gives W_Q and W_K no gradient
#
# With the diagonal mask each query has exactly one admissible key, so the softmax is over a single score and
# equals 1 *whatever the score is*: $\mathrm{softmax}(s) = e^s / e^s = 1$, $\partial/\partial s = 0$. The output
# is then just $V_i W^O$, the queries and keys never influence anything, and $W^Q$, $W^K$ get an exactly zero
# gradient — they are dead parameters. (The same happens in FaceFormer: with its diagonal mask the
# cross-attention reduces to a per-frame value projection, and its W_Q/W_K never leave their initial values.)
# With `window=2` each query chooses between two frames and the gradient flows.
# DualTalker ties $W^Q$/$W^K$ across the two tasks (Fig. 3), which only makes sense if they learn, hence the
# package's default `window=2`.

# %%
x = torch.randn(B, T, d, generator=gen)  # (B, T, d) audio features X (queries)
y_bar = torch.randn(B, T, d, generator=gen)  # (B, T, d) gated motion Ȳ (keys and values)
grad_norm = {}
for window in (1, 2):
    torch.manual_seed(2)
    att = MultiHeadAttention(d, n_heads)
    o, _ = att(x, y_bar, mask=alignment_mask(T, T, window))
    o.pow(2).mean().backward()
    grad_norm[window] = {name: getattr(att, name).weight.grad.norm().item()
                         for name in ("q_proj", "k_proj", "v_proj", "out_proj")}
    if window == 1:  # exactly zero, not merely small, for W^Q and W^K (and their biases)
        assert (att.q_proj.weight.grad == 0).all() and (att.k_proj.weight.grad == 0).all()
        assert (att.q_proj.bias.grad == 0).all() and (att.k_proj.bias.grad == 0).all()
assert all(g > 0 for g in grad_norm[2].values()) and grad_norm[1]["v_proj"] > 0

# %%
# The same with the model's own integration module (shared projections of Fig. 3), primal direction (eq. 6).
for window in (1, 2):
    torch.manual_seed(2)
    integ = DualIntegration(d, n_heads, window=window)
    o, w_int = integ(*integ.route(x, y_bar), "primal")
    check_shape(w_int, (B, n_heads, T, T), "integration weights")
    o.pow(2).mean().backward()
    shared = torch.cat([integ.proj_audio.weight.grad.flatten(), integ.proj_motion.weight.grad.flatten()])
    assert (shared == 0).all() if window == 1 else (shared != 0).any()
    if window == 1:
        assert (w_int[..., torch.eye(T, dtype=torch.bool)] == 1).all()  # every weight is exactly 1

# %%
# NBVAL_CHECK_OUTPUT
table = [f"{'window':>6} {'W^Q grad = 0':>13} {'W^K grad = 0':>13} {'W^V grad = 0':>13}"]
for window in (1, 2):
    g = grad_norm[window]
    table.append(f"{window:>6} {str(g['q_proj'] == 0):>13} {str(g['k_proj'] == 0):>13} {str(g['v_proj'] == 0):>13}")
print("\n".join(table))

# %%
fig, ax = plt.subplots(figsize=(6.5, 3.5))
names = ["q_proj", "k_proj", "v_proj", "out_proj"]
pos = np.arange(len(names))
for off, window in ((-0.2, 1), (0.2, 2)):
    ax.bar(pos + off, [grad_norm[window][n] for n in names], width=0.4, label=f"window={window}")
ax.set_xticks(pos, ["$W^Q$", "$W^K$", "$W^V$", "$W^O$"])
ax.set_ylabel("gradient norm ||dL/dW|| (a.u.)")
for p_i in range(2):  # the window=1 bars of W^Q and W^K have zero height
    ax.text(p_i - 0.2, 0.003, "exactly 0", ha="center", va="bottom", rotation=90, fontsize=8)
ax.set_title("Cross-attention with the alignment mask: window=1 freezes $W^Q$, $W^K$")
ax.legend()
plt.show()

# %% [markdown]
# ## 8. Optional: the clip lengths of the shipped corpus
#
# If the shipped corpus `data_samples/` is present, the cell below builds the bias for its longest clip — no
# change is needed for any length. It is skipped (with a message) when the sample has not been generated.

# %%
try:
    from dualtalker_lite.data.corpus import Corpus

    corpus = Corpus(sample_path())
    lengths = [corpus.meta(c)["n_frames"] for c in corpus.clips]
    longest = max(lengths)
    b = alibi_causal_bias(n_heads, longest, longest, period=period)
    check_shape(b, (1, n_heads, longest, longest), "bias of the longest clip")
    print(f"{len(lengths)} clips, {min(lengths)}..{longest} frames ({longest / corpus.fps:.1f} s); "
          f"bias for the longest clip: {tuple(b.shape)}")
except FileNotFoundError as err:
    print("shipped corpus not available:", err)

# %% [markdown]
# ## Summary
#
# - Eq. 3 is `softmax(q k^T / sqrt(d_k)) v`; the package's `scaled_dot_product_attention` equals a one-line
#   re-derivation and PyTorch's kernel, and also returns the weights. The $1/\sqrt{d_k}$ keeps scores at unit
#   scale so the softmax does not saturate for wide heads.
# - Eq. 4 runs $H$ such attentions on slices of $W^Q, W^K, W^V$ and mixes them with $W^{\hat{Y}}$.
# - FaceFormer's bias $B_h(i,j) = -m_h\lfloor (i-j)/p \rfloor$ (and $-\infty$ for the future) makes the motion
#   self-attention causal and gives each head its own memory span; the PPE encodes position within a 30-frame
#   period. Both are computed for any length: there is no maximum clip length.
# - The alignment mask decides which audio frame meets which motion frame: FaceFormer's diagonal, or
#   DualTalker's causal window. With a one-frame window the softmax is constant, so $W^Q$ and $W^K$ receive
#   exactly zero gradient; `window=2` is the smallest window in which they learn.
#
# ## Exercises
#
# 1. Replace the ALiBi bias in section 3 by a plain causal mask (`mask=torch.ones(T, T).tril().bool()`). Which
#    head's attention map changes the most? Relate your answer to the slopes $m_h$.
# 2. For $H = 6$ heads, `alibi_slopes` does not return $2^{-8h/6}$. Print the slopes and explain ALiBi's rule
#    for non-powers of two (see the docstring of `alibi_slopes`).
# 3. Two frames exactly one period apart have the same PPE. Show that the self-attention of section 3 can
#    still tell frame 5 from frame 35 when both are queries (hint: look at the bias rows 5 and 35).
# 4. Repeat section 7 with `mode="centred"` and `window=2`. Do $W^Q$/$W^K$ get a gradient? What about the
#    first query row of `mode="causal"`, `window=2`, which has a single admissible key?
