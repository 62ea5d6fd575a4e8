"""CorrTalk's facial activity intensity (dualtalker_lite.blocks.fai): STFT amplitudes on signals of known frequency and
amplitude, computed by hand from the Hann-window DFT, the three band readings, the corpus invariant, bad inputs."""
import math

import numpy as np
import pytest
import torch

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.blocks.fai import (BANDS, displacement_stft, fai_from_corpus, fai_from_dataset,
                                 facial_activity_intensity, mean_amplitude_spectrum, normalised_fai, select_band,
                                 vertex_displacements)


def hann(n_fft):
    """Periodic Hann window, w_n = 0.5 - 0.5 cos(2 pi n / N)."""
    return np.array([0.5 - 0.5 * math.cos(2 * math.pi * n / n_fft) for n in range(n_fft)])


def reference_amplitude(x, n_fft, hop):
    """Eq. 3 written out: A(k, m) = c_k |sum_n w_n x[mH + n] e^{-2 pi i k n / N}|, c_0 = c_{N/2} = 1 / sum w,
    else 2 / sum w; plain loops, no FFT. Returns (F, M)."""
    w = hann(n_fft)
    n_frames = 1 + (len(x) - n_fft) // hop
    out = np.zeros((n_fft // 2 + 1, n_frames))
    for m in range(n_frames):
        for k in range(n_fft // 2 + 1):
            acc = sum(w[n] * x[m * hop + n] * complex(math.cos(2 * math.pi * k * n / n_fft),
                                                      -math.sin(2 * math.pi * k * n / n_fft))
                      for n in range(n_fft))
            c = (1.0 if k in (0, n_fft // 2) else 2.0) / w.sum()
            out[k, m] = c * abs(acc)
    return out


def signals(columns):
    """(T, V) displacement tensor from a list of 1-D signals."""
    return torch.tensor(np.stack(columns, axis=1), dtype=torch.float64)


# ------------------------------------------------------------------------------------------ displacements
def test_vertex_displacements_hand_case_both_layouts():
    template = np.zeros((2, 3))
    verts = np.array([[[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]],
                      [[0.0, 0.0, 0.0], [1.0, 2.0, 2.0]]])                    # (T=2, V=2, 3)
    expected = torch.tensor([[5.0, 0.0], [0.0, 3.0]], dtype=torch.float64)
    torch.testing.assert_close(vertex_displacements(verts, template), expected)
    torch.testing.assert_close(vertex_displacements(verts.reshape(2, 6), template.reshape(6)), expected)
    moved = vertex_displacements(verts + 1.0, template + 1.0)             # translation invariant
    torch.testing.assert_close(moved, expected)


# ------------------------------------------------------------------------------------------ the STFT
def test_constant_plus_cosine_on_a_bin_reads_its_amplitudes():
    # x_n = c + a cos(2 pi k0 n / N), one frame (T = N). The periodic Hann window's DFT is W_0 = N/2, W_{+-1} = -N/4,
    # 0 elsewhere, so X_k = c W_k + a/2 (W_{k-k0} + W_{k+k0}); with k0 = 2:
    #   X_0 = c N/2, X_1 = -(c + a/2) N/4, X_2 = a N/4, X_3 = -a N/8, X_k = 0 for k >= 4.
    # c_0 = 1 / (N/2), c_k = 2 / (N/2): amplitudes c, c + a/2, a, a/2, 0, ...
    n_fft, c, a = 16, 1.0, 4.0
    x = c + a * np.cos(2 * np.pi * 2 * np.arange(n_fft) / n_fft)
    freqs, amp = displacement_stft(signals([x]), fps=30.0, n_fft=n_fft, hop=4)
    assert amp.shape == (9, 1, 1)
    expected = np.array([c, c + a / 2, a, a / 2, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(amp[:, 0, 0].numpy(), expected, atol=1e-12)
    np.testing.assert_allclose(freqs.numpy(), np.arange(9) * 30.0 / 16)   # bin k at k fs / N Hz


def test_multi_frame_off_bin_signal_matches_written_out_stft():
    # 3.3 Hz with a DC offset at 30 fps (between bins), 70 frames, N = 16, hop 5: 11 frames; a second vertex still.
    rng = np.random.default_rng(0)
    t = np.arange(70) / 30.0
    x = 0.002 + 0.0015 * np.sin(2 * np.pi * 3.3 * t + 0.4) + 1e-4 * rng.standard_normal(70)
    _, amp = displacement_stft(signals([x, np.zeros(70)]), fps=30.0, n_fft=16, hop=5)
    ref = reference_amplitude(x, 16, 5)
    assert amp.shape == (9, 11, 2)
    np.testing.assert_allclose(amp[:, :, 0].numpy(), ref, rtol=1e-10, atol=1e-15)
    assert float(amp[:, :, 1].abs().max()) == 0.0


def test_clip_shorter_than_the_window_keeps_a_constant():
    # T = 10 < N = 16: zero-padded to N, normalised by the window sum over the 10 real samples.
    _, amp = displacement_stft(signals([np.full(10, 0.003)]), fps=30.0, n_fft=16, hop=4)
    assert amp.shape == (9, 1, 1)
    assert float(amp[0, 0, 0]) == pytest.approx(0.003, rel=1e-12)


def test_detrend_removes_the_mean_and_its_leakage():
    n_fft, c, a = 16, 1.0, 4.0
    x = c + a * np.cos(2 * np.pi * 3 * np.arange(n_fft) / n_fft)         # k0 = 3: the cosine does not reach bin 1
    _, plain = displacement_stft(signals([x]), 30.0, n_fft, 4)
    _, flat = displacement_stft(signals([x]), 30.0, n_fft, 4, detrend=True)
    # plain: bin 0 = c, bin 1 = c (Hann leakage of the mean), bin 3 = a; detrended: bins 0 and 1 vanish.
    np.testing.assert_allclose(plain[:4, 0, 0].numpy(), [c, c, a / 2, a], atol=1e-12)
    np.testing.assert_allclose(flat[:4, 0, 0].numpy(), [0, 0, a / 2, a], atol=1e-12)


# ------------------------------------------------------------------------------------------ bands and averaging
def test_three_band_readings_differ_as_computed_by_hand():
    # Signed signal x = 1 + 4 cos(2 pi 2 n / 16), one frame: amplitudes c, c + a/2, a, a/2 = 1, 3, 4, 2 (see above),
    # so dc = 1, first = 3, dominant = 4 (bin 2); a still vertex reads 0 in every band.
    n_fft = 16
    x = 1.0 + 4.0 * np.cos(2 * np.pi * 2 * np.arange(n_fft) / n_fft)
    _, amp = displacement_stft(signals([x, np.zeros(n_fft)]), 30.0, n_fft, 4)
    spectrum = amp.mean(dim=1)                                            # (F, V)
    expected = {"dc": [1.0, 0.0], "first": [3.0, 0.0], "dominant": [4.0, 0.0]}
    for band in BANDS:
        torch.testing.assert_close(select_band(spectrum, band), torch.tensor(expected[band], dtype=torch.float64))


def test_band_readings_on_a_moving_vertex_with_and_without_detrend():
    # A distance is non-negative: d = 3 + 2 cos(2 pi 2 n / 16) in [1, 5]. Plain: c, c + a/2, a, a/2 = 3, 4, 2, 1,
    # so dc = 3 and first = dominant = 4 (the mean leaks into bin 1). Detrended (d - 3): 0, 1, 2, 1 -> 0, 1, 2.
    n_fft = 16
    verts = np.zeros((n_fft, 2, 3))
    verts[:, 0, 1] = 3.0 + 2.0 * np.cos(2 * np.pi * 2 * np.arange(n_fft) / n_fft)
    clip = (verts, np.zeros((2, 3)))
    plain = {b: facial_activity_intensity([clip], 30.0, band=b, n_fft=n_fft, hop=4) for b in BANDS}
    flat = {b: facial_activity_intensity([clip], 30.0, band=b, n_fft=n_fft, hop=4, detrend=True) for b in BANDS}
    for band, want_plain, want_flat in (("dc", 3.0, 0.0), ("first", 4.0, 1.0), ("dominant", 4.0, 2.0)):
        torch.testing.assert_close(plain[band], torch.tensor([want_plain, 0.0]))
        torch.testing.assert_close(flat[band], torch.tensor([want_flat, 0.0]))
    assert plain["dc"].dtype == torch.float32


def test_dominant_reading_finds_the_oscillation_frequency_after_detrend():
    n_fft, fps = 32, 32.0
    t = np.arange(96)
    x = 5.0 + 2.0 * np.cos(2 * np.pi * 5 * t / n_fft)                     # 5 Hz = bin 5, 3 windows' worth
    verts = np.zeros((96, 1, 3))
    verts[:, 0, 2] = x
    freqs, spec = mean_amplitude_spectrum([(verts, np.zeros(3))], fps, n_fft, 8, detrend=True)
    k = int(spec[1:, 0].argmax()) + 1
    assert freqs[k] == 5.0
    assert float(select_band(spec, "dominant")[0]) == pytest.approx(2.0, abs=1e-9)   # hops of 8: integer cycles


def test_average_is_per_clip_then_over_clips():
    # Constant displacement 1 for 64 frames (7 STFT frames) and 3 for 16 frames (1 frame): equal clip weights -> 2.
    def clip(value, n):
        verts = np.zeros((n, 1, 3))
        verts[:, 0, 0] = value
        return {"vertices": verts, "template": np.zeros(3)}
    fai = facial_activity_intensity([clip(1.0, 64), clip(3.0, 16)], fps=30.0, band="dc", n_fft=16, hop=8)
    assert float(fai[0]) == pytest.approx(2.0, rel=1e-6)


def test_normalised_fai_min_max_hand_case():
    torch.testing.assert_close(normalised_fai(torch.tensor([2.0, 4.0, 3.0, 2.5])), torch.tensor([0.0, 1.0, 0.5, 0.25]))
    out = normalised_fai(np.array([0.1, 0.3]))
    assert out.dtype == torch.float32 and out.tolist() == [0.0, 1.0]


# ------------------------------------------------------------------------------------------ a tiny mesh, by hand
# Four vertices of a tiny mesh (a corner of a cube) and N = 8, hop H = 4. Every expected number below is worked out
# from eq. 3 as printed in the module docstring, not from the package:
#   w_n = 1/2 - 1/2 cos(2 pi n / 8) = 1/2 - 1/4 e^{2 pi i n/8} - 1/4 e^{-2 pi i n/8}   (periodic Hann),  sum_n w_n = 4,
#   so the window's DFT W_k = sum_n w_n e^{-2 pi i k n/8} is W_0 = 4, W_1 = W_7 = -2, W_k = 0 otherwise;
#   c_0 = c_4 = 1/4, c_1 = c_2 = c_3 = 2/4 = 1/2;
#   A(k, m) = c_k |X_k(m)|,  X_k(m) = sum_n w_n d_{4m+n} e^{-2 pi i k n/8}.
TINY_TEMPLATE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])  # (V = 4, 3)


def tiny_clip(n_frames):
    """Vertices (T, 4, 3) of the tiny mesh whose distances from the template are, at frame n:
    v0 5 (offset (3, 0, 4), constant); v1 3 + 2 cos(2 pi 2 n / 8) = 5, 3, 1, 3, ... (a cosine on bin 2, on an offset
    since a distance is never negative; offset along +y); v2 4 when n = 2 mod 4, else 0 (a pulse every 4 frames,
    offset along -x); v3 0 (still)."""
    n = np.arange(n_frames)
    offsets = np.zeros((n_frames, 4, 3))
    offsets[:, 0] = [3.0, 0.0, 4.0]
    offsets[:, 1, 1] = 3.0 + 2.0 * np.cos(2 * np.pi * 2 * n / 8)
    offsets[:, 2, 0] = -np.where(n % 4 == 2, 4.0, 0.0)
    return TINY_TEMPLATE + offsets


# Every signal has period 4 = H, so every STFT frame reads the same amplitudes. Worked out per vertex (bins k = 0..4):
#   v0, d = 5:                 X_k = 5 W_k: X_0 = 20, X_1 = -10, rest 0           -> A = (5, 5, 0, 0, 0)
#                              (bin 1 = 5: the Hann window's leakage of the mean)
#   v1, d = 3 + 2 cos(pi n/2): X_k = 3 W_k + (W_{k-2} + W_{k+2}):
#                              X_0 = 12, X_1 = -6 - 2 = -8, X_2 = W_0 = 4, X_3 = W_1 = -2, X_4 = W_2 + W_6 = 0
#                                                                                  -> A = (3, 4, 2, 1, 0)
#   v2, pulse (d_2 = d_6 = 4): X_k = 4 w_2 e^{-i pi k/2} + 4 w_6 e^{-3 i pi k/2} = 2 (e^{-i pi k/2} + e^{i pi k/2})
#                              = 4 cos(pi k / 2): X = (4, 0, -4, 0, 4)            -> A = (1, 0, 2, 0, 1)
#   v3, d = 0:                                                                     -> A = (0, 0, 0, 0, 0)
# so FAI (mean over frames of identical values) = dc: bin 0; first: bin 1; dominant: max over bins 1..4:
TINY_FAI = {"dc": [5.0, 3.0, 1.0, 0.0], "first": [5.0, 4.0, 0.0, 0.0], "dominant": [5.0, 4.0, 2.0, 0.0]}
# min-max: (FAI - 0) / (5 - 0)
TINY_MASK = {"dc": [1.0, 0.6, 0.2, 0.0], "first": [1.0, 0.8, 0.0, 0.0], "dominant": [1.0, 0.8, 0.4, 0.0]}


@pytest.mark.parametrize("band", BANDS)
def test_tiny_mesh_fai_hand_computed_for_each_band(band):
    # T = 18: STFT frames start at 0, 4 and 8 (M = 3); frames 16-17 do not fill a hop and are dropped.
    # The three readings rank the vertices differently: the pulse v2 is the least active moving vertex by the DC
    # reading, reads 0 by bin 1 (its odd bins are 0) like the still v3, and twice its DC by the dominant reading
    # (bin 2). For the cosine v1 "first" and "dominant" agree: a distance is >= 0, so its mean (3) is at least the
    # cosine's amplitude (2), and the mean's leakage into bin 1 (3 + 2/2 = 4) beats the cosine's own bin (2).
    verts = tiny_clip(18)
    fai = facial_activity_intensity([(verts, TINY_TEMPLATE)], fps=30.0, band=band, n_fft=8, hop=4)
    torch.testing.assert_close(fai, torch.tensor(TINY_FAI[band]), atol=1e-6, rtol=0)
    torch.testing.assert_close(normalised_fai(fai), torch.tensor(TINY_MASK[band]), atol=1e-6, rtol=0)
    _, amp = displacement_stft(vertex_displacements(verts, TINY_TEMPLATE), 30.0, n_fft=8, hop=4)
    assert amp.shape == (5, 3, 4)                                          # F = 8 // 2 + 1 bins, M = 3 frames, V
    expected = np.array([[5, 5, 0, 0, 0], [3, 4, 2, 1, 0], [1, 0, 2, 0, 1], [0, 0, 0, 0, 0]], dtype=float).T
    np.testing.assert_allclose(amp.numpy(), np.repeat(expected[:, None, :], 3, axis=1), atol=1e-12)


def test_tiny_mesh_two_clips_are_averaged_per_clip_then_min_max():
    # Clip 1: the clip above (T = 18, 3 STFT frames). Clip 2: T = 8 (1 STFT frame), only v3 moves, a constant
    # offset (0, 0, 2): its spectrum is (2, 2, 0, 0, 0) (like v0 above, scaled by 2/5), the other vertices read 0.
    # Equal weight per clip, whatever its number of frames:
    #   dc:       ((5, 3, 1, 0) + (0, 0, 0, 2)) / 2 = (2.5, 1.5, 0.5, 1);  min 0.5, max 2.5 -> (1, 0.5, 0, 0.25)
    #   first:    ((5, 4, 0, 0) + (0, 0, 0, 2)) / 2 = (2.5, 2, 0, 1);      min 0,   max 2.5 -> (1, 0.8, 0, 0.4)
    #   dominant: max over bins 1..4 of the mean spectra  v0 (2.5, 2.5, 0, 0, 0), v1 (1.5, 2, 1, 0.5, 0),
    #             v2 (0.5, 0, 1, 0, 0.5), v3 (1, 1, 0, 0, 0):  (2.5, 2, 1, 1);  min 1, max 2.5 -> (1, 2/3, 0, 0)
    # (a mean weighted by STFT frames instead would give dc (3.75, 2.25, 0.75, 0.5), mask (1, 0.54, 0.08, 0)).
    clip2 = np.tile(TINY_TEMPLATE, (8, 1, 1))
    clip2[:, 3, 2] += 2.0
    clips = [{"vertices": tiny_clip(18), "template": TINY_TEMPLATE},
             {"vertices": clip2.reshape(8, 12), "template": TINY_TEMPLATE.reshape(12)}]   # the flat layout too
    want = {"dc": ([2.5, 1.5, 0.5, 1.0], [1.0, 0.5, 0.0, 0.25]), "first": ([2.5, 2.0, 0.0, 1.0], [1.0, 0.8, 0.0, 0.4]),
            "dominant": ([2.5, 2.0, 1.0, 1.0], [1.0, 2 / 3, 0.0, 0.0])}
    for band, (fai_want, mask_want) in want.items():
        fai = facial_activity_intensity(clips, fps=30.0, band=band, n_fft=8, hop=4)
        torch.testing.assert_close(fai, torch.tensor(fai_want), atol=1e-6, rtol=0)
        torch.testing.assert_close(normalised_fai(fai), torch.tensor(mask_want), atol=1e-6, rtol=0)
        # the entry point CorrTalk's mask initialisation calls, on the same item dicts
        torch.testing.assert_close(fai_from_dataset(clips, fps=30.0, band=band, n_fft=8, hop=4), fai)


# ------------------------------------------------------------------------------------------ the shipped corpus
@pytest.fixture(scope="module")
def corpus():
    return Corpus(sample_path())


def test_mouth_moves_more_than_forehead_on_the_corpus(corpus):
    regions = corpus.regions
    for band in BANDS:
        fai = fai_from_corpus(corpus, "train", band=band)
        assert fai.shape == (len(corpus.template(corpus.meta(corpus.split("train")[0])["subject"])) // 3,)
        lips, forehead = float(fai[regions["lips"]].mean()), float(fai[regions["forehead"]].mean())
        assert lips > 3.0 * forehead > 0.0, (band, lips, forehead)
        mask = normalised_fai(fai)
        assert float(mask.min()) == 0.0 and float(mask.max()) == 1.0
        assert float(mask[regions["lips"]].mean()) > float(mask[regions["forehead"]].mean())


def reference_dc_fai(clips, n_fft=32, hop=8):
    """Eq. 3, band "dc", written out in numpy from the printed formula (not the package): d_{t,v} = ||y_{t,v} - h_v||;
    STFT frame m covers d[mH .. mH + N - 1] (frames start at 0, a tail that does not fill a hop is dropped; a clip
    shorter than N is one zero-padded frame); bin 0 of a non-negative signal is A(0, m) = sum_n w_n d_{mH+n} /
    sum_n w_n (w the periodic Hann window, the sum over the real samples); mean over frames, then over clips."""
    w = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(n_fft) / n_fft)
    per_clip = []
    for verts, tpl in clips:
        d = np.linalg.norm(np.asarray(verts, np.float64).reshape(len(verts), -1, 3)
                           - np.asarray(tpl, np.float64).reshape(-1, 3), axis=-1)  # (T, V)
        starts = range(0, len(d) - n_fft + 1, hop) if len(d) >= n_fft else [0]
        frames = [w[:len(d[s:s + n_fft])] @ d[s:s + n_fft] / w[:len(d[s:s + n_fft])].sum() for s in starts]
        per_clip.append(np.mean(frames, axis=0))
    return np.mean(per_clip, axis=0)


def test_fai_from_dataset_and_corpus_equal_eq_3_written_out_and_ignore_crops(corpus):
    """Eq. 3 (reconstructed, "dc" reading): both entry points on the shipped corpus's val split equal the numpy
    reference above over the *whole* clips (the dataset crops to 20 frames for training; the FAI must not)."""
    from dualtalker_lite.data.dataset import TalkingFaceDataset

    names = corpus.split("val")
    whole = [(corpus.vertices(n), corpus.template(corpus.meta(n)["subject"])) for n in names]
    expected = torch.tensor(reference_dc_fai(whole), dtype=torch.float32)
    dataset = TalkingFaceDataset(corpus, "val", max_frames=20)
    torch.testing.assert_close(fai_from_dataset(dataset), expected, atol=1e-6, rtol=1e-5)
    torch.testing.assert_close(fai_from_corpus(corpus, "val"), expected, atol=1e-6, rtol=1e-5)
    cropped = reference_dc_fai([(v[:20], t) for v, t in whole])  # what reading the crops would give
    assert np.abs(cropped - expected.numpy()).max() > 1e-4
    items = [dataset.items[i] for i in range(3)]                          # a plain list of item dicts needs fps
    torch.testing.assert_close(fai_from_dataset(items, fps=corpus.fps),
                               torch.tensor(reference_dc_fai([(it["vertices"], it["template"]) for it in items]),
                                            dtype=torch.float32), atol=1e-6, rtol=1e-5)
    with pytest.raises(ValueError, match=r"^fai_from_dataset: pass fps="):
        fai_from_dataset(items)


# ------------------------------------------------------------------------------------------ bad inputs
def test_nan_vertices_named_with_clip_and_index():
    verts = np.zeros((20, 4, 3))
    verts[7, 2, 1] = np.nan
    clips = [(np.zeros((20, 4, 3)), np.zeros((4, 3))), {"name": "SPK01_s03", "vertices": verts,
                                                         "template": np.zeros(12)}]
    with pytest.raises(ValueError, match=r"^clip 1 \('SPK01_s03'\): vertices: 1 NaN/infinite value\(s\), "
                                         r"first at index \(7, 2, 1\)$"):
        facial_activity_intensity(clips, fps=30.0)


def test_bad_shapes_and_arguments():
    tpl = np.zeros((4, 3))
    with pytest.raises(ValueError, match=r"^clip: vertices: expected shape \(T, 12\) or \(T, 4, 3\) with T >= 1 "
                                         r"\(V = 4 from the template\), got \(20, 5, 3\)$"):
        vertex_displacements(np.zeros((20, 5, 3)), tpl)
    with pytest.raises(ValueError, match=r"^clip: template: expected shape \(V\*3,\) or \(V, 3\), got \(4, 2\)$"):
        vertex_displacements(np.zeros((20, 4, 3)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"^clip: template: 1 NaN/infinite"):
        vertex_displacements(np.zeros((20, 4, 3)), np.array([[np.inf, 0, 0]] + [[0, 0, 0]] * 3))
    with pytest.raises(ValueError, match=r"^displacements: expected shape \(T, V\) with T, V >= 1, got \(20,\)$"):
        displacement_stft(torch.zeros(20), 30.0)
    with pytest.raises(ValueError, match=r"^fps must be a positive number, got 0"):
        displacement_stft(torch.zeros(20, 2), 0)
    with pytest.raises(ValueError, match=r"^STFT: need integers n_fft >= 2 and hop >= 1"):
        displacement_stft(torch.zeros(20, 2), 30.0, hop=0)
    clip = (np.zeros((20, 4, 3)), tpl)
    with pytest.raises(ValueError, match=r"^band must be one of \('dc', 'first', 'dominant'\), got 'fundamental'$"):
        facial_activity_intensity([clip], 30.0, band="fundamental")
    with pytest.raises(ValueError, match=r"^facial activity intensity: no clips given$"):
        facial_activity_intensity([], 30.0)
    with pytest.raises(ValueError, match=r"^clip 1: has 5 vertices, the clips before it have 4$"):
        facial_activity_intensity([clip, (np.zeros((20, 5, 3)), np.zeros((5, 3)))], 30.0)
    with pytest.raises(ValueError, match=r"^clip 0: a dict clip needs keys 'vertices' and 'template', "
                                         r"missing \['template'\]$"):
        facial_activity_intensity([{"vertices": np.zeros((20, 12))}], 30.0)
    with pytest.raises(ValueError, match=r"^clip 0: expected a \(vertices, template\) pair"):
        facial_activity_intensity([np.zeros((20, 12))], 30.0)


def test_normalised_fai_refuses_constant_nan_and_wrong_shape():
    with pytest.raises(ValueError, match=r"^FAI: all 3 values equal \(0\); min-max normalisation is undefined"):
        normalised_fai(torch.zeros(3))
    with pytest.raises(ValueError, match=r"^FAI: 1 NaN/infinite value\(s\), first at index \(1,\)$"):
        normalised_fai(torch.tensor([0.0, float("nan"), 1.0]))
    with pytest.raises(ValueError, match=r"^FAI: expected shape \(V,\) with V >= 2, got \(2, 2\)$"):
        normalised_fai(torch.zeros(2, 2))
