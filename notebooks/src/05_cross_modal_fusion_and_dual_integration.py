# %% [markdown]
# # 05 · Cross-modal fusion and its dual form (Fig. 2, Fig. 3, eqs. 5-7)
#
# DualTalker predicts each motion frame from the speech and the motion predicted so far (the **primal task**,
# facial animation) and, at training time, each audio frame from the motion and the audio so far (the **dual
# task**, lip reading). Both tasks run through the same kind of *cross-modal fusion* (Fig. 2 of the paper), and
# the two audio-visual integration modules are tied together by sharing their query/key projections (Fig. 3).
#
# **We will cover**
#
# 1. a small batch and the inputs of the fusion: $X$, $Y$, $S_n$ and the shifted stream $\hat Y$;
# 2. Fig. 2 piece by piece: motion-attentive self-attention (eqs. 3-4) → speaker-aware gate (eq. 5) →
#    audio-visual integration (eq. 6) → feed-forward, checked against the package and the full model;
# 3. Fig. 3: the dual form (eq. 7), where the queries come from the motion and the keys/values from the audio stream;
# 4. the weight sharing $W_{Q_X} = W_{K_{\bar X}}$, $W_{Q_Y} = W_{K_{\bar Y}}$: same tensors, gradients from each
#    task alone, transposed attention logits;
# 5. the paper's reading of eq. 6 versus FaceFormer's, with attention heatmaps;
# 6. where the parameters of the tiny model are.
#
# Everything is imported from `dualtalker_lite`; the notebook only wires the package's modules together and
# checks them.

# %%
%matplotlib inline
import math

import matplotlib.pyplot as plt
import torch

from dualtalker_lite.blocks.attention import merge_heads, split_heads
from dualtalker_lite.blocks.positional import alibi_causal_bias, alibi_slopes, alignment_mask
from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.dataset import TalkingFaceDataset, collate
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.checks import check_shape
from dualtalker_lite.seeding import set_seed

torch.set_num_threads(2)
_ = set_seed(0)  # (it also returns a seeded generator, not needed here)

# %% [markdown]
# ## Symbols
#
# | paper symbol | code name | shape |
# |---|---|---|
# | $A_{1:T}$ (log-mel per mesh frame) | `batch["audio"]` | (B, T, 160) |
# | $M_{1:T}$ (motion = vertices − template) | `motion` | (B, T, V·3) |
# | $X_{1:T}$ (audio encoder features) | `x` | (B, T, d) |
# | $Y_{1:T}$ (motion encoder features) | `y` | (B, T, d) |
# | $S_n$ (speaker style embedding) | `style` | (B, d) |
# | $\hat Y_{1:T}$ (past motion, shifted, + PPE) | `stream` | (B, T, d) |
# | $\check Y_{1:T}$ (after the motion-attentive module) | `attended` | (B, T, d) |
# | $\bar Y_{1:T}$ (after the speaker-aware gate) | `gated` | (B, T, d) |
# | $\breve Y_{1:T}$ (fused feature of the primal task) | `y_fused` | (B, T, d) |
# | $\hat X, \check X, \bar X, \breve X$ (the same for the dual task) | `stream_a`, `attended_a`, `gated_a`, `x_fused` | (B, T, d) |
# | $Q^X, K^{\bar Y}, V^{\bar Y}$ (per head) | `q`, `k`, `v` | (B, H, T, d/H) |
# | $W_{Q_X} = W_{K_{\bar X}}$ | `integ.proj_audio` | weight (d, d) |
# | $W_{Q_Y} = W_{K_{\bar Y}}$ | `integ.proj_motion` | weight (d, d) |
# | attention weights $\mathrm{softmax}(\cdot)$ | `alpha`, `w_int` | (B, H, T, T) |
#
# $B$ clips, $T$ mesh frames (30 fps), $d$ = `d_model`, $H$ heads. In the paper the audio runs at its own rate
# $T'$; here the audio features are already resampled to the mesh rate, so $T' = T$.

# %% [markdown]
# ## 1. A small batch and the inputs of the fusion
#
# Two validation clips of two different speakers, cropped to 36 frames (1.2 s), and an untrained tiny DualTalker
# sized for the shipped corpus. Untrained weights are enough here: this notebook is about *structure* (which
# tensor feeds which projection), not about what a trained model has learnt.

# %%
corpus = Corpus(sample_path())
val = TalkingFaceDataset(corpus, "val", max_frames=36)
speakers = [val[i]["speaker"] for i in range(len(val))]
picks = [0, next(i for i, s in enumerate(speakers) if s != speakers[0])]  # two different speakers
batch = collate([val[i] for i in picks])
B, T = batch["audio"].shape[:2]
V3 = batch["vertices"].shape[-1]
assert (B, T) == (2, 36) and bool(batch["mask"].all()), "both crops must be 36 valid frames"
assert batch["speaker"][0] != batch["speaker"][1]

cfg = DualTalkerConfig.tiny(n_vertices=V3 // 3, n_speakers=len(corpus.train_speakers))
model = DualTalker(cfg).eval()
H, d = cfg.n_heads, cfg.d_model
print(f"batch: {batch['name']}, T = {T} frames; d = {d}, H = {H}, window = {cfg.align_window}")

# %% [markdown]
# The fusion consumes three things (Fig. 1): the audio features $X$ (audio feature extractor + audio encoder), the
# motion features $Y = \mathrm{Me}(M)$ (motion encoder; the package feeds it the motion in mm) and the speaker's style
# vector $S_n$. The *autoregressive
# stream* $\hat Y$ is the past: the start token $S_n$ followed by $Y_1, \dots, Y_{T-1}$, plus FaceFormer's periodic
# positional encoding (PPE). Its row $t$ therefore only knows motion frames $< t$.

# %%
with torch.no_grad():
    motion = batch["vertices"] - batch["template"][:, None, :]  # M_{1:T}
    x = model.encode_audio(batch["audio"], batch["mask"])  # X_{1:T}
    y = model.decoder.encode_motion(motion)  # Y_{1:T} = Me(M), with M in mm inside the network
    style = model.decoder.speaker_style(batch["speaker"])  # S_n
    stream = model.decoder.ppe(torch.cat([style[:, None, :], y[:, :-1]], dim=1))  # Ŷ: [S_n, Y_1..Y_{T-1}] + PPE

check_shape(motion, (B, T, V3), "M")
check_shape(x, (B, T, d), "X")
check_shape(y, (B, T, d), "Y")
check_shape(style, (B, d), "S_n")
check_shape(stream, (B, T, d), "Ŷ")
torch.testing.assert_close(stream, model.decoder.ppe(model.decoder.stream(y, style)))  # the model's own shift
torch.testing.assert_close(stream[:, 0], style + model.decoder.ppe.encoding(1)[0])  # frame 0 = S_n (+ PPE of t=0)

# %% [markdown]
# ## 2. Fig. 2, the primal task's fusion, piece by piece
#
# One `DualFusionLayer` holds the task-specific parts of both tasks: `layer.primal`, `layer.dual` (each FaceFormer's
# decoder layer, `FaceFormerLayer`, without a cross-attention of its own: self-attention, layer norms, FF), the
# speaker-aware gates `layer.primal_gate`, `layer.dual_gate`, and **one** `DualIntegration` shared by both tasks.
#
# ### 2.1 Motion-attentive module (eqs. 3-4)
#
# Multi-head self-attention over the stream, with FaceFormer's causal ALiBi bias $B_h(i,j)$ (not in the paper's
# eq. 3, but the supplementary material calls these layers "biased"), then residual + LayerNorm:
#
# $$\mathrm{Att}(Q^{\hat Y}, K^{\hat Y}, V^{\hat Y}) = \mathrm{softmax}\Big(\frac{Q^{\hat Y} (K^{\hat Y})^\top}{\sqrt{d_k}} + B\Big) V^{\hat Y} \tag{3}$$
# $$\mathrm{MH}(Q^{\hat Y}, K^{\hat Y}, V^{\hat Y}) = \mathrm{Concat}(\mathrm{head}_1, \dots, \mathrm{head}_H)\, W^{\hat Y},
#   \qquad \check Y = \mathrm{LN}(\hat Y + \mathrm{MH}(\hat Y, \hat Y, \hat Y)) \tag{4}$$
#
# $B_h(i, j) = -m_h \lfloor (i-j)/p \rfloor$ for $j \le i$ and $-\infty$ for $j > i$ (period $p$ = 30 frames).

# %%
layer = model.decoder.layers[0]
fusion, gate, integ = layer.primal, layer.primal_gate, layer.integration
with torch.no_grad():
    bias = alibi_causal_bias(H, T, T, cfg.period)  # (1, H, T, T)
    sa, w_self = fusion.self_attn(stream, bias=bias, need_weights=True)  # eqs. 3-4
    attended = fusion.norm1(stream + sa)  # Y̌

check_shape(bias, (1, H, T, T), "ALiBi bias")
check_shape(w_self, (B, H, T, T), "self-attention weights")
check_shape(attended, (B, T, d), "Y̌")
assert torch.all(w_self.triu(1) == 0), "frame i must not attend to a later frame j > i"
torch.testing.assert_close(w_self.sum(-1), torch.ones(B, H, T))
assert bias[0, 0, T - 1, 0] == -alibi_slopes(H)[0] * ((T - 1) // cfg.period)  # lag 35 frames: one period

# %%
fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), constrained_layout=True)
b_img = bias[0, 0].clone()
b_img[torch.isinf(b_img)] = float("nan")
im = axes[0].imshow(b_img, cmap="viridis")
axes[0].set_title("ALiBi bias, head 1 (white = $-\\infty$)")
fig.colorbar(im, ax=axes[0], shrink=0.8, label="bias (logit units)")
for ax, h in zip(axes[1:], (0, H - 1)):
    im = ax.imshow(w_self[0, h], cmap="magma", vmin=0)
    ax.set_title(f"self-attention weights, head {h + 1}")
    fig.colorbar(im, ax=ax, shrink=0.8, label="weight")
for ax in axes:
    ax.set_xlabel("key frame j (stream $\\hat Y$)")
    ax.set_ylabel("query frame i (stream $\\hat Y$)")
plt.show()

# %% [markdown]
# ### 2.2 Speaker-aware module (eq. 5)
#
# A squeeze-and-excitation gate whose MLP also sees the style vector; it scales every channel of every frame
# by a number in $(0, 1)$ that depends on the speaker:
#
# $$\bar Y_{1:T} = \mathrm{MLP}(\mathrm{Concat}(S_n, \check Y_{1:T})) \cdot \check Y_{1:T},\qquad
#   \mathrm{MLP} = \mathrm{FC}_{2d \to 2d/r} \to \mathrm{ReLU} \to \mathrm{FC}_{2d/r \to d} \to \sigma \tag{5}$$

# %%
with torch.no_grad():
    g = gate.gate(attended, style)  # MLP(Concat(S_n, Y̌)) in (0, 1)
    gated = g * attended  # Ȳ
    g_swapped = gate.gate(attended, style.flip(0))  # the same frames, the other clip's speaker

check_shape(g, (B, T, d), "gate")
check_shape(gated, (B, T, d), "Ȳ")
assert gate.fc1.out_features == 2 * d // cfg.gate_reduction  # 2d/r hidden channels
assert bool(((g > 0) & (g < 1)).all())
torch.testing.assert_close(gated, gate(attended, style))
change = (g - g_swapped).abs().mean().item()
assert change > 1e-3, "the gate must depend on the speaker"
print(f"mean |gate(S_n) - gate(S_other)| = {change:.3f} (same frames, swapped style)")

# %%
fig, axes = plt.subplots(1, 2, figsize=(11, 3.4), constrained_layout=True, sharey=True)
for b, ax in enumerate(axes):
    im = ax.imshow(g[b].T, aspect="auto", cmap="coolwarm", vmin=0, vmax=1, extent=(0, T / 30, d - 0.5, -0.5))
    ax.set_title(f"speaker-aware gate, clip {batch['name'][b]}")
    ax.set_xlabel("time (s)")
axes[0].set_ylabel("channel of the attended features")
fig.colorbar(im, ax=axes, shrink=0.8, label="gate value (unitless, 0..1)")
plt.show()

# %% [markdown]
# Untrained, the gate sits around 0.5, with a channel pattern that differs between the two speakers. The change at
# 1.0 s is frame 30, where ALiBi's first period penalty starts (previous figure): from there on the oldest keys,
# first of all the start token $S_n$, get less attention, so $\check Y$, and with it the gate, shifts. (The self-attention weights above are nearly
# uniform over the past: an untrained model has no preference yet.)

# %% [markdown]
# ### 2.3 Audio-visual integration (eq. 6)
#
# The text of section III-B: "$\bar Y$ is transformed into keys $K^{\bar Y}$ and values $V^{\bar Y}$, while $X$ is
# converted into query vectors $Q^X$":
#
# $$\mathrm{Att}(Q^X, K^{\bar Y}, V^{\bar Y}) = \mathrm{softmax}\Big(\frac{Q^X (K^{\bar Y})^\top}{\sqrt{d_k}}\Big)
#   V^{\bar Y} \tag{6}$$
#
# with $Q^X = X W_{Q_X}$, $K^{\bar Y} = \bar Y W_{K_{\bar Y}}$, $V^{\bar Y} = \bar Y W_{V_{\bar Y}}$, extended to $H$
# heads as in eq. 4. $\bar Y_j$ only knows motion frames $< j$, so the audio frame $t$ may look at $\bar Y_j$ for
# $j \in [t - w + 1, t]$, a causal window of $w$ = `align_window` frames (section 5 explains why $w \ge 2$).
# `integ.route` picks the query and key/value inputs, `integ.projections` the four linear maps. We recompute
# eq. 6 from those maps and compare with the module.

# %%
query, key_value = integ.route(x, gated)  # paper's reading: queries from X, keys/values from Ȳ
W_Q, W_K, W_V, W_O = integ.projections("primal")
assert torch.equal(query, x) and torch.equal(key_value, gated)
assert W_Q is integ.proj_audio and W_K is integ.proj_motion  # W_{Q_X}, W_{K_Ȳ}

with torch.no_grad():
    q, k, v = split_heads(W_Q(query), H), split_heads(W_K(key_value), H), split_heads(W_V(key_value), H)
    allowed = integ.alignment(T, T)  # (T, T) causal window over Ȳ
    scores = (q @ k.transpose(-2, -1) / math.sqrt(d // H)).masked_fill(~allowed, float("-inf"))
    alpha = scores.softmax(dim=-1)  # (B, H, T, T)
    att_scratch = W_O(merge_heads(alpha @ v))  # (B, T, d)
    att, w_int = integ(query, key_value, "primal")  # the package

check_shape(q, (B, H, T, d // H), "Q^X")
check_shape(k, (B, H, T, d // H), "K^Ȳ")
check_shape(alpha, (B, H, T, T), "attention weights")
check_shape(att, (B, T, d), "integration output")
torch.testing.assert_close(att_scratch, att)
torch.testing.assert_close(alpha, w_int)
assert torch.equal(allowed, alignment_mask(T, T, cfg.align_window, mode="causal"))
assert torch.equal(w_int[0, 0] > 0, allowed), "weights are positive exactly inside the causal window"

# %% [markdown]
# ### 2.4 Residuals, feed-forward, and the whole layer
#
# The residual of the integration is taken on the query stream (as in any transformer layer), then a FF layer:
# $Z = \mathrm{LN}(X + \mathrm{MH}(Q^X, K^{\bar Y}, V^{\bar Y}))$, $\breve Y = \mathrm{LN}(Z + \mathrm{FF}(Z))$. With one
# layer, $\breve Y$ goes straight to the motion decoder. The pieces must reproduce `DualFusionLayer.forward` and the
# `y_fused` of the full model's teacher-forced forward pass.

# %%
with torch.no_grad():
    z = fusion.norm2(query + att)
    y_fused = fusion.norm3(z + fusion.ff(z))  # Y̆
    y_fused_layer, _ = layer(stream, x, style, "primal")
    out = model(batch, need_weights=True)

check_shape(y_fused, (B, T, d), "Y̆")
torch.testing.assert_close(y_fused, y_fused_layer)
torch.testing.assert_close(y_fused, out["y_fused"])
torch.testing.assert_close(w_int, out["attention"]["primal"][0]["integration"])
print("Fig. 2 rebuilt from its pieces = DualFusionLayer = DualTalker.forward")

# %% [markdown]
# ## 3. Fig. 3, the dual form (eq. 7)
#
# Lip reading mirrors the primal task: the stream is the *past audio* ($S_n$, then a per-frame embedding of
# $a_1, \dots, a_{T-1}$; per frame, because the contextual audio layers would leak $a_t$ into earlier frames), it
# goes through its own audio-attentive module and speaker-aware gate to give $\bar X$, and the integration now
# takes the queries from the (given) motion features $Y$ and keys/values from $\bar X$:
#
# $$\mathrm{Att}(Q^{Y}, K^{\bar X}, V^{\bar X}) = \mathrm{softmax}\Big(\frac{Q^{Y} (K^{\bar X})^\top}{\sqrt{d_k}}\Big)
#   V^{\bar X} \tag{7}$$
#
# (The printed eq. 7 writes $Q^{\bar Y}$ in the softmax; the text says "$Y_{1:T}$ is converted into query vectors
# $Q^Y$", which we follow.) The same `DualIntegration` computes it with `direction="dual"`.

# %%
fusion_d = layer.dual
with torch.no_grad():
    past_audio = model.audio_encoder(model.extractor.embed_frames(batch["audio"]))  # Ae(a_t), per frame
    stream_a = model.decoder.ppe(torch.cat([style[:, None, :], past_audio[:, :-1]], dim=1))  # X̂
    attended_a = fusion_d.norm1(stream_a + fusion_d.self_attn(stream_a, bias=bias)[0])  # X̌ (audio-attentive)
    gated_a = layer.dual_gate(attended_a, style)  # X̄ (eq. 5, the dual task's own gate)
    query_d, key_value_d = integ.route(y, gated_a)  # queries from Y, keys/values from X̄
    att_d, w_dual = integ(query_d, key_value_d, "dual")  # eq. 7
    z_d = fusion_d.norm2(query_d + att_d)
    x_fused = fusion_d.norm3(z_d + fusion_d.ff(z_d))  # X̆

W_Qd, W_Kd, W_Vd, W_Od = integ.projections("dual")
assert W_Qd is integ.proj_motion and W_Kd is integ.proj_audio  # W_{Q_Y}, W_{K_X̄}
assert W_Vd is not W_V and W_Od is not W_O  # values and outputs belong to one direction
for name, t_ in [("X̂", stream_a), ("X̌", attended_a), ("X̄", gated_a), ("X̆", x_fused)]:
    check_shape(t_, (B, T, d), name)
check_shape(w_dual, (B, H, T, T), "dual attention weights")
torch.testing.assert_close(x_fused, out["x_fused"])
torch.testing.assert_close(w_dual, out["attention"]["dual"][0]["integration"])
check_shape(out["audio"], (B, T, cfg.audio_dim), "Ã (predicted audio features)")

# %% [markdown]
# ## 4. Weight sharing: $W_{Q_X} = W_{K_{\bar X}}$ and $W_{Q_Y} = W_{K_{\bar Y}}$
#
# "As depicted in Fig. 3, we unify the two dual modules by sharing parameters $W_{Q_X} = W_{K_{\bar X}}$ and
# $W_{Q_Y} = W_{K_{\bar Y}}$." The package implements this *structurally*: there is one projection for every
# audio-side input (`proj_audio`: the primal task's query $X$, the dual task's key $\bar X$) and one for every
# motion-side input (`proj_motion`: the primal key $\bar Y$, the dual query $Y$). There is nothing to keep in sync:
#
# **(a) identity.** The primal query weight *is* the dual key weight (the same `Parameter` object).

# %%
shared = {"W_Q_X = W_K_X̄ (proj_audio)": (W_Q, W_Kd), "W_Q_Y = W_K_Ȳ (proj_motion)": (W_Qd, W_K)}
for name, (a, b) in shared.items():
    assert a is b and a.weight is b.weight and a.bias is b.bias
    print(f"{name}: the same tensor, id {'equal' if id(a.weight) == id(b.weight) else 'different'}")
unique = {id(p) for p in integ.parameters()}
assert len(unique) == 12  # 6 linear maps x (weight, bias): Q/K stored once for both tasks

# %% [markdown]
# **(b) gradients from each task alone.** Because the tensors are shared, training *either* task trains the
# query/key projections of *both*. We run a backward pass from the primal task only, then from the dual task
# only, and look at which integration parameters receive gradient. As each task's loss we use a fixed random
# read-out of its fused feature ($\breve Y$, resp. $\breve X$): the real $L_{\rm primal}$ would send no gradient into
# the fusion at initialisation, because the motion decoder starts at zero (an untrained model outputs the template).

# %%
probe = torch.randn(B, T, d, generator=torch.Generator().manual_seed(1))
names = ["proj_audio", "proj_motion", "value_primal", "out_primal", "value_dual", "out_dual"]


def integration_grads(task: str) -> dict[str, torch.Tensor | None]:
    """Backward from one task's fused feature only -> gradient of each integration weight (None = not reached)."""
    model.zero_grad(set_to_none=True)
    o = model(batch)
    (o["y_fused" if task == "primal" else "x_fused"] * probe).mean().backward()
    return {n: None if getattr(integ, n).weight.grad is None else getattr(integ, n).weight.grad.clone() for n in names}


grads = {task: integration_grads(task) for task in ("primal", "dual")}
print(f"{'weight':<14} {'primal alone':>13} {'dual alone':>11}")
for n in names:
    cells = ["yes" if grads[t][n] is not None and grads[t][n].abs().sum() > 0 else "-" for t in ("primal", "dual")]
    print(f"{n:<14} {cells[0]:>13} {cells[1]:>11}")
for task in ("primal", "dual"):
    for n in ("proj_audio", "proj_motion"):
        assert grads[task][n] is not None and grads[task][n].abs().sum() > 0, (task, n)
assert grads["primal"]["value_dual"] is None and grads["dual"]["value_primal"] is None

# %% [markdown]
# Trained jointly, the shared tensors simply receive the *sum* of both tasks' gradients:

# %%
model.zero_grad(set_to_none=True)
o = model(batch)
((o["y_fused"] * probe).mean() + (o["x_fused"] * probe).mean()).backward()
for n in ("proj_audio", "proj_motion"):
    torch.testing.assert_close(getattr(integ, n).weight.grad, grads["primal"][n] + grads["dual"][n])
model.zero_grad(set_to_none=True)

# %% [markdown]
# **(c) the two directions' logits are transposes in structure.** Per head, the primal logits are the bilinear
# form $s(a, m) = (a W_{Q_X}) (m W_{K_{\bar Y}})^\top / \sqrt{d_k}$ between an audio-side vector $a$ (query) and a
# motion-side vector $m$ (key). The dual logits use the *same two matrices* with the roles swapped,
# $(m W_{Q_Y}) (a W_{K_{\bar X}})^\top / \sqrt{d_k} = s(a, m)$. So if the dual direction is fed the same two sequences
# (queries from the motion side $\bar Y$, keys from the audio side $X$), its logit matrix is exactly the transpose of
# the primal one: "which motion frame fits this audio frame" and "which audio frame fits this motion frame"
# are answered by one compatibility function. (The masks differ: each direction's causal window runs over its
# own key stream.)

# %%
def raw_logits(direction: str, query_in: torch.Tensor, key_in: torch.Tensor) -> torch.Tensor:
    """Q K^T / sqrt(d_k) per head, before any mask, with the direction's (shared) projections -> (B, H, Tq, Tk)."""
    w_q, w_k, _, _ = integ.projections(direction)
    return split_heads(w_q(query_in), H) @ split_heads(w_k(key_in), H).transpose(-2, -1) / math.sqrt(d // H)


with torch.no_grad():
    s_primal = raw_logits("primal", x, gated)  # Q^X (K^Ȳ)^T: audio frames x motion frames
    s_dual = raw_logits("dual", gated, x)  # Q^Y (K^X̄)^T with Y := Ȳ, X̄ := X: motion frames x audio frames

check_shape(s_primal, (B, H, T, T), "primal logits")
torch.testing.assert_close(s_dual, s_primal.transpose(-2, -1))
torch.testing.assert_close(s_primal.masked_fill(~allowed, float("-inf")), scores)  # = the logits of eq. 6 above

# %%
fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
lim = float(s_primal[0, 0].abs().max())
panels = [(s_primal[0, 0], "primal logits $Q^X (K^{\\bar Y})^\\top/\\sqrt{d_k}$", "key: motion frame j ($\\bar Y$)",
           "query: audio frame i ($X$)"),
          (s_dual[0, 0], "dual logits $Q^Y (K^{\\bar X})^\\top/\\sqrt{d_k}$", "key: audio frame j ($X$ as $\\bar X$)",
           "query: motion frame i ($\\bar Y$ as $Y$)")]
for ax, (img, title, xl, yl) in zip(axes, panels):
    im = ax.imshow(img, cmap="RdBu_r", vmin=-lim, vmax=lim)
    ax.set_title(title + ", head 1")
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)
fig.colorbar(im, ax=axes, shrink=0.8, label="logit (unmasked)")
plt.show()

# %% [markdown]
# ## 5. Two readings of eq. 6: the paper's and FaceFormer's
#
# DualTalker builds on FaceFormer, whose cross-modal attention does the opposite: the **queries come from the
# motion stream** and the keys/values from the (fully known) audio, with an alignment mask that lets motion frame
# $t$ see audio frame $t$ only (the diagonal, on VOCASET). The package offers both (`query_from`):
#
# | | paper (`query_from="encoder"`, default) | FaceFormer (`query_from="decoder"`) |
# |---|---|---|
# | primal queries | audio $X$ (given) | motion stream $\bar Y$ |
# | primal keys/values | motion stream $\bar Y$ | audio $X$ |
# | allowed keys for query frame $t$ | causal: $j \in [t-w+1, t]$ ($\bar Y_j$ is built from motion $< j$) | centred around $t$ (the audio is known) |
# | residual | on $X$: $\breve Y_t$ = audio feature + motion context | on $\bar Y$: motion stream + audio read-out |
#
# With a one-frame window ($w = 1$, FaceFormer's diagonal) each softmax has a single element: its weight is 1 whatever
# the logits, so the attention is a per-frame linear map and **$W_Q$, $W_K$ get no gradient at all** (in both readings).
# The tiny model therefore uses $w = 2$ for the paper's reading. Below: the primal integration weights (head 1, first
# clip) of four untrained models that differ only in the reading and the window.

# %%
readings = [("encoder", 2, "paper, causal window 2 (default)"), ("encoder", 6, "paper, causal window 6"),
            ("decoder", 1, "FaceFormer, diagonal (VOCASET)"), ("decoder", 5, "FaceFormer, centred window 5")]
weights = {}
for query_from, window, title in readings:
    set_seed(0)
    m = DualTalker(DualTalkerConfig.tiny(n_vertices=V3 // 3, n_speakers=cfg.n_speakers, query_from=query_from,
                                         align_window=window)).eval()
    with torch.no_grad():
        w = m(batch, need_weights=True)["attention"]["primal"][0]["integration"]
    check_shape(w, (B, H, T, T), title)
    mode = "causal" if query_from == "encoder" else "centred"
    assert torch.equal(w[0, 0] > 0, alignment_mask(T, T, window, mode=mode)), title
    torch.testing.assert_close(w.sum(-1), torch.ones(B, H, T))
    weights[title] = w
torch.testing.assert_close(weights["FaceFormer, diagonal (VOCASET)"], torch.eye(T).expand(B, H, T, T))

# %%
fig, axes = plt.subplots(1, 4, figsize=(12, 3.4), constrained_layout=True)
for ax, (query_from, window, title) in zip(axes, readings):
    im = ax.imshow(weights[title][0, 0], cmap="magma", vmin=0, vmax=1)
    ax.set_title(title, fontsize=10)
    paper = query_from == "encoder"
    ax.set_xlabel("key: motion frame j ($\\bar Y$)" if paper else "key: audio frame j ($X$)")
    ax.set_ylabel("query: audio frame i ($X$)" if paper else "query: motion frame i ($\\bar Y$)")
fig.colorbar(im, ax=axes, shrink=0.8, label="attention weight")
plt.show()

# %% [markdown]
# In the paper's reading each row is an audio frame choosing among the most recent motion-stream frames; in
# FaceFormer's, each motion frame reads the audio around it (with the diagonal, just its own audio frame, weight
# 1). The dual direction is the same picture with the modalities swapped.

# %% [markdown]
# ## 6. Where the parameters are
#
# The full tiny model, by component. "Used by" says which task's forward pass reads the tensor; the shared
# query/key projections of section 4 are counted once.

# %%
integ_names = {"proj_audio": "both (shared W_Q_X = W_K_X̄)", "proj_motion": "both (shared W_Q_Y = W_K_Ȳ)",
               "value_primal": "primal", "out_primal": "primal", "value_dual": "dual", "out_dual": "dual"}
per_frame = ("input_norm", "feature_projection")  # embed_frames: also embeds the dual task's past audio
rows = [("audio extractor: input LN + frame projection",
         [p for n, p in model.extractor.named_parameters() if n.startswith(per_frame)], "both"),
        ("audio extractor: TCN + transformer",
         [p for n, p in model.extractor.named_parameters() if not n.startswith(per_frame)], "primal"),
        ("audio encoder (C -> d)", model.audio_encoder, "both"),
        ("motion encoder Me (V*3 -> d)", model.decoder.motion_encoder, "both"),
        ("style embeddings S_n", model.decoder.style, "both"),
        ("primal fusion: self-attn + FF + LNs", layer.primal, "primal"),
        ("primal speaker-aware gate", layer.primal_gate, "primal"),
        ("dual fusion: self-attn + FF + LNs", layer.dual, "dual"),
        ("dual speaker-aware gate", layer.dual_gate, "dual")]
rows += [(f"integration: {n}", getattr(integ, n), u) for n, u in integ_names.items()]
rows += [("motion decoder (d -> V*3)", model.decoder.motion_decoder, "primal"),
         ("audio decoder (d -> C -> D_a)", model.audio_decoder, "dual")]


def count(part) -> int:
    return sum(p.numel() for p in (part.parameters() if hasattr(part, "parameters") else part))


# %%
# NBVAL_CHECK_OUTPUT
total = 0
print(f"{'component':<46} {'parameters':>10}  used by")
for name, part, used in rows:
    total += count(part)
    print(f"{name:<46} {count(part):>10,}  {used}")
print(f"{'total':<46} {total:>10,}")
saved = count(integ.proj_audio) + count(integ.proj_motion)
print(f"without the Fig. 3 sharing the dual task would need {saved:,} more ({100 * saved / total:.2f} %)")

# %%
assert total == model.num_parameters()  # every tensor counted once
assert saved == 2 * (d * d + d)
per_task = {t: sum(count(p) for _, p, u in rows if u == t) for t in ("primal", "dual")}
print(f"task-specific parameters: primal {per_task['primal']:,}, dual {per_task['dual']:,}; "
      f"shared {total - sum(per_task.values()):,}")

# %% [markdown]
# The motion encoder and decoder ($V \cdot 3 \times d$ each) dominate; the whole cross-modal fusion layer of both tasks
# is small, and the Fig. 3 sharing saves two $d \times d$ maps per layer. The paper's point is less the saving than
# the coupling: both tasks' gradients meet in the same query/key tensors.
#
# ## Summary
#
# - One fusion layer of the primal task (Fig. 2) is: shifted past motion $\hat Y$ → causal, ALiBi-biased
#   self-attention + LN ($\check Y$, eqs. 3-4) → speaker-aware gate ($\bar Y$, eq. 5) → cross-modal attention with
#   queries $X$ and keys/values $\bar Y$ in a causal window (eq. 6) → residual, FF, LN → $\breve Y$. Rebuilt here from the
#   package's modules, it equals `DualFusionLayer` and `DualTalker.forward` exactly.
# - The dual task (Fig. 3, eq. 7) runs the same structure on the past audio, with queries from $Y$ and keys/values
#   from $\bar X$, giving $\breve X$.
# - $W_{Q_X} = W_{K_{\bar X}}$ and $W_{Q_Y} = W_{K_{\bar Y}}$ hold by construction (`proj_audio`, `proj_motion`): the same
#   tensors, trained by each task alone and by the sum of both; the two directions' logits are one bilinear form,
#   transposed.
# - The paper's reading (queries from the given modality) needs a window of at least 2 frames to train $W_Q, W_K$;
#   FaceFormer's reading takes the queries from the motion stream, and on VOCASET its diagonal window also leaves
#   $W_Q, W_K$ untrained.
#
# ## Exercises
#
# 1. Build `DualTalker(DualTalkerConfig.tiny(..., align_window=1))`, rerun `integration_grads("primal")` and check
#    that `proj_audio` and `proj_motion` now get exactly zero gradient. Explain with the softmax of a single logit.
# 2. Untie the projections: make a copy of the integration whose dual direction uses `copy.deepcopy(proj_audio)`
#    and `copy.deepcopy(proj_motion)`. How many parameters does the model gain? Do the two directions' logits
#    (section 4c) still transpose into each other?
# 3. Which tensors of section 2 change when you swap the two clips' style vectors `style.flip(0)`: $\hat Y$,
#    $\check Y$, $\bar Y$, $\breve Y$? Why does $S_n$ reach $\check Y$ at all (hint: the start token)?
# 4. Repeat section 4c with `query_from="decoder"`: which sequences must you feed the two directions to get
#    transposed logits now?
