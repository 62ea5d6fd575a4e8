# %% [markdown]
# # 00 · Overview: speech-driven 3D facial animation
#
# Give a model a recording of someone speaking and a neutral 3D head of that person; it must move the head's
# vertices, 30 times a second, so that the lips, jaw and face follow the speech. This series builds that, one
# equation at a time, following three recent papers — **DualTalker**, **CorrTalk** and **EmoFace** — on a small
# synthetic corpus that ships with the repository (`data_samples/`: real synthesized speech driving a procedural
# face rig; notebook 01 shows how it is made).
#
# **We will cover**
#
# 1. The task: speech in, per-frame 3D vertex displacements of a template out (DualTalker eq. 1).
# 2. Why it is hard: one-to-many mapping, coarticulation, and the over-smoothing a regressor falls into.
# 3. What each of the three papers adds.
# 4. The map of this series (notebooks 00-15: DualTalker, then CorrTalk, then EmoFace).
# 5. A 30-second tour: one clip of the corpus — its text, frames, lip distance, and an animation with its speech.
# 6. Your own recording: upload a WAV, pick a checkpoint and a speaker, watch the animation with sound.
#
# | paper symbol | code name | shape |
# |---|---|---|
# | $\mathcal{X}$ (raw speech, 16 kHz) | `wave` | (N,) |
# | $A_{1:T'}$ (speech features per mesh frame; notebook 02) | `audio` | (T, 160) |
# | $h$ (neutral template of the speaker) | `template` | (V*3,) |
# | $M_{1:T}$, $m_t$ (motion: displacements from $h$) | `motion` | (T, V*3) |
# | $M_{1:T} + h$ (absolute vertex positions, metres) | `vertices` | (T, V*3) |
# | $S_n$ (style of speaker $n$) | `speaker` (an index here; an embedding in the models) | int |
# | $T$ (mesh frames, 30 fps), $V$ (vertices) | `n_frames`, `n_vertices` | int |

# %%
%matplotlib inline
import matplotlib.pyplot as plt
import numpy as np
import torch

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.metrics import lip_distance
from dualtalker_lite.checks import check_shape
from dualtalker_lite.seeding import set_seed
from dualtalker_lite.viz import animate_clip, plot_frames, plot_lip_distance

torch.set_num_threads(2)
gen = set_seed(0)
corpus = Corpus(sample_path())  # the shipped corpus (data_samples/)
print(f"{len(corpus)} clips, {len(corpus.speakers)} speakers, {corpus.fps} fps, {corpus.sample_rate} Hz audio")

# %% [markdown]
# ## 1. The task (DualTalker eq. 1)
#
# A sequence of face meshes is stored as absolute vertex positions, but every model in this series predicts
# the **motion** $m_t \in \mathbb{R}^{V\times 3}$: the displacement of each of the $V$ vertices from the speaker's
# neutral template $h$, at mesh frame $t$ (30 frames per second). DualTalker writes the primal task as an
# autoregressive model — each frame depends on the past predicted frames, the speaker's style $S_n$ and the
# whole speech signal $\mathcal{X}$:
#
# $$\hat{m}_t = \mathrm{FacialAnimation}_{\theta}(\hat{m}_{<t}, S_n, \mathcal{X}) \tag{1}$$
#
# and the vertices shown on screen are $\hat{m}_t + h$. Its *dual* task, lip reading, runs the other way:
# $\hat{a}_t = \mathrm{LipReading}_{\gamma}(\hat{a}_{<t}, S_n, M_{1:T})$ (eq. 2). Here is one clip in those terms.

# %%
name = "SPK01_s02"  # a test clip: seen speaker, sentence never used for training
meta = corpus.meta(name)
vertices = corpus.vertices(name)                  # (T, V*3) metres: M_{1:T} + h
template = corpus.template(meta["subject"])       # (V*3,)    h
wave = corpus.wave(name)                          # (N,)      16 kHz speech
motion = vertices - template                      # (T, V*3)  M_{1:T}
T, V = meta["n_frames"], corpus.metadata["n_vertices"]
check_shape(vertices, (T, 3 * V), "vertices")
check_shape(motion, (T, 3 * V), "motion")
assert abs(len(wave) / corpus.sample_rate * corpus.fps - T) <= 1   # audio and mesh cover the same time
step = np.linalg.norm(motion.reshape(T, V, 3), axis=-1) * 1000      # (T, V) displacement length, mm
print(f"T = {T} frames = {T / corpus.fps:.2f} s, V = {V} vertices, audio N = {len(wave)} samples")
print(f"largest displacement {step.max():.1f} mm; vertices that ever move > 1 mm: {(step.max(0) > 1).sum()}")

# %% [markdown]
# ## 2. Why it is hard
#
# - **One-to-many.** The same sentence has many plausible facial motions: speakers differ in timing, in how far
#   they open the jaw, in their resting face, and upper-face motion (blinks, brows) is barely related to speech.
# - **Coarticulation.** A phoneme's mouth shape depends on its neighbours: the lips start rounding for the /u:/
#   in "two" during the /t/. A lookup table phoneme -> mouth shape is not enough (notebook 01).
# - **Over-smoothing.** Trained with a mean squared error, a regressor predicts the *average* of the plausible
#   motions. Averages of out-of-phase, differently sized movements are flat: the mouth under-articulates.
#
# The cell below makes the first and last points concrete with the 8 seen speakers saying the same training
# sentence, put on a common time axis (fraction of the utterance). Left: the lip distance (the DualTalker Fig. 5
# curve, upper- to lower-lip midpoint), which the speech largely determines. Right: the mean displacement of the
# eye vertices, which moves only when the speaker happens to blink. The black lines are the means over speakers —
# what an MSE model, which cannot tell the speakers' random blinks apart, would aim for.

# %%
sentence = "s00"
clips = [c for c in corpus.split("train") if c.endswith("_" + sentence)]
upper_mid, lower_mid = corpus.regions["lip_midpoints"]
eyes = corpus.regions["eyes"]
grid = np.linspace(0.0, 1.0, 100)                 # common time axis: fraction of the utterance
lips, blinks = [], []
for c in clips:
    v = corpus.vertices(c).reshape(-1, V, 3)                         # (T_c, V, 3)
    h = corpus.template(corpus.meta(c)["subject"]).reshape(V, 3)
    d = lip_distance(v, upper_mid, lower_mid)                         # (T_c,) mm
    e = np.linalg.norm(v[:, eyes] - h[eyes], axis=-1).mean(1) * 1000  # (T_c,) mm
    t_c = np.linspace(0.0, 1.0, len(d))
    lips.append(np.interp(grid, t_c, d)), blinks.append(np.interp(grid, t_c, e))
lips, blinks = np.stack(lips), np.stack(blinks)   # (speakers, 100) each
print(f"{len(clips)} speakers: '{corpus.meta(clips[0])['text']}'")
ratios = {}
for label, curves in (("lip distance", lips), ("eye displacement", blinks)):
    each, of_mean = curves.std(1).mean(), curves.mean(0).std()  # temporal std: per speaker vs of the mean
    ratios[label] = of_mean / each
    print(f"{label:16s}: temporal std per speaker {each:.3f} mm, of the mean curve {of_mean:.3f} mm "
          f"({100 * ratios[label]:.0f} %)")
assert len(clips) == 8
assert ratios["lip distance"] > 0.8 and ratios["eye displacement"] < 0.6   # blinks average out, lips do not

# %%
fig, axes = plt.subplots(1, 2, figsize=(10, 3.2), layout="constrained")
for ax, curves, what in ((axes[0], lips, "lip distance (mm)"), (axes[1], blinks, "eye displacement (mm)")):
    for c, curve in zip(clips, curves):
        ax.plot(grid, curve, lw=1, alpha=0.7, label=c.split("_")[0])
    ax.plot(grid, curves.mean(0), color="black", lw=2.5, label="mean (MSE target)")
    ax.set(xlabel="time (fraction of the utterance)", ylabel=what)
axes[0].set_title("Lips: driven by the speech, the mean keeps the motion", fontsize=10)
axes[1].set_title("Blinks: random times, the mean is nearly flat", fontsize=10)
axes[1].legend(fontsize=7, ncols=3, loc="upper right")
plt.show()

# %% [markdown]
# Where the plausible motions agree (the lips, once the timing is known from the audio) their mean keeps most of
# the movement; where they do not (blinks, brow motion), the mean — and hence an MSE model's prediction — is
# nearly still. DualTalker's FDD metric (eq. 12) measures exactly this loss of upper-face dynamics, and real
# data adds the same effect *inside* the mouth motion (speakers differ in timing and in how they coarticulate).

# %% [markdown]
# ## 3. What each paper adds
#
# All three build on **FaceFormer** (Fan et al., 2022): a wav2vec 2.0 audio encoder, an autoregressive
# transformer decoder over past motion with a biased causal self-attention, and cross-attention from motion to
# audio. They attack the problems above from different sides:
#
# | paper | problem it targets | what it adds | equations |
# |---|---|---|---|
# | **DualTalker** (Su, Yang, Li) | little paired data; over-smoothing | **dual learning**: the primal task (audio -> face) is trained jointly with its inverse, **lip reading** (face -> audio), sharing the audio/motion/style encoders; a speaker-aware gate; audio-visual integration with shared Q/K weights; a **duality loss** (Smooth L1 between the fused features of the two tasks); **CCRL**, a contrastive loss whose negatives are weighted by a kernel on motion distance | eqs. 1-12 |
# | **CorrTalk** (Chu et al.) | one speech feature level for the whole face | **facial activity intensity** (FAI): the STFT of each vertex's displacement separates strongly moving (mouth) from weakly moving (upper face) vertices; **hierarchical speech features** (frame / phoneme / word / utterance windows) mixed by learned weights; a **strong/weak dual-branch decoder** with an FAI-initialised mask | (inline; see the paper) |
# | **EmoFace** (Lin et al.) | emotion is ignored or entangled with content | **emotion/content disentanglement** with cross-reconstruction on pseudo-pairs (same sentence, another emotion); **Mesh Attention** built on SpiralConv3D (spirals on the mesh, deltas in time) to fuse the two branches per vertex; **self-growing training**, a schedule that feeds the decoder more of its own predictions over time | eqs. 6-11 |
#
# The three report the same metrics: **LVE** (lip vertex error), **FDD** (upper-face dynamics deviation,
# DualTalker eq. 12) and EmoFace's **EVE** (eye/forehead error) — notebook 09.

# %% [markdown]
# ## 4. The map of this series
#
# | notebook | what it builds |
# |---|---|
# | **00** overview | the task, the papers, a tour of one clip (this notebook) |
# | **01** synthetic talking faces | the corpus: template mesh, rig, espeak-ng speech, visemes, coarticulation, speakers, emotions |
# | **02** audio features | STFT, mel filterbank, log-mel, alignment to 30 fps; where wav2vec 2.0 fits |
# | **02a** phonetic front end | why log-mel from one voice fails on people; a phoneme recogniser's viseme track, the route that lip-syncs real voices |
# | **02b** distilling our own ears | a small causal viseme recogniser distilled from that track: teacher labels, a causal receptive field with a look-ahead, the distillation loss, the look-ahead trade-off, the student on a real voice |
# | **03** attention | scaled dot-product and multi-head attention (eqs. 3-4), FaceFormer's biases, alignment mask |
# | **04** speaker-aware gate | DualTalker's SE-style speaker gate (eq. 5) |
# | **05** cross-modal fusion and dual integration | audio-visual integration (eq. 6) and its dual with shared Q/K (eq. 7) |
# | **06** duality loss | Smooth L1 between the fused features of the primal and dual tasks (eq. 8) |
# | **07** CCRL kernel weighting | the kernel-weighted cross-modal contrastive loss (eqs. 9-11) |
# | **08** training DualTalker | the joint loss with $\lambda_1..\lambda_4$, the training loop, checkpoints |
# | **09** evaluation and ablations | LVE, FDD, EVE, lip-distance plots; the ablations of DualTalker Table IV |
# | **10** facial activity intensity | CorrTalk: how much each vertex moves (FAI, eq. 3) and the mask it gives (eqs. 7-8) |
# | **11** hierarchical speech features | CorrTalk: phoneme-, word- and utterance-level windows of the speech encoder (eqs. 1, 4-6) |
# | **12** training CorrTalk | CorrTalk's strong/weak dual-branch decoder trained (eqs. 7-11), its Table III ablations, beside DualTalker |
# | **13** spiral convolution | EmoFace: k-rings, spirals and SpiralConv3D on the mesh (eqs. 1-3), Mesh Attention, the Table 4 sweep |
# | **14** emotion/content disentanglement | EmoFace: pseudo-pairs, two encoders, cross-reconstruction and the emotion classifier (eqs. 7-18) |
# | **15** self-growing and Mesh Attention | EmoFace: self-growing training (eq. 6), the Mesh Attention map, emotion control, the Table 2/3 analogues |

# %% [markdown]
# ## 5. A 30-second tour of one clip
#
# Every clip carries its text, speaker, emotion (with an intensity level), and a phoneme track with exact times
# from the speech synthesizer.

# %%
# NBVAL_CHECK_OUTPUT
print(f"clip    : {name}  (split {meta['split']})")
print(f"text    : {meta['text']}")
print(f"speaker : {meta['subject']}  (training index {corpus.speaker_index(meta['subject'])})")
print(f"emotion : {meta['emotion']}, level {meta['level']}")
print(f"frames  : {meta['n_frames']} at {corpus.fps} fps = {meta['n_frames'] / corpus.fps:.3f} s; "
      f"audio {meta['n_samples']} samples at {corpus.sample_rate} Hz")
print("phonemes:", " ".join(p for p, _, _ in meta["phonemes"]))

# %% [markdown]
# Four frames: the widest-open and the most-closed mouth, and two in between. The lip distance over time
# drops to zero on every /p/, /b/ and /m/ — there are many in this sentence.

# %%
d = lip_distance(vertices, upper_mid, lower_mid)                     # (T,) mm
frames = sorted({int(d.argmax()), int(d.argmin()), T // 3, 2 * T // 3})
fig = plot_frames(vertices.reshape(T, V, 3)[frames], corpus.faces,
                  titles=[f"t = {f / corpus.fps:.2f} s, {d[f]:.1f} mm" for f in frames],
                  suptitle=f"{name}: '{meta['text']}'", panel_size=2.2)
fig

# %%
assert d.min() < 1.0 and d.max() > 5.0    # lips close on bilabials and open on vowels
times = np.arange(T) / corpus.fps
plot_lip_distance(times, {name: d}, phonemes=meta["phonemes"], title="Lip distance of the clip (DualTalker Fig. 5)")

# %% [markdown]
# And the clip itself, with its speech (`animate_clip` renders the frames, encodes H.264 and muxes the audio;
# the video is written under `runs/videos/` and embedded in the notebook).

# %%
# NBVAL_IGNORE_OUTPUT
from IPython.display import HTML

video = animate_clip(vertices.reshape(T, V, 3), corpus.faces, wave=wave, sample_rate=corpus.sample_rate, size=256)
HTML(video._repr_html_())  # the player only (the object's repr would show a local file path)

# %% [markdown]
# ## 6. Your own recording
#
# Everything above used the shipped corpus. To animate **your own speech**, upload a WAV file (any sample rate,
# mono), pick a checkpoint trained in this series and one of the speakers it was trained on, and press
# *Animate*. This is the same path as the command line `dualtalker-lite animate --checkpoint ... --wav ...
# --speaker ...` (README, "Your own recordings"): the audio is validated (stereo, empty, NaN, overflowing or
# truncated files are refused with a message naming the problem), the speaker names come from the checkpoint
# itself, and the prediction is checked to be finite.
#
# The checkpoint list shows every `*.pt` under `runs/` (notebook 08 writes `runs/nb08/dualtalker_tiny.pt`,
# `make demo` writes `runs/demo/dualtalker.pt`). If there is none yet, a stand-in is trained here in a few
# seconds (a VOCA-style model, 3 epochs on 59 clips): it moves the mouth with the speech, but crudely; train properly in
# notebook 08 or with `make demo`. Without an upload, the cell animates a shipped test clip's speech, so the
# notebook also runs unattended.

# %%
from dualtalker_lite.checkpoints import save_checkpoint
from dualtalker_lite.files import runs_dir


def stand_in_checkpoint():
    """A quickly trained VOCA-style model, written once to runs/nb00/ (a self-describing checkpoint)."""
    from torch.utils.data import Subset

    from dualtalker_lite.data.dataset import TalkingFaceDataset, make_loader
    from dualtalker_lite.losses import ReconstructionWeights
    from dualtalker_lite.models.baselines import VocaConfig, VocaStyle
    from dualtalker_lite.train import TrainConfig, train

    path = runs_dir("nb00") / "voca_stand_in.pt"
    if not path.exists():
        train_set = TalkingFaceDataset(corpus, "train")
        data = Subset(train_set, range(0, len(train_set), 3))  # every third clip (59 of 176), every speaker
        set_seed(0)
        cfg = VocaConfig.tiny(n_vertices=V, audio_dim=160, n_speakers=len(corpus.train_speakers))
        model, tc = VocaStyle(cfg), TrainConfig.tiny(epochs=3, progress=False, validate_every=0,
                                                     weights=ReconstructionWeights())
        history = train(model, make_loader(data, tc.batch_size, seed=0), tc)
        save_checkpoint(path, model, cfg, tc, history, speakers=corpus.train_speakers, faces=corpus.faces)
    return path


# %% [markdown]
# The widget (`dualtalker_lite.viz.widgets.RecordingPanel`): upload, pick, animate. The button is disabled while
# it works; errors (a stereo file, a speaker the model does not know, ...) appear as one line under it.

# %%
# NBVAL_IGNORE_OUTPUT
from IPython.display import display

from dualtalker_lite.viz.widgets import RecordingPanel

checkpoints = sorted(p for p in runs_dir().rglob("*.pt") if not p.name.startswith(".")) or [stand_in_checkpoint()]
panel = RecordingPanel(corpus, checkpoints, default_wave=corpus.wave(name), root=runs_dir())
display(panel.widget)
panel.run()  # the default path (no upload: the tour's test clip), run once so the notebook shows a result
print(panel.status.value)

# %%
# The default path without widgets, checked: a shipped clip's speech through the chosen checkpoint.
from dualtalker_lite.checkpoints import load_checkpoint
from dualtalker_lite.front_ends import from_settings
from dualtalker_lite.inference import animate_wave, resolve_speaker

model_own, info_own = load_checkpoint(panel.checkpoint.value)
index_own, _ = resolve_speaker(info_own, panel.speaker.value, corpus)
verts_own = animate_wave(model_own, corpus.wave(name), corpus.template(panel.speaker.value), index_own,
                         front_end=from_settings(info_own.get("features")))  # (T, V*3)
assert verts_own.shape == (T, 3 * V) and np.isfinite(verts_own).all()
print(f"{panel.speaker.value}: {len(verts_own)} frames, mouth moves up to "
      f"{1000 * np.abs(verts_own - corpus.template(panel.speaker.value)).max():.1f} mm from the template")

# %% [markdown]
# ## Summary
#
# - The task maps speech $\mathcal{X}$ (16 kHz) to motion $M_{1:T}$: per-frame displacements (metres) of the $V$
#   template vertices at 30 fps; DualTalker writes it as the autoregressive eq. 1 and adds its inverse, lip
#   reading (eq. 2).
# - It is hard because one sentence allows many motions (speakers, timing, upper face), because of
#   coarticulation, and because an MSE regressor averages the plausible motions into a flat, over-smoothed one.
# - DualTalker adds dual learning with lip reading, the duality loss and CCRL; CorrTalk adds facial activity
#   intensity, hierarchical speech features and a strong/weak decoder; EmoFace adds emotion/content
#   disentanglement, Mesh Attention and self-growing training.
# - Your own recording goes through the same validated path as `dualtalker-lite animate`: the checkpoint knows
#   its speakers, the audio and the output are checked, nothing half-written is left behind.
#
# ## Exercises
#
# 1. Pick a clip from `corpus.split("test_b")` (an unseen speaker) and repeat the tour. What does
#    `corpus.speaker_index` return for it, and why does that matter for a model with one style embedding per
#    training speaker?
# 2. In section 2, plot the curves against time in seconds instead of the fraction of the utterance (the
#    speakers talk at different rates). How much flatter is the mean lip curve now? Which of the two alignments
#    corresponds to a model that hears the audio?
# 3. Compute the largest displacement (mm) of the `upper_face` region for a few clips and compare it with the
#    `lips` region. Which region will dominate a plain MSE over all vertices?
