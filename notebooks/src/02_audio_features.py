# %% [markdown]
# # 02 · Audio features: from the waveform to $A_{1:T}$ at the mesh rate
#
# Every model in this series reads speech through one tensor per clip, $A_{1:T}$ of shape (T, 160): two
# log-mel frames of 80 bands for each of the $T$ mesh frames (30 fps). This notebook derives it step by step —
# STFT, mel filterbank, logarithm, interpolation to the mesh rate, stacking — checks each step against the
# package (`dualtalker_lite.audio`), and places it next to what the papers use: wav2vec 2.0 features,
# linearly interpolated to the mesh rate as in FaceFormer.
#
# **We will cover**
#
# 1. The waveform of one clip.
# 2. The short-time Fourier transform (STFT) with `torch.stft`.
# 3. The mel scale and the triangular mel filterbank, rebuilt from scratch.
# 4. The log-mel spectrogram.
# 5. Alignment to 30 fps: 100 Hz -> 60 Hz by linear interpolation -> stacked (T, 160).
# 6. Why the papers use wav2vec 2.0, what this project uses offline, and how to plug wav2vec 2.0 in.
# 7. Phoneme one-hot tracks: the "higher-level features" input of the ablation, next to the log-mel.
#
# | symbol | code name | shape |
# |---|---|---|
# | $x[n]$ (speech, 16 kHz, in [-1, 1]) | `wave` | (N,) |
# | $w[n]$ (Hann window, 400 samples = 25 ms) | `window` | (400,) |
# | $H$ (hop, 160 samples = 10 ms), $N_{\mathrm{fft}}$ (512) | `HOP_LENGTH`, `N_FFT` | int |
# | $X(\ell, k)$ (STFT, frame $\ell$, bin $k$) | `spec` | (K, L) = (257, 1 + N // 160) |
# | $P(\ell, k) = \lvert X(\ell, k)\rvert^2$ (power) | `power` | (K, L) |
# | $F_{mk}$ (mel filterbank) | `fb` = `mel_filterbank()` | (M, K) = (80, 257) |
# | $S(\ell, m)$ (log-mel, 100 Hz) | `log_mel` | (L, 80) |
# | $\tilde S(j, m)$ (log-mel resampled to 60 Hz) | `log_mel_60` | (2T, 80) |
# | $A_{1:T}$ (stacked per mesh frame) | `audio` | (T, 160) |
# | $T$ (mesh frames at 30 fps) | `n_frames` | int |

# %%
%matplotlib inline
import matplotlib.pyplot as plt
import numpy as np
import torch
import torch.nn.functional as F

from dualtalker_lite.audio import (HOP_LENGTH, LOG_EPS, N_FFT, N_MELS, WIN_LENGTH, FeatureExtractor,
                                   LogMelExtractor, Wav2Vec2Extractor, hz_to_mel, interpolate_frames,
                                   log_mel_spectrogram, mel_filterbank)
from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.dataset import TalkingFaceDataset, segments_to_frames
from dualtalker_lite.checks import check_shape
from dualtalker_lite.seeding import set_seed
from dualtalker_lite.viz import plot_waveform_and_phonemes

torch.set_num_threads(2)
gen = set_seed(0)
corpus = Corpus(sample_path())
SR, FPS = corpus.sample_rate, corpus.fps   # 16000 Hz, 30 fps

# %% [markdown]
# ## 1. The waveform
#
# A training clip rich in sibilants (/s/ and /S/ carry their energy above 4 kHz, vowels below 1 kHz).

# %%
name = "SPK03_s08"
meta = corpus.meta(name)
wave = corpus.wave(name)                           # (N,) float32, 16 kHz
N, n_frames = len(wave), meta["n_frames"]
check_shape(wave, (meta["n_samples"],), "wave")
print(f"'{meta['text']}' ({meta['subject']}): N = {N} samples = {N / SR:.3f} s, T = {n_frames} mesh frames")
plot_waveform_and_phonemes(wave, SR, meta["phonemes"], title=f"{name}: waveform and phonemes")

# %% [markdown]
# ## 2. The short-time Fourier transform
#
# The signal is cut into overlapping frames, each multiplied by a window and Fourier-transformed. With hop $H$,
# window $w$ of 400 samples zero-padded to $N_{\mathrm{fft}} = 512$ and frame $\ell$ centred on sample $\ell H$
# (`center=True`, zero padding at both ends):
#
# $$X(\ell, k) = \sum_{n=0}^{N_{\mathrm{fft}}-1} x\big[\ell H + n - N_{\mathrm{fft}}/2\big]\, w[n]\, e^{-2\pi i k n / N_{\mathrm{fft}}},
# \qquad k = 0, \dots, N_{\mathrm{fft}}/2$$
#
# Bin $k$ is the frequency $k \cdot 16000 / 512 = 31.25\,k$ Hz; there are $L = 1 + \lfloor N / H \rfloor$ frames at
# 100 Hz. We compute it with `torch.stft` and check one frame against the formula with an explicit DFT.

# %%
window = torch.hann_window(WIN_LENGTH)                                   # periodic Hann, 400 samples
x = torch.from_numpy(wave)
spec = torch.stft(x, N_FFT, hop_length=HOP_LENGTH, win_length=WIN_LENGTH, window=window, center=True,
                  pad_mode="constant", return_complex=True)              # (K, L) complex
K, L = N_FFT // 2 + 1, 1 + N // HOP_LENGTH
check_shape(spec, (K, L), "spec")
power = spec.abs() ** 2                                                  # |X|^2, (K, L)

ell = 100                                                                # one frame, by the formula
w_full = F.pad(window, ((N_FFT - WIN_LENGTH) // 2, (N_FFT - WIN_LENGTH) // 2))   # window centred in 512
segment = F.pad(x, (N_FFT // 2, N_FFT // 2))[ell * HOP_LENGTH: ell * HOP_LENGTH + N_FFT]
n, k = torch.arange(N_FFT, dtype=torch.float64), torch.arange(K, dtype=torch.float64)
basis = torch.exp(-2j * torch.pi * torch.outer(n, k) / N_FFT)                 # (N_fft, K) complex128
dft = (segment.double() * w_full.double()).to(torch.complex128) @ basis
torch.testing.assert_close(spec[:, ell].to(torch.complex128), dft, rtol=1e-4, atol=1e-4)
print(f"spec: {K} bins x {L} frames (100 Hz); frame {ell} == explicit DFT")

fig, ax = plt.subplots(figsize=(9, 3.2), layout="constrained")
im = ax.imshow(10 * torch.log10(power + 1e-10).numpy(), origin="lower", aspect="auto", cmap="magma",
               interpolation="nearest", extent=(0, L / 100, 0, SR / 2), vmin=-80)
ax.set(xlabel="time (s)", ylabel="frequency (Hz)", title="Power spectrogram $|X(\\ell, k)|^2$")
fig.colorbar(im, ax=ax, label="power (dB)")
plt.show()

# %% [markdown]
# ## 3. The mel scale and the filterbank
#
# Pitch perception is roughly linear below 1 kHz and logarithmic above. The (HTK) mel scale models this:
#
# $$\mathrm{mel}(f) = 2595 \log_{10}\!\left(1 + \frac{f}{700}\right), \qquad f = 700\left(10^{\mathrm{mel}/2595} - 1\right)$$
#
# The filterbank places $M + 2 = 82$ points $f_0 < f_1 < \dots < f_{81}$ equally spaced in mel between 0 and 8000 Hz;
# filter $m$ is a triangle rising from $f_{m-1}$ to a peak of 1 at $f_m$ and falling to 0 at $f_{m+1}$:
#
# $$F_{mk} = \max\!\left(0,\ \min\!\left(\frac{f(k) - f_{m-1}}{f_m - f_{m-1}},\ \frac{f_{m+1} - f(k)}{f_{m+1} - f_m}\right)\right),
# \qquad f(k) = k\,\frac{16000}{512}$$
#
# Built from scratch, one filter at a time, and checked against `mel_filterbank()`:

# %%
def mel_scratch(f):
    return 2595.0 * torch.log10(1.0 + f / 700.0)


def mel_inverse_scratch(m):
    return 700.0 * (10.0 ** (m / 2595.0) - 1.0)


points = mel_inverse_scratch(torch.linspace(0.0, float(mel_scratch(torch.tensor(8000.0))), N_MELS + 2,
                                            dtype=torch.float64))        # (82,) Hz, equally spaced in mel
bin_hz = torch.arange(K, dtype=torch.float64) * SR / N_FFT              # (257,) f(k)
fb_scratch = torch.zeros(N_MELS, K, dtype=torch.float64)
for m in range(1, N_MELS + 1):                                          # filter m uses f_{m-1}, f_m, f_{m+1}
    rise = (bin_hz - points[m - 1]) / (points[m] - points[m - 1])
    fall = (points[m + 1] - bin_hz) / (points[m + 1] - points[m])
    fb_scratch[m - 1] = torch.clamp(torch.minimum(rise, fall), min=0.0)

fb = mel_filterbank()                                                    # (80, 257) float32
check_shape(fb, (N_MELS, K), "fb")
torch.testing.assert_close(fb, fb_scratch.float(), rtol=1e-5, atol=1e-5)
np.testing.assert_allclose(hz_to_mel([0.0, 700.0, 1000.0]), [0.0, 2595 * np.log10(2), 1000.0], atol=0.1)
inner = (bin_hz >= points[1]) & (bin_hz <= points[-2])                  # between the first and last peaks
torch.testing.assert_close(fb_scratch.sum(0)[inner], torch.ones(int(inner.sum()), dtype=torch.float64))
print(f"mel_filterbank() == from scratch; the triangles sum to 1 between {points[1]:.0f} and {points[-2]:.0f} Hz")

# %%
fig, axes = plt.subplots(1, 2, figsize=(10, 3.2), layout="constrained", width_ratios=(1, 2))
f_axis = np.linspace(0, 8000, 400)
axes[0].plot(f_axis, hz_to_mel(f_axis))
axes[0].plot(points.numpy(), hz_to_mel(points.numpy()), ".", ms=4, label="filter edges/centres")
axes[0].set(xlabel="frequency (Hz)", ylabel="mel", title="The mel scale")
axes[0].legend(fontsize=8)
for m in range(0, N_MELS, 1):
    axes[1].plot(bin_hz.numpy(), fb[m].numpy(), lw=0.8, color=plt.get_cmap("viridis")(m / N_MELS))
axes[1].set(xlabel="frequency (Hz)", ylabel="weight $F_{mk}$", xlim=(0, 8000),
            title=f"{N_MELS} triangular mel filters (narrow at low, wide at high frequencies)")
plt.show()

# %% [markdown]
# ## 4. The log-mel spectrogram
#
# Each frame's power spectrum is summed under every triangle, and the logarithm compresses the dynamic range
# (loudness is perceived roughly logarithmically); $\varepsilon = 10^{-6}$ keeps digital silence finite:
#
# $$S(\ell, m) = \log\!\Big(\sum_{k} F_{mk}\, \lvert X(\ell, k)\rvert^2 + \varepsilon\Big)$$

# %%
log_mel_scratch = torch.log(fb @ power + LOG_EPS).T                      # (L, M)
log_mel = log_mel_spectrogram(wave)                                      # (L, M), the package
check_shape(log_mel, (L, N_MELS), "log_mel")
torch.testing.assert_close(log_mel, log_mel_scratch, rtol=1e-4, atol=1e-4)
print(f"log_mel: {tuple(log_mel.shape)} at 100 Hz, range {log_mel.min():.1f} .. {log_mel.max():.1f}")

fig, ax = plt.subplots(figsize=(9, 3.0), layout="constrained")
im = ax.imshow(log_mel.T.numpy(), origin="lower", aspect="auto", cmap="magma", interpolation="nearest",
               extent=(0, L / 100, 0, N_MELS))
ax.set(xlabel="time (s)", ylabel="mel band m", title="Log-mel spectrogram $S(\\ell, m)$ (100 Hz)")
fig.colorbar(im, ax=ax, label="log power (a.u.)")
plt.show()

# %% [markdown]
# ## 5. Alignment to the mesh rate: 100 Hz -> 60 Hz -> (T, 160)
#
# The mesh runs at 30 fps, the log-mel at 100 Hz. Following FaceFormer (which does this to 50 Hz wav2vec 2.0
# features), the $L$ frames are **linearly interpolated** in time to exactly $2T$ frames (60 Hz) with
# `align_corners=True` — the first and last frames are kept, the rest evenly spread between them. Output frame
# $j$ reads the input at the fractional position $u_j$:
#
# $$u_j = j\,\frac{L-1}{2T-1}, \qquad \tilde S(j) = (1-\lambda_j)\, S(\lfloor u_j \rfloor) + \lambda_j\, S(\lfloor u_j \rfloor + 1),
# \quad \lambda_j = u_j - \lfloor u_j \rfloor$$
#
# and then each mesh frame gets two consecutive 60 Hz frames, side by side:
# $A_t = [\tilde S(2t);\ \tilde S(2t+1)] \in \mathbb{R}^{160}$. Below: the interpolation from scratch with `np.interp`,
# checked against `interpolate_frames`, and the stacking checked against `LogMelExtractor`.

# %%
u = np.arange(2 * n_frames) * (L - 1) / (2 * n_frames - 1)               # (2T,) fractional input positions
log_mel_60_scratch = np.stack([np.interp(u, np.arange(L), log_mel[:, m].numpy()) for m in range(N_MELS)], 1)
log_mel_60 = interpolate_frames(log_mel, 2 * n_frames)                   # (2T, 80)
check_shape(log_mel_60, (2 * n_frames, N_MELS), "log_mel_60")
torch.testing.assert_close(log_mel_60, torch.from_numpy(log_mel_60_scratch).float(), rtol=1e-4, atol=1e-4)

extractor = LogMelExtractor(fps=FPS)                                     # n_mels=80, frames_per_mesh_frame=2
audio = extractor(wave, n_frames)                                        # (T, 160): A_{1:T}
check_shape(audio, (n_frames, 2 * N_MELS), "audio")
torch.testing.assert_close(audio, log_mel_60.reshape(n_frames, 2 * N_MELS))
torch.testing.assert_close(audio[5, :N_MELS], log_mel_60[10])            # A_5 = [S~(10); S~(11)]
torch.testing.assert_close(audio[5, N_MELS:], log_mel_60[11])
drift_ms = np.abs(u[::2] / 100 - np.arange(n_frames) / FPS).max() * 1000  # first half of A_t vs the mesh frame time
print(f"L = {L} frames (100 Hz) -> 2T = {2 * n_frames} (60 Hz) -> audio {tuple(audio.shape)}; "
      f"largest offset from the mesh frame times: {drift_ms:.1f} ms")
assert drift_ms < 1000 / 60                                              # under one 60 Hz frame

# %% [markdown]
# The same holds for every clip: the extractor returns exactly one 160-dimensional row per mesh frame, and the
# dataset (`TalkingFaceDataset`) pairs it with the vertices. A few clips of every split:

# %%
# NBVAL_CHECK_OUTPUT
print(f"{'clip':22} {'N':>6} {'L (100 Hz)':>10} {'2T (60 Hz)':>10} {'T':>4} {'audio':>10} {'vertices':>11}")
for split in ("train", "val", "test_a", "test_b"):
    for clip in corpus.split(split)[:2]:
        w = corpus.wave(clip)
        verts = corpus.vertices(clip)                                    # (T, V*3)
        a = extractor(w, verts.shape[0])
        assert a.shape == (verts.shape[0], 160) and verts.shape[0] == corpus.meta(clip)["n_frames"]
        print(f"{clip:22} {len(w):6d} {1 + len(w) // HOP_LENGTH:10d} {2 * len(verts):10d} {len(verts):4d} "
              f"{str(tuple(a.shape)):>10} {str(verts.shape):>11}")

# %%
val_set = TalkingFaceDataset(corpus, "val")                              # features computed once, here
for item in val_set:
    check_shape(item["audio"], (item["vertices"].shape[0], 160), item["name"])
print(f"{val_set}: every item has audio (T, 160) with T = its number of mesh frames")

t_show = 0.3                                                             # seconds shown
fig, ax = plt.subplots(figsize=(9, 2.4), layout="constrained")
for y, rate, label, marker in ((2, 100, "log-mel, 100 Hz", "|"), (1, 60, "interpolated, 60 Hz", "x"),
                               (0, 30, "mesh frames, 30 fps", "o")):
    times = np.arange(int(t_show * rate) + 1) / rate if rate != 60 else u[u / 100 <= t_show] / 100
    ax.plot(times, np.full(len(times), y), marker, ms=8, ls="none", label=label)
for t_mesh in np.arange(int(t_show * FPS) + 1) / FPS:
    ax.axvline(t_mesh, color="0.85", lw=0.8, zorder=0)
ax.set(yticks=[0, 1, 2], yticklabels=["30 fps", "60 Hz", "100 Hz"], xlabel="time (s)", ylim=(-0.6, 2.6),
       title="Frame times: two interpolated 60 Hz frames per mesh frame")
plt.show()

# %% [markdown]
# ## 6. Why the papers use wav2vec 2.0, and what this project does offline
#
# Log-mel frames describe the *sound* of 25 ms of speech; they carry no context. **wav2vec 2.0** (Baevski et al.,
# 2020) is a network pre-trained, self-supervised, on hundreds of hours of speech: a temporal convolutional
# feature encoder (TCN) over the raw waveform (one vector per 20 ms, 50 Hz) followed by a transformer whose
# outputs are **contextual** — each frame's vector depends on the whole utterance — and close to phonetic
# content while robust to speaker and recording. FaceFormer, and after it DualTalker, CorrTalk and EmoFace, start
# from it: DualTalker's supplementary describes "a TCN followed by a linear interpolation layer" that resamples to
# the mesh frame rate, then 12 transformer layers (d = 768), then a linear audio encoder to $d$ = 128 or 256.
# DualTalker's Table IV shows that replacing it by DeepSpeech character probabilities hurts lip accuracy.
#
# Pre-trained weights cannot be downloaded here, so this project keeps the *shape* of that pipeline and learns
# it from scratch: the fixed log-mel $A_{1:T}$ of this notebook is the input of a small stand-in inside the model,
# `dualtalker_lite.blocks.audio_encoder.AudioFeatureExtractor` (per-frame projection, a few temporal convolutions,
# periodic positional encoding and one or two transformer encoder layers; notebook 08 trains it).
#
# **Plugging wav2vec 2.0 in.** Every extractor follows the `FeatureExtractor` protocol: attributes `sample_rate`
# and `dim`, and `__call__(wave, n_frames) -> (n_frames, dim)`. `Wav2Vec2Extractor` is one: it loads a
# Hugging Face model from a **local** folder (`local_files_only=True`, it never downloads), takes the hidden states
# of one layer and interpolates them to the mesh rate exactly as above. With such a folder (and `transformers`
# installed) the rest of the code does not change (not run here):
#
# ```python
# from dualtalker_lite.audio import Wav2Vec2Extractor
#
# w2v = Wav2Vec2Extractor("/data/models/wav2vec2-base-960h", fps=30, frames_per_mesh_frame=1, layer=-1)
# train_set = TalkingFaceDataset(corpus, "train", front_end=w2v, threads=None)   # item["audio"]: (T, 768)
# # and the model's audio input width: DualTalkerConfig(audio_dim=w2v.dim, ...)
# ```
#
# The cell below shows the protocol at work with a tiny extractor of our own (loudness of each 60 Hz frame,
# stacked like the log-mel), and that `Wav2Vec2Extractor` refuses a missing folder instead of downloading.

# %%
class LoudnessExtractor:
    """Log energy of the 100 Hz frames, interpolated to 2 frames per mesh frame: (n_frames, 2)."""

    sample_rate, dim = SR, 2

    def __call__(self, wave, n_frames):
        energy = torch.logsumexp(log_mel_spectrogram(wave), dim=1, keepdim=True)    # (L, 1)
        return interpolate_frames(energy, 2 * n_frames).reshape(n_frames, 2)


loudness = LoudnessExtractor()
assert isinstance(loudness, FeatureExtractor) and isinstance(extractor, FeatureExtractor)
small_set = TalkingFaceDataset(corpus, "val", front_end=loudness)
check_shape(small_set[0]["audio"], (small_set[0]["vertices"].shape[0], 2), "loudness features")
try:
    Wav2Vec2Extractor(corpus.root / "no-such-model")
except FileNotFoundError as err:
    print("Wav2Vec2Extractor:", str(err).split(" (")[0].replace(str(corpus.root), "<corpus>"))
print(f"custom extractor: item audio {tuple(small_set[0]['audio'].shape)}")

# %% [markdown]
# ## 7. Phoneme one-hot tracks: the "higher-level features" input
#
# DualTalker's ablation "DeepSpeech encoding" asks whether higher-level, text-like features can replace the
# acoustic ones. The corpus offers the extreme version: the **phoneme** of every mesh frame, exact, from the
# synthesizer (the dataset's `item["phonemes"]`, built by `segments_to_frames`: an index into
# `corpus.phoneme_inventory`, 0 = silence). As a one-hot track it is a (T, 72) input that carries *what* is said
# and exactly *when*, but none of *how* (loudness, speaker, emotion).
# Below, the rows of the phonemes that occur in the clip, under the log-mel at 60 Hz.

# %%
phoneme_ids = segments_to_frames(meta["phonemes"], corpus.phoneme_inventory, n_frames, FPS)  # (T,) as item["phonemes"]
one_hot = F.one_hot(phoneme_ids, len(corpus.phoneme_inventory)).float()        # (T, 72)
check_shape(one_hot, (n_frames, len(corpus.phoneme_inventory)), "one_hot")
present = list(dict.fromkeys(phoneme_ids.tolist()))                             # ids in order of appearance
labels = [corpus.phoneme_inventory[i] for i in present]
print(f"one-hot {tuple(one_hot.shape)}: {len(present)} distinct phonemes in this clip: {' '.join(labels)}")

fig, axes = plt.subplots(2, 1, figsize=(9, 5), sharex=True, layout="constrained", height_ratios=(1.2, 1))
axes[0].imshow(audio.reshape(2 * n_frames, N_MELS).T.numpy(), origin="lower", aspect="auto", cmap="magma",
               interpolation="nearest", extent=(0, n_frames / FPS, 0, N_MELS))
axes[0].set(ylabel="mel band", title="Log-mel $A_{1:T}$ (unstacked to 60 Hz)")
axes[1].imshow(one_hot[:, present].T.numpy(), origin="upper", aspect="auto", cmap="Greys",
               interpolation="nearest", extent=(0, n_frames / FPS, len(present), 0))
axes[1].set(yticks=np.arange(len(present)) + 0.5, xlabel="time (s)", ylabel="phoneme",
            title="Phoneme one-hot track (30 fps; only the rows that occur)")
axes[1].set_yticklabels(labels, fontsize=7)
plt.show()

# %% [markdown]
# ## Summary
#
# - $A_{1:T}$ = log-mel (Hann 25 ms, hop 10 ms, 512-point FFT, 80 HTK mel bands up to 8 kHz, $\log(\cdot + 10^{-6})$),
#   linearly interpolated (`align_corners=True`) from 100 Hz to exactly $2T$ frames at 60 Hz, and stacked in
#   pairs: shape (T, 160), one row per mesh frame, for every clip.
# - Each step was re-derived from its formula and matched the package: the STFT against an explicit DFT, the
#   filterbank against a from-scratch construction (whose triangles sum to 1), the log-mel, the interpolation.
# - The papers use wav2vec 2.0: self-supervised, contextual speech features, interpolated to the mesh rate as in
#   FaceFormer. Offline, this project learns a small TCN + transformer stand-in on top of the log-mel; a local
#   wav2vec 2.0 model plugs in through the `FeatureExtractor` protocol (`Wav2Vec2Extractor`).
# - Phoneme one-hot tracks (T, 72) are the "higher-level features" input for the ablation.
#
# ## What each front end can and cannot do
#
# | front end | what the decoder sees | works on | cannot |
# |---|---|---|---|
# | log-mel (this notebook; `--features logmel`) | the spectrum of this corpus's voices | the synthetic espeak voices it was trained on | carry phonetic identity to other voices: on real people the lips barely close (`results/real_voices.md`: 0.16 of /p b m/ under 1 mm) |
# | phonetic route (notebook 02a; the default of `make demo`, `train`, `animate` and the tables) | 15 viseme classes: the corpus's labels in training, the hama phoneme recogniser's per-frame classes at test time | any voice the recogniser hears, including telephone audio | see the voice: loudness, emotion and speaker style are gone (EmoFace keeps log-mel for its emotion branch); a phone the recogniser misses is a closure the face misses |
# | phoneme one-hot (above) | the corpus's own phoneme labels | only clips with phoneme timing | run on audio: no labels exist for a new recording |
# | wav2vec 2.0 (`Wav2Vec2Extractor`) | learnt speech features, as in the papers | any voice, once a local model is given | run here: no such weights come from PyPI |
#
# ## Exercises
#
# 1. Replace `align_corners=True` by `False` in a copy of `interpolate_frames`. Where do the 60 Hz frames fall
#    now (plot their times as in section 5), and what is the largest offset from the mesh frame times?
# 2. Compute the log-mel with `mel_filterbank(slaney_norm=True)` (equal-area triangles). Which bands change most,
#    and why do the low bands get louder relative to the high ones?
# 3. Write a `FeatureExtractor` that returns only the upper 40 mel bands (2 x 40 per frame) and build a
#    `TalkingFaceDataset` with it. Which phonemes of section 7 would you expect to become hard to see?
# 4. With `frames_per_mesh_frame=1` the extractor gives (T, 80). What information is lost compared with the
#    stacked (T, 160), given that the mouth can change shape within 33 ms?
