# %% [markdown]
# # 06 · The duality regularisation loss (eq. 8)
#
# DualTalker trains facial animation (primal: audio → motion) and lip reading (dual: motion → audio) as
# *inverse processes* of each other. Besides sharing modules (notebook 05), the two tasks are tied by a loss
# on their hidden features, the duality regularisation $L_{\rm DR}$ of section III-D.
#
# **We will cover**
#
# 1. eq. 8: which features $L_{\rm DR}$ compares, and how the package reads the printed equation;
# 2. Smooth L1 against L2 and L1: values and gradients;
# 3. the package's `duality_loss` checked against `torch.nn.functional.smooth_l1_loss` (with padding);
# 4. a short experiment: the tiny DualTalker trained with $\lambda_3 = 0$ and with $\lambda_3 > 0$, following
#    $L_{\rm DR}$ and the cosine similarity between $\breve Y$ and $Y$ during training, and what ends up aligned.

# %%
%matplotlib inline
import time

import matplotlib.pyplot as plt
import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import Subset

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.dataset import TalkingFaceDataset, collate, make_loader
from dualtalker_lite.losses import LossWeights, dual_loss, duality_loss, primal_loss
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.train import TrainConfig, train
from dualtalker_lite.checks import check_shape
from dualtalker_lite.seeding import set_seed

torch.set_num_threads(2)
_ = set_seed(0)  # (it also returns a seeded generator, not needed here)

# %% [markdown]
# ## Symbols
#
# | paper symbol | code name | shape |
# |---|---|---|
# | $X_{1:T'}$ (audio encoder features of the true audio) | `out["x"]` | (B, T, d) |
# | $Y_{1:T}$ (motion encoder features of the true motion) | `out["y"]` | (B, T, d) |
# | $\breve Y_{1:T}$ (fused feature of the primal task, input of the motion decoder) | `out["y_fused"]` | (B, T, d) |
# | $\breve X_{1:T'}$ (fused feature of the dual task, input of the audio decoder) | `out["x_fused"]` | (B, T, d) |
# | $\beta$ (Smooth L1 threshold) | `beta`, `LossWeights.dr_beta` | scalar |
# | $\lambda_3$ (weight of $L_{\rm DR}$ in the joint loss) | `LossWeights.lambda3` | scalar |
# | $L_{\rm DR}$ | `duality_loss(...)`, `terms["dr"]` | scalar |
# | valid frames | `batch["mask"]` | (B, T) |
#
# The audio features are resampled to the mesh rate, so $T' = T$ here.

# %% [markdown]
# ## 1. Eq. 8: what is pulled towards what
#
# "When given an audio/motion pair $(X_{1:T'}, Y_{1:T})$, the predicted fusion feature of cross-modal fusion, which
# includes motion/audio representations $(\breve X_{1:T'}, \breve Y_{1:T})$, is expected to converge". The extracted
# eq. 8 has lost its accents (it reads $\mathrm{Smooth_{L1}}(X, X) + \mathrm{Smooth_{L1}}(Y, Y)$, which is always 0); the
# package reads it as
#
# $$L_{\rm DR} = \mathrm{Smooth_{L1}}(\breve X_{1:T'}, X_{1:T'}) + \mathrm{Smooth_{L1}}(\breve Y_{1:T}, Y_{1:T}) \tag{8}$$
#
# $$\mathrm{Smooth_{L1}}(a, b) = \frac{1}{N} \sum_{i=1}^{N} \begin{cases} \dfrac{(a_i - b_i)^2}{2\beta} & |a_i - b_i| < \beta \\[4pt]
#   |a_i - b_i| - \dfrac{\beta}{2} & \text{otherwise} \end{cases}$$
#
# with the mean over the $N$ elements of the valid frames and $\beta = 1$ by default.
#
# | term | pulled | towards | meaning |
# |---|---|---|---|
# | $\mathrm{Smooth_{L1}}(\breve Y, Y)$ | $\breve Y_t$: primal fused feature, built from the audio $X$ and the motion *before* $t$ | $Y_t = \mathrm{Me}(M_t)$: the motion encoder's feature of the true motion at $t$ | "from the audio, predict what the motion encoder would say" |
# | $\mathrm{Smooth_{L1}}(\breve X, X)$ | $\breve X_t$: dual fused feature, built from the motion $Y$ and the audio *before* $t$ | $X_t$: the audio encoder's feature of the true audio at $t$ | "from the motion, predict what the audio encoder would say" |
#
# If $\breve Y \approx Y$, the motion decoder, which maps $\breve Y$ to the motion, also inverts the motion encoder:
# decoder ∘ encoder ≈ identity on the data, the "inverse processes" of section III-D. By default (`detach_targets=False`)
# the gradient reaches both sides, the fusion *and* the encoders ("the entire model can be trained end-to-end");
# `detach_targets=True` treats $X, Y$ as fixed "soft targets".

# %% [markdown]
# ## 2. Smooth L1 versus L2 and L1
#
# Smooth L1 (Huber loss divided by $\beta$) is quadratic near zero, so small differences get small, smooth gradients,
# and linear far away, so the gradient never exceeds 1 in magnitude: a few badly matched frames cannot dominate
# the update, unlike L2 whose gradient grows with the error.

# %%
e = torch.linspace(-3, 3, 601, requires_grad=True)  # difference a - b
zeros = torch.zeros_like(e)
curves = {"L2: $e^2/2$": 0.5 * e.square(), "L1: $|e|$": e.abs(),
          "Smooth L1, $\\beta=1$": F.smooth_l1_loss(e, zeros, reduction="none", beta=1.0),
          "Smooth L1, $\\beta=0.5$": F.smooth_l1_loss(e, zeros, reduction="none", beta=0.5)}
grads = {k: torch.autograd.grad(v.sum(), e)[0] for k, v in curves.items()}

inside = e.abs() < 1
sl1 = curves["Smooth L1, $\\beta=1$"]
torch.testing.assert_close(sl1[inside], 0.5 * e[inside].square())  # quadratic branch: e^2 / (2 beta)
torch.testing.assert_close(sl1[~inside], e[~inside].abs() - 0.5)  # linear branch: |e| - beta / 2
assert grads["Smooth L1, $\\beta=1$"].abs().max() <= 1 and grads["L2: $e^2/2$"].abs().max() > 2.9

# %%
fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), constrained_layout=True)
for name in curves:
    axes[0].plot(e.detach(), curves[name].detach(), label=name)
    axes[1].plot(e.detach(), grads[name], label=name)
axes[0].set(title="loss of one element", xlabel="difference $e = a - b$ (feature units)", ylabel="loss")
axes[1].set(title="gradient with respect to $a$", xlabel="difference $e = a - b$ (feature units)",
            ylabel="d loss / d a")
axes[0].set_ylim(0, 3)
axes[0].legend()
plt.show()

# %% [markdown]
# ## 3. The package's `duality_loss`, checked against PyTorch
#
# `duality_loss(x, x_fused, y, y_fused, mask, beta)` is a mean over the valid frames only: padded frames (here
# filled with NaN) must change neither the value nor the gradient. The reference is
# `F.smooth_l1_loss` on the valid frames, one call per term.

# %%
g = torch.Generator().manual_seed(0)
B, T, d = 3, 7, 16
lengths = torch.tensor([7, 5, 2])
mask = torch.arange(T)[None, :] < lengths[:, None]  # (B, T)
x, x_fused, y, y_fused = (torch.randn(B, T, d, generator=g) * 1.5 for _ in range(4))
for t_ in (x, x_fused, y, y_fused):
    t_[~mask] = float("nan")  # padding holds garbage
x_fused.requires_grad_(True)

for beta in (1.0, 0.5):
    ours = duality_loss(x, x_fused, y, y_fused, mask, beta=beta)
    ref = F.smooth_l1_loss(x_fused[mask], x[mask], beta=beta) + F.smooth_l1_loss(y_fused[mask], y[mask], beta=beta)
    torch.testing.assert_close(ours, ref)
    print(f"beta = {beta}: duality_loss = {ours.item():.4f}, F.smooth_l1_loss reference = {ref.item():.4f}")
ours.backward()
assert torch.isfinite(x_fused.grad).all() and bool((x_fused.grad[~mask] == 0).all())
assert duality_loss(x, x, y, y, mask) == 0  # eq. 8 as printed (no accents) is identically zero

# %% [markdown]
# ## 4. Experiment: training with and without $L_{\rm DR}$
#
# The joint loss of section III-F is $\lambda_1 L_{\rm primal} + \lambda_2 L_{\rm dual} + \lambda_3 L_{\rm DR} +
# \lambda_4 L_{\rm CCRL}$. We train the same tiny DualTalker (same seed, same data order) twice, with $\lambda_3 = 0$ and
# with $\lambda_3 = 1$, all other weights at the package defaults, on a subset of the shipped corpus's training
# split, and look at what $L_{\rm DR}$ changes.
#
# ### 4.1 Data

# %%
corpus = Corpus(sample_path())
train_ds = TalkingFaceDataset(corpus, "train")
val_ds = TalkingFaceDataset(corpus, "val")
subset = Subset(train_ds, torch.randperm(len(train_ds), generator=torch.Generator().manual_seed(0))[:48].tolist())
val_batch = collate([val_ds[i] for i in range(len(val_ds))])  # the whole validation split, one batch
V3 = val_batch["vertices"].shape[-1]
print(f"{len(subset)} of {len(train_ds)} training clips, {len(val_ds)} validation clips, "
      f"{corpus.metadata['n_vertices']} vertices")
assert V3 == 3 * corpus.metadata["n_vertices"]
B_val, T_val = val_batch["mask"].shape
check_shape(val_batch["audio"], (B_val, T_val, 160), "A")
check_shape(val_batch["vertices"], (B_val, T_val, V3), "M + template")

# %% [markdown]
# ### 4.2 A probe on the features
#
# `train` logs per-epoch means of the weighted terms only (with $\lambda_3 = 0$ it does not even compute $L_{\rm DR}$).
# To follow $L_{\rm DR}$ at every step of both runs we attach a forward hook to the model: it sees each training batch
# and the model's output dictionary and records, without gradient:
#
# - $L_{\rm DR}$ (eq. 8) and its two terms;
# - the mean cosine similarity $\cos(\breve Y_t, Y_t)$ over valid frames, and the same with the target taken half a
#   second later, $\cos(\breve Y_t, Y_{t+15})$. A loss that aligns *frames* must raise the first above the second; if
#   both rise together, the two features only came to share a common direction;
# - the same two numbers for $\breve X$ and $X$, and the mean feature norms;
# - $L_{\rm primal}$ (mm², as in the joint loss) and a **round trip** that tests the inverse-process idea directly:
#   decode the *encoder* feature of the true motion with the motion decoder, $\mathrm{Md}(Y) = \mathrm{Md}(\mathrm{Me}(M))$,
#   and compare it with $M$ (MSE, mm²). Nothing but eq. 8 asks the decoder to invert the encoder.

# %%
SHIFT = 15  # frames = 0.5 s


def frame_cosine(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor, shift: int = 0) -> float:
    """Mean of cos(a_t, b_{t+shift}) over the frames t where both are valid; a, b (B, T, d), mask (B, T)."""
    if shift:
        a, b, mask = a[:, :-shift], b[:, shift:], mask[:, :-shift] & mask[:, shift:]
    return F.cosine_similarity(a, b, dim=-1)[mask].mean().item()


@torch.no_grad()
def feature_stats(model: DualTalker, out: dict, batch: dict) -> dict[str, float]:
    """Eq. 8 and its terms, cosine similarities, feature norms, L_primal and the motion round trip."""
    m, xf, x, yf, y = batch["mask"], out["x_fused"], out["x"], out["y_fused"], out["y"]
    motion_mm = (batch["vertices"] - batch["template"][:, None, :]) * 1e3  # M (B, T, V*3) in mm
    return {"dr": duality_loss(x, xf, y, yf, m).item(),
            "dr_x": F.smooth_l1_loss(xf[m], x[m]).item(), "dr_y": F.smooth_l1_loss(yf[m], y[m]).item(),
            "cos_y": frame_cosine(yf, y, m), "cos_y_shift": frame_cosine(yf, y, m, SHIFT),
            "cos_x": frame_cosine(xf, x, m), "cos_x_shift": frame_cosine(xf, x, m, SHIFT),
            "norm_y": y[m].norm(dim=-1).mean().item(), "norm_y_fused": yf[m].norm(dim=-1).mean().item(),
            "norm_x": x[m].norm(dim=-1).mean().item(), "norm_x_fused": xf[m].norm(dim=-1).mean().item(),
            "primal": primal_loss(out["vertices"] * 1e3, batch["vertices"] * 1e3, m).item(),
            "roundtrip_motion": primal_loss(model.decoder.decode_motion(y) * 1e3, motion_mm, m).item()}

# %% [markdown]
# ### 4.3 Two runs
#
# `TrainConfig.tiny`'s optimiser settings (Adam, gradient clipping at 1) for 4 epochs of 6 batches of 8 clips, random
# crops of at most 60 frames, no validation inside `train`; $\lambda_3 = 0$, then $\lambda_3 = 1$ (the package default
# is 0.1; a larger weight shows the effect within 24 steps). The model is rebuilt from the same seed for each run and
# `train` re-seeds the loader, so the two runs differ only in $\lambda_3$. (`DualTalkerConfig.tiny` also hides half of
# the fed-back past motion frames during training, `motion_dropout=0.5`; that is the same in both runs.)

# %%
cfg = DualTalkerConfig.tiny(n_vertices=V3 // 3, n_speakers=len(corpus.train_speakers))
LAMBDAS = (0.0, 1.0)
EPOCHS = 4
runs = {}
torch.set_num_threads(1)  # tiny tensors: a second intra-op thread gains nothing and thrashes on a busy machine
t0 = time.perf_counter()
for lam in LAMBDAS:
    set_seed(0)
    model = DualTalker(cfg)
    steps: list[dict] = []
    hook = model.register_forward_hook(lambda mod, args, out, log=steps: log.append(feature_stats(mod, out, args[0])))
    tc = TrainConfig.tiny(epochs=EPOCHS, max_frames=60, validate_every=0, progress=False,
                          weights=LossWeights(lambda3=lam))
    history = train(model, make_loader(subset, batch_size=tc.batch_size, seed=0), tc)
    hook.remove()
    runs[lam] = {"model": model, "history": history, "steps": {k: np.array([s[k] for s in steps]) for k in steps[0]}}
train_seconds = time.perf_counter() - t0
torch.set_num_threads(2)
n_steps = len(runs[0.0]["steps"]["dr"])
per_epoch = n_steps // EPOCHS
print(f"{len(LAMBDAS)} runs x {n_steps} steps ({per_epoch} per epoch), Adam lr = {tc.lr:g}")

# %%
# NBVAL_IGNORE_OUTPUT
print(f"training time: {train_seconds:.1f} s for {len(LAMBDAS)} runs")

# %% [markdown]
# Sanity checks: both runs took the same steps, and for $\lambda_3 > 0$ the hook's $L_{\rm DR}$ averages, epoch by epoch,
# to exactly the "dr" that `train` logged from `joint_loss` (with $\lambda_3 = 0$ `train` logs 0: the term is skipped).

# %%
assert n_steps == EPOCHS * -(-len(subset) // tc.batch_size)
assert all(len(r["steps"]["dr"]) == n_steps for r in runs.values())
logged = np.array(runs[1.0]["history"].term("dr"))
np.testing.assert_allclose(runs[1.0]["steps"]["dr"].reshape(EPOCHS, per_epoch).mean(1), logged, rtol=1e-5)
assert runs[0.0]["history"].term("dr") == [0.0] * EPOCHS
s_off, s_on = runs[0.0]["steps"], runs[1.0]["steps"]
np.testing.assert_allclose(s_on["dr"], s_on["dr_x"] + s_on["dr_y"], rtol=1e-5)  # eq. 8 = its two terms

# %%
fig, axes = plt.subplots(2, 3, figsize=(12, 6.6), constrained_layout=True)
step, colors = np.arange(1, n_steps + 1), {0.0: "tab:gray", 1.0: "tab:red"}
for lam, r in runs.items():
    s, c, lab = r["steps"], colors[lam], f"$\\lambda_3$ = {lam:g}"
    axes[0, 0].plot(step, s["dr"], color=c, label=lab)
    axes[0, 1].plot(step, s["dr_x"], color=c, label=f"{lab}: $\\breve X$ vs $X$")
    axes[0, 1].plot(step, s["dr_y"], color=c, ls=":", label=f"{lab}: $\\breve Y$ vs $Y$")
    axes[0, 2].plot(step, s["primal"], color=c, label=f"{lab}: $L_{{\\rm primal}}$")
    axes[0, 2].plot(step, s["roundtrip_motion"], color=c, ls="--", label=f"{lab}: round trip Md(Me(M))")
    for ax, key in ((axes[1, 0], "cos_y"), (axes[1, 1], "cos_x")):
        ax.plot(step, s[key], color=c, label=f"{lab}: same frame")
        ax.plot(step, s[key + "_shift"], color=c, ls="--", label=f"{lab}: target 0.5 s later")
    for key, ls, sym in (("norm_y", ":", "Y"), ("norm_y_fused", "-", "\\breve Y"), ("norm_x", "-.", "X"),
                         ("norm_x_fused", "--", "\\breve X")):
        axes[1, 2].plot(step, s[key], color=c, ls=ls, label=f"{lab}: $\\|{sym}\\|$")
axes[0, 0].set(title="$L_{\\rm DR}$ (eq. 8), training batch", ylabel="$L_{\\rm DR}$", yscale="log")
axes[0, 1].set(title="the two terms of eq. 8", ylabel="Smooth L1", yscale="log")
axes[0, 2].set(title="motion errors, training batch", ylabel="MSE (mm$^2$)", yscale="log")
axes[1, 0].set(title="$\\cos(\\breve Y_t, Y_{t+s})$", ylabel="mean cosine similarity", ylim=(-0.25, 1.05))
axes[1, 1].set(title="$\\cos(\\breve X_t, X_{t+s})$", ylabel="mean cosine similarity", ylim=(-0.25, 1.05))
axes[1, 2].set(title="mean feature norms", ylabel="$\\|\\cdot\\|_2$ (feature units)", yscale="log")
for ax in axes.flat:
    ax.set_xlabel("training step")
    ax.legend(fontsize=7)
plt.show()

# %% [markdown]
# ### 4.4 After training, on the validation split
#
# One teacher-forced forward pass over the 16 validation clips for each model. Besides the probe's numbers:
#
# - a **centred cosine**: each clip's mean feature (over its frames) is removed from both sides first, so only the
#   frame-to-frame variations are compared;
# - the audio round trip: decode $X$ with the audio decoder, $\mathrm{Ad}(X)$, and compare it with $A$ (MSE).
#
# For scale: predicting the template (zero motion) costs $L_{\rm primal} = \overline{M^2}$.

# %%
def centred_cosine(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor) -> float:
    """Mean cos(a_t - mean_t a, b_t - mean_t b) over valid frames, the means taken per clip over its valid frames."""
    w = mask[..., None].to(a.dtype)
    centre = lambda v: v - (v * w).sum(1, keepdim=True) / w.sum(1, keepdim=True)  # noqa: E731
    return frame_cosine(centre(a), centre(b), mask)


@torch.no_grad()
def evaluate(model: DualTalker, batch: dict) -> tuple[dict, dict[str, float]]:
    """Teacher-forced outputs on ``batch`` and the numbers of the table below."""
    model.eval()
    out, m = model(batch), batch["mask"]
    for key in ("x", "y", "x_fused", "y_fused"):
        check_shape(out[key], (*m.shape, model.cfg.d_model), key)
    return out, {**feature_stats(model, out, batch), "dual": dual_loss(out["audio"], batch["audio"], m).item(),
                 "ccos_y": centred_cosine(out["y_fused"], out["y"], m),
                 "ccos_x": centred_cosine(out["x_fused"], out["x"], m),
                 "roundtrip_audio": dual_loss(model.audio_decoder(out["x"]), batch["audio"], m).item()}


# %% [markdown]
# Evaluate both models and print the table (the template row is the zero-motion baseline).

# %%
outs, results = {}, {}
for lam, r in runs.items():
    outs[lam], results[lam] = evaluate(r["model"], val_batch)
m = val_batch["mask"]
template_mse = ((val_batch["vertices"] - val_batch["template"][:, None, :])[m] * 1e3).square().mean().item()
rows = [("L_DR (eq. 8)", "dr"), ("  Smooth L1(X̆, X)", "dr_x"), ("  Smooth L1(Y̆, Y)", "dr_y"),
        ("cos(Y̆_t, Y_t)", "cos_y"), ("cos(Y̆_t, Y_t+15)", "cos_y_shift"), ("centred cos(Y̆, Y)", "ccos_y"),
        ("cos(X̆_t, X_t)", "cos_x"), ("cos(X̆_t, X_t+15)", "cos_x_shift"), ("centred cos(X̆, X)", "ccos_x"),
        ("|Y| / |Y̆|", ("norm_y", "norm_y_fused")), ("|X| / |X̆|", ("norm_x", "norm_x_fused")),
        ("L_primal (mm²)", "primal"), ("L_dual", "dual"),
        ("round trip Md(Me(M)) (mm²)", "roundtrip_motion"), ("round trip Ad(X)", "roundtrip_audio")]


def cell(r: dict, key) -> str:
    return f"{r[key[0]]:.3g} / {r[key[1]]:.3g}" if isinstance(key, tuple) else f"{r[key]:.3g}"


print(f"{'validation (16 clips)':<28}" + "".join(f"{'λ3 = ' + format(lam, 'g'):>16}" for lam in LAMBDAS))
for label, key in rows:
    print(f"{label:<28}" + "".join(f"{cell(results[lam], key):>16}" for lam in LAMBDAS))
print(f"{'template (zero motion) (mm²)':<28}{template_mse:>16.3g}")

# %%
off, on = results[0.0], results[1.0]
assert on["dr"] < off["dr"], "L_DR must end lower when it is trained"
assert s_on["dr"][-per_epoch:].mean() < s_off["dr"][-per_epoch:].mean()  # also on the last epoch's training batches
assert on["dr_x"] < off["dr_x"] and on["cos_x"] > off["cos_x"], "the dual term pulls X̆ towards X"
drop = off["dr"] - on["dr"]
print(f"L_DR: {off['dr']:.3g} -> {on['dr']:.3g} ({100 * drop / off['dr']:.0f} % lower); "
      f"share of the fall from the Y-term: {100 * (off['dr_y'] - on['dr_y']) / drop:.0f} %")
print(f"|Y|: {s_off['norm_y'][0]:.3g} at step 1 -> {off['norm_y']:.3g} without L_DR, {on['norm_y']:.3g} with it "
      f"(|Y̆| = {on['norm_y_fused']:.3g})")
print(f"same-frame minus shifted cosine with L_DR: Y {on['cos_y'] - on['cos_y_shift']:+.3f}, "
      f"X {on['cos_x'] - on['cos_x_shift']:+.3f}")

# %% [markdown]
# A picture of the alignment: the frame-by-frame cosine similarity matrices $\cos(\breve Y_t, Y_s)$ and
# $\cos(\breve X_t, X_s)$ for one validation clip. Per-frame alignment draws a bright diagonal; a direction shared by
# all frames colours the whole matrix alike; vertical stripes mean that the target frames $s$ differ in how much
# they point along that shared direction.

# %%
clip, n = 0, int(val_batch["lengths"][0])
fig, axes = plt.subplots(1, 4, figsize=(12, 3.4), constrained_layout=True)
for col, lam in enumerate(LAMBDAS):
    for row, (fused, enc, sym) in enumerate((("y_fused", "y", "Y"), ("x_fused", "x", "X"))):
        ax = axes[2 * row + col]
        a, b = F.normalize(outs[lam][fused][clip, :n], dim=-1), F.normalize(outs[lam][enc][clip, :n], dim=-1)
        im = ax.imshow(a @ b.T, cmap="RdBu_r", vmin=-1, vmax=1, extent=(0, n / 30, n / 30, 0))
        ax.set(title=f"$\\cos(\\breve {sym}_t, {sym}_s)$, $\\lambda_3$ = {lam:g}", xlabel=f"s: ${sym}$ time (s)",
               ylabel=f"t: $\\breve {sym}$ time (s)")
fig.colorbar(im, ax=axes, shrink=0.8, label="cosine similarity")
plt.show()

# %% [markdown]
# ### 4.5 What the numbers say
#
# The assertions check the robust facts; the numbers are those printed above.
#
# - **$L_{\rm DR}$ ends far lower when it is trained**, on the training batches and on the validation clips.
# - **Without $L_{\rm DR}$, nothing holds the motion features to a scale.** $\breve Y$ and $\breve X$ leave LayerNorms, so
#   their norms stay near $\sqrt d = 8$. $Y = \mathrm{Me}(M)$ is a plain linear map; the primal task only sees it through
#   the motion stream, whose LayerNorm hides its scale, and with $\lambda_3 = 0$ its norm grows by well over an order
#   of magnitude within a few dozen Adam steps. $\mathrm{Smooth_{L1}}(\breve Y, Y)$ then grows like the mean $|Y_i|$ and
#   $L_{\rm DR}$ *rises*. With $\lambda_3 = 1$, almost all of the difference is this term: eq. 8 pulls both ways
#   (`detach_targets=False`), and its first effect is to hold the encoder's output at the scale of the fused feature.
# - **The cosines see a shared direction, not frames.** $\cos(\breve X_t, X_t)$ climbs close to 1 with $\lambda_3 = 1$, but
#   the cosine with the target half a second later climbs just as much, and the centred cosine stays small; the same
#   holds, less strongly, for $\breve Y$ and $Y$. Over all $d$ channels, what the two sides share after a few dozen
#   steps is mostly their mean direction; the similarity matrices show uniform colour or vertical stripes, no
#   diagonal.
# - **The round trip is where the inverse processes show.** With $\lambda_3 = 1$ the motion decoder, applied to the
#   *encoder's* feature of the true motion, gives that motion back with an error well below the template's (and
#   below the primal task's own error): along the directions the decoder reads, $Y_t$ and $\breve Y_t$ agree frame by
#   frame, although the full-width cosine hardly shows it. Without $L_{\rm DR}$ the round trip is erratic during training
#   (top right panel) and ends worse. The audio round trip $\mathrm{Ad}(X)$ is also better with $L_{\rm DR}$.
# - **The primal task itself is unchanged at this budget:** the two $L_{\rm primal}$ training curves lie nearly on top of
#   each other, and the validation $L_{\rm primal}$ (and $L_{\rm dual}$) of the two runs are close. Whether the coupling
#   helps the animation is a question for longer training, not for 24 steps.

# %%
assert off["norm_y"] > 5 * on["norm_y"], "without L_DR the motion features grow far beyond the fused features"
assert on["roundtrip_motion"] < template_mse, "with L_DR, Md(Me(M)) beats the static template"

# %% [markdown]
# ## Summary
#
# - Eq. 8 compares each task's *fused* feature with the *encoder* feature of the true signal it predicts: $\breve Y$
#   (primal, from the audio) with $Y = \mathrm{Me}(M)$, and $\breve X$ (dual, from the motion) with $X$. The printed
#   equation lost its accents; without them it would be identically zero.
# - Smooth L1 is quadratic below $\beta$ and linear above, so its gradient is bounded by 1.
# - `duality_loss` equals two calls of `F.smooth_l1_loss` on the valid frames, for any $\beta$, and ignores padding.
# - In a short run of the tiny model, $\lambda_3 > 0$ keeps $L_{\rm DR}$ low mainly by holding the encoder features to the
#   scale and dominant direction of the fused features (gradients reach both sides), and it makes the motion decoder
#   an approximate inverse of the motion encoder (the round trip $\mathrm{Md}(\mathrm{Me}(M)) \approx M$). Over all channels,
#   the frame-by-frame cosine alignment stays small, and $L_{\rm primal}$ is not changed within 24 steps.
#
# ## Exercises
#
# 1. Rerun section 4 with `LossWeights(lambda3=1.0, dr_detach_targets=True)`: now only the fusion paths move and $X$,
#    $Y$ are fixed targets. What happens to $\|Y\|$ and to the Y-term?
# 2. Add a run with the package default $\lambda_3 = 0.1$. Is the effect on $\|Y\|$ and on $\mathrm{Smooth_{L1}}(\breve X, X)$
#    proportional to $\lambda_3$?
# 3. A scale-free variant of eq. 8: compare `F.normalize(y_fused, dim=-1)` with `F.normalize(y, dim=-1)` (and the same
#    for X). Which of the effects of section 4.5 would it remove, and which would it keep?
# 4. Train longer (e.g. `TrainConfig.tiny()` on the whole training split) and watch the centred cosine and the
#    round trip. Does per-frame alignment appear over all channels? Does $L_{\rm primal}$ start to differ?
