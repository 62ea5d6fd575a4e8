# %% [markdown]
# # 01 · Synthetic talking faces: the corpus this series trains on
#
# The papers train on VOCASET, BIWI and 3D-RAVDESS, which may not be downloaded or redistributed here. So the
# project makes its own talking faces: **real synthesized speech** (espeak-ng) provides sample-accurate phoneme
# timing; phonemes become **visemes** (mouth shapes), blended over time with the **Cohen-Massaro coarticulation**
# model into the control tracks of a procedural **face rig**; speakers, emotions, blinks and brow motion add the
# variety that makes the task one-to-many. Above the mouth, the motion is weak but partly *follows the speech*
# (brows rise at stressed syllables and with the pitch, blinks come at pauses), as in real talking faces: that is
# what CorrTalk's weak-activity branch and the FDD metric look at. Everything here is a few calls into `dualtalker_lite.face` and
# `dualtalker_lite.data.speech`, and the last check shows that one clip of the shipped corpus is regenerated
# bit for bit.
#
# **We will cover**
#
# 1. The template mesh and its named regions.
# 2. The rig: 14 controls; the jaw is a rotation about a hinge.
# 3. Speech, live: espeak-ng speaks a sentence; waveform and phoneme segments.
# 4. Phonemes -> visemes.
# 5. Coarticulation: Cohen-Massaro dominance functions; anticipatory lip rounding.
# 6. Lip distance against the phoneme track: bilabials close the lips, open vowels open them.
# 7. Speakers: different heads and different motion for the same sentence.
# 8. Emotions: prosody in the audio, offsets on the face; a pseudo-pair side by side with sound.
# 9. The upper face: brows that follow stress and F0, cheeks that follow the smile, blinks at pauses, and what
#    stays random.
# 10. An animation with sound, and a live rig with sliders.
# 11. The corpus on disk: splits, emotions, pairs and long clips.
#
# | symbol | code name | shape |
# |---|---|---|
# | $h$ (template vertices, metres) | `rig.template` | (V, 3) |
# | $q_t$ (rig controls of frame $t$) | `controls[t]` | (C,) = (14,) |
# | $D_c$ (blendshape delta of control $c$) | `rig.deltas[c]` | (V, 3) |
# | $w_v$ (jaw weight of vertex $v$), $\mathbf{c}$ (hinge point) | `rig.jaw_weights`, `rig.hinge` | (V,), (3,) |
# | $\varphi$ (jaw angle) = `jaw_open` $\times$ 0.30 rad | `JAW_MAX_ANGLE` | float |
# | $s$ (a viseme segment, centre $c_s$) | `(viseme, start_s, end_s)` | tuple |
# | $D_{sk}(t)$ (dominance of segment $s$ on control $k$) | `dominance(t, viseme, start, end)` | (len(t), C) |
# | $T_{sk}$ (target of viseme $s$ on control $k$) | `VISEME_PARAMS[viseme].target` | dict |
# | $F_k(t)$ (coarticulated control track) | `coarticulate(segments, n_frames)` | (T, C) |
# | $f_0(t)$ (pitch, semitones re the clip median) | `pitch_track(wave, n_frames)[0]` | (T,) |

# %%
%matplotlib inline
import json
import zlib

import ipywidgets as widgets
import matplotlib.pyplot as plt
import numpy as np
import torch
from IPython.display import HTML, display
from matplotlib.patches import Patch

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.probe import (event_locked_brows, onset_lift, pause_blink_ratio, stress_onset_precision,
                                        upper_face_probe)
from dualtalker_lite.data.speech import emotional_prosody, speaker_voices, synthesize

# %%
from dualtalker_lite.face import (CONTROL_INDEX, CONTROL_NAMES, CONTROL_RANGES, CONTROL_REGIONS, EMOTIONS, VISEMES,
                                  FaceRig, build_template, clip_controls, coarticulate, control_vector,
                                  emotion_controls, make_speakers, phoneme_to_viseme, phonemes_to_visemes)
from dualtalker_lite.face.rig import JAW_MAX_ANGLE
from dualtalker_lite.face.upper import accent_track, pitch_track
from dualtalker_lite.face.visemes import (DOMINANCE_POWER, PHONEME_TO_VISEME, PLATEAU_MARGIN, REST_DOMINANCE,
                                          VISEME_PARAMS, dominance)
from dualtalker_lite.metrics import lip_distance
from dualtalker_lite.checks import check_shape
from dualtalker_lite.seeding import set_seed
from dualtalker_lite.viz import MeshViewer, animate_clip, plot_frames, plot_lip_distance, plot_waveform_and_phonemes
from dualtalker_lite.export.render import draw_mesh

torch.set_num_threads(2)
gen = set_seed(0)
corpus = Corpus(sample_path())
FPS, SR = corpus.fps, corpus.sample_rate  # 30 mesh frames/s, 16 kHz audio

# %% [markdown]
# ## 1. The template mesh
#
# `build_template()` builds a left/right-symmetric head procedurally: a stack of super-elliptic rings, densely
# sampled on the face, with a **mouth slit** (the lip row is duplicated so the lips can part, and a small mouth
# bag closes the surface behind them), eyelids, nose, brows and chin. Coordinates follow FaceFormer/VOCASET:
# metres, $y$ up, the face looks towards $+z$. Every speaker's head has the same topology — same triangles, same
# named regions — only the vertex positions differ.

# %%
# NBVAL_CHECK_OUTPUT
mesh = build_template()
V = mesh.n_vertices
check_shape(mesh.vertices, (V, 3), "template vertices")
extent_mm = (mesh.vertices.max(0) - mesh.vertices.min(0)) * 1000
print(f"{V} vertices, {len(mesh.faces)} triangles, watertight: {mesh.to_trimesh().is_watertight}")
print(f"size x, y, z: {extent_mm[0]:.0f} x {extent_mm[1]:.0f} x {extent_mm[2]:.0f} mm")
print("regions:", ", ".join(f"{k} {len(v)}" for k, v in mesh.regions.items()))
print("lip midpoints (upper, lower):", mesh.lip_midpoints)
assert V == corpus.metadata["n_vertices"] and np.array_equal(mesh.faces, corpus.faces)

# %% [markdown]
# The regions are what the metrics use: `lips` for the lip vertex error, `upper_face` for FDD, `eyes_forehead`
# for EmoFace's EVE. Here are the main ones, as dots over a front and a side view.

# %%
shown = ["forehead", "brows", "eyes", "nose", "cheeks", "jaw", "lips"]   # later entries win where regions overlap
label = np.full(V, -1)
for i, region in enumerate(shown):
    label[mesh.regions[region]] = i
colours = plt.get_cmap("tab10")(np.arange(len(shown)))
fig, axes = plt.subplots(1, 2, figsize=(8.5, 4.2), layout="constrained")
for ax, view in zip(axes, ("front", "side")):
    draw_mesh(ax, mesh.vertices, mesh.faces, view, scale=1e3)       # axes in mm
    for i in range(len(shown)):
        pts = mesh.vertices[label == i] * 1000
        if view == "front":                           # camera on +z: image x = x; keep the front half
            ax.scatter(pts[pts[:, 2] > 0, 0], pts[pts[:, 2] > 0, 1], s=5, color=colours[i], zorder=3)
        else:                                         # camera on +x: image x = -z; keep the near (left) half
            ax.scatter(-pts[pts[:, 0] >= 0, 2], pts[pts[:, 0] >= 0, 1], s=5, color=colours[i], zorder=3)
    ax.set(xlabel="x (mm)" if view == "front" else "-z (mm)", ylabel="y (mm)", title=f"{view} view")
fig.legend(handles=[Patch(color=colours[i], label=r) for i, r in enumerate(shown)], loc="outside right center")
fig.suptitle("Template mesh and named regions")
plt.show()

# %% [markdown]
# ## 2. The rig: 14 controls
#
# `FaceRig(speaker).animate(controls)` maps a control vector $q_t \in \mathbb{R}^{14}$ per frame to vertices.
# Thirteen controls are **blendshapes** — fixed per-vertex offsets $D_c$ scaled by the control value — and the
# jaw is a **rotation** (below); `lip_press` additionally pulls each upper-lip vertex and its lower-lip partner
# towards their midpoint, so the lips meet wherever the jaw is:
#
# $$p_v(q) = h_v + \sum_{c \neq \mathrm{jaw}} q_c D_{c,v} \;+\; \text{jaw rotation} \;+\; \text{lip closure}$$
#
# Below, every control is set to 1 on its own; colour is the displacement from the template in mm (the jaw
# moves the chin by 33 mm, so the colour scale is clipped at 6 mm). Each control
# keeps at least 90 % of its displacement energy inside the regions it is meant for (`CONTROL_REGIONS`).

# %%
rig = FaceRig()                                                    # the canonical head (no speaker)
single = np.eye(len(CONTROL_NAMES))                                # (C, C): control c = 1, the rest 0
posed = rig.animate(single)                                        # (C, V, 3)
check_shape(posed, (len(CONTROL_NAMES), V, 3), "posed")
disp = np.linalg.norm(posed - rig.template, axis=-1) * 1000        # (C, V) mm
for c, name in enumerate(CONTROL_NAMES):
    inside = np.unique(np.concatenate([mesh.regions[r] for r in CONTROL_REGIONS[name]]))
    share = (disp[c, inside] ** 2).sum() / (disp[c] ** 2).sum()
    assert share >= 0.9, (name, share)
print("largest displacement per control (mm):",
      ", ".join(f"{n} {d:.1f}" for n, d in zip(CONTROL_NAMES, disp.max(1))))
fig = plot_frames(posed, rig.faces, titles=list(CONTROL_NAMES), colors=disp, cmap="YlOrRd", vmax=6.0,
                  view="three_quarter", color_label="displacement (clipped at 6)", ncols=7, panel_size=1.55,
                  suptitle="Each rig control at 1.0 (three-quarter view)")
fig

# %% [markdown]
# **The jaw is a hinge, not a blendshape.** A linear offset would move the chin along a straight line and
# stretch it. Instead, with angle $\varphi = 0.30\,\mathrm{rad} \times$ `jaw_open` and $R(\varphi)$ the rotation
# about the $x$ axis through the hinge point $\mathbf{c}$ (near the ear),
#
# $$p_v' = p_v + w_v\,\big(R(\varphi)(p_v - \mathbf{c}) - (p_v - \mathbf{c})\big),$$
#
# where $w_v = 1$ on the lower lip and chin and falls to 0 towards the upper lip and ears. Vertices with
# $w_v = 1$ move on circles: the chin's distance to the hinge axis does not change as the jaw opens.

# %%
front_jaw = np.nonzero((np.abs(rig.template[:, 0]) < 1e-6) & (rig.jaw_weights == 1.0))[0]   # midline, w_v = 1
chin = front_jaw[np.argmin(np.abs(rig.template[front_jaw, 1] - mesh.landmarks["y_chin"]))]
openings = np.linspace(0.0, 1.0, 11)
jaw_poses = rig.animate(openings[:, None] * control_vector({"jaw_open": 1.0}))                   # (11, V, 3)
rel = jaw_poses[:, chin, 1:] - rig.hinge[1:]                       # (11, 2) chin - hinge in the y-z plane
radius = np.linalg.norm(rel, axis=1)                               # distance to the hinge axis (along x)
angle = np.degrees(np.arctan2(rel[:, 0], rel[:, 1]))
print(f"chin vertex {chin}: radius {radius.min() * 1000:.4f}..{radius.max() * 1000:.4f} mm, "
      f"swept {angle[0] - angle[-1]:.1f} degrees (JAW_MAX_ANGLE = {np.degrees(JAW_MAX_ANGLE):.1f})")
assert np.ptp(radius) < 1e-6                                       # metres: constant to float32 precision
assert abs((angle[0] - angle[-1]) - np.degrees(JAW_MAX_ANGLE)) < 0.01
assert np.linalg.norm(jaw_poses[-1, chin] - jaw_poses[0, chin]) > 0.02   # and it does move, > 2 cm

fig, ax = plt.subplots(figsize=(4.5, 4.2), layout="constrained")
arc = np.radians(np.linspace(angle[-1] - 5, angle[0] + 5, 100))
ax.plot((rig.hinge[2] + radius[0] * np.cos(arc)) * 1000, (rig.hinge[1] + radius[0] * np.sin(arc)) * 1000,
        "--", color="0.6", label="circle about the hinge")
ax.scatter(jaw_poses[:, chin, 2] * 1000, jaw_poses[:, chin, 1] * 1000, c=openings, cmap="viridis", zorder=3,
           label="chin, jaw_open 0 -> 1")
ax.plot(rig.hinge[2] * 1000, rig.hinge[1] * 1000, "k+", ms=12, label="hinge axis")
ax.set(xlabel="z (mm, towards the face)", ylabel="y (mm, up)", title="The chin moves on a circle", aspect="equal")
ax.legend(fontsize=8, loc="lower left")
plt.show()

# %% [markdown]
# ## 3. Speech, live: espeak-ng
#
# `synthesize(text, voice)` runs espeak-ng in a fresh worker process and returns the 16 kHz wave and the
# phoneme segments `(symbol, start_s, end_s)`, timed from espeak's own phoneme events (sample-accurate, not
# forced alignment). Fresh processes make it deterministic: here we speak the first training sentence with the
# voice of speaker SPK01 and get *exactly* the audio stored in the corpus (FLAC, 16-bit).

# %%
voice = speaker_voices(1)[0]                      # SPK01's voice: espeak variant, pitch, range, rate, volume
text = corpus.meta("SPK01_s00")["text"]
utt = synthesize(text, voice)
wave, phonemes = utt.wave, utt.phonemes           # (N,) float32, [(symbol, start_s, end_s), ...]
print(f"'{text}' with {voice}: {utt.duration:.3f} s, {len(phonemes)} phoneme segments")
pcm16 = np.clip(np.round(wave * 32767), -32768, 32767) / 32768          # as the corpus stores it
assert np.array_equal(pcm16.astype(np.float32), corpus.wave("SPK01_s00"))
assert [[p, round(s, 6), round(e, 6)] for p, s, e in phonemes] == corpus.meta("SPK01_s00")["phonemes"]
assert utt.stress == corpus.meta("SPK01_s00")["stress"]       # espeak's stress marks: 2 primary, 1 secondary
print("primary stress on:", [p for (p, _, _), st in zip(phonemes, utt.stress) if st == 2])
plot_waveform_and_phonemes(wave, SR, phonemes, title=f"espeak-ng: '{text}'")

# %% [markdown]
# ## 4. Phonemes -> visemes
#
# Many phonemes look the same on the face: /p/, /b/ and /m/ all close the lips; /t d n l/ differ inside the
# mouth, not on the lips. `phoneme_to_viseme` maps espeak's phoneme symbols to 15 visemes (diphthongs such as
# /oU/ are split into their parts for the motion); unknown symbols fall back to a neutral consonant or vowel.

# %%
# NBVAL_CHECK_OUTPUT
groups = {v: [p for p, vv in PHONEME_TO_VISEME.items() if vv == v] for v in VISEMES}
for v in VISEMES:
    print(f"{v:>3}: {' '.join(groups[v])}")
print()
print("sentence:", " ".join(f"{p}->{phoneme_to_viseme(p)}" for p, _, _ in phonemes))
assert {phoneme_to_viseme(p) for p in "pbm"} == {"PP"}

# %% [markdown]
# ## 5. Coarticulation: Cohen-Massaro dominance functions
#
# A viseme is not switched on and off: each segment $s$ (centre $c_s$) exerts a **dominance** on every control
# $k$ that peaks at the segment and decays exponentially away from it (Cohen & Massaro, 1993),
#
# $$D_{sk}(\tau) = \alpha_{sk}\, \exp\!\big(-\theta_s^{\pm}\, |\tau|^{c}\big), \qquad \tau = t - c_s \tag{CM1}$$
#
# with a rate $\theta^{-}_s$ before the centre (**anticipation**) and $\theta^{+}_s$ after it (**carry-over**), and
# $c = 1$. Long segments hold full dominance on a plateau ($\tau$ is measured from the plateau's ends, which lie
# 50 ms inside the segment). The control track is the dominance-weighted mean of the viseme targets $T_{sk}$,
#
# $$F_k(t) = \frac{\sum_s D_{sk}(t)\, T_{sk}}{\sum_s D_{sk}(t) + \varepsilon}, \tag{CM2}$$
#
# where $\varepsilon$ = `REST_DOMINANCE` is a weak pull towards the rest pose. Strong dominance ($\alpha$ large:
# bilabials) wins over weak neighbours; slow decay ($\theta^-$ small: rounded vowels) reaches far back.
# First, both equations from scratch, checked against the package:

# %%
def dominance_scratch(t, viseme, start, end, k):
    """(CM1) for control k, written out."""
    p = VISEME_PARAMS[viseme]
    centre, plateau = 0.5 * (start + end), max(0.0, 0.5 * (end - start) - PLATEAU_MARGIN)
    tau = np.maximum(np.abs(t - centre) - plateau, 0.0)          # s, distance to the plateau
    theta = np.where(t < centre, p.theta_back, p.theta_fwd)       # theta^- before, theta^+ after the centre
    alpha = p.alpha_jaw if CONTROL_NAMES[k] == "jaw_open" else p.alpha_lips
    return alpha * np.exp(-theta * tau ** DOMINANCE_POWER)


segments = phonemes_to_visemes(phonemes)          # [(viseme, start_s, end_s)], diphthongs split
n_frames = int(round(len(wave) * FPS / SR))
t = np.arange(n_frames) / FPS                     # frame f is at time f / fps
num, den = np.zeros((n_frames, len(CONTROL_NAMES))), np.full((n_frames, len(CONTROL_NAMES)), REST_DOMINANCE)
for viseme, start, end in segments:
    d = dominance(t, viseme, start, end)                                             # (T, C)
    for k in (CONTROL_INDEX["jaw_open"], CONTROL_INDEX["lip_pucker"]):
        np.testing.assert_allclose(d[:, k], dominance_scratch(t, viseme, start, end, k), rtol=1e-12)
    target = np.array([VISEME_PARAMS[viseme].target.get(n, 0.0) for n in CONTROL_NAMES])
    num, den = num + d * target, den + d
torch.testing.assert_close(torch.from_numpy(num / den).float(), torch.from_numpy(coarticulate(segments, n_frames)))
print(f"(CM1) and (CM2) from scratch == coarticulate(): {len(segments)} segments, {n_frames} frames")

# %% [markdown]
# **Anticipatory lip rounding.** In "two" the lips are already rounded during the /t/, in "tea" they are
# spread: the /t/ has almost no dominance on the lips ($\alpha$ = 0.3), so the strongly dominant, slowly
# decaying /u:/ ($\alpha$ = 2, $\theta^-$ = 7/s) takes over. Two hand-timed phoneme tracks show it:

# %%
def word(vowel):
    return [("_", 0.0, 0.25), ("t", 0.25, 0.33), (vowel, 0.33, 0.55), ("_", 0.55, 0.9)]


n_word = 27                                       # 0.9 s at 30 fps
t_word = np.arange(n_word) / FPS
k_pucker = CONTROL_INDEX["lip_pucker"]
tracks = {w: coarticulate(phonemes_to_visemes(word(v)), n_word)[:, k_pucker] for w, v in (("two", "u:"), ("tea", "i:"))}
t_frame = int(round(0.29 * FPS))                  # the frame nearest the centre of the /t/
print(f"lip_pucker at the /t/ (t = {t_frame / FPS:.2f} s): 'two' {tracks['two'][t_frame]:.2f}, "
      f"'tea' {tracks['tea'][t_frame]:.2f}")
assert tracks["two"][t_frame] > 0.3 and tracks["tea"][t_frame] < 0.05

# %%
t_fine = np.linspace(0.0, 0.9, 400)
fig, axes = plt.subplots(1, 2, figsize=(10, 3.2), layout="constrained")
for viseme, start, end in phonemes_to_visemes(word("u:")):
    axes[0].plot(t_fine, dominance(t_fine, viseme, start, end)[:, k_pucker],
                 label=f"{viseme} [{start:.2f}, {end:.2f}] s")
axes[0].set(xlabel="time (s)", ylabel="dominance $D_{s,k}$ (a.u.)", title="'two': dominance on lip_pucker (CM1)")
axes[0].legend(fontsize=8)
for w, track in tracks.items():
    axes[1].plot(t_word, track, "o-", ms=3, label=f"'{w}'")
for ax in axes:
    ax.axvspan(0.25, 0.33, color="0.85", zorder=0)
    ax.text(0.29, 0.97, "/t/", transform=ax.get_xaxis_transform(), ha="center", va="top")
axes[1].set(xlabel="time (s)", ylabel="lip_pucker (control units)", title="Blended track $F_k(t)$ (CM2) at 30 fps")
axes[1].legend(fontsize=8)
plt.show()

# %% [markdown]
# ## 6. Lip distance against the phoneme track
#
# `clip_controls` is the whole recipe of one clip: coarticulated visemes x the speaker's gains + the speaker's
# resting face + emotion offsets + the upper-face motion that follows the speech (from the stress marks and the
# F0 of the stored 16-bit wave, section 9) + blinks and brow drift (from a seeded generator). With SPK01's rig
# and the clip's seed it regenerates the corpus clip `SPK01_s00` exactly. The lip distance (upper- to lower-lip
# midpoint, DualTalker Fig. 5) must drop below 1 mm at every /p b m/ and open wide on open vowels.

# %%
speakers = make_speakers(10, seed=0)
assert {s.name: s.to_dict() for s in speakers} == json.loads((sample_path() / "speakers.json").read_text())
spk01 = speakers[0]
rig01 = FaceRig(spk01)
controls = clip_controls(phonemes, n_frames, spk01, seed=zlib.crc32(b"SPK01_s00"),  # the generator's clip seed
                         stress=utt.stress, wave=pcm16)
check_shape(controls, (n_frames, len(CONTROL_NAMES)), "controls")
verts = rig01.animate(controls)                                     # (T, V, 3)
assert np.array_equal(verts.reshape(n_frames, -1), corpus.vertices("SPK01_s00"))   # bit for bit

upper_mid, lower_mid = mesh.lip_midpoints
lips_mm = lip_distance(verts, upper_mid, lower_mid)                 # (T,) mm
rows = []
for p, start, end in phonemes:
    f = min(int(round(0.5 * (start + end) * FPS)), n_frames - 1)    # frame nearest the segment centre
    rows.append((p, phoneme_to_viseme(p), f, lips_mm[f]))
bilabial = [r[3] for r in rows if r[1] == "PP"]
open_vowel = [r[3] for r in rows if r[1] in ("aa", "O")]
print("phoneme viseme frame lip distance (mm)")
print("\n".join(f"{p:>7} {v:>6} {f:>5} {d:8.2f}" for p, v, f, d in rows))
assert max(bilabial) < 1.0 and min(open_vowel) > 5.0
print(f"/p b m/: max {max(bilabial):.2f} mm over {len(bilabial)} segments; open vowels: min {min(open_vowel):.2f} mm")

# %%
plot_lip_distance(t, {"SPK01": lips_mm}, phonemes=phonemes, title=f"Lip distance: '{text}'")

# %% [markdown]
# ## 7. Speakers
#
# `make_speakers(n, seed)` draws each speaker's head proportions (17 `FaceShape` numbers) and speaking style:
# gains on the speech controls, a resting face, smile asymmetry, overall articulation, blink rate — plus one
# strong *signature* trait so identities are easy to tell apart (the corpus's `speakers.json` is exactly
# `make_speakers(10, seed=0)`, checked above). Three of them, driven by the **same** phoneme track:

# %%
# NBVAL_CHECK_OUTPUT
trio = [speakers[i] for i in (0, 2, 3)]
print(f"{'speaker':8} {'signature':18} {'head w (mm)':>11} {'mouth w (mm)':>12} {'jaw gain':>8} {'pucker gain':>11} "
      f"{'articulation':>12}")
for s in trio:
    print(f"{s.name:8} {s.signature:18} {s.shape.head_width * 1000:11.1f} {s.shape.mouth_width * 1000:12.1f} "
          f"{s.gains['jaw_open']:8.2f} {s.gains['lip_pucker']:11.2f} {s.articulation:12.2f}")

# %%
rigs = {s.name: FaceRig(s) for s in trio}
clips = {s.name: rigs[s.name].animate(clip_controls(phonemes, n_frames, s, seed=0, stress=utt.stress, wave=pcm16))
         for s in trio}                                                                            # (T, V, 3)
templates = np.stack([r.template for r in rigs.values()])                              # (3, V, 3)
shape_mm = np.linalg.norm(templates - mesh.vertices, axis=-1) * 1000                    # vs the canonical head
fig = plot_frames(templates, mesh.faces, titles=[f"{s.name}: {s.signature}" for s in trio], colors=shape_mm,
                  cmap="YlOrRd", color_label="distance to the canonical head", panel_size=2.4,
                  suptitle="Speaker templates (same topology, different shape)")
fig

# %%
curves = {name: lip_distance(v, upper_mid, lower_mid) for name, v in clips.items()}
ranges = {name: np.ptp(c) for name, c in curves.items()}
print("lip-distance range (mm):", ", ".join(f"{n} {r:.1f}" for n, r in ranges.items()))
assert ranges["SPK01"] > ranges["SPK04"] * 1.2          # the wide jaw opens much more than the restrained speaker
plot_lip_distance(t, curves, phonemes=phonemes, title="Same phonemes, three speakers")

# %% [markdown]
# ## 8. Emotions
#
# EmoFace's five emotions at intensity levels 1 and 2 change **both** modalities. The voice: `emotional_prosody`
# shifts espeak's pitch, pitch range, rate and volume (sad: lower, slower, quieter; angry: louder, faster). The
# face: `emotion_controls` adds a static offset to the controls and scales articulation (sad speech moves less).
# The corpus has six speakers saying eight training sentences with every emotion and level (split `train_emo`)
# — pseudo-pairs with the same content as their neutral twin in `train`. Prosody measured on the stored audio of
# SPK01, "Bob bought a big blue boat.", level 2:

# %%
# NBVAL_CHECK_OUTPUT
print(f"{'emotion':10} {'pitch':>5} {'range':>5} {'rate':>4} {'volume':>6} | {'duration (s)':>12} {'RMS (dBFS)':>10} "
      f"{'artic. gain':>11}")
stats = {}
for e in EMOTIONS:
    clip = "SPK01_s00" if e == "neutral" else f"SPK01_s00-{e}2"
    w = corpus.wave(clip)
    v = emotional_prosody(voice, e, 0 if e == "neutral" else 2)
    stats[e] = (len(w) / SR, 20 * np.log10(np.sqrt(np.mean(w.astype(np.float64) ** 2))))
    print(f"{e:10} {v.pitch:5d} {v.pitch_range:5d} {v.rate:4d} {v.volume:6d} | {stats[e][0]:12.3f} {stats[e][1]:10.1f} "
          f"{emotion_controls(e, 2)[1]:11.2f}")
assert max(stats, key=lambda e: stats[e][0]) == "sad" and min(stats, key=lambda e: stats[e][1]) == "sad"
assert max(stats, key=lambda e: stats[e][1]) == "angry"

# %%
offsets = np.stack([emotion_controls(e, 2)[0] for e in EMOTIONS])        # (5, C) level-2 offsets
faces_e = rig.animate(offsets)                                           # (5, V, 3)
emo_mm = np.linalg.norm(faces_e - rig.template, axis=-1) * 1000
fig = plot_frames(faces_e, rig.faces, titles=list(EMOTIONS), colors=emo_mm, cmap="YlOrRd",
                  color_label="offset from neutral", ncols=5, panel_size=2.0,
                  suptitle="Emotion offsets at level 2 (no speech)")
fig

# %% [markdown]
# `metadata.json` lists the pseudo-pairs under `pairs`: one group per speaker and sentence, `neutral` plus every
# emotion and level. On the faces of one group: the brows (mean height of the brow vertices above the template),
# the mouth corners (smile), the eyelids (opening) and the jaw (largest lip distance) all move with the emotion.

# %%
# NBVAL_CHECK_OUTPUT
group = corpus.metadata["pairs"]["SPK01_s00"]
print("pair group SPK01_s00:", ", ".join(group))
brows, corners = corpus.regions["brows"], corpus.regions["mouth_corners"]
h01 = corpus.template("SPK01").reshape(V, 3)
print(f"{'clip':12} {'s':>5} {'brow (mm)':>9} {'corner y (mm)':>13} {'max lip gap (mm)':>16}")
for key in ("neutral", "happy2", "sad2", "angry2", "surprised2"):
    v = corpus.vertices(group[key]).reshape(-1, V, 3)
    gap = lip_distance(v, *corpus.regions["lip_midpoints"])
    print(f"{key:12} {len(v) / FPS:5.2f} {1000 * (v[:, brows, 1] - h01[brows, 1]).mean():9.2f} "
          f"{1000 * (v[:, corners, 1] - h01[corners, 1]).mean():13.2f} {gap.max():16.1f}")

# %% [markdown]
# A pair side by side, with sound: the neutral clip speaks first (the surprised face waits), then the surprised
# one (level 2: higher, wider pitch; raised brows, wide eyes, bigger accents).

# %%
# NBVAL_IGNORE_OUTPUT
a, b = corpus.vertices(group["neutral"]).reshape(-1, V, 3), corpus.vertices(group["surprised2"]).reshape(-1, V, 3)
pair = {"neutral": np.concatenate([a, np.repeat(a[-1:], len(b), 0)]),
        "surprised 2": np.concatenate([np.repeat(b[:1], len(a), 0), b])}
video = animate_clip(pair, corpus.faces, sample_rate=SR, size=160,
                     wave=np.concatenate([corpus.wave(group["neutral"]), corpus.wave(group["surprised2"])]))
HTML(video._repr_html_())                                   # the player only (its repr would show a local path)

# %% [markdown]
# ## 9. The upper face: what follows the speech, and what stays random
#
# Real faces move above the mouth too, weakly, and partly in step with the voice. `face/upper.py` adds three
# such sources, each a few mm at most and styled per speaker (`Speaker.accent`, `pitch_brow`, `cheek`, ...):
#
# - **pitch accents**: each primary-stressed vowel (espeak's `'` mark) starts a brief brow raise
#   `accent_lead` s before it (120 ms up, 350 ms down), higher when the vowel's F0 peak is high:
#   prominence $=\mathrm{clip}(0.6 + 0.15\,f_0^{\text{peak}}, 0.3, 1.6)$ with $f_0$ in semitones re the clip median;
# - **F0 contour**: the brows also follow the smoothed pitch, `pitch_brow` control units per semitone;
# - **cheeks** follow the smile and lip stretch (and the eyes narrow a little with a smile);
# - **blinks** start at a pause (phrase boundary) with probability `boundary_blink`; others stay random.
#
# What remains random: the timing of the other blinks, a slow brow drift, and a +-15 % jitter of each accent.
# The long clip SPK01_long01 (five sentences) shows all of it: pitch with the stressed vowels, the brows, the blinks.

# %%
clip = "SPK01_long01"
meta, wave_l = corpus.meta(clip), corpus.wave(clip).astype(np.float64)
T_l = meta["n_frames"]
semitones, voiced = pitch_track(wave_l, T_l)                                   # (T,), (T,) bool
v_l = corpus.vertices(clip).reshape(T_l, V, 3)
brow_mm = 1000 * (v_l[:, brows, 1] - h01[brows, 1]).mean(1)                    # (T,) mean brow height, mm
blink = corpus._all_controls()[clip][:, CONTROL_INDEX["blink"]]
stressed = [s for (p, s, e), st in zip(meta["phonemes"], meta["stress"]) if st == 2]
pauses = [(s, e) for p, s, e in meta["phonemes"][1:] if p == "_" and e - s >= 0.08]
check_shape(semitones, (T_l,), "semitones")

# %%
t_l = np.arange(T_l) / FPS
fig, axes = plt.subplots(3, 1, figsize=(10, 5.5), sharex=True, layout="constrained")
axes[0].plot(t_l[voiced], semitones[voiced], ".", ms=3, label="F0 (voiced frames)")
axes[0].set_ylabel("F0 (semitones\nre median)")
axes[1].plot(t_l, brow_mm, color="C1", label="brow height")
axes[1].set_ylabel("brows (mm)")
axes[2].plot(t_l, blink, color="C2", label="blink control")
axes[2].set_ylabel("blink (0-1)")
for ax in axes:
    for s in stressed:
        ax.axvline(s, color="0.6", lw=0.7, ls=":")
    for s, e in pauses:
        ax.axvspan(s, e, color="C3", alpha=0.12, lw=0)
axes[0].set_title(f"{clip}: dotted = primary-stressed vowels, shaded = pauses")
axes[-1].set_xlabel("time (s)")
plt.show()

# %% [markdown]
# Averaged over all neutral training clips (event-locked average of the brow height, minus its value 0.2 s
# before the vowel), the brows rise right at the onsets of **stressed** vowels — from the lowest point in the
# 0.2 s before to the highest in the 0.2 s after — and not at unstressed ones. (The average is small, about half
# a millimetre: speakers differ, some accents are weak, and the drift is not locked to the vowels.) Blink onsets
# pile up in the 250 ms after a pause starts.

# %%
window = np.arange(-6, 16)                                            # frames around a vowel onset
locked = event_locked_brows(corpus, "train", window)                 # {kind: (n, 22)} mm, minus frame -6
rise = {k: v.mean(0) for k, v in locked.items()}                     # (22,) mm
lift = {k: onset_lift(r, window) for k, r in rise.items()}           # max over [0, 6] - min over [-6, 0]
print(f"brow lift at the vowel onset: stressed {lift['stressed vowel']:.2f} mm ({len(locked['stressed vowel'])} "
      f"vowels), unstressed {lift['unstressed vowel']:.2f} mm ({len(locked['unstressed vowel'])} vowels)")
blinks = pause_blink_ratio(corpus, "train")                          # blink onsets within 250 ms of a pause
ratio = blinks["ratio"]
print(f"blinks starting within 250 ms of a pause: {blinks['near']}/{blinks['blinks']}, "
      f"{ratio:.1f}x the rate expected by chance")
assert lift["stressed vowel"] > 0.25 and lift["stressed vowel"] > lift["unstressed vowel"] + 0.2
assert ratio > 3
fig, ax = plt.subplots(figsize=(6, 3), layout="constrained")
for k, r in rise.items():
    ax.plot(window / FPS, r, label=k)
ax.axvline(0, color="0.5", lw=0.8)
ax.set(xlabel="time from the vowel onset (s)", ylabel="brow height change (mm)",
       title="Event-locked brow height, neutral training clips")
ax.legend(fontsize=8)
plt.show()

# %% [markdown]
# The random part: same phonemes, stress and audio — the sentence said six times in a row, 9.5 s — with two seeds.
# The mouth controls are identical; blinks, brow drift and accent jitter are not.

# %%
mouth_controls = [CONTROL_INDEX[n] for n in ("jaw_open", "lip_press", "lip_pucker", "lip_stretch")]
idle = [CONTROL_INDEX[n] for n in ("blink", "brow_raise")]
repeats = 6
long_phonemes = [(p, s + r * utt.duration, e + r * utt.duration) for r in range(repeats) for p, s, e in phonemes]
n_long = repeats * n_frames
t_long = np.arange(n_long) / FPS
wave_rep = np.tile(pcm16, repeats)
by_seed = {seed: clip_controls(long_phonemes, n_long, spk01, seed=seed, stress=utt.stress * repeats, wave=wave_rep)
           for seed in (0, 1)}
assert np.array_equal(by_seed[0][:, mouth_controls], by_seed[1][:, mouth_controls])
closed = {seed: (c[:, CONTROL_INDEX["blink"]] > 0.5).astype(int) for seed, c in by_seed.items()}   # eyes shut
blinks = {seed: int((np.diff(shut) == 1).sum()) for seed, shut in closed.items()}                 # closings
print(f"{n_long / FPS:.1f} s: blinks with seed 0: {blinks[0]}, seed 1: {blinks[1]}")
assert not np.array_equal(by_seed[0][:, idle], by_seed[1][:, idle])
r_brow = np.corrcoef(by_seed[0][:, CONTROL_INDEX["brow_raise"]], by_seed[1][:, CONTROL_INDEX["brow_raise"]])[0, 1]
print(f"brow_raise of the two seeds correlates at r = {r_brow:.2f}: the part that follows the speech")

# %%
fig, axes = plt.subplots(3, 1, figsize=(9, 5), sharex=True, layout="constrained")
for ax, name in zip(axes, ("jaw_open", "blink", "brow_raise")):
    for seed, track in by_seed.items():
        ax.plot(t_long, track[:, CONTROL_INDEX[name]], lw=1.5, ls="-" if seed == 0 else "--", label=f"seed {seed}")
    ax.set_ylabel(f"{name}\n(control units)", fontsize=8)
axes[0].set_title("Same speech, two seeds: the mouth is identical, the brows share the accents, blinks differ")
axes[0].legend(fontsize=8)
axes[-1].set_xlabel("time (s)")
plt.show()

# %% [markdown]
# How much of the upper face can a model predict from the audio? A linear probe answers it: ridge regression
# from prosody features of the audio alone (F0, voicing and loudness, +-8 frames of context) to brow height,
# fitted on every other neutral `train` clip and scored on `test_a` (unseen sentences). A constant scores $R^2 = 0$;
# the same probe fed another clip's audio scores about 0 or below. `dualtalker_lite.data.probe` has the probe and
# the stress-onset check (`tests/test_upper_face.py` checks both claims with its own code).

# %%
probe = upper_face_probe(corpus, corpus.split("train")[::2], corpus.split("test_a"))  # every other train clip
print(f"brow height on test_a: std {probe['std_mm']:.2f} mm; probe R^2 with its own audio {probe['r2']:.2f}, "
      f"with another clip's audio {probe['r2_other_audio']:.2f}")
onsets = stress_onset_precision(corpus, corpus.split("train") + corpus.split("test_a"))
print(f"brow-raise onsets within -150..+50 ms of a stressed vowel: {100 * onsets['precision']:.0f} % of "
      f"{onsets['onsets']} (chance {100 * onsets['chance']:.0f} %); stressed vowels with an onset: "
      f"{100 * onsets['recall']:.0f} %")
assert probe["r2"] > 0.15 and probe["r2_other_audio"] < 0.05 and onsets["precision"] > 0.8

# %% [markdown]
# ## 10. An animation with sound, and a live rig
#
# The three speakers of section 7 side by side, with the synthesized speech (notebook players show the mp4
# with its audio; the file is cached under `runs/videos/`).

# %%
# NBVAL_IGNORE_OUTPUT
HTML(animate_clip(clips, mesh.faces, wave=wave, sample_rate=SR, size=192)._repr_html_())

# %% [markdown]
# With a running kernel, the sliders below drive the rig live in a pythreejs viewer (drag to orbit, scroll to
# zoom). The same `pose` function is called once with the default values, so the non-interactive run also
# exercises it. (`dualtalker_lite.viz.static_html(vertices, faces)` gives a kernel-free three.js view instead,
# but it embeds three.js — about 0.75 MB — so it is not used in the committed notebook.)

# %%
# NBVAL_IGNORE_OUTPUT
viewer = MeshViewer(rig.template, rig.faces, width=360, height=360)
sliders = {name: widgets.FloatSlider(value=0.0, min=CONTROL_RANGES[name][0], max=CONTROL_RANGES[name][1], step=0.05,
                                     description=name, continuous_update=True)
           for name in ("jaw_open", "lip_press", "lip_pucker", "smile_left", "smile_right", "brow_raise", "blink")}


def pose(**values):
    """Rig controls from the sliders -> vertices (V, 3), shown in the viewer."""
    vertices = rig.animate(control_vector(values))
    viewer.update(vertices)
    return vertices


widgets.interactive_output(pose, sliders)
display(widgets.HBox([widgets.VBox(list(sliders.values())), viewer.widget]))
neutral = pose(**{name: s.value for name, s in sliders.items()})      # the default values, once
assert np.array_equal(neutral, rig.template)

# %%
opened = pose(jaw_open=1.0, smile_left=0.5)                             # what moving two sliders does
assert lip_distance(opened[None], upper_mid, lower_mid)[0] > 10.0
assert np.array_equal(pose(**{name: s.value for name, s in sliders.items()}), rig.template)   # back to rest

# %% [markdown]
# ## 11. The corpus on disk: splits, emotions, pairs, long clips
#
# `train`, `val`, `test_a` (seen speakers, unseen sentences) and `test_b` (unseen speakers) are neutral, as in
# VOCASET. The emotional clips live in their own splits: `train_emo` (pseudo-pairs of `train` sentences),
# `test_emo_a` (seen speakers, an unseen sentence, every emotion and level) and `test_emo_b` (unseen speakers);
# every emotional clip names its `neutral_twin`. `long` holds multi-sentence clips of 10-30 s (length
# generalisation; FaceFormer's code stops at 600 frames). `data_samples/README.md` documents all of it.

# %%
# NBVAL_CHECK_OUTPUT
for split, names in corpus.metadata["splits"].items():
    emotions = sorted({corpus.meta(n)["emotion"] for n in names})
    seconds = sum(corpus.meta(n)["n_samples"] for n in names) / SR
    print(f"{split:10} {len(names):4d} clips {seconds / 60:5.1f} min  speakers "
          f"{len({corpus.meta(n)['subject'] for n in names}):2d}  {', '.join(emotions)}")
print("long clips (s):", [round(corpus.meta(n)["n_samples"] / SR, 1) for n in corpus.split("long")])
emo = corpus.split("train_emo")
assert all(corpus.meta(corpus.meta(n)["neutral_twin"])["split"] == "train" for n in emo)

# %% [markdown]
# ## Summary
#
# - The template is a procedural 1,558-vertex head with a mouth slit and named regions (`lips`, `upper_face`,
#   `eyes_forehead`, ...) shared by every speaker.
# - The rig has 14 controls: 13 blendshapes plus a hinged jaw (vertices with full jaw weight move on circles
#   about the hinge) and a lip closure that makes the lips meet.
# - espeak-ng provides real speech and exact phoneme times; phonemes map to 15 visemes; Cohen-Massaro dominance
#   functions (CM1, CM2) blend viseme targets into smooth tracks with anticipation (the /t/ of "two" is rounded).
# - The result behaves like speech: lips close (< 1 mm) on /p b m/ and open wide on open vowels. Speakers
#   differ in shape and style, emotions in prosody and face offsets.
# - The upper face is weak (about a millimetre) and partly follows the speech: brows rise at stressed vowels and
#   with the pitch, cheeks follow the smile, blinks come at pauses; a linear probe from prosody predicts a good
#   part of the brow motion on unseen sentences, the rest (drift, other blinks) is random and seeded.
# - The corpus keeps `train` neutral and puts EmoFace's pseudo-pairs in `train_emo` / `test_emo_a` / `test_emo_b`,
#   with `pairs` and `neutral_twin` in the metadata; `long` has 10-30 s clips. `clip_controls` + `FaceRig`
#   reproduce a corpus clip bit for bit.
#
# ## Exercises
#
# 1. Change `dominance_scratch` so that the `U` viseme decays as fast before its centre as after it
#    ($\theta^-$ = 12/s instead of 7/s), re-blend "two" with (CM2), and measure the rounding left at the /t/.
# 2. Make the jaw a blendshape: replace the rotation by the straight-line offset between `jaw_open` = 0 and 1 of
#    the chin. How far (mm) does the chin leave the circle half way, and which way does the mouth deform?
# 3. Synthesize the same sentence with `emotional_prosody(voice, "sad", 1)` and `("sad", 2)`. Is the duration
#    change between levels 0, 1 and 2 linear? Compare with espeak's rate in the voice specs.
# 4. Compute the lip distance at every /f/ and /v/ of "Four fat frogs fell off the fence." (`synthesize` it). Do
#    labiodentals close the lips? Look at `VISEME_PARAMS["FF"]` to explain what you see.
# 5. Regenerate SPK01_s00 with `Speaker.pitch_brow = 0` (`dataclasses.replace`) and rerun the probe of section 9
#    on a few clips: how much of its $R^2$ came from the F0 contour, how much from the accents?
