# %% [markdown]
# # 08 · Training DualTalker: the joint loss (section III-F)
#
# Notebooks 03-07 built every piece of DualTalker: the fusion of the primal task (facial animation) and of the
# dual task (lip reading), the duality regularisation $L_{\rm DR}$ and the consistency loss $L_{\rm CCRL}$. Here the
# pieces are trained together, end to end, with the joint loss of section III-F, and the trained model is used
# the way it is at test time: it generates the motion of an unseen sentence frame by frame from the speech, and
# of two real recordings that it never saw.
#
# The model is trained on the project's default front end, the **phonetic route** (notebook 02a): it reads the
# 15 visemes of the speech (in training the corpus's own labels, on new speech the phoneme recogniser's track),
# not the log-mel spectrum, so a model trained on espeak voices also animates people.
#
# **We will cover**
#
# 1. the joint loss and its four weights $\lambda_1 \dots \lambda_4$, checked on one batch;
# 2. a training run with the short recipe `TrainConfig.fast()` (VOCA's PCA-initialised output layer, trained in its
#    basis, and a bilabial contact term; about 25 CPU seconds): the loss terms, step by step;
# 3. saving a checkpoint under `runs/` and reloading it (identical predictions);
# 4. the generated lips against the ground truth (the lip-distance plot of the paper's Fig. 5), the closures at
#    /p b m/, and two real recordings animated with the speech;
# 5. an interactive fine-tuning: sliders for $\lambda_1 \dots \lambda_4$ and the kernel bandwidth, a "Train"
#    button, and two settings side by side.

# %%
%matplotlib inline
import copy
import json
import time
from dataclasses import asdict
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import torch
from IPython.display import HTML, display

from dualtalker_lite.audio import load_audio
from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.dataset import SILENCE_PAD, TalkingFaceDataset, VisemeLabels, collate, make_loader

# %%
from dualtalker_lite import front_ends
from dualtalker_lite.checks import check_shape
from dualtalker_lite.files import runs_dir
from dualtalker_lite.inference import animate_wave
from dualtalker_lite.losses import LossWeights, joint_loss
from dualtalker_lite.metrics import (BILABIALS, closure_rate, lip_distance, lip_sync_metrics, lve_euclidean,
                                    segment_extrema)
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.seeding import set_seed
from dualtalker_lite.checkpoints import load_checkpoint, save_checkpoint
from dualtalker_lite.train import TrainConfig, predict, train
from dualtalker_lite.viz import animate_clip, plot_frames, plot_lip_distance
from dualtalker_lite.viz.widgets import RetrainPanel, progress_loader

# One thread, as the recipe pins (TrainConfig.threads = 1): the tensors here are tiny, and on a busy 2-core machine
# a second intra-op thread makes each step slower (threads wait for each other). The thread count is part of
# determinism too.
torch.set_num_threads(1)
set_seed(0)
corpus = Corpus(sample_path())
SR, FPS = corpus.sample_rate, corpus.fps                 # 16000 Hz, 30 fps
REAL = Path("data/real")                                 # notebooks/data/real/ (the notebook runs in notebooks/)

# %% [markdown]
# ## Symbols
#
# | paper symbol | code name | shape |
# |---|---|---|
# | $A_{1:T'}$, $\tilde A_{1:T'}$ (true / predicted audio features, dual task; here one-hot visemes) | `batch["audio"]`, `out["audio"]` | (B, T, 15) |
# | $M_{1:T} + h$, $\tilde M_{1:T} + h$ (true / predicted vertices, primal task) | `batch["vertices"]`, `out["vertices"]` | (B, T, V·3) |
# | $X, \breve X, Y, \breve Y$ (encoder and fused features) | `out["x"]`, `out["x_fused"]`, `out["y"]`, `out["y_fused"]` | (B, T, d) |
# | $L_{\rm Primal}$ (MSE, mm²) | `terms["primal"]` | scalar |
# | $L_{\rm Dual}$ (MSE on the audio features) | `terms["dual"]` | scalar |
# | $L_{\rm DR}$ (eq. 8, notebook 06) | `terms["dr"]` | scalar |
# | $L_{\rm CCRL}$ (eqs. 9-11, notebook 07) | `terms["ccrl"]` | scalar |
# | $\lambda_1, \lambda_2, \lambda_3, \lambda_4$ | `LossWeights(lambda1=..., lambda2=..., lambda3=..., lambda4=...)` | scalars |
# | $\sigma$ (bandwidth of the CCRL kernel; `None` = median heuristic) | `LossWeights.bandwidth` (metres) | scalar |
# | $L_{\rm contact}$, $\lambda_c$ (eq. C1, the short recipe's bilabial contact term; not the paper's) | `terms["contact"]`, `TrainConfig.lip_contact` | scalars |
# | Loss (the weighted sum) | `total`, `terms["total"]` | scalar |
# | $d(f)$ (distance of the lip midpoints at mesh frame $f$, mm) | `lip_distance(...)` | (T,) |
#
# $T' = T$: the audio features are at the mesh rate (30 fps).

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
# weighted total (to backpropagate) and the *unweighted* terms (to log). On the phonetic route the dual task reads
# the visemes back from the motion: $A$ is the one-hot viseme track, and $L_{\rm Dual}$ is its MSE.
#
# The data: the 176 training clips of the 8 training speakers as `VisemeLabels` (the one-hot of each clip's viseme
# labels, with 0-20 frames of silence on each side, as `dualtalker-lite train` does), and the 48 test-A clips (seen
# speakers, unseen sentences).

# %%
t0 = time.perf_counter()
train_ds, test_ds = TalkingFaceDataset(corpus, "train"), TalkingFaceDataset(corpus, "test_a")
train_set = VisemeLabels(train_ds, pad_silence=SILENCE_PAD)       # what the model trains on: one-hot (T, 15)
test_batch = collate([VisemeLabels(test_ds)[i] for i in range(len(test_ds))])
lip_idx = corpus.regions["lips"]
upper_mid, lower_mid = corpus.regions["lip_midpoints"]
print(f"train {len(train_set)} clips, test-A {len(test_batch['name'])}; audio features {train_set.dim} wide")
assert (len(train_set), len(test_batch["name"]), train_set.dim) == (176, 48, 15)

# %%
# NBVAL_IGNORE_OUTPUT
print(f"features in {time.perf_counter() - t0:.1f} s")

# %% [markdown]
# One batch through an untrained model: the total is the weighted sum of the logged terms, and $L_{\rm Primal}$
# is the plain MSE of the vertices in mm² (the untrained model outputs the template, so it equals the mean
# squared motion).

# %%
# NBVAL_CHECK_OUTPUT
cfg = DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], n_speakers=len(corpus.train_speakers),
                            audio_dim=train_set.dim)
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
# norm of the gradient clipped to 1. The recipe is `TrainConfig.fast()`, the short recipe of
# `results/time_to_quality.md`: the tiny recipe (batches of 8, crops of 90 frames, 30 warm-up steps, cosine decay)
# with three changes. The motion head starts as the top 64 **principal components** of the training motion, each
# scaled by its standard deviation (VOCA initialises its output layer so), so the first step already moves the
# face along directions it really moves in; the learning rate is doubled to $6 \cdot 10^{-3}$; and the step works
# in that basis (`basis_space`): each frame's 4674 vertex coordinates become its 64 coordinates along those
# directions, and the head and the motion encoder stay within them, which gives the same loss up to a constant at
# about two thirds of the CPU time (`docs/design-notes.md`, "The step in the basis's coordinates"). The third
# change is not the paper's: a **bilabial contact term** (`losses.contact`, Imitator's lip contact loss in one
# reading) adds $\lambda_c L_{\rm contact}$ to the joint loss, with $\lambda_c = 10^{-3}$ (`TrainConfig.lip_contact`;
# 0 switches it off):
#
# $$L_{\rm contact} = \frac{1}{|\mathcal{P}|} \sum_{t \in \mathcal{P}} \| \hat v^{u}_t - \hat v^{l}_t \|^2 \tag{C1}$$
#
# the mean squared distance (mm²) between the predicted upper- and lower-lip midpoints $\hat v^u_t, \hat v^l_t$
# over the frames $\mathcal{P}$ labelled /p b m/. The vertex MSE alone leaves the lips of a one-frame /p/ about as
# often 1 mm open as closed in a short budget; this term asks for the closure the rig makes. This cell gives
# DualTalker 18 epochs of 22 steps (396 steps, about 25 CPU seconds: a notebook's budget); the recipe's own 20
# epochs (`dualtalker-lite train`) took 28 ± 1 CPU s over 5 seeds (recipe C20 of
# `results/time_to_quality_2core.md`).

# %%
tc = TrainConfig.fast("dualtalker", epochs=18, validate_every=0, progress=False)   # the recipe's default: 20
print(f"{tc.epochs} epochs, lr {tc.lr:g}, PCA head {tc.pca_init} components (basis_space {tc.basis_space}), "
      f"contact term λ_c {tc.lip_contact:g}, crops of {tc.max_frames} frames")
set_seed(0)
model = DualTalker(cfg)
t0, c0 = time.perf_counter(), time.process_time()
history = train(model, make_loader(train_set, batch_size=tc.batch_size, seed=0), tc)
train_seconds, train_cpu = time.perf_counter() - t0, time.process_time() - c0
assert len(history.terms) == tc.epochs
assert history.term("total")[-1] < 0.2 * history.term("total")[0]
assert history.term("primal")[-1] < 0.2 * history.term("primal")[0]
# the figures the text below the plot quotes (epoch means), within CPU-to-CPU differences
primal, dual, dr, contact = (history.term(k) for k in ("primal", "dual", "dr", "contact"))
assert history.steps[-1] == 396 and 0.8 <= primal[0] <= 1.5 and primal[-1] < 0.1 * primal[0]
assert abs(float(terms["primal"]) - 5.4) <= 0.05   # the untrained model's L_Primal (section 1), for comparison
assert dual[-1] < 0.6 * dual[0] and max(dr) > dr[0] > dr[-1]          # L_Dual halves; L_DR rises, then falls
assert abs(contact[0] - 29) <= 2 and abs(contact[-1] - 0.2) <= 0.05

# %%
# NBVAL_IGNORE_OUTPUT
print(f"training: {train_seconds:.1f} s wall, {train_cpu:.1f} CPU s, {tc.epochs} epochs ({history.steps[-1]} steps)")

# %%
fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), constrained_layout=True)
epochs = np.arange(1, tc.epochs + 1)
for key, label in (("primal", "$L_{\\rm Primal}$ (mm²)"), ("dual", "$L_{\\rm Dual}$"), ("dr", "$L_{\\rm DR}$"),
                   ("ccrl", "$L_{\\rm CCRL}$"), ("contact", "$L_{\\rm contact}$ (mm²)"),
                   ("total", "Loss (weighted total)")):
    axes[0].plot(epochs, history.term(key), marker="o", ms=3, label=label, lw=2.2 if key == "total" else 1.3)
axes[0].set(title="loss terms (unweighted), training batches", xlabel="epoch", ylabel="epoch mean", yscale="log")
for i, (key, sym) in enumerate((("primal", "Primal"), ("dual", "Dual"), ("dr", "DR"), ("ccrl", "CCRL")), start=1):
    axes[1].plot(epochs, lam[key] * np.array(history.term(key)), marker="o", ms=3,
                 label=f"$\\lambda_{i} L_{{\\rm {sym}}}$ ($\\lambda_{i}$ = {lam[key]:g})")
axes[1].plot(epochs, tc.lip_contact * np.array(history.term("contact")), marker="o", ms=3,
             label=f"$\\lambda_c L_{{\\rm contact}}$ ($\\lambda_c$ = {tc.lip_contact:g})")
axes[1].set(title="weighted terms: what the gradient sees", xlabel="epoch", ylabel="$\\lambda_i L_i$", yscale="log")
for ax in axes:
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
plt.show()

# %% [markdown]
# $L_{\rm Primal}$ is already about 1 mm² in the first epoch's mean (5.4 mm² for the untrained model above): the
# PCA-initialised head starts in the space the face moves in. It falls by more than an order of magnitude over the
# 18 epochs. $L_{\rm DR}$ first rises, while the two tasks' features move apart, then falls with the primal loss;
# $L_{\rm Dual}$ (reading 15 visemes back) falls by half. $L_{\rm CCRL}$ hardly moves at $\lambda_4 = 0.01$
# (notebook 07 looks at it in detail). Weighted, the primal term dominates the loss throughout, as the default
# weights intend. $L_{\rm contact}$ starts at 29 mm² (the lips about 5 mm apart at /p b m/) and ends near 0.2 mm²;
# times $\lambda_c = 10^{-3}$ it is a small part of the total, but its gradient falls on two vertices at a few frames,
# where the primal MSE spreads its gradient over 4674 coordinates of every frame.
#
# ## 3. A checkpoint
#
# `save_checkpoint` writes the weights, both configs and the history atomically, as plain tensors and values
# (loadable with `torch.load(weights_only=True)`); `load_checkpoint` rebuilds the model from the stored config.
# Passing the training speakers (in style-index order), the mesh's faces and the front end makes the checkpoint
# self-describing: `dualtalker-lite animate --checkpoint ... --list-speakers` names the speakers, a corpus or
# template with another topology is refused instead of silently giving a speaker someone else's style, and
# `animate` feeds new speech through the phoneme recogniser, as the model expects.
# Everything a notebook writes goes under `runs/` (git-ignored).

# %%
front_end = front_ends.build("visemes", FPS)               # the phoneme recogniser -> one-hot visemes (T, 15)
path = save_checkpoint(runs_dir("nb08") / "dualtalker_tiny.pt", model, cfg, tc, history,
                       speakers=corpus.train_speakers, faces=corpus.faces,
                       features=front_ends.settings("visemes", front_end))
reloaded, ckpt = load_checkpoint(path)
assert ckpt["speakers"] == corpus.train_speakers and ckpt["n_vertices"] == corpus.metadata["n_vertices"]
pred = predict(model, test_batch)                                        # (B, T, V*3) autoregressive
torch.testing.assert_close(predict(reloaded, test_batch), pred, rtol=0, atol=0)  # bit-identical
assert ckpt["model_config"] == asdict(cfg) and ckpt["history"]["terms"] == history.terms
check_shape(pred, test_batch["vertices"].shape, "prediction")
print(f"{path.relative_to(runs_dir())}: {path.stat().st_size / 1e6:.2f} MB, {model.num_parameters():,} parameters")

# %% [markdown]
# ## 4. What the model generates
#
# The field judges lip sync first by the closures at /p/ /b/ /m/ and the opening on vowels. `lip_sync_metrics`
# measures both from the phoneme timing of each clip (`metrics` module docstring): the fraction of bilabials at
# which the lips come within 2 mm (and 1 mm), the mean smallest lip distance there, the mean largest at open
# vowels, and the correlation of the lip-distance curves; `*_gt` is the ground truth's own score. Here on the 48
# test-A clips (sentences the model never heard), fed the true viseme labels, next to the LVE (per frame the
# largest lip-vertex error, mm, averaged over frames) of the model and of the static template.

# %%
# trained-model figures: nbval does not compare them (their last digit differs between CPU instruction sets);
# the assert is the check
lengths = test_batch["lengths"].tolist()
unpad = lambda x: [x[i, :n] for i, n in enumerate(lengths)]  # noqa: E731 padded (B, T, V*3) -> list of (T_i, V*3)
sync = lip_sync_metrics(unpad(pred), unpad(test_batch["vertices"]),
                        [corpus.meta(c)["phonemes"] for c in test_batch["name"]], corpus.regions)
static_test = test_batch["template"][:, None].expand_as(test_batch["vertices"])
lve = {k: lve_euclidean(p, test_batch["vertices"], lip_idx, mask=test_batch["mask"])
       for k, p in (("model", pred), ("static", static_test))}
for key in ("bilabial_closure_2mm", "bilabial_closure_1mm", "bilabial_min_mm", "open_vowel_max_mm"):
    print(f"{key:<22} model {sync[key]:6.2f}   ground truth {sync[key + '_gt']:6.2f}")
print(f"lip_distance_corr {sync['lip_distance_corr']:.2f}; {sync['n_bilabials']} bilabials; "
      f"LVE model {lve['model']:.2f} mm, static template {lve['static']:.2f} mm")
assert sync["bilabial_closure_2mm"] >= 0.8 and lve["model"] < lve["static"]
# the figures the text below quotes: the model's within CPU-to-CPU differences (0.02 = 3 of the 152 bilabials),
# the ground truth's exactly
assert abs(sync["bilabial_closure_2mm"] - 0.95) <= 0.02 and abs(sync["bilabial_closure_1mm"] - 0.93) <= 0.03
assert abs(sync["bilabial_min_mm"] - 0.55) <= 0.1 and abs(sync["open_vowel_max_mm"] - 14.0) <= 0.3
assert (round(sync["bilabial_closure_1mm_gt"], 2), round(sync["bilabial_min_mm_gt"], 2),
        round(sync["open_vowel_max_mm_gt"], 1), sync["n_bilabials"]) == (0.89, 0.30, 13.6, 152)

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
# The generated curve follows the true one: the openings at the vowels reach the ground truth's height (mean largest
# opening 14.0 mm against 13.6 mm), and the lips close at the shaded /p/ /b/ /m/: 0.95 of test-A's 152 bilabials
# within 2 mm and 0.93 within 1 mm, more often than the ground truth itself (0.89), though a little less deeply (a
# mean smallest distance of 0.55 mm against 0.30 mm). The contact term asks for closed lips on every frame labelled
# /p b m/, also the first and last of a closure, where the rig that made the corpus is still closing or opening
# them. Without it the closures within 1 mm fall: over 5 seeds at about the recipe's length, test-A's bilabials
# fed the true labels close within 1 mm at 0.93 ± 0.02 with the term (20 epochs) and at 0.57 ± 0.07 without it
# (23 epochs), for about the same LVE (3.74 against 3.68 mm on the recogniser's track;
# `results/time_to_quality_2core.md`, recipes C20 and B23). Exercise 2 repeats the comparison here.
#
# ### Real voices
#
# The two real prompts shipped in `notebooks/data/real/` (a telephone voice, CC-BY-SA, `NOTICE`) go through the
# path of `dualtalker-lite animate`: the phoneme recogniser turns the speech into a viseme track, and the model
# generates the face of the first training speaker from it (`inference.animate_wave`). Their phones, force-aligned
# offline (the JSON next to each recording), say where the /p b m/ are; a bilabial window is widened by one frame
# for the aligner's timing, as in `benchmarks/real_voices.py`.

# %%
subject = corpus.train_speakers[0]
real = {}
for p in sorted(REAL.glob("*.json")):
    info = json.loads(p.read_text())
    wave = load_audio(p.with_suffix(".flac"), front_end="visemes")  # 8 kHz -> 16 kHz, one warning line each
    verts = animate_wave(model, wave, corpus.template(subject), 0, front_end=front_end)   # (T, V*3)
    d = lip_distance(verts, upper_mid, lower_mid)
    real[info["name"]] = dict(info, wave=wave, verts=verts, d=d,
                              mins=segment_extrema(d, info["phones"], BILABIALS, tolerance_frames=1))

# %%
# NBVAL_CHECK_OUTPUT
mins = np.concatenate([r["mins"] for r in real.values()])
print(f"{len(mins)} real /p b m/ in {len(real)} prompts: closed < 2 mm {closure_rate(mins, 2.0):.2f}, "
      f"< 1 mm {closure_rate(mins, 1.0):.2f}")
assert closure_rate(mins, 2.0) >= 0.5

# %%
r = real["agent-pass"]
pbm = [s for s in r["phones"] if s[0] in BILABIALS]
plot_lip_distance(np.arange(len(r["d"])) / FPS, {"DualTalker (tiny), recogniser's visemes": r["d"]}, phonemes=pbm,
                  figsize=(11, 3.2), title=f"Real voice: '{r['text']}' (/p b m/ shaded)")

# %% [markdown]
# The face at the deepest closure of the "p" of "password" and at the widest opening of the prompt:

# %%
seg = next(s for s in pbm if s[1] > 0.3)                               # the p of "password"
lo, hi = int(seg[1] * FPS) - 1, int(np.ceil(seg[2] * FPS)) + 1
f_closed, f_open = lo + int(np.argmin(r["d"][lo:hi + 1])), int(np.argmax(r["d"]))
frames = r["verts"][[f_closed, f_open]].reshape(2, -1, 3)
plot_frames(frames, corpus.faces, titles=[f"/{seg[0]}/ at {f_closed / FPS:.2f} s: {r['d'][f_closed]:.1f} mm",
                                          f"widest, {f_open / FPS:.2f} s: {r['d'][f_open]:.1f} mm"],
            suptitle="DualTalker (tiny) on a real voice")

# %% [markdown]
# And as an animation with the speech: first the test-A clip (ground truth left, the model right), then the real
# prompt.

# %%
# NBVAL_IGNORE_OUTPUT
V = corpus.metadata["n_vertices"]
video = animate_clip({"ground truth": test_batch["vertices"][b, :n_b].reshape(n_b, V, 3).numpy(),
                      "DualTalker (tiny)": pred[b, :n_b].reshape(n_b, V, 3).numpy()},
                     corpus.faces, wave=corpus.wave(CLIP), sample_rate=SR, size=160)
display(video)
animate_clip(r["verts"].reshape(len(r["verts"]), V, 3), corpus.faces, wave=r["wave"], sample_rate=SR, size=192,
             renderer="raster")

# %% [markdown]
# ## 5. Fine-tune it yourself
#
# The sliders set $\lambda_1 \dots \lambda_4$ (log scales; untick a box to switch a term off, $\lambda = 0$) and the
# CCRL kernel bandwidth $\sigma$ (mm, RMS per coordinate; tick "median" for the per-clip median heuristic, the
# default). "Train" copies the model trained above and fine-tunes the copy for "steps" steps (batches of 8 of the
# 176 clips, constant lr $10^{-3}$, about 0.1-0.15 s a step) with those weights, then redraws the loss terms and
# the lip distance of the test clip next to the ground truth and the trained model's. With the same settings you
# get the same curves: the seed is fixed.

# %%
def retrain_figure(hist, lips: np.ndarray, title: str):
    """Loss terms per epoch (left) and the fine-tuned model's lip distance against the ground truth (right)."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.4), constrained_layout=True)
    for key in ("primal", "dual", "dr", "ccrl", "total"):
        if any(hist.term(key)):
            axes[0].plot(np.arange(1, len(hist.terms) + 1), hist.term(key), marker="o", label=key)
    axes[0].set(title="loss terms (unweighted; 'total' weighted)", xlabel="epoch of the fine-tuning",
                ylabel="loss", yscale="log")
    for label, curve in (("ground truth", gt_lips), ("trained (section 2)", pred_lips), ("fine-tuned", lips)):
        axes[1].plot(times, curve, label=label)
    axes[1].set(title=f"lip distance, {CLIP}", xlabel="time (s)", ylabel="lip distance (mm)")
    for ax in axes:
        ax.legend(fontsize=8)
    fig.suptitle(title)
    plt.close(fig)
    return fig


# %%
def retrain(lambdas: tuple[float, float, float, float], bandwidth_mm: float | None, steps: int = 30,
            on_step=lambda: None):
    """Fine-tune a copy of ``model`` with these weights for ``steps`` steps -> (history, lip distance, figure).
    ``on_step()`` runs before every training step (the panel's progress bar)."""
    w = LossWeights(**{f"lambda{i + 1}": lam for i, lam in enumerate(lambdas)},
                    bandwidth=None if bandwidth_mm is None else bandwidth_mm * 1e-3)
    per_epoch = -(-len(train_set) // 8)
    ft = TrainConfig.tiny(epochs=-(-steps // per_epoch), max_steps=steps, lr=1e-3, warmup_steps=0, decay="none",
                          mean_init=False, validate_every=0, progress=False, weights=w)
    set_seed(0)
    net = copy.deepcopy(model)
    hist = train(net, progress_loader(make_loader(train_set, batch_size=8, seed=1), on_step), ft)
    lips = lip_distance(predict(net, test_batch)[b, :n_b], upper_mid, lower_mid)
    sigma = "median" if bandwidth_mm is None else f"{bandwidth_mm:.2f} mm"
    title = f"λ = {tuple(round(x, 4) for x in lambdas)}, σ = {sigma}, {steps} steps"
    return hist, lips, retrain_figure(hist, lips, title)


# %% [markdown]
# The panel (`dualtalker_lite.viz.widgets.RetrainPanel`) holds the controls. "Train" is disabled while a run is
# going, the progress bar follows the training steps, and the line under it says how long the last run took.
# The panel runs once here with the default values, exactly as a click would.

# %%
# NBVAL_IGNORE_OUTPUT
panel = RetrainPanel(retrain, defaults=LossWeights(), steps=30)
display(panel.widget)
hist_a, lips_a, fig_a = panel.run()                                      # the default values, once
print(panel.status.value)

# %% [markdown]
# Two settings side by side: the defaults, and the same run with the primal term switched off ($\lambda_1 = 0$: the
# face is trained only through the dual task, $L_{\rm DR}$ and $L_{\rm CCRL}$, none of which compares the motion
# with the captured one).

# %%
assert panel.settings() == ((1.0, 0.1, 0.1, 0.01), None, 30)
assert panel.progress.value == panel.progress.max == 30 and not panel.button.disabled
hist_b, lips_b, _ = retrain((0.0, 0.1, 0.1, 0.01), None, 30)
bil = [s for s in corpus.meta(CLIP)["phonemes"] if s[0] in BILABIALS]
closure = {k: segment_extrema(c, bil, BILABIALS) for k, c in (("default", lips_a), ("no primal", lips_b))}
fig, axes = plt.subplots(1, 2, figsize=(12, 3.4), sharey=True, constrained_layout=True)
for ax, (label, lips) in zip(axes, (("λ = (1, 0.1, 0.1, 0.01), 30 steps", lips_a),
                                    ("λ = (0, 0.1, 0.1, 0.01), 30 steps", lips_b))):
    for name, curve in (("ground truth", gt_lips), ("trained (section 2)", pred_lips), ("fine-tuned", lips)):
        ax.plot(times, curve, label=name, lw=2.0 if name == "fine-tuned" else 1.0)
    ax.set(title=label, xlabel="time (s)")
    ax.legend(fontsize=8)
axes[0].set(ylabel="lip distance (mm)")
plt.show()
print({k: f"smallest lip distance at /p b m/ {np.min(v):.1f} mm" for k, v in closure.items()})
assert np.min(closure["no primal"]) > np.min(closure["default"]) + 1.0
assert np.min(closure["default"]) < 1.0 and abs(np.min(closure["no primal"]) - 4.0) <= 0.5  # the text below

# %% [markdown]
# With the defaults, 30 more steps leave the lips closing at the clip's /p b m/ (smallest distance below 1 mm).
# With $\lambda_1 = 0$ the same 30 steps lose the closures: the smallest lip distance at the bilabials grows to
# about 4 mm, because nothing in the
# remaining terms pulls the vertices towards the captured motion (the dual task only needs the motion to be
# *readable*, not right). The loss weights are not cosmetic: which terms the gradient sees decides what the lips do
# within seconds.
#
# ## Summary
#
# - DualTalker trains both tasks at once with $\lambda_1 L_{\rm Primal} + \lambda_2 L_{\rm Dual} + \lambda_3 L_{\rm DR}
#   + \lambda_4 L_{\rm CCRL}$; `joint_loss` returns the weighted total and the unweighted terms, all means over valid
#   frames, with $L_{\rm Primal}$ in mm².
# - On the phonetic route, with the short recipe `TrainConfig.fast()` (PCA-initialised motion head, lr
#   $6 \cdot 10^{-3}$, the step in the head's 64 coordinates, the bilabial contact term of eq. C1, 18 epochs, about
#   25 CPU seconds), the tiny model closes the lips within 1 mm at 0.93 of the /p b m/ of unseen test-A sentences
#   and at all 5 of two real recordings it never saw, and opens them about as wide as the ground truth at vowels.
# - `save_checkpoint` / `load_checkpoint` round-trip the model exactly (bit-identical predictions); the checkpoint
#   names its front end, so `animate` feeds new speech through the recogniser.
# - The loss weights matter within seconds: without $L_{\rm Primal}$, nothing holds the lips to the captured motion
#   and the closures are lost in 30 steps.
# - Training is deterministic for a given seed and thread count: the same settings give the same history.
#
# ## Exercises
#
# 1. With the sliders, fine-tune with $\lambda_4$ (CCRL) at 1 instead of 0.01, and with $\lambda_2, \lambda_3,
#    \lambda_4$ all off (primal task only). Which closes the lips of the test clip more deeply after 30 steps?
#    Relate it to the gradient norms of notebook 07, section 5.3.
# 2. Train the model of section 2 with `TrainConfig.fast(lip_contact=0)` (the joint loss alone), then with
#    `TrainConfig.fast(pca_init=0, basis_space=False)` (the head starts at zero, as in the tiny recipe), and compare
#    the closure rates < 1 mm and the LVE. Which change moves which figure (`results/time_to_quality_2core.md`)?
# 3. Load the checkpoint of section 3 and evaluate it on test-B (unseen speakers, `TalkingFaceDataset(corpus,
#    "test_b")`). `predict` conditions unseen speakers on the style of training speaker 0: how much worse is the
#    LVE than on test-A?
