# %% [markdown]
# # 02a · The phonetic front-end: a phoneme recogniser between the voice and the face
#
# Notebook 02 built the log-mel features $A_{1:T}$ that every model reads. They describe the *sound*, and every
# clip of the corpus is spoken by one synthetic voice family (espeak-ng): a model that learns lip shapes from
# them learns that voice, and barely moves the lips for a real person (`results/real_voices.md`). This notebook
# teaches the project's answer (issue 19): a pretrained **CTC phoneme recogniser** (`hama`, shipped inside its
# PyPI wheel) turns any voice into phone symbols, the symbols become the corpus's own 15 **visemes**, and the
# face is driven by those classes (`dualtalker_lite.recogniser`; `docs/front-ends.md` has the measurements).
#
# **We will cover**
#
# 1. Why log-mel trained on one voice family fails on people: a linear viseme probe, espeak vs a real voice.
# 2. What a CTC phoneme recogniser outputs: posteriors at 50 frames/s, blanks and spikes, and their lag.
# 3. The viseme route: symbols to visemes, the spike track, frame accuracy against the corpus's labels, and the
#    rig driven by the recogniser's classes against the ground truth.
# 4. A real recording (two CC-BY-SA telephone prompts shipped in `notebooks/data/real/`): the rig driven by the
#    recogniser next to the rig driven by the force-aligned phones.
# 5. Your own voice: record from the browser's microphone and animate it here, or go live with
#    `dualtalker-lite live`.
# 6. What each front-end can and cannot do.
#
# | symbol | code name | shape |
# |---|---|---|
# | $A_t$ (log-mel of mesh frame $t$, standardised) | `X_train[t]` | (160,) |
# | $W, b$ (linear probe) | `probe.weight`, `probe.bias` | (15, 160), (15,) |
# | $v$ (viseme index into `VISEMES`, 0 = `sil`) | `labels`, `track` | (T,) |
# | $\log p_j(s)$ (recogniser log-probabilities, frame $j$, symbol $s$) | `log_probs` | (J, 191) = (1 + N // 320, 191) |
# | $t_j = 0.02\,j$ (recogniser frame time, s) | `spike_frames / RATE` | (S,) |
# | $\beta$ (blank bias) | `BLANK_BIAS` = -0.1 | scalar |
# | $\nu(s)$ (symbol to viseme) | `SYMBOL_TO_VISEME` | dict, 191 entries |
# | $\delta$ (lag, s), $w$ (window, s) | `LAG_S` = 0.02, `WINDOW_S` = 0.1 | scalars |
# | $d(f)$ (lip distance of mesh frame $f$, mm) | `lip_distance(...)` | (T,) |
# | $T$ (mesh frames at 30 fps), $J$ (recogniser frames at 50 fps) | `n_frames`, `len(log_probs)` | int |

# %%
%matplotlib inline
import json
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import torch
from IPython.display import HTML

from dualtalker_lite.audio import LogMelExtractor, hz_to_mel, load_audio
from dualtalker_lite.checks import check_shape
from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus, read_json
from dualtalker_lite.data.dataset import TalkingFaceDataset, VisemeLabels
from dualtalker_lite.face import FaceRig, Speaker, VISEMES, clip_controls, phonemes_to_visemes, viseme_ids
from dualtalker_lite.metrics import BILABIALS, closure_rate, lip_distance, segment_extrema
from dualtalker_lite.recogniser import (BLANK_BIAS, LAG_S, RATE, SYMBOL_TO_VISEME, WINDOW_S, PhonemeRecogniser,
                                        RecogniserExtractor, spike_track)
from dualtalker_lite.seeding import set_seed
from dualtalker_lite.viz import animate_clip, plot_lip_distance

torch.set_num_threads(2)
gen = set_seed(0)
corpus = Corpus(sample_path())
SR, FPS = corpus.sample_rate, corpus.fps                    # 16000 Hz, 30 fps
LIP_MID = tuple(corpus.regions["lip_midpoints"])            # (upper, lower) lip midpoint vertex
REAL = Path("data/real")                                     # notebooks/data/real/ (the notebook runs in notebooks/)
recogniser = PhonemeRecogniser()     # cached under $DUALTALKER_CACHE or ~/.cache/dualtalker-lite (first run computes)
extractor = RecogniserExtractor("visemes", recogniser=recogniser)

# %% [markdown]
# ## 1. Why log-mel trained on one voice family fails on people
#
# A **linear probe** asks how much of the mouth shape is *linearly readable* from a representation. Per mesh frame,
# the standardised log-mel $A_t$ goes through one affine map and a softmax over the 15 visemes:
#
# $$\hat p(v \mid A_t) = \mathrm{softmax}\big(W A_t + b\big)_v \tag{1}$$
#
# trained with cross-entropy on the corpus's labels (`item["visemes"]`) of the 176 training clips, and tested on
# held-out sentences (`test_a`, the same espeak voices) and on a real voice. The real voice is two prompts of
# Debian's `asterisk-core-sounds-en-wav` ("Allison", CC-BY-SA 3.0, 8 kHz telephone audio; see
# `notebooks/data/real/NOTICE`), with their phones force-aligned by pocketsphinx (precomputed JSON).

# %%
logmel = LogMelExtractor(fps=FPS)
train_set, test_set = TalkingFaceDataset(corpus, "train"), TalkingFaceDataset(corpus, "test_a")
X_train = torch.cat([it["audio"] for it in train_set]); y_train = torch.cat([it["visemes"] for it in train_set])
X_test = torch.cat([it["audio"] for it in test_set]); y_test = torch.cat([it["visemes"] for it in test_set])
real = {}
for path in sorted(REAL.glob("*.json")):                     # the two real prompts
    info = json.loads(path.read_text())
    wave = load_audio(path.with_suffix(".flac"))             # 8 kHz -> 16 kHz (one warning line each)
    n = int(round(len(wave) * FPS / SR))
    labels = torch.from_numpy(viseme_ids(phonemes_to_visemes(info["phones"]), n, FPS))
    real[info["name"]] = dict(info, wave=wave, n=n, labels=labels, audio=logmel(wave, n))
X_real = torch.cat([r["audio"] for r in real.values()]); y_real = torch.cat([r["labels"] for r in real.values()])
mu, sd = X_train.mean(0), X_train.std(0) + 1e-3
check_shape(X_train, (len(y_train), 160), "X_train")
print(f"frames: train {len(y_train)}, test_a {len(y_test)}, real {len(y_real)}")

# %%
probe = torch.nn.Linear(160, len(VISEMES))
opt = torch.optim.Adam(probe.parameters(), lr=0.05)
for step in range(300):                                      # full batch: a convex problem
    opt.zero_grad()
    loss = torch.nn.functional.cross_entropy(probe((X_train - mu) / sd), y_train)
    loss.backward()
    opt.step()


def probe_accuracy(X, y):
    with torch.no_grad():
        return float((probe((X - mu) / sd).argmax(1) == y).float().mean())


acc = {"espeak, train": probe_accuracy(X_train, y_train), "espeak, held-out sentences": probe_accuracy(X_test, y_test),
       "real voice (2 prompts)": probe_accuracy(X_real, y_real)}
majority = float((y_real == torch.bincount(y_train).argmax()).float().mean())
for k, v in acc.items():
    print(f"probe accuracy, {k:28s}: {v:.2f}")
print(f"(the most frequent training viseme on the real frames: {majority:.2f})")
assert acc["espeak, held-out sentences"] > 0.5 and acc["real voice (2 prompts)"] < acc["espeak, held-out sentences"] - 0.3

# %%
fig, axes = plt.subplots(1, 2, figsize=(11, 3.4), layout="constrained", width_ratios=(1, 1.6))
axes[0].bar(range(len(acc)), list(acc.values()), color=["tab:blue", "tab:blue", "tab:red"])
axes[0].set_xticks(range(len(acc)), [k.replace(", ", "\n") for k in acc], fontsize=8)
axes[0].set(ylabel="frame accuracy", ylim=(0, 1), title="Linear viseme probe on log-mel (eq. 1)")
for name, colour in (("SPK01_s02", "tab:blue"), (next(iter(real)), "tab:red")):
    a = test_set[test_set.names.index(name)]["audio"] if name in test_set.names else real[name]["audio"]
    axes[1].plot(np.arange(80), a[:, :80].mean(0), color=colour, label=name)
axes[1].axvline(hz_to_mel(4000.0) / hz_to_mel(8000.0) * 81 - 1, color="k", ls="--", lw=0.8, label="4 kHz")
axes[1].set(xlabel="mel band m (0-8 kHz)", ylabel="mean log power (a.u.)",
            title="Average log-mel spectrum: espeak clip vs real telephone prompt")
axes[1].legend(fontsize=8)
plt.show()

# %% [markdown]
# The probe reads most espeak frames of sentences it never saw, and few of the real voice's: what it learned
# is how *this voice family* sounds for each mouth shape. Part of the gap here is the channel (the real prompts
# are telephone audio: the mel bands above 4 kHz are empty, right panel), but the issue measured the same on
# 15 wide-band recordings of people (72% espeak vs 13% real, `docs/front-ends.md`), and a model is no better off
# than its input: DualTalker on log-mel closes the lips on 0.34 of real bilabials (< 2 mm,
# `results/real_voices.md`). Exercise 1 separates the channel from the voice.
#
# ## 2. What a CTC phoneme recogniser outputs
#
# `PhonemeRecogniser.log_probs` maps 16 kHz speech to log-probabilities over 191 symbols (phones of many
# languages, marks, the word boundary `<wb>` and the CTC **blank** $\varnothing$) at 50 frames per second: frame
# $j$ is at $t_j = 0.02\,j$ s and a wave of $N$ samples gives $1 + \lfloor N / 320 \rfloor$ frames. A CTC model
# is trained to emit each phone on one or two frames and the blank everywhere else, so the useful output is the
# greedy path with its **spikes**, the frames whose best symbol is a phone:
#
# $$\hat y_j = \arg\max_{s} \Big(\log p_j(s) + \beta\,[\,s = \varnothing\,]\Big), \qquad
# S = \{\, j : \nu(\hat y_j) \neq \mathrm{None} \,\} \tag{2}$$
#
# Below: a held-out clip of the corpus, "Pam put the paper map back." (8 /p b m/).

# %%
name = "SPK01_s02"
meta, wave_syn = corpus.meta(name), corpus.wave(name)
log_probs = np.asarray(recogniser.log_probs(wave_syn), dtype=np.float32)   # (J, 191), float16 on disk
J = len(log_probs)
check_shape(log_probs, (1 + len(wave_syn) // 320, 191), "log_probs")
biased = log_probs.copy()
biased[:, recogniser.blank_id] += BLANK_BIAS                                # eq. 2, as spikes() does
best = biased.argmax(1)
blank_share = float((best == recogniser.blank_id).mean())
spike_frames, spike_vis = recogniser.spikes(log_probs)                      # eq. 2
spike_symbols = [recogniser.symbols[best[j]] for j in spike_frames]
print(f"{meta['text']!r}: J = {J} frames at {RATE} fps; blank wins {blank_share:.0%} of them")
print("greedy phones:", " ".join(spike_symbols))
assert blank_share > 0.5 and 10 <= len(spike_frames) <= 40
assert np.allclose(np.exp(log_probs).sum(1), 1.0, atol=0.05)              # a distribution per frame

# %%
shown = sorted(set(best.tolist()) | {recogniser.blank_id})                  # the symbols that win somewhere
fig, axes = plt.subplots(2, 1, figsize=(11, 5.6), layout="constrained", sharex=True, height_ratios=(2.2, 1))
im = axes[0].imshow(np.exp(log_probs[:, shown]).T, aspect="auto", cmap="Greys", origin="lower",
                    interpolation="nearest", extent=(0, J / RATE, 0, len(shown)), vmin=0, vmax=1)
axes[0].set_yticks(np.arange(len(shown)) + 0.5, [recogniser.symbols[s] for s in shown], fontsize=7)
axes[0].set(ylabel="symbol", title="Recogniser posteriors $p_j(s)$ at 50 fps (only the symbols that win a frame)")
fig.colorbar(im, ax=axes[0], label="probability")
for v, a, b in meta["visemes"]:                                             # the aligned transcript (labels)
    axes[1].axvspan(a, b, 0.55, 0.95, color="tab:orange" if v == "PP" else "0.85")
    axes[1].text((a + b) / 2, 0.75, v, ha="center", va="center", fontsize=7)
for j, v in zip(spike_frames, spike_vis):
    axes[1].axvline(j / RATE, 0.05, 0.45, color="tab:red" if VISEMES[v] == "PP" else "tab:blue", lw=1.5)
    axes[1].text(j / RATE, 0.12, VISEMES[v], rotation=90, fontsize=6, ha="right")
axes[1].set(yticks=[], xlabel="time (s)", title="Corpus labels (top, /p b m/ orange) and spikes (bottom, PP red)")
plt.show()

# %% [markdown]
# Nearly every frame is blank; each phone is a spike of one or two frames, near the labelled phone but a little
# **after** its centre. Measured on every held-out clip: each spike against the centre of the nearest labelled
# segment of the same viseme (within 200 ms).

# %%
lags, syn_tracks = [], {}
for clip in corpus.split("test_a"):
    m = corpus.meta(clip)
    frames, vis = recogniser.spikes(recogniser.log_probs(corpus.wave(clip)))
    centres = np.array([(VISEMES.index(v), (a + b) / 2) for v, a, b in m["visemes"]])
    for j, v in zip(frames, vis):
        same = centres[centres[:, 0] == v, 1]
        if len(same) and np.abs(j / RATE - same).min() <= 0.2:
            lags.append(j / RATE - same[np.abs(j / RATE - same).argmin()])
    syn_tracks[clip] = (frames, vis)
lags = np.array(lags) * 1000
print(f"{len(lags)} spikes: median lag {np.median(lags):+.0f} ms, mean {lags.mean():+.0f} ms "
      f"(docs/front-ends.md, training split: +14 ms median); the extractor moves spikes {LAG_S * 1000:.0f} ms earlier")
assert 0 < np.median(lags) < 40

# %%
fig, ax = plt.subplots(figsize=(7, 3), layout="constrained")
ax.hist(lags, bins=np.arange(-200, 201, 20), color="tab:blue", alpha=0.8)
ax.axvline(np.median(lags), color="k", ls="--", label=f"median {np.median(lags):+.0f} ms")
ax.axvline(LAG_S * 1000, color="tab:red", label=f"LAG_S = {LAG_S * 1000:.0f} ms")
ax.set(xlabel="spike time minus labelled segment centre (ms)", ylabel="spikes",
       title="How late the spikes come (test_a, 48 clips)")
ax.legend(fontsize=8)
plt.show()

# %% [markdown]
# ## 3. The viseme route
#
# `SYMBOL_TO_VISEME` maps every one of the 191 symbols to a viseme $\nu(s)$ of `face/visemes.py`, or to `None`
# for non-phones. Mesh frame $f$ (at $f / 30$ s) then takes the viseme of the nearest spike, moved $\delta$
# earlier, if it is within $w$; otherwise silence (`spike_track`):
#
# $$\begin{aligned} j^\ast(f) &= \arg\min_{j \in S} \big\lvert f/30 - (t_j - \delta) \big\rvert, \\
# v_f &= \nu(\hat y_{j^\ast}) \ \text{if}\ \big\lvert f/30 - (t_{j^\ast} - \delta) \big\rvert \le w,
# \ \text{else}\ \mathrm{sil} \end{aligned} \tag{3}$$
#
# and `RecogniserExtractor("visemes")` returns its one-hot, (T, 15). The models are *trained* on the same one-hot
# of the corpus's own labels (`VisemeLabels`), so what they see never depends on the voice. Scored per frame
# against those labels $v^\star_f$:
#
# $$\mathrm{acc} = \frac{1}{T} \sum_{f=1}^{T} \big[\, v_f = v^\star_f \,\big] \tag{4}$$

# %%
# NBVAL_CHECK_OUTPUT
groups = {v: [s for s, g in SYMBOL_TO_VISEME.items() if g == v] for v in VISEMES[1:]}
print(f"{len(SYMBOL_TO_VISEME)} symbols: {sum(map(len, groups.values()))} phones, "
      f"{sum(g is None for g in SYMBOL_TO_VISEME.values())} non-phones; PP <- {' '.join(groups['PP'])}")
assert len(SYMBOL_TO_VISEME) == len(recogniser.symbols) == 191
n_frames = meta["n_frames"]
track = spike_track(spike_frames / RATE - LAG_S, spike_vis, n_frames, FPS, WINDOW_S)     # eq. 3
feats = extractor(wave_syn, n_frames)                                                     # (T, 15) one-hot
torch.testing.assert_close(feats, torch.nn.functional.one_hot(torch.from_numpy(track), len(VISEMES)).float())
labels_set = VisemeLabels(test_set)                                                       # the corpus's labels
truth = labels_set[test_set.names.index(name)]["audio"].argmax(1).numpy()
clip_acc = float((track == truth).mean())                                                 # eq. 4
hits = [(spike_track(f / RATE - LAG_S, v, len(truth_c), FPS, WINDOW_S) == truth_c)
        for clip, (f, v) in syn_tracks.items()
        for truth_c in [labels_set[test_set.names.index(clip)]["audio"].argmax(1).numpy()]]
split_acc = float(np.concatenate(hits).mean())
print(f"frame accuracy (eq. 4): {name} {clip_acc:.2f}, all of test_a {split_acc:.2f} "
      f"(training split: 0.549, docs/front-ends.md)")
assert 0.4 < split_acc < 0.75

# %%
fig, ax = plt.subplots(figsize=(11, 3.2), layout="constrained")
t = np.arange(n_frames) / FPS
ax.step(t, truth, where="post", lw=2.2, color="0.6", label="corpus labels (VisemeLabels)")
ax.step(t, track, where="post", lw=1.2, color="tab:red", label="recogniser (spike_track, eq. 3)")
ax.set_yticks(range(len(VISEMES)), VISEMES, fontsize=7)
ax.set(xlabel="time (s)", ylabel="viseme", title=f"{name}: viseme per mesh frame, frame accuracy {clip_acc:.2f}")
ax.legend(fontsize=8, loc="upper right")
plt.show()

# %% [markdown]
# The classes drive the project's rig exactly as the corpus generator's phone timing does
# (`face.clip_controls`, then `FaceRig.animate`): no learning at all. This is the "rig driven by the recogniser"
# row of `results/real_voices.md`, the baseline every phonetic model must beat. Each run of equal classes becomes
# one segment with a representative espeak phone; the small helper is checked against `viseme_ids`. The lip
# distance $d(f)$ is measured between the lip midpoints, and a bilabial counts as closed if
#
# $$\min_{f \in \mathrm{seg}} d(f) < \tau, \qquad \tau \in \{2, 1\}\ \mathrm{mm} \tag{5}$$

# %%
PHONE_OF = {"sil": "_", "PP": "p", "FF": "f", "TH": "T", "DD": "d", "KK": "k", "CH": "S", "SS": "s",
            "RR": "r", "WW": "w", "aa": "a", "E": "E", "I": "I", "O": "O:", "U": "u:"}   # one espeak phone each


def track_to_phones(ids, fps=FPS):
    """Per-frame viseme ids -> [[espeak phone, start_s, end_s]], one segment per run of equal ids."""
    edges = np.flatnonzero(np.diff(ids)) + 1
    starts, ends = np.r_[0, edges], np.r_[edges, len(ids)]
    return [[PHONE_OF[VISEMES[ids[a]]], a / fps, b / fps] for a, b in zip(starts, ends)]


assert np.array_equal(viseme_ids(phonemes_to_visemes(track_to_phones(track)), n_frames, FPS), track)
speakers = read_json(corpus.root / "speakers.json")


def rig_from_phones(phones, n, subject, wave):
    speaker = Speaker.from_dict(speakers[subject])
    return FaceRig(speaker).animate(clip_controls(phones, n, speaker, seed=0, wave=wave)).reshape(n, -1)

# %%
gt = corpus.vertices(name)                                                    # (T, V*3), the ground truth
driven = rig_from_phones(track_to_phones(track), n_frames, meta["subject"], wave_syn)
d_gt, d_rec = lip_distance(gt, *LIP_MID), lip_distance(driven, *LIP_MID)      # (T,) mm
mins = {k: segment_extrema(d, meta["phonemes"], BILABIALS) for k, d in (("gt", d_gt), ("rec", d_rec))}
for k, label in (("gt", "ground truth"), ("rec", "rig driven by the recogniser")):
    print(f"{label:30s}: closed < 2 mm {closure_rate(mins[k], 2.0):.2f}, < 1 mm {closure_rate(mins[k], 1.0):.2f} "
          f"of {len(mins[k])} /p b m/; r = {np.corrcoef(d_gt, d_rec)[0, 1] if k == 'rec' else 1.0:.2f}")
assert closure_rate(mins["gt"], 2.0) == 1.0 and closure_rate(mins["rec"], 2.0) >= 0.5
pbm = [s for s in meta["phonemes"] if s[0] in BILABIALS]
plot_lip_distance(t, {"ground truth": d_gt, "rig driven by the recogniser": d_rec}, phonemes=pbm,
                  title=f"{name}: lip distance, /p b m/ shaded", figsize=(11, 3.2))

# %% [markdown]
# On espeak the recogniser misses some bilabials (the held-out split: 0.61 closed < 1 mm against 0.89 for the
# ground truth, `results/real_voices.md`); on real voices it misses fewer.
#
# ## 4. A real recording
#
# The two prompts of section 1, animated both ways with the first training speaker's face: the rig driven by
# the **force-aligned phones** (pocketsphinx 5.1.1 with the prompt's text, made by
# `notebooks/data/real/make_real.py` with `benchmarks/real_voices.py`'s aligner: the benchmark's reference)
# and the rig driven by the **recogniser's classes** (no transcript). Bilabial windows are widened by one mesh
# frame for the aligner's 10-30 ms timing, as in the benchmark.

# %%
# NBVAL_CHECK_OUTPUT
subject = corpus.train_speakers[0]
rows = []
for r in real.values():
    r["ref"] = rig_from_phones(r["phones"], r["n"], subject, r["wave"])
    r["track"] = extractor.viseme_ids(r["wave"], r["n"])
    r["rec"] = rig_from_phones(track_to_phones(r["track"]), r["n"], subject, r["wave"])
    r["d_ref"], r["d_rec"] = lip_distance(r["ref"], *LIP_MID), lip_distance(r["rec"], *LIP_MID)
    rows.append([segment_extrema(r[k], r["phones"], BILABIALS, tolerance_frames=1) for k in ("d_ref", "d_rec")])
ref_min, rec_min = (np.concatenate(c) for c in zip(*rows))
r_real = np.mean([np.corrcoef(r["d_ref"], r["d_rec"])[0, 1] for r in real.values()])
print(f"{len(ref_min)} real /p b m/; closed < 2 mm: aligned phones {closure_rate(ref_min, 2.0):.2f}, "
      f"recogniser {closure_rate(rec_min, 2.0):.2f}; < 1 mm: {closure_rate(ref_min, 1.0):.2f}, "
      f"{closure_rate(rec_min, 1.0):.2f}; r = {r_real:.2f}")
assert closure_rate(rec_min, 2.0) >= 0.6 and r_real > 0.5

# %%
r = real["agent-pass"]
tr = np.arange(r["n"]) / FPS
fig = plot_lip_distance(tr, {"rig, aligned phones (reference)": r["d_ref"], "rig, recogniser": r["d_rec"]},
                        phonemes=[s for s in r["phones"] if s[0] in BILABIALS], figsize=(11, 3.2),
                        title=f"Real voice: '{r['text']}' (/p b m/ shaded)")
fig

# %% [markdown]
# The animation, with the speech: left the reference, right the recogniser (3 s, raster renderer).

# %%
# NBVAL_IGNORE_OUTPUT
n3 = 3 * FPS
video = animate_clip({"aligned phones": r["ref"][:n3], "recogniser": r["rec"][:n3]}, corpus.faces,
                     wave=r["wave"][:3 * SR], sample_rate=SR, size=192, renderer="raster")
HTML(video._repr_html_())

# %% [markdown]
# ## 5. Your own voice
#
# The panel below records from the browser's microphone (`dualtalker_lite.viz.microphone.MicrophonePanel`, an
# [anywidget](https://anywidget.dev)): press **Record**, allow the microphone, speak, press **Stop**. The browser
# resamples the recording to 16 kHz mono and sends it to the kernel as float32 samples, and the kernel runs this
# notebook's phonetic route on it: the recogniser's viseme track (eq. 3) driving the rig of the first training
# speaker, as in section 4, shown with your speech under the button. No microphone, or a recording that is empty,
# silent or too short, gives one `error:` line instead. When the notebook runs without anyone at it (nbval, CI),
# the same cell sends the shipped `agent-pass` prompt through the same path, exactly as a recording would.
#
# A trained phonetic checkpoint (e.g. `make demo`'s) animates instead with
# `MicrophonePanel(lambda w: animate_recording(w, "runs/m.pt", "SPK01", corpus)[0])`
# (`dualtalker_lite.viz.widgets.animate_recording`, the `animate` command's path).
#
# **Live, while you speak.** The recording above is animated after you stop. For a face that follows you as you
# speak, serve such a checkpoint with [`dualtalker-lite live --checkpoint runs/m.pt`](../docs/live.md) and open
# <http://127.0.0.1:8765/>: the page streams the microphone to a local server that runs a causal version of
# this viseme track (250 ms of look-ahead) and the model's cached decoder step, and draws the face, and beside
# it a second head driven by the 15 standard viseme curves (`viseme_sil`, `viseme_PP`, ...), about half a
# second behind the voice (`docs/live.md`).

# %%
# NBVAL_IGNORE_OUTPUT
from IPython.display import display

from dualtalker_lite.viz.microphone import MicrophonePanel, encode_recording


def animate_speech(wave):
    """16 kHz speech (N,) -> the rig of `subject` driven by the recogniser's track (section 4), with the speech."""
    n = max(1, int(round(len(wave) * FPS / SR)))
    verts = rig_from_phones(track_to_phones(extractor.viseme_ids(wave, n)), n, subject, wave)   # (n, V*3)
    return animate_clip(verts.reshape(n, -1, 3), corpus.faces, wave=wave, sample_rate=SR, size=192,
                        renderer="raster")


mic = MicrophonePanel(animate_speech, max_seconds=10)
display(mic.widget)
mic.run(encode_recording(r["wave"][:3 * SR]));    # what a 3 s recording does: the shipped prompt, once

# %%
assert mic.status.value.startswith("3.0 s of speech animated in "), mic.status.value
assert mic.wave.shape == (3 * SR,) and "<video" in mic.result._repr_html_()

# %% [markdown]
# ## 6. What each front-end can and cannot do
#
# From `docs/front-ends.md` and `results/real_voices.md` (`python benchmarks/real_voices.py --seeds 3`; 255 real
# prompts of the same voice, 437 /p b m/, 3 seeds; closure with windows widened by one frame):
#
# | front-end | can | cannot | real: closed < 2 mm / < 1 mm, r |
# |---|---|---|---|
# | log-mel (`LogMelExtractor`, DualTalker) | carries everything in the signal: voice, loudness, pitch, emotion | transfer from one synthetic voice family to people | 0.34 / 0.16, r 0.36 |
# | rig driven by the recogniser's classes (no learning) | any voice, no training | style, loudness, emotion, upper face | 0.93 / 0.86, r 0.78 |
# | recogniser visemes (`RecogniserExtractor("visemes")`, DualTalker trained on `VisemeLabels`) | any voice; the model adds the speaker's template and style | speaker style from the voice, emotion, loudness; phones hama misses | 0.95 / 0.82, r 0.77 |
# | recogniser log-probs + log-mel, end to end | tracks the timing | close the lips: depth does not transfer from one voice's posteriors | 0.03 / 0.00, r 0.68 |
#
# ## Summary
#
# - A linear probe on log-mel reads the visemes of held-out espeak sentences and fails on a real voice: the
#   features, and every model trained on them, learn one voice family.
# - hama's CTC output is blank on most frames; phones appear as one- or two-frame spikes a little after the
#   labelled phone centres (median +5 ms on test_a here, +14 ms on the training split, 30 ms on the real voices
#   of the benchmark), so the extractor moves them 20 ms earlier (chosen on the training split only).
# - The viseme route maps the 191 symbols to 15 visemes, takes the nearest spike within 100 ms per mesh frame
#   (eq. 3), and reaches about 0.5 frame accuracy against the corpus's labels; models are trained on the labels
#   and fed the recogniser's track, which looks the same for any voice.
# - On the real prompts the rig driven by the recogniser closes the lips on the bilabials the aligned phones
#   close; the tiny phonetic DualTalker is about as good as that rig, not better (`results/real_voices.md`).
#
# ## Exercises
#
# 1. Separate the channel from the voice: band-limit the espeak test clips to 4 kHz (zero the FFT bins above
#    4 kHz, or resample to 8 kHz and back) and score the probe of section 1 on them. How much of the drop to the
#    real voice is left?
# 2. Change `LAG_S` to 0 and to 0.06 in `spike_track` (section 3) and recompute the test_a frame accuracy. Compare
#    with the lag-by-window table of `docs/front-ends.md`.
# 3. The PP recall of the spike track is 0.675 (`docs/front-ends.md`). Let a frame also spike PP where the summed
#    posterior of the PP symbols exceeds 0.2 even if the blank wins; how many more of the held-out bilabials close
#    in the rig of section 3?
# 4. Feed the rig the track of 3 s of `0.003 * np.random.randn(48000)` (room tone). What does the mouth do, and
#    why would a trained autoregressive decoder behave differently (`results/real_voices.md`, room tone)?
# 5. Record one sentence twice with the panel of section 5, once slowly and once as fast as you can. Which
#    bilabials does the recogniser's track lose at speed (plot `extractor.viseme_ids(mic.wave, n)` of each)?
