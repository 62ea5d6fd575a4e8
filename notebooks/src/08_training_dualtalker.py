# %% [markdown]
# # 08 · Training DualTalker: the joint loss (section III-F)
#
# Notebooks 03-07 built every piece of DualTalker: the fusion of the primal task (facial animation) and of the
# dual task (lip reading), the duality regularisation $L_{\rm DR}$ and the consistency loss $L_{\rm CCRL}$. Here the
# pieces are trained together, end to end, with the joint loss of section III-F, and the trained model is used
# the way it is at test time: it generates the motion of an unseen sentence frame by frame from the speech.
#
# **We will cover**
#
# 1. the joint loss and its four weights $\lambda_1 \dots \lambda_4$, checked on one batch;
# 2. a training run of the tiny DualTalker on two speakers: the four loss terms and the validation lip vertex
#    error, epoch by epoch;
# 3. saving a checkpoint under `runs/` and reloading it (identical predictions);
# 4. the generated lips against the ground truth (the lip-distance plot of the paper's Fig. 5) and an
#    animation with the speech;
# 5. an interactive retraining: sliders for $\lambda_1 \dots \lambda_4$ and the kernel bandwidth, and a "Train"
#    button; same seed, same history.

# %%
%matplotlib inline
import time
from dataclasses import asdict

import matplotlib.pyplot as plt
import numpy as np
import torch
from IPython.display import display
from torch.utils.data import Subset

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.dataset import TalkingFaceDataset, collate, make_loader

# %%
from dualtalker_lite.losses import LossWeights, joint_loss
from dualtalker_lite.metrics import lip_distance, lip_sync_metrics, lve_euclidean
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.train import TrainConfig, load_checkpoint, predict, save_checkpoint, train
from dualtalker_lite.checks import check_shape
from dualtalker_lite.files import runs_dir
from dualtalker_lite.seeding import set_seed
from dualtalker_lite.viz import animate_clip, plot_lip_distance
from dualtalker_lite.viz.widgets import RetrainPanel, progress_loader

# One thread, not two: the tensors here are tiny, and on a busy 2-core machine a second intra-op thread makes
# each training step 10-30x slower (threads wait for each other). The thread count is part of determinism too.
torch.set_num_threads(1)
set_seed(0)
corpus = Corpus(sample_path())
FPS = corpus.fps

# %% [markdown]
# ## Symbols
#
# | paper symbol | code name | shape |
# |---|---|---|
# | $A_{1:T'}$, $\tilde A_{1:T'}$ (true / predicted audio features, dual task) | `batch["audio"]`, `out["audio"]` | (B, T, 160) |
# | $M_{1:T} + h$, $\tilde M_{1:T} + h$ (true / predicted vertices, primal task) | `batch["vertices"]`, `out["vertices"]` | (B, T, V·3) |
# | $X, \breve X, Y, \breve Y$ (encoder and fused features) | `out["x"]`, `out["x_fused"]`, `out["y"]`, `out["y_fused"]` | (B, T, d) |
# | $L_{\rm Primal}$ (MSE, mm²) | `terms["primal"]` | scalar |
# | $L_{\rm Dual}$ (MSE on the log-mel features) | `terms["dual"]` | scalar |
# | $L_{\rm DR}$ (eq. 8, notebook 06) | `terms["dr"]` | scalar |
# | $L_{\rm CCRL}$ (eqs. 9-11, notebook 07) | `terms["ccrl"]` | scalar |
# | $\lambda_1, \lambda_2, \lambda_3, \lambda_4$ | `LossWeights(lambda1=..., lambda2=..., lambda3=..., lambda4=...)` | scalars |
# | $\sigma$ (bandwidth of the CCRL kernel; `None` = median heuristic) | `LossWeights.bandwidth` (metres) | scalar |
# | Loss (the weighted sum) | `total`, `terms["total"]` | scalar |
#
# $T' = T$: the audio features are resampled to the mesh rate (30 fps).

# %% [markdown]
# ## 1. The joint loss
#
# "The overall training loss is"
#
# $$\mathrm{Loss} = \lambda_1 L_{\rm Primal}(M_{1:T}, \tilde M_{1:T}) + \lambda_2 L_{\rm Dual}(A_{1:T'}, \tilde A_{1:T'})
#   + \lambda_3 L_{\rm DR} + \lambda_4 L_{\rm CCRL} \tag{III-F}$$
#
# with the mean squared error for both regression tasks. The package measures every term as a mean over the valid
# (non-padded) frames and, because vertices are stored in metres, computes $L_{\rm Primal}$ on vertices scaled to
# **mm** (`LossWeights.vertex_scale = 1000`): a metre-MSE of $10^{-7}$ would vanish next to the $O(1)$ audio and
# feature terms. The paper's BIWI weights ($1, 10^{-8}, 10^{-9}, 10^{-6}$) belong to un-normalised sums and do not
# transfer; the package's defaults, $(\lambda_1, \lambda_2, \lambda_3, \lambda_4) = (1, 0.1, 0.1, 0.01)$, make every
# term matter at initialisation without overriding the primal task. `joint_loss(out, batch, weights)` returns the
# weighted total (to backpropagate) and the *unweighted* terms (to log).
#
# The data: the 44 training clips of speakers SPK03 and SPK04 (a subset, so that training takes seconds), their
# 4 validation clips, and their 12 test-A clips (seen speakers, unseen sentences).

# %%
t0 = time.perf_counter()
SPEAKERS = ("SPK03", "SPK04")
mine = lambda ds: [i for i, c in enumerate(ds.names) if corpus.meta(c)["subject"] in SPEAKERS]  # noqa: E731
train_ds, val_ds, test_ds = (TalkingFaceDataset(corpus, s) for s in ("train", "val", "test_a"))
train_set = Subset(train_ds, mine(train_ds))
val_batch = collate([val_ds[i] for i in mine(val_ds)])
test_batch = collate([test_ds[i] for i in mine(test_ds)])
lip_idx = corpus.regions["lips"]
upper_mid, lower_mid = corpus.regions["lip_midpoints"]
print(f"train {len(train_set)} clips, val {len(val_batch['name'])}, test-A {len(test_batch['name'])}")
assert (len(train_set), len(val_batch["name"]), len(test_batch["name"])) == (44, 4, 12)

# %%
# NBVAL_IGNORE_OUTPUT
print(f"features in {time.perf_counter() - t0:.1f} s")

# %% [markdown]
# One batch through an untrained model: the total is the weighted sum of the logged terms, and $L_{\rm Primal}$
# is the plain MSE of the vertices in mm² (the untrained model outputs the template, so it equals the mean
# squared motion).

# %%
# NBVAL_CHECK_OUTPUT
cfg = DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], n_speakers=len(corpus.train_speakers))
set_seed(0)
model = DualTalker(cfg)
batch = collate([train_set[i] for i in range(8)])
out = model(batch)
weights = LossWeights()
total, terms = joint_loss(out, batch, weights)
check_shape(out["vertices"], batch["vertices"].shape, "predicted vertices")
check_shape(out["audio"], batch["audio"].shape, "predicted audio features")
lam = {"primal": weights.lambda1, "dual": weights.lambda2, "dr": weights.lambda3, "ccrl": weights.lambda4}
torch.testing.assert_close(total, sum(lam[k] * terms[k] for k in lam))
m = batch["mask"]
motion_mm = (batch["vertices"] - batch["template"][:, None]) * 1e3
torch.testing.assert_close(terms["primal"], motion_mm[m].square().mean())  # template out: MSE = mean motion²
print("unweighted terms:", {k: f"{v.item():.3g}" for k, v in terms.items()})
print("weighted terms:  ", {k: f"{lam[k] * terms[k].item():.3g}" for k in lam})

# %% [markdown]
# ## 2. A training run
#
# `train(model, loader, TrainConfig)`: Adam, seeded random order and crops, the joint loss at every step, the
# norm of the gradient clipped to 1; after every epoch the validation **lip vertex error** (LVE: per frame the
# largest lip-vertex error, mm, averaged over frames) measured with *autoregressive* generation, exactly as at
# test time. Here: 16 epochs of 6 batches of 8 clips (96 steps), random crops of 40 frames, lr 6e-3, default
# loss weights.

# %%
EPOCHS = 16
tc = TrainConfig.tiny(epochs=EPOCHS, lr=6e-3, max_frames=40, progress=False)
set_seed(0)
model = DualTalker(cfg)
val_loader = [val_batch]                                                 # one batch = the 4 validation clips
t0 = time.perf_counter()
history = train(model, make_loader(train_set, batch_size=tc.batch_size, seed=0), tc, val_loader, lip_idx)
train_seconds = time.perf_counter() - t0
static_val = lve_euclidean(val_batch["template"][:, None].expand_as(val_batch["vertices"]), val_batch["vertices"],
                           lip_idx, mask=val_batch["mask"])
assert len(history.terms) == len(history.val_lve) == EPOCHS
assert history.term("total")[-1] < 0.5 * history.term("total")[0]
assert history.term("primal")[-1] < 0.5 * history.term("primal")[0]
assert history.val_lve[-1] < static_val, "the trained model must beat the static template on validation"

# %%
# NBVAL_IGNORE_OUTPUT
print(f"training: {train_seconds:.1f} s for {EPOCHS} epochs ({sum(history.seconds[:1]):.1f} s for the first)")

# %%
fig, axes = plt.subplots(1, 3, figsize=(12, 3.8), constrained_layout=True)
epochs = np.arange(1, EPOCHS + 1)
for key, label in (("primal", "$L_{\\rm Primal}$ (mm²)"), ("dual", "$L_{\\rm Dual}$"), ("dr", "$L_{\\rm DR}$"),
                   ("ccrl", "$L_{\\rm CCRL}$"), ("total", "Loss (weighted total)")):
    axes[0].plot(epochs, history.term(key), marker="o", ms=3, label=label, lw=2.2 if key == "total" else 1.3)
axes[0].set(title="loss terms (unweighted), training batches", xlabel="epoch", ylabel="epoch mean", yscale="log")
for i, (key, sym) in enumerate((("primal", "Primal"), ("dual", "Dual"), ("dr", "DR"), ("ccrl", "CCRL")), start=1):
    axes[1].plot(epochs, lam[key] * np.array(history.term(key)), marker="o", ms=3,
                 label=f"$\\lambda_{i} L_{{\\rm {sym}}}$ ($\\lambda_{i}$ = {lam[key]:g})")
axes[1].set(title="weighted terms: what the gradient sees", xlabel="epoch", ylabel="$\\lambda_i L_i$", yscale="log")
axes[2].plot(epochs, history.val_lve, marker="o", label="DualTalker (tiny)")
axes[2].axhline(static_val, color="gray", ls="--", label="static template")
axes[2].set(title="validation lip vertex error (autoregressive)", xlabel="epoch", ylabel="LVE (mm)", ylim=(0, None))
for ax in axes:
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
plt.show()

# %% [markdown]
# $L_{\rm Dual}$ starts largest (the log-mel features are $O(1)$ in 160 dimensions), drops in the first epochs and
# then levels off; $L_{\rm Primal}$ keeps falling, by about an order of magnitude, and $L_{\rm DR}$ falls with it.
# $L_{\rm CCRL}$ hardly moves at $\lambda_4 = 0.01$ (notebook 07 looks at it in detail); weighted, it is the smallest
# term by far. The validation LVE, measured on *generated* motion, is below the static template's from the first
# epoch on, but it is noisy from epoch to epoch: a small change of the weights can change how an autoregressive
# rollout drifts.
#
# ## 3. A checkpoint
#
# `save_checkpoint` writes the weights, both configs and the history atomically, as plain tensors and values
# (loadable with `torch.load(weights_only=True)`); `load_checkpoint` rebuilds the model from the stored config.
# Passing the training speakers (in style-index order) and the mesh's faces makes the checkpoint self-describing:
# `dualtalker-lite animate --checkpoint ... --list-speakers` names them, and a corpus or template with another
# topology is refused instead of silently giving a speaker someone else's style.
# Everything a notebook writes goes under `runs/` (git-ignored).

# %%
path = save_checkpoint(runs_dir("nb08") / "dualtalker_tiny.pt", model, cfg, tc, history,
                       speakers=corpus.train_speakers, faces=corpus.faces)
reloaded, ckpt = load_checkpoint(path)
assert ckpt["speakers"] == corpus.train_speakers and ckpt["n_vertices"] == corpus.metadata["n_vertices"]
pred = predict(model, test_batch)                                        # (B, T, V*3) autoregressive
torch.testing.assert_close(predict(reloaded, test_batch), pred, rtol=0, atol=0)  # bit-identical
assert ckpt["model_config"] == asdict(cfg) and ckpt["history"]["val_lve"] == history.val_lve
assert all(torch.equal(a, b) for a, b in zip(model.state_dict().values(), reloaded.state_dict().values()))
check_shape(pred, test_batch["vertices"].shape, "prediction")
print(f"{path.relative_to(runs_dir())}: {path.stat().st_size / 1e6:.2f} MB, {model.num_parameters():,} parameters")

# %% [markdown]
# ## 4. What the model generates
#
# On the 12 test-A clips (sentences the model never heard), the LVE of the generated motion against the static
# template:

# %%
lve_model = lve_euclidean(pred, test_batch["vertices"], lip_idx, mask=test_batch["mask"])
static_test = test_batch["template"][:, None].expand_as(test_batch["vertices"])
lve_static = lve_euclidean(static_test, test_batch["vertices"], lip_idx, mask=test_batch["mask"])
print(f"test-A LVE: DualTalker (tiny) {lve_model:.2f} mm, static template {lve_static:.2f} mm")
assert lve_model < lve_static

# %% [markdown]
# The field judges lip sync first by the closures at /p/ /b/ /m/ and the opening on vowels. `lip_sync_metrics`
# measures both from the phoneme timing of each clip (`metrics` module docstring): the fraction of bilabials at
# which the lips come within 2 mm (and 1 mm), the mean smallest lip distance there, the mean largest at open
# vowels, and the correlation of the lip-distance curves; `*_gt` is the ground truth's own score.

# %%
lengths = test_batch["lengths"].tolist()
unpad = lambda x: [x[i, :n] for i, n in enumerate(lengths)]  # noqa: E731 padded (B, T, V*3) -> list of (T_i, V*3)
sync = lip_sync_metrics(unpad(pred), unpad(test_batch["vertices"]),
                        [corpus.meta(c)["phonemes"] for c in test_batch["name"]], corpus.regions)
for key in ("bilabial_closure_2mm", "bilabial_closure_1mm", "bilabial_min_mm", "open_vowel_max_mm"):
    print(f"{key:<22} model {sync[key]:6.2f}   ground truth {sync[key + '_gt']:6.2f}")
print(f"lip_distance_corr      {sync['lip_distance_corr']:.2f}; lip motion ratio {sync['lip_motion_ratio']:.2f}; "
      f"{sync['n_bilabials']} bilabials, {sync['n_open_vowels']} open vowels")
assert sync["bilabial_closure_2mm_gt"] == 1.0 and sync["n_bilabials"] > 0

# %% [markdown]
# DualTalker's Fig. 5 compares methods by the distance between the midpoints of the upper and lower lips over a
# test sequence. The same for one clip, with its phonemes:

# %%
CLIP = "SPK03_s02"
b = test_batch["name"].index(CLIP)
n_b = int(test_batch["lengths"][b])
times = np.arange(n_b) / FPS
gt_lips = lip_distance(test_batch["vertices"][b, :n_b], upper_mid, lower_mid)
pred_lips = lip_distance(pred[b, :n_b], upper_mid, lower_mid)
corr = np.corrcoef(gt_lips, pred_lips)[0, 1]
print(f"{CLIP}: correlation of predicted and true lip distance = {corr:.2f}")
plot_lip_distance(times, {"ground truth": gt_lips, "DualTalker (tiny)": pred_lips,
                          "static template": lip_distance(test_batch["template"][b][None].expand(n_b, -1),
                                                          upper_mid, lower_mid)},
                  phonemes=corpus.meta(CLIP)["phonemes"],
                  title=f"Lip distance, {CLIP}: '{corpus.meta(CLIP)['text']}' (cf. DualTalker Fig. 5)")

# %% [markdown]
# Compare the generated curve with the true one: the timing of openings and closures, the amplitude, and whether
# the lips close at /p/, /m/, /b/ (the closure rates above). A short training run gives roughly the mean mouth,
# modulated by the speech: the curve follows the timing with too small an amplitude.
#
# And as an animation with the speech: ground truth on the left, the generated motion on the right.

# %%
# NBVAL_IGNORE_OUTPUT
V = corpus.metadata["n_vertices"]
animate_clip({"ground truth": test_batch["vertices"][b, :n_b].reshape(n_b, V, 3).numpy(),
              "DualTalker (tiny)": pred[b, :n_b].reshape(n_b, V, 3).numpy()},
             corpus.faces, wave=corpus.wave(CLIP), sample_rate=corpus.sample_rate, size=160)

# %% [markdown]
# ## 5. Retrain it yourself
#
# The sliders set $\lambda_1 \dots \lambda_4$ (log scales; untick a box to switch a term off, $\lambda = 0$) and the
# CCRL kernel bandwidth $\sigma$ (mm, RMS per coordinate; tick "median" for the per-clip median heuristic, the
# default). "Train" retrains a fresh model on 8 clips of SPK03 (one batch, so each epoch is one step; 10 steps
# take a couple of seconds) and redraws the loss curves and the lip distance of the test clip. In 10 steps the
# model only learns a constant, average mouth; raise "steps" (60 steps: about 10 s) to see the lips start to
# move. With the same settings you get the same curves: the seed is fixed. The retrain function runs once below
# with the default values.

# %%
tiny_set = Subset(train_ds, mine(train_ds)[:8])


def retrain_figure(hist, lips: np.ndarray, epochs: int, title: str):
    """Loss terms per step (left) and the retrained model's lip distance against the ground truth (right)."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.4), constrained_layout=True)
    for key in ("primal", "dual", "dr", "ccrl", "total"):
        if any(hist.term(key)):
            axes[0].plot(np.arange(1, epochs + 1), hist.term(key), marker="o", ms=3, label=key)
    axes[0].set(title="loss terms (unweighted; 'total' weighted)", xlabel="training step (= epoch)",
                ylabel="loss", yscale="log")
    axes[1].plot(times, gt_lips, label="ground truth")
    axes[1].plot(times, lips, label="retrained model")
    axes[1].set(title=f"lip distance, {CLIP}", xlabel="time (s)", ylabel="lip distance (mm)")
    for ax in axes:
        ax.legend(fontsize=8)
    fig.suptitle(title)
    plt.close(fig)
    return fig


# %%
def retrain(lambdas: tuple[float, float, float, float], bandwidth_mm: float | None, epochs: int = 10,
            on_step=lambda: None):
    """Train a fresh tiny DualTalker on ``tiny_set`` with these weights -> (history, lip distance, figure).
    ``on_step()`` runs before every training step (the panel's progress bar)."""
    w = LossWeights(**{f"lambda{i + 1}": lam for i, lam in enumerate(lambdas)},
                    bandwidth=None if bandwidth_mm is None else bandwidth_mm * 1e-3)
    cfg_tiny = TrainConfig.tiny(epochs=epochs, lr=6e-3, max_frames=40, validate_every=0, progress=False, weights=w)
    set_seed(0)
    net = DualTalker(cfg)
    hist = train(net, progress_loader(make_loader(tiny_set, batch_size=8, seed=0), on_step), cfg_tiny)
    lips = lip_distance(predict(net, test_batch)[b, :n_b], upper_mid, lower_mid)
    sigma = "median" if bandwidth_mm is None else f"{bandwidth_mm:.2f} mm"
    title = f"λ = {tuple(round(x, 4) for x in lambdas)}, σ = {sigma}, {epochs} steps"
    return hist, lips, retrain_figure(hist, lips, epochs, title)


# %% [markdown]
# The panel (`dualtalker_lite.viz.widgets.RetrainPanel`) holds the controls. "Train" is disabled while a run is
# going, the progress bar follows the training steps, and the line under it says how long the last run took.
# The panel runs once here with the default values, exactly as a click would.

# %%
# NBVAL_IGNORE_OUTPUT
panel = RetrainPanel(retrain, defaults=LossWeights(), steps=10)
display(panel.widget)
hist_a, lips_a, fig_a = panel.run()                                      # the default values, once
print(panel.status.value)

# %% [markdown]
# The non-interactive run checks the retrain path: the default settings are the package's `LossWeights()`, the
# progress bar counted every step, the button is enabled again, the loss falls, and retraining with the same
# settings reproduces the history exactly (same seed, same data order, same thread count; only the wall-clock
# times differ). Below: the figure of the default run (in a live kernel it appears in the panel's output area).

# %%
assert panel.settings() == ((1.0, 0.1, 0.1, 0.01), None, 10)
assert panel.progress.value == panel.progress.max == 10 and not panel.button.disabled
assert panel.status.value.startswith("retrained in ")
assert hist_a.term("total")[-1] < hist_a.term("total")[0] and hist_a.term("primal")[-1] < hist_a.term("primal")[0]
hist_b, lips_b, _ = retrain(*panel.settings())
assert hist_b.terms == hist_a.terms and hist_b.val_lve == hist_a.val_lve
np.testing.assert_array_equal(lips_b, lips_a)
print(f"total loss {hist_a.term('total')[0]:.3f} -> {hist_a.term('total')[-1]:.3f}; second run identical")
fig_a  # what the Train button draws with the default settings (inside the panel when the kernel runs)

# %% [markdown]
# ## Summary
#
# - DualTalker trains both tasks at once with $\lambda_1 L_{\rm Primal} + \lambda_2 L_{\rm Dual} + \lambda_3 L_{\rm DR}
#   + \lambda_4 L_{\rm CCRL}$; `joint_loss` returns the weighted total and the unweighted terms, all means over valid
#   frames, with $L_{\rm Primal}$ in mm².
# - `train` logs every term per epoch and the validation LVE of *generated* motion; 96 steps on two speakers
#   bring the tiny model well below the static template.
# - `save_checkpoint` / `load_checkpoint` round-trip the model exactly (bit-identical predictions).
# - The generated lips follow the timing of the openings and closures only roughly, with too small an amplitude:
#   30 seconds of training is far from a trained model (notebook 07: over-smoothing). `lip_sync_metrics` says how
#   often they close at /p b m/ and how far they open at vowels, next to the ground truth's own scores.
# - Training is deterministic for a given seed and thread count: the same settings give the same history.
#
# ## Exercises
#
# 1. With the sliders, switch $\lambda_2$, $\lambda_3$ and $\lambda_4$ off (primal task only). Does the primal
#    loss fall faster or slower in 10 steps? Relate it to the gradient norms of notebook 07, section 5.3.
# 2. Train the model of section 2 for 30 epochs, or on all eight speakers (`train_ds`), and plot the validation
#    LVE. When does it stop improving?
# 3. Train with `TrainConfig.tiny(max_frames=None)` (whole clips) and compare the wall-clock time per epoch and
#    the final validation LVE with the 40-frame crops.
# 4. Load the checkpoint of section 3 and evaluate it on test-B (unseen speakers, `TalkingFaceDataset(corpus,
#    "test_b")`). `predict` conditions unseen speakers on the style of training speaker 0: how much worse is the
#    LVE than on test-A?
