r"""CorrTalk's facial activity intensity (FAI): an STFT of per-vertex displacements (section III-B, Fig. 1, eq. 3).

CorrTalk (Chu et al.) splits the face into *strong* activity (lips, jaw) and *weak* activity (brows, forehead,
cheeks) by measurement: each vertex's distance from the neutral template is a signal over time, decomposed with a
short-time Fourier transform (STFT), and "the amplitude value of the fundamental frequency" is that vertex's FAI
(Fig. 1); normalised, it initialises the dual-branch decoder's learnable mask (section III-D, eq. 7). **Eq. 3 is a
reconstruction** from the prose (the symbols and the numbered equation were lost in the text extraction; the prose
quoted: docs/design-notes.md, "CorrTalk's FAI"). With
:math:`y_{t,v} \in \mathbb{R}^3` vertex v of frame t, :math:`h_v` its template position, w a Hann window of N
frames and hop H:

.. math::

    d_{t,v} = \lVert y_{t,v} - h_v \rVert_2, \qquad
    A_v(k, m) = c_k \Big| \sum_{n=0}^{N-1} w_n \, d_{mH+n,\,v} \, e^{-2\pi i k n / N} \Big|, \qquad
    c_k = \frac{2 - [k = 0] - [k = N/2]}{\sum_n w_n}                                            \tag{3}

    \mathrm{FAI}_v = \frac{1}{|\mathcal{C}|} \sum_{c \in \mathcal{C}} \frac{1}{M_c} \sum_{m=1}^{M_c}
        A^{(c)}_v(k^\star, m), \qquad
    \bar{\mathrm{FAI}}_v = \frac{\mathrm{FAI}_v - \min_u \mathrm{FAI}_u}{\max_u \mathrm{FAI}_u - \min_u \mathrm{FAI}_u}

with bin k at frequency :math:`k f_s / N` (f_s the mesh frame rate), :math:`\mathcal{C}` the training clips and
:math:`M_c` the STFT frames of clip c. Readings that were possible, and the one taken:

- *Displacement*: the Euclidean distance (a scalar per vertex and frame), not the 3-D offset vector.
- *Amplitude*: magnitude :math:`|X|`, not power, one-sided (:math:`c_k`: FAI in metres); *window*: a periodic Hann
  window, ``center=False``, the tail that does not fill a last hop dropped.
- *"Fundamental frequency band"* (:math:`k^\star`), three readings, all exposed via ``band``:

  ``"dc"`` (default)  bin 0, the lowest row of the spectrogram: the window-weighted mean displacement;
  ``"first"``         bin 1, the lowest non-zero frequency (:math:`f_s / N`);
  ``"dominant"``      per vertex, the non-DC bin with the largest mean amplitude (over clips and frames).

  ``"dc"`` is taken: the text contrasts "the fundamental frequency band" with "the higher frequency bands", which
  reads most plainly as the spectrogram's lowest row; why, and how the other readings compare on the corpus, is in
  docs/design-notes.md ("CorrTalk: which band is the fundamental") and notebook 10.
- *Averaging*: over each clip's STFT frames, then over clips with equal weight per clip; *normalisation*: min-max
  over the vertices, to [0, 1] (a constant FAI is refused).
Shapes: T mesh frames, V vertices, F = N // 2 + 1 frequency bins, M STFT frames; analysis in float64, FAI float32.
"""
from __future__ import annotations

from typing import Iterable, Literal, Mapping, Sequence

import numpy as np
import torch

__all__ = ["BANDS", "DEFAULT_BAND", "N_FFT", "HOP", "vertex_displacements", "displacement_stft",
           "mean_amplitude_spectrum", "select_band", "facial_activity_intensity", "normalised_fai",
           "fai_from_dataset", "fai_from_corpus"]

Band = Literal["dc", "first", "dominant"]
BANDS: tuple[str, ...] = ("dc", "first", "dominant")
DEFAULT_BAND: Band = "dc"
N_FFT = 32  # STFT window, mesh frames: 1.07 s at 30 fps, bins 0.94 Hz apart (speech moves the lips at ~2-7 Hz)
HOP = 8     # STFT hop, mesh frames (75 % overlap, where a Hann window's frames sum to a constant)


def _as_tensor(x, what: str) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        t = x.detach()
    else:
        try:
            t = torch.as_tensor(np.asarray(x))
        except (TypeError, ValueError) as e:
            raise ValueError(f"{what}: expected a numeric array, got {type(x).__name__}") from e
    if not (t.is_floating_point() or t.dtype in (torch.int16, torch.int32, torch.int64, torch.uint8)):
        raise ValueError(f"{what}: expected real numbers, got dtype {t.dtype}")
    return t.to(torch.float64)


def _check_finite(t: torch.Tensor, what: str) -> None:
    bad = ~torch.isfinite(t)
    if bool(bad.any()):
        first = tuple(int(i) for i in bad.nonzero()[0])
        raise ValueError(f"{what}: {int(bad.sum())} NaN/infinite value(s), first at index {first}")


def vertex_displacements(vertices, template, what: str = "clip") -> torch.Tensor:
    """d_{t,v} = ||y_{t,v} - h_v||_2 (eq. 3, first part): (T, V) float64, metres if the inputs are.

    ``vertices`` (T, V*3) or (T, V, 3); ``template`` (V*3,) or (V, 3). ``what`` names the clip in error messages.
    """
    tpl = _as_tensor(template, f"{what}: template")
    if tpl.ndim == 1 and tpl.numel() % 3 == 0 and tpl.numel() > 0:
        tpl = tpl.reshape(-1, 3)                                         # (V, 3)
    if tpl.ndim != 2 or tpl.shape[1] != 3 or tpl.shape[0] == 0:
        raise ValueError(f"{what}: template: expected shape (V*3,) or (V, 3), got {tuple(tpl.shape)}")
    n_v = tpl.shape[0]
    y = _as_tensor(vertices, f"{what}: vertices")
    if y.ndim == 2 and y.shape[1] == 3 * n_v:
        y = y.reshape(y.shape[0], n_v, 3)                                # (T, V, 3)
    if y.ndim != 3 or tuple(y.shape[1:]) != (n_v, 3) or y.shape[0] == 0:
        raise ValueError(f"{what}: vertices: expected shape (T, {3 * n_v}) or (T, {n_v}, 3) with T >= 1 "
                         f"(V = {n_v} from the template), got {tuple(y.shape)}")
    _check_finite(tpl, f"{what}: template")
    _check_finite(y, f"{what}: vertices")
    return torch.linalg.vector_norm(y - tpl, dim=-1)                     # (T, V)


def displacement_stft(disp, fps: float, n_fft: int = N_FFT, hop: int = HOP,
                      detrend: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Amplitude spectrogram A_v(k, m) of eq. 3 for every vertex: ``(freqs (F,) Hz, amplitude (F, M, V))``.

    ``torch.stft`` with a periodic Hann window of ``n_fft`` frames, hop ``hop``, ``center=False`` (frame m covers
    frames m*hop .. m*hop + n_fft - 1; a tail shorter than a hop is dropped), one-sided, then the amplitude
    normalisation c_k of the module docstring (bin 0 and the Nyquist bin: 1 / sum(w); the others 2 / sum(w)).

    Clips shorter than ``n_fft`` (T < N) give one STFT frame: the clip is zero-padded to N and c_k uses the
    window sum over the T real samples only, so a constant still reads its value in bin 0; its frequency
    resolution is that of the shorter clip (leakage is wider), so such clips are best kept few.

    ``detrend=True`` subtracts each vertex's mean over the clip first, so that bins 1.. show the oscillation
    alone, without the Hann leakage of the mean into bin 1 (bin 0 then holds only what the window makes of the
    remaining slow drift; use it with ``band="first"`` or ``"dominant"``, not ``"dc"``).
    """
    d = _as_tensor(disp, "displacements")
    if d.ndim != 2 or d.shape[0] == 0 or d.shape[1] == 0:
        raise ValueError(f"displacements: expected shape (T, V) with T, V >= 1, got {tuple(d.shape)}")
    if not (isinstance(n_fft, int) and n_fft >= 2 and isinstance(hop, int) and hop >= 1):
        raise ValueError(f"STFT: need integers n_fft >= 2 and hop >= 1, got n_fft={n_fft!r}, hop={hop!r}")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    _check_finite(d, "displacements")
    if detrend:
        d = d - d.mean(dim=0, keepdim=True)
    n_t = d.shape[0]
    window = torch.hann_window(n_fft, periodic=True, dtype=torch.float64)          # (N,)
    win_sum = float(window.sum())
    if n_t < n_fft:
        win_sum = float(window[:n_t].sum())
        d = torch.cat([d, d.new_zeros(n_fft - n_t, d.shape[1])])                   # (N, V)
    spec = torch.stft(d.T, n_fft=n_fft, hop_length=hop, win_length=n_fft, window=window, center=False,
                      onesided=True, return_complex=True)                          # (V, F, M)
    scale = torch.full((spec.shape[1],), 2.0 / win_sum, dtype=torch.float64)       # c_k, (F,)
    scale[0] = 1.0 / win_sum
    if n_fft % 2 == 0:
        scale[-1] = 1.0 / win_sum                                                  # Nyquist bin
    amplitude = spec.abs().permute(1, 2, 0) * scale[:, None, None]                 # (F, M, V)
    freqs = torch.arange(spec.shape[1], dtype=torch.float64) * (fps / n_fft)       # (F,) Hz
    return freqs, amplitude


def _clip_pairs(clips) -> Iterable[tuple[str, object, object]]:
    for i, clip in enumerate(clips):
        if isinstance(clip, Mapping):
            missing = [k for k in ("vertices", "template") if k not in clip]
            if missing:
                raise ValueError(f"clip {i}: a dict clip needs keys 'vertices' and 'template', missing {missing}")
            name = f"clip {i} ({clip['name']!r})" if "name" in clip else f"clip {i}"
            yield name, clip["vertices"], clip["template"]
        elif isinstance(clip, Sequence) and not isinstance(clip, str) and len(clip) == 2:
            yield f"clip {i}", clip[0], clip[1]
        else:
            raise ValueError(f"clip {i}: expected a (vertices, template) pair or a dict with 'vertices' and "
                             f"'template', got {type(clip).__name__}")


def mean_amplitude_spectrum(clips, fps: float, n_fft: int = N_FFT, hop: int = HOP,
                            detrend: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Amplitude spectrum averaged over each clip's STFT frames, then over clips: ``(freqs (F,), (F, V))``.

    ``clips``: an iterable of ``(vertices, template)`` pairs or dicts with ``"vertices"`` and ``"template"``
    (a :class:`~dualtalker_lite.data.dataset.TalkingFaceDataset` item is such a dict). All clips must share V.
    """
    total, count, n_v, freqs = None, 0, None, None
    for name, vertices, template in _clip_pairs(clips):
        disp = vertex_displacements(vertices, template, what=name)                 # (T, V)
        if n_v is not None and disp.shape[1] != n_v:
            raise ValueError(f"{name}: has {disp.shape[1]} vertices, the clips before it have {n_v}")
        n_v = disp.shape[1]
        freqs, amp = displacement_stft(disp, fps, n_fft, hop, detrend)             # (F, M, V)
        mean = amp.mean(dim=1)                                                     # (F, V)
        total = mean if total is None else total + mean
        count += 1
    if count == 0:
        raise ValueError("facial activity intensity: no clips given")
    return freqs, total / count


def select_band(spectrum: torch.Tensor, band: Band = DEFAULT_BAND) -> torch.Tensor:
    """FAI_v from a mean amplitude spectrum (F, V): bin 0 (``"dc"``), bin 1 (``"first"``) or, per vertex, the
    non-DC bin with the largest amplitude (``"dominant"``). Returns (V,) in the spectrum's dtype."""
    if band not in BANDS:
        raise ValueError(f"band must be one of {BANDS}, got {band!r}")
    if spectrum.ndim != 2 or spectrum.shape[0] < 2:
        raise ValueError(f"spectrum: expected shape (F, V) with F >= 2 bins, got {tuple(spectrum.shape)}")
    if band == "dc":
        return spectrum[0]
    if band == "first":
        return spectrum[1]
    return spectrum[1:].max(dim=0).values


def facial_activity_intensity(clips, fps: float, band: Band = DEFAULT_BAND, n_fft: int = N_FFT,
                              hop: int = HOP, detrend: bool = False) -> torch.Tensor:
    """FAI per vertex (V,) float32, in the displacement's units (metres for corpus clips): eq. 3's amplitude in
    the ``band`` reading of the "fundamental frequency band", averaged over STFT frames and clips.

    ``clips``: ``(vertices, template)`` pairs or dicts with ``"vertices"`` / ``"template"`` (see
    :func:`mean_amplitude_spectrum`); ``fps``: the mesh frame rate; ``detrend``: see :func:`displacement_stft`.
    See the module docstring for the readings.
    """
    if band not in BANDS:
        raise ValueError(f"band must be one of {BANDS}, got {band!r}")
    _, spectrum = mean_amplitude_spectrum(clips, fps, n_fft, hop, detrend)         # (F, V)
    return select_band(spectrum, band).to(torch.float32)


def normalised_fai(fai) -> torch.Tensor:
    """Min-max normalised FAI in [0, 1], (V,) float32: (FAI - min) / (max - min). It initialises CorrTalk's mask
    (eq. 7): the strong branch is multiplied by it, the weak branch by its complement 1 - mask."""
    f = _as_tensor(fai, "FAI")
    if f.ndim != 1 or f.numel() < 2:
        raise ValueError(f"FAI: expected shape (V,) with V >= 2, got {tuple(f.shape)}")
    _check_finite(f, "FAI")
    lo, hi = float(f.min()), float(f.max())
    if not hi > lo:
        raise ValueError(f"FAI: all {f.numel()} values equal ({lo:.6g}); min-max normalisation is undefined "
                         f"(does the data move at all?)")
    return ((f - lo) / (hi - lo)).to(torch.float32)


def _dataset_clips(dataset) -> Iterable[dict]:
    items = getattr(dataset, "items", None)  # TalkingFaceDataset keeps whole clips here (items may be cropped)
    if items is None:
        items = (dataset[i] for i in range(len(dataset)))
    return items


def fai_from_dataset(dataset, fps: float | None = None, band: Band = DEFAULT_BAND, n_fft: int = N_FFT,
                     hop: int = HOP) -> torch.Tensor:
    """FAI (V,) float32 over every clip of a :class:`~dualtalker_lite.data.dataset.TalkingFaceDataset` (whole
    clips, ignoring ``max_frames`` crops). ``fps`` defaults to ``dataset.corpus.fps``. Any sequence of dicts
    with ``"vertices"`` / ``"template"`` also works when ``fps`` is given.

    One line for the CorrTalk mask: ``mask0 = normalised_fai(fai_from_dataset(train_set))``.
    """
    if fps is None:
        corpus = getattr(dataset, "corpus", None)
        if corpus is None or not hasattr(corpus, "fps"):
            raise ValueError("fai_from_dataset: pass fps= (the dataset has no corpus to read the frame rate from)")
        fps = corpus.fps
    return facial_activity_intensity(_dataset_clips(dataset), fps, band, n_fft, hop)


def fai_from_corpus(corpus, split: str = "train", band: Band = DEFAULT_BAND, n_fft: int = N_FFT,
                    hop: int = HOP) -> torch.Tensor:
    """FAI (V,) float32 over one split of a :class:`~dualtalker_lite.data.corpus.Corpus` (or its path), reading
    only vertices and templates (no audio features: faster than building a dataset)."""
    from ..data.corpus import Corpus

    corpus = corpus if isinstance(corpus, Corpus) else Corpus(corpus)
    names = corpus.split(split)
    clips = ({"name": n, "vertices": corpus.vertices(n), "template": corpus.template(corpus.meta(n)["subject"])}
             for n in names)
    return facial_activity_intensity(clips, corpus.fps, band, n_fft, hop)
