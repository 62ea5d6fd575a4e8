# %% [markdown]
# # 14 · EmoFace: emotion-content disentanglement (section 3.3.2, appendix A.2, eqs. 7-18)
#
# EmoFace (the third paper of this project) reads the same speech twice: a **content branch** for what is said (the
# lips) and an **emotion branch** for how it is said (brows, eyes, mouth corners). Each branch drives the face with
# its own autoregressive decoder, and Mesh Attention (notebook 15) fuses their vertex offsets. What makes the two
# branches specialise is **cross-reconstruction on pseudo-pairs**: two clips with the same speaker and sentence
# in different emotions swap their emotion features, and the model must still rebuild the other clip.
#
# **We will cover**
#
# 1. pseudo-pairs in the shipped corpus, and how two readings of different lengths are aligned;
# 2. the content and emotion encoders on the shared acoustic front-end (eqs. 12-14), and the conditions;
# 3. cross-reconstruction (eqs. 15-18), checked on the package's model: the swapped pass uses the partner's
#    emotion features and clip 1's content features, nothing else;
# 4. the losses of eqs. 7-11 (self, cross, velocity, classification) and the paper's weights in our units;
# 5. a short training run, the emotion classifier, and a PCA of the emotion and content features coloured by
#    emotion and by sentence;
# 6. a pseudo-pair in 3D;
# 7. lips that close, driven by the content: a phonetic EmoFace trained 100 steps, then one clip's content with
#    another clip's emotion (the cross-reconstruction of eqs. 15-18 at test time).

# %%
%matplotlib inline
import matplotlib.pyplot as plt
import numpy as np
import torch
from IPython.display import display

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.dataset import SILENCE_PAD, TalkingFaceDataset, VisemeLabels, collate
from dualtalker_lite.data.pairs import PairDataset, make_pair_loader, pair_collate, resample_time
from dualtalker_lite.face.visemes import VISEMES
from dualtalker_lite.losses.emoface import EmoFaceWeights, emoface_loss
from dualtalker_lite.metrics import BILABIALS, lip_distance, segment_extrema
from dualtalker_lite.metrics.emotion import brow_raise
from dualtalker_lite.models.emoface import EmoFace, EmoFaceConfig
from dualtalker_lite.train import TrainConfig, train
from dualtalker_lite.checks import check_shape
from dualtalker_lite.seeding import set_seed
from dualtalker_lite.viz import MeshViewer, plot_lip_distance

torch.set_num_threads(1)  # tiny tensors: a second thread only waits on a shared machine
set_seed(0)
pairs = PairDataset(sample_path())  # the neutral "train" and emotional "train_emo" splits, with partners
corpus = pairs.corpus
EMOTIONS = corpus.emotions

# %% [markdown]
# ## Symbols
#
# | paper symbol | code name | shape |
# |---|---|---|
# | $A_{c1,e1}$, $A_{c1,e2}$ (speech of clip 1 and of its partner) | `batch["audio"]`, `batch["pair_audio"]` | (B, T, 160) |
# | $\hat M_{c1,e1}$, $\hat M_{c1,e2}$ (ground-truth meshes) | `batch["vertices"]`, `batch["pair_vertices"]` | (B, T, V·3) |
# | $F_{c1}$ (content features, eq. 12) | `out["content_features"]` | (B, T, d) |
# | $F_{e1}$, $F_{e2}$ (emotion features, eqs. 13-14) | `out["emotion_features"]`, `out["pair_emotion_features"]` | (B, T, d) |
# | $M^c$, $M^e$, $M$ (content branch, emotion branch, fused; eqs. 15-17) | `out["content"]`, `out["emotion"]`, `out["vertices"]` | (B, T, V·3) |
# | $M^c_{c1,e2}$, $M^e_{c1,e2}$, $M_{c1,e2}$ (cross-reconstruction, eqs. 15, 16, 18) | `out["cross_content"]`, `out["cross_emotion"]`, `out["cross_vertices"]` | (B, T, V·3) |
# | $p_{i\phi}$ (emotion classifier, eq. 10) | `softmax(out["emotion_logits"])` | (B, $N_e$) |
# | $l$ (level one-hot), $s$ (speaking style one-hot) | `batch["level"]`, `batch["speaker"]` | (B,) |
# | $\lambda_1 \dots \lambda_4$ (eq. 11) | `EmoFaceWeights` | scalars |

# %% [markdown]
# ## 1. Pseudo-pairs
#
# "We set a pseudo-training pair of samples with the same content but different emotions" (section 3.3.2). The
# corpus lists them in its metadata (`pairs`): one group per speaker and sentence, the neutral clip (split `train`)
# and eight emotional readings (four emotions × two levels, split `train_emo`). `PairDataset` gives every clip a
# partner drawn at random from its group; clips outside any group (most neutral training sentences) get themselves,
# flagged `pair_valid = False`, and no cross term.

# %%
# NBVAL_CHECK_OUTPUT
group = corpus.metadata["pairs"]["SPK01_s00"]
print(f"{len(pairs)} clips, {pairs.n_paired} with a partner; group SPK01_s00 ({corpus.meta('SPK01_s00')['text']!r}):")
for label, name in sorted(group.items()):
    print(f"  {label:11s} {name:22s} {corpus.meta(name)['n_frames']} frames")
assert pairs.n_paired == sum(1 for n in pairs.names if pairs.partners[n])

# %% [markdown]
# The two readings of a sentence do not have the same length: emotion changes the prosody (the sad
# readings are 20-40% longer than the happy ones). Eqs. 12-18 write both clips with one length $T$. We read that literally:
# the partner's features and vertices are **resampled linearly in time** to clip 1's length (first and last frames
# kept), so $M_{c1,e2}$ is a length-$T$ sequence. The start and end are aligned exactly, the middle only
# approximately (a dynamic time warping would align the phonemes; the paper does not say).

# %%
item = pairs[pairs.names.index("SPK01_s00-happy1")]
other = pairs.items[pairs.names.index(item["pair_name"])]
lips = corpus.regions["lips"]
def opening(v):  # vertical spread of the lip vertices, mm: a simple mouth-opening curve
    y = v.reshape(v.shape[0], -1, 3)[:, lips, 1]
    return 1000 * (y.max(1).values - y.min(1).values)
check_shape(item["pair_vertices"], item["vertices"].shape, "pair_vertices")
torch.testing.assert_close(item["pair_vertices"][[0, -1]], other["vertices"][[0, -1]])  # ends kept

fig, ax = plt.subplots(figsize=(9, 3.2), constrained_layout=True)
ax.plot(opening(item["vertices"]), label=f"clip 1: {item['name']} ({len(item['vertices'])} frames)")
ax.plot(opening(other["vertices"]), "--", alpha=0.6, label=f"partner as recorded: {other['name']} ({len(other['vertices'])})")
ax.plot(opening(item["pair_vertices"]), label="partner resampled to clip 1's length")
ax.set(title="Aligning a pseudo-pair by linear resampling", xlabel="frame (30 fps)", ylabel="lip spread (mm)")
ax.legend(fontsize=8)
plt.show()

# %% [markdown]
# ## 2. Two encoders on one front-end (eqs. 12-14)
#
# $$F_{c1} = E_c(A_{c1,e1}) \tag{12}$$
# $$F_{e1} = E_e(A_{c1,e1}) \tag{13}$$
# $$F_{e2} = E_e(A_{c1,e2}) \tag{14}$$
#
# Both encoders read the shared acoustic front-end (our small stand-in for wav2vec 2.0). The content encoder is a
# per-frame projection (short-term: phonemes); the emotion encoder adds a transformer layer over the whole clip
# (long-term: emotion lives in the prosody of the whole sentence). The **emotion classifier** pools $F_e$ over the
# valid frames into its mean and its standard deviation (concatenated, $2d$ numbers; our reading: eq. 10 gives only
# the output $p$) and predicts the emotion (eq. 10). The emotion branch also gets the **conditions**. The paper's are
# the level one-hot $l \in \mathbb R^2$ and the speaking style $s$ (the decoders' style embedding, as in
# FaceFormer). **The emotion type as an input, $W_{type}\, y$, is this project's addition**, not the paper's (its
# type is only recognised, eq. 10): in training $y$ is the true label, at generation the classifier's probabilities,
# or a type the user picks (`--emotion`); without it the type would follow the audio alone.

# %%
set_seed(0)
n_vertices = corpus.metadata["n_vertices"]
cfg = EmoFaceConfig.tiny(n_vertices=n_vertices, n_speakers=len(corpus.train_speakers), n_emotions=len(EMOTIONS),
                         fusion="sum", past_motion="teacher_forcing")
model = EmoFace(cfg)
emo_idx = [i for i, n in enumerate(pairs.names) if pairs.partners[n] and "-" in n][:4]
batch = pair_collate([pairs[i] for i in emo_idx])
with torch.no_grad():
    fc, fe = model.encode(batch["audio"], batch["mask"])
B, T = batch["mask"].shape
check_shape(fc, (B, T, cfg.d_model), "F_c")
check_shape(fe, (B, T, cfg.d_model), "F_e")
check_shape(model.classify(fe, batch["mask"]), (B, len(EMOTIONS)), "emotion logits")
print(f"d = {cfg.d_model}, {model.num_parameters():,} parameters; batch {B} x {T} frames")

# %% [markdown]
# ## 3. Cross-reconstruction (eqs. 15-18)
#
# $$M^c_{c1,e1} = M^c_{c1,e2} = D_c(F_{c1}) \tag{15}$$
# $$M^e_{c1,e1} = D_e(F_{e1}),\quad M^e_{c1,e2} = D_e(F_{e2}) \tag{16}$$
# $$M_{c1,e1} = \epsilon(M^e_{c1,e1}, M^c_{c1,e1}) \tag{17}$$
# $$M_{c1,e2} = \epsilon(M^e_{c1,e2}, M^c_{c1,e2}) \tag{18}$$
#
# The content decoder $D_c$ only ever sees clip 1's content; to rebuild clip 2 the emotion decoder $D_e$ must
# bring everything emotion adds, from clip 2's emotion features. Eq. 15 says more: the content output of the cross
# pass *is* the self pass's, so the model runs $D_c$ once and reuses it (were $D_c$ re-run on clip 2's past motion,
# it could copy clip 2's emotion from that past). $D_e$ runs twice, teacher-forced on each clip's own past. Both
# decoders are the package's FaceFormer-style decoder block (`blocks.decoder.MotionDecoder`). $\epsilon$ is Mesh
# Attention; this notebook uses the "sum" ablation (the equal-weight mean) to stay fast. The checks below are the
# definitions: the cross pass's content branch equals the self pass's exactly (eq. 15), and its emotion branch
# equals the emotion branch run on clip 2 itself (eq. 16).
# (An untrained decoder is zero, so every output is the template whatever it reads: we nudge both decoders first.)

# %%
for dec in (model.emotion_decoder, model.content_decoder):
    torch.nn.init.normal_(dec.motion_decoder.weight, std=1e-2)
with torch.no_grad():
    out = model(batch)
    as_clip_2 = model({**batch, "audio": batch["pair_audio"], "vertices": batch["pair_vertices"],
                       "emotion": batch["pair_emotion"], "level": batch["pair_level"]})
torch.testing.assert_close(out["cross_emotion"], as_clip_2["emotion"], atol=1e-6, rtol=0)  # D_e(F_e2)
torch.testing.assert_close(out["cross_content"], out["content"], atol=0, rtol=0)  # eq. 15: one D_c(F_c1) pass
assert (out["cross_content"] - as_clip_2["content"]).abs().max() > 1e-6  # D_c(F_c1), not D_c(F_c2)
for key in ("vertices", "emotion", "content", "cross_vertices", "cross_emotion", "cross_content"):
    check_shape(out[key], (B, T, 3 * n_vertices), key)

# %% [markdown]
# ## 4. The losses (eqs. 7-11)
#
# $$L_{self} = \|M^e_{c1,e1} - \hat M_{c1,e1}\|_1 + \|M^c_{c1,e1} - \hat M_{c1,e1}\|_1 + \|M_{c1,e1} - \hat M_{c1,e1}\|_1 \tag{7}$$
# $$L_{cross} = \|M^e_{c1,e2} - \hat M_{c1,e2}\|_1 + \|M^c_{c1,e2} - \hat M_{c1,e2}\|_1 + \|M_{c1,e2} - \hat M_{c1,e2}\|_1 \tag{8}$$
# $$L_{vel} = \sum_{y \in \{e1, e2\}} \|(M^t_{c1,y} - M^{t-1}_{c1,y}) - (\hat M^t_{c1,y} - \hat M^{t-1}_{c1,y})\|_1 \tag{9}$$
# $$L_{cls} = -\sum_i \sum_{\phi=1}^{N_e} y_{i\phi} \log p_{i\phi} \tag{10}$$
# $$L = \lambda_1 L_{self} + \lambda_2 L_{cross} + \lambda_3 L_{vel} + \lambda_4 L_{cls} \tag{11}$$
#
# The first two terms of eqs. 7-8 are the "intermediate supervision" of each branch: each branch alone is pulled
# towards the whole face. $\|\cdot\|_1$ is read as a mean; eq. 9's comma as a difference of velocities. The paper's
# $\lambda = 1000 / 1000 / 500 / 10^{-4}$ act on metres; we measure the vertex terms in mm (`vertex_scale` 1000), so
# $\lambda = 1 / 1 / 0.5$ is the *same* weighting, and $\lambda_4 = 0.01$ (untuned) because our cross-entropy is a batch
# mean where the paper's is a sum at batch size 1.

# %%
# NBVAL_CHECK_OUTPUT
paper, ours = EmoFaceWeights.paper(), EmoFaceWeights()
total_paper, _ = emoface_loss({**out, "emotion_logits": None, "pair_emotion_logits": None}, batch, paper)
total_ours, terms = emoface_loss({**out, "emotion_logits": None, "pair_emotion_logits": None}, batch, ours)
assert abs(float(total_paper) - float(total_ours)) < 1e-4 * float(total_ours)  # same vertex weighting
total, terms = model.loss(out, batch)
print("untrained model:", {k: round(float(v), 3) for k, v in terms.items()})
print(f"chance level of the classifier: ln {len(EMOTIONS)} = {np.log(len(EMOTIONS)):.3f} per clip, x 2 clips")

# %% [markdown]
# ## 5. A short training run, then what the features separate
#
# The generic training loop (`train.train`) trains EmoFace like every model: the pair loader only adds the
# partner's tensors under `pair_*` keys. 36 steps (40-frame crops, a 5-step warm-up; about 6 CPU seconds) are
# a step budget, so the run is the same on every machine: the reconstruction terms fall quickly, but this is far from a trained model (notebook 15 trains longer, with
# Mesh Attention and the self-growing schedule). Read everything below as "after a few dozen steps".

# %%
def loss_on(b):
    with torch.no_grad():
        return {k: round(float(v), 3) for k, v in model.eval().loss(model(b), b)[1].items()}

set_seed(0)
model = EmoFace(cfg)
before = loss_on(batch)
loader = make_pair_loader(pairs, batch_size=8, seed=0)
hist = train(model, loader, TrainConfig.tiny(epochs=1, max_steps=36, warmup_steps=5, progress=False, max_frames=40))
after = loss_on(batch)
print(f"{hist.steps[-1]} steps in {hist.cpu_seconds[-1]:.0f} CPU s; loss terms on the batch of section 2:")
print("  before", before, "\n  after ", after)
assert after["total"] < before["total"] and after["cross"] < before["cross"]
assert after["self"] < 0.4 * before["self"] and after["cross"] < 0.45 * before["cross"]  # "to about a third"

# %% [markdown]
# Now encode every emotional training clip and the emotional test clips of seen speakers with an unseen sentence
# (`test_emo_a`), and pool each clip's features over its frames. The classifier's accuracy on `test_emo_a` says whether
# the emotion branch recognises emotion beyond the sentences it was trained on (chance: 1 in 4 emotional classes).

# %%
@torch.no_grad()
def pooled(items):
    """Per clip: mean F_e, mean F_c (each (N, d)), predicted emotion, true emotion, sentence id."""
    model.eval()
    b = collate(items)
    fc, fe = model.encode(b["audio"], b["mask"])
    m = b["mask"][..., None].float()
    mean = lambda f: ((f * m).sum(1) / m.sum(1)).numpy()  # noqa: E731
    pred = model.classify(fe, b["mask"]).argmax(-1).numpy()
    sentence = [corpus.meta(n)["sentence_id"] for n in b["name"]]
    return mean(fe), mean(fc), pred, b["emotion"].numpy(), np.array(sentence)

emotional = set(corpus.split("train_emo"))
train_items = [it for it in pairs.items if it["name"] in emotional]
test_items = TalkingFaceDataset(corpus, "test_emo_a").items
fe_tr, fc_tr, pred_tr, emo_tr, sent_tr = pooled(train_items)
fe_te, fc_te, pred_te, emo_te, sent_te = pooled(test_items)
acc_train, acc_test = (pred_tr == emo_tr).mean(), (pred_te == emo_te).mean()
print(f"the model's emotion classifier: accuracy train_emo {acc_train:.2f}, test_emo_a {acc_test:.2f} (chance 0.25)")
assert acc_test < 0.25  # below chance after 36 steps (the text below)

# %% [markdown]
# The classifier head itself learns slowly: a few dozen noisy steps mostly teach it the class prior (a third of the
# training clips are neutral, and `train_emo` has none). What the *features* contain is a separate question: a linear
# probe (ridge regression on one-hot labels, standardised pooled features, fitted on `train_emo`, tested on the
# unseen sentence of `test_emo_a`) asks it directly. For reference, the same probe on the pooled log-mel input
# itself (each clip's mean frame of the front end's features) reaches 0.56: the emotion is in the audio.

# %%
def probe(x_train, y_train, x_test, y_test, ridge=10.0):
    """Accuracy of a ridge one-hot linear probe (closed form) fitted on train, scored on test."""
    mu, sd = x_train.mean(0), x_train.std(0) + 1e-6
    a, b = (x_train - mu) / sd, (x_test - mu) / sd
    w = np.linalg.solve(a.T @ a + ridge * np.eye(a.shape[1]), a.T @ np.eye(len(EMOTIONS))[y_train])
    return float(((b @ w).argmax(1) == y_test).mean())

probes = {"F_e": probe(fe_tr, emo_tr, fe_te, emo_te), "F_c": probe(fc_tr, emo_tr, fc_te, emo_te)}
print("linear probe for emotion on test_emo_a:", {k: round(v, 2) for k, v in probes.items()})
assert all(0 <= v <= 1 for v in probes.values())
pooled_input = lambda items: np.stack([it["audio"].mean(0).numpy() for it in items])  # noqa: E731 (N, 160)
input_probe = probe(pooled_input(train_items), emo_tr, pooled_input(test_items), emo_te)  # no training involved
print(f"the same probe on the pooled log-mel input: {input_probe:.2f}")
assert abs(input_probe - 0.56) <= 0.02  # the text above

# %% [markdown]
# **Which feature space knows what?** For each pooled feature and each label, the share of the variance that the
# label explains, $\eta^2 = SS_{between} / SS_{total}$ (1: the clusters are points; 0: the label tells nothing). If the
# branches disentangle, $F_e$ explains emotion better than sentence, and $F_c$ the other way round.

# %%
def eta2(x, labels):
    """Fraction of the total variance of x (N, d) explained by the group means of ``labels``."""
    total = ((x - x.mean(0)) ** 2).sum()
    between = sum((labels == g).sum() * ((x[labels == g].mean(0) - x.mean(0)) ** 2).sum() for g in np.unique(labels))
    return between / total

table = {(f, lab): eta2(x, y) for f, x in (("F_e", fe_tr), ("F_c", fc_tr))
         for lab, y in (("emotion", emo_tr), ("sentence", sent_tr))}
for f in ("F_e", "F_c"):
    print(f"{f}: eta^2 emotion {table[(f, 'emotion')]:.3f}, sentence {table[(f, 'sentence')]:.3f}")
assert all(0 <= v <= 1 for v in table.values())
assert table[("F_e", "emotion")] > table[("F_c", "emotion")]  # the prose below
assert all(table[(f, "sentence")] > table[(f, "emotion")] for f in ("F_e", "F_c"))

# %%
def pca2(x):
    x = x - x.mean(0)
    _, s, vt = np.linalg.svd(x, full_matrices=False)
    return x @ vt[:2].T, (s[:2] ** 2).sum() / (s ** 2).sum()

fig, axes = plt.subplots(2, 2, figsize=(10, 8), constrained_layout=True)
for row, (name, x) in enumerate((("emotion features $F_e$", fe_tr), ("content features $F_c$", fc_tr))):
    z, share = pca2(x)
    for col, (lab, y, names) in enumerate((("emotion", emo_tr, EMOTIONS), ("sentence", sent_tr, None))):
        ax = axes[row, col]
        for g in np.unique(y):
            ax.scatter(*z[y == g].T, s=12, label=names[g] if names else g)
        ax.set(title=f"{name}, coloured by {lab}", xlabel=f"PC 1 (PCs 1-2: {share:.0%} of the variance)", ylabel="PC 2")
        ax.legend(fontsize=7, ncol=2 if lab == "sentence" else 1)
plt.show()

# %% [markdown]
# **What 36 steps give.** The reconstruction terms fell to about a third, and the cross term with them. The
# classifier is still below chance (0.25) on the emotional clips: it leans on the class prior (neutral, the most
# frequent training label, absent from test-emo-A). Emotion explains a larger share of the emotion features'
# variance than of the content features' ($\eta^2$): the emotion branch sees each frame's loudness and spread, which
# the shared front-end's per-frame normalisation removes from the content branch. The linear probe does not agree
# yet at this budget (in this run emotion is read from $F_c$ about as well as from $F_e$, or better: printed above),
# and sentence still explains more of either space than emotion does: the separation eqs. 7-10 aim for has started,
# not finished; this notebook shows the machinery. With the
# tables' budget (840 steps, notebook 15 section 7) the same classifier names the emotion of fewer than half the
# test-emo-A clips (0.47 ± 0.07 over 5 seeds, the "emotion acc." column of `results/emotion.md`).

# %% [markdown]
# ## 6. A pseudo-pair in 3D
#
# What the emotion changes, seen on the face: an emotional clip of the training pairs, each vertex coloured by
# its distance (mm) to the same speaker's neutral reading of the sentence, aligned in time as the pairs of
# section 1 are (`resample_time`).
#
# With a running kernel the cell below shows it live in 3D (drag to orbit, scroll to zoom, the play button or
# the frame slider runs the clip); the committed notebook stores only the widget's placeholder, as in
# notebook 01.

# %%
# NBVAL_IGNORE_OUTPUT
emo_name = next(n for n in pairs.names if n.endswith("-surprised2"))
emo = torch.from_numpy(corpus.vertices(emo_name))  # (T, V*3) metres
neutral = resample_time(torch.from_numpy(corpus.vertices(corpus.meta(emo_name)["neutral_twin"])), len(emo))
emo_v = emo.reshape(len(emo), -1, 3).numpy()  # (T, V, 3)
diff_mm = np.linalg.norm(emo_v - neutral.reshape(len(emo), -1, 3).numpy(), axis=-1) * 1e3  # (T, V)
viewer = MeshViewer(emo_v[0], corpus.faces, colors=diff_mm[0], cmap="magma", vmin=0.0,
                    vmax=float(np.percentile(diff_mm, 99)), width=360, height=360)
display(viewer.player(emo_v, colors=diff_mm))
print(f"{emo_name} against its neutral twin: {diff_mm.mean():.2f} mm per vertex on average")

# %% [markdown]
# ## 7. The lips come from the content
#
# The model above has not learned to close its lips: 36 steps from log-mel are far too few. Notebook 15 (section 6)
# shows what does it in a notebook's budget: the **phonetic route**, where the content encoder $E_c$ reads the
# one-hot viseme track (the corpus's labels in training, a phoneme recogniser's on new speech) instead of the speech
# of eq. 12, a project deviation (`content_dims`; docs/faithfulness.md), while $E_e$ keeps the log-mel, where the
# emotion is; and three levers of `dualtalker-lite train`'s short recipe (PCA-initialised motion heads, lr 6e-3, the
# bilabial contact term of notebook 08). The same 100 steps here, with this notebook's model ("sum" fusion) fed its
# past as notebook 15 feeds it (self-growing, eq. 6: teacher forcing generates worse on its own output), then the cross-reconstruction of eqs. 15-18 at test time: the **content** of one test clip (SPK03 reads
# s02 happily, level 2) with the **emotion** (log-mel, resampled to its length, and the type condition) of the same
# speaker's angry reading of the same sentence. If the branches have split the work, the lips follow the content
# (closing at its /p b m/), whatever the emotion.

# %%
phonetic_pairs = VisemeLabels(pairs, pad_silence=SILENCE_PAD, keep_audio=True)  # audio: (T, 15 visemes + log-mel)
lip_cfg = EmoFaceConfig.tiny(**{**cfg.__dict__, "audio_dim": phonetic_pairs.dim, "content_dims": len(VISEMES),
                                "past_motion": "self_growing", "growing_warmup": 0.2})  # as notebook 15 trains it
tc = TrainConfig.tiny(epochs=2, max_steps=100, max_frames=30, lr=6e-3, pca_init=64, lip_contact=1e-3,
                      progress=False)
set_seed(0)
lip_model = EmoFace(lip_cfg)
lip_hist = train(lip_model, make_pair_loader(phonetic_pairs, batch_size=8, seed=0), tc)
assert lip_hist.steps[-1] == 100 and lip_hist.term("contact")[-1] < 0.5 * lip_hist.term("contact")[0]

# %%
# trained-model figures: nbval does not compare them (their last digit differs between CPU instruction sets);
# the assert is the check
emo_test = TalkingFaceDataset(corpus, "test_emo_a", pairs.front_end)
labelled = VisemeLabels(emo_test, keep_audio=True)
own, other = (labelled[emo_test.names.index(n)] for n in ("SPK03_s02-happy2", "SPK03_s02-angry2"))
k = len(VISEMES)
crossed = torch.cat([own["audio"][:, :k], resample_time(other["audio"][:, k:], len(own["audio"]))], -1)
upper_mid, lower_mid = corpus.regions["lip_midpoints"]
pbm = [s for s in corpus.meta("SPK03_s02-happy2")["phonemes"] if s[0] in BILABIALS]
curves, brows, closures = {}, {}, {}
for label, audio, emotion in (("happy content, happy emotion", own["audio"], "happy"),
                              ("happy content, angry emotion", crossed, "angry")):
    x = lip_model.generate(audio[None], own["template"][None], torch.tensor([own["speaker"]]),
                           emotion=EMOTIONS.index(emotion), level=2)[0]  # (T, V*3)
    curves[label] = lip_distance(x, upper_mid, lower_mid)
    brows[label] = brow_raise(x, own["template"], corpus.regions["brows"])
    mins = closures[label] = segment_extrema(curves[label], pbm, BILABIALS, tolerance_frames=1)
    print(f"{label}: smallest lip distance at the {len(pbm)} /p b m/ {', '.join(f'{m:.1f}' for m in mins)} mm; "
          f"brow raise {brows[label]:+.2f} mm")
corr = np.corrcoef(*curves.values())[0, 1]
print(f"correlation of the two lip-distance curves {corr:.3f}")
assert corr > 0.9  # the lips follow the content

# %%
# the figures the text below quotes, within CPU-to-CPU differences: the emotion moves the brows, the lips stay
happy, angry = brows["happy content, happy emotion"], brows["happy content, angry emotion"]
assert abs(happy - 1.12) <= 0.1 and abs(angry - 0.34) <= 0.1 and happy - angry >= 0.5
near = closures["happy content, happy emotion"]
assert (sum(near < 1.0), sum(near < 2.0)) == (5, 7) and abs(corr - 0.997) <= 0.002
assert np.abs(near - closures["happy content, angry emotion"]).max() <= 0.45

# %%
curves = {"ground truth (happy)": lip_distance(own["vertices"], upper_mid, lower_mid), **curves}
plot_lip_distance(np.arange(len(own["audio"])) / corpus.fps, curves, phonemes=pbm, figsize=(11, 3.2),
                  title=f"SPK03 s02: '{corpus.meta('SPK03_s02-happy2')['text']}' (/p b m/ shaded)")

# %% [markdown]
# After 100 steps the lips close at the /p b m/ of this unseen sentence (within 1 mm at five of the eight, within
# 2 mm at seven: the printout; the first falls at the clip's start, where the model begins at the template's rest
# gap), and they open at the vowels, though only about half as far as the ground truth: the contact term's trade on
# EmoFace, measured over the whole split in notebook 15 (section 6). With the angry reading's emotion the lip curve
# is almost the same (correlation 0.997, the closures within 0.4 mm), while the brows change (a raise of 0.34 mm
# against 1.12): on the phonetic route the mouth is the content's and the brows the emotion's, the split that
# eqs. 15-18 ask for. It holds by construction for the content's side (viseme labels carry no emotion); whether the
# emotion branch also leaves the mouth alone is what the unchanged lip curve shows.

# %% [markdown]
# ## Summary
#
# - A pseudo-pair is the same speaker and sentence in two emotions; the corpus lists them, and `PairDataset` hands
#   each clip a partner, resampled linearly to the clip's length (our reading of the paper's equal-length notation).
# - The content encoder is per frame, the emotion encoder sees the whole clip, and an emotion classifier (eq. 10)
#   reads the mean and standard deviation of the emotion features. The emotion branch is conditioned on the level
#   (one-hot, the paper's) and on the type (this project's addition: the true label in training).
# - Cross-reconstruction rebuilds the partner from clip 1's content features and the partner's emotion features
#   (eqs. 15-18); the check in section 3 is exactly that definition.
# - Eqs. 7-11 weight the branches' intermediate supervision, the fused output, the velocity and the classifier;
#   the paper's $\lambda$'s in metres equal ours in mm on every vertex term.
# - After a few dozen steps, read the classifier's accuracy, the probes and the $\eta^2$ table above: they show how far
#   the two feature spaces have split at this budget (the printed numbers, not a claim of this notebook). A real
#   split needs the longer runs of notebook 15 and the experiments.
# - On the phonetic route (the content encoder reads visemes, a project deviation from eq. 12) with the short
#   recipe's levers, 100 steps close the lips at the /p b m/ of an unseen sentence; the content of a happy reading
#   with the emotion of an angry one keeps the same lips and changes the brows.
#
# ## Exercises
#
# 1. Train without cross-reconstruction (`EmoFaceConfig.tiny(..., cross_reconstruction=False)`) for the same
#    budget. Does $\eta^2$(emotion) of $F_e$ change? Does $\eta^2$(sentence) of $F_e$ rise?
# 2. Replace the linear resampling by cropping both clips to the shorter length (write a small `collate`). Which
#    frames of the cross target are then misaligned, and what does that do to $L_{cross}$?
# 3. Set $\lambda_4 = 0$ (`EmoFaceWeights(lambda_cls=0)`). Is the emotion still recognisable from $F_e$ (accuracy of
#    a nearest-centroid classifier on the pooled features)?
# 4. Generate one test sentence with each emotion (`model.generate(..., emotion=k, level=2)`) and plot the brow
#    height over time: which emotions move the brows?
