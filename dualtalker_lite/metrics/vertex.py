"""Evaluation metrics: lip vertex error (LVE), upper-face dynamics deviation (FDD), emotional vertex error (EVE),
lip-sync metrics (bilabial closures, vowel opening, lip-distance correlation, lip motion ratio).

DualTalker sec. IV-C (LVE; FDD, eq. 12; lip distance, Fig. 5), CorrTalk Fig. 5 (per-vertex mean error map),
EmoFace sec. 4.2 (EVE = the lip error on eye and forehead vertices).

Two readings of each metric: the papers' *text* (LVE: "the maximal L2 error of all lip vertices for each frame,
averaged over all frames"; FDD's dyn(.): "the standard deviation of the element-wise L2 norm along the temporal
axis") and their *tables* (the public MeshTalk/FaceFormer/CodeTalker code, no square root: *squared lengths* in the
meshes' unit; docs/design-notes.md, "Metrics"). p prediction, g ground truth, h template, std over time (ddof=0):

| function          | formula                                             | unit="mm" | unit="m" |
|-------------------|-----------------------------------------------------|-----------|----------|
| `lve_published`   | pooled mean_t max_v ||p - g||^2                     | mm^2      | m^2      |
| `lve_euclidean`   | pooled mean_t max_v ||p - g||        (paper text)   | mm        | m        |
| `fdd_published`   | mean_seq mean_v [std_t ||g-h||^2 - std_t ||p-h||^2] | mm^2      | m^2      |
| `fdd_paper`       | mean_seq mean_v [std_t ||g-h||   - std_t ||p-h||]   | mm        | m        |
| `eve`             | either LVE on eye + forehead vertices               |           |          |

Inputs are vertices in **metres**; ``unit`` only picks the output unit (``unit="m"`` with the ``*_published``
functions compares with the papers' VOCASET tables). LVE/EVE pool all frames of the test set (long clips weigh
more); FDD averages per sequence and is signed: positive = the ground truth moves more (over-smoothing).

Lip sync (:func:`lip_sync_metrics`; the papers' Fig. 5 lip-distance plots made quantitative), from the phoneme
segments of the metadata (``[[phoneme, start_s, end_s]]``, espeak-ng mnemonics) and the lip distance (upper to lower
lip midpoint, the ``lip_midpoints`` region), in mm:

| key                        | meaning                                                                      |
|----------------------------|------------------------------------------------------------------------------|
| `bilabial_closure_2mm/1mm` | fraction of /p b m/ segments whose minimum predicted lip distance is < 2 / 1 mm |
| `bilabial_min_mm`          | mean over /p b m/ segments of that minimum                                   |
| `open_vowel_max_mm`        | mean over open-vowel segments of the maximum lip distance                    |
| `lip_distance_corr`        | mean over clips of the Pearson correlation of the predicted and true curves  |
| `lip_motion_ratio`         | temporal std of the lip vertices, prediction / ground truth (1 = as lively)   |

Read the closure rates with the other columns: the rig's rest gap is about 2 mm (docs/design-notes.md, "Metrics").
Inputs: numpy or torch, any float dtype (computed in float64, returned as Python floats); a list of (T_i, V, 3) or
(T_i, V*3) sequences, or a padded (B, T, V*3) / (B, T, V, 3) array with a (B, T) bool ``mask``. Prediction and
ground truth must have the same length (the published code truncates silently; here a mismatch is an error).
"""
from __future__ import annotations

from typing import Mapping, Sequence, Union

import numpy as np
import torch

__all__ = ["as_sequences", "lve_published", "lve_euclidean", "fdd_published", "fdd_paper", "eve",
           "lip_distance", "mean_vertex_error", "evaluate", "BILABIALS", "OPEN_VOWELS", "segment_frames",
           "segment_extrema", "closure_rate", "curve_correlation", "motion_ratio", "lip_sync_metrics"]

Array = Union[np.ndarray, torch.Tensor]
Seqs = Union[Sequence[Array], Array]
_SCALE = {"mm": 1000.0, "m": 1.0}


def _np(x) -> np.ndarray:
    """numpy float64 copy/view of a numpy array, torch tensor or nested list."""
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().double().numpy()
    return np.asarray(x, dtype=np.float64)


def _scale(unit: str) -> float:
    if unit not in _SCALE:
        raise ValueError(f"unit must be 'mm' or 'm', got {unit!r}")
    return _SCALE[unit]


def _as_vertices(x: Array, name: str) -> np.ndarray:
    """One sequence (T, V, 3) or (T, V*3) -> float64 (T, V, 3)."""
    x = _np(x)
    if x.ndim == 2 and x.shape[1] % 3 == 0:
        return x.reshape(x.shape[0], -1, 3)
    if x.ndim == 3 and x.shape[2] == 3:
        return x
    raise ValueError(f"{name}: expected one sequence of shape (T, V, 3) or (T, V*3), got {tuple(x.shape)}")


def as_sequences(seqs: Seqs, mask: Array | None = None, name: str = "sequences") -> list[np.ndarray]:
    """Normalise metric input to a list of float64 (T_i, V, 3) arrays (list input, or padded batch + mask)."""
    if isinstance(seqs, (list, tuple)):
        if mask is not None:
            raise ValueError(f"{name}: mask is only for padded (B, T, V*3) input, not for a list of sequences")
        out = [_as_vertices(s, f"{name}[{i}]") for i, s in enumerate(seqs)]
    else:
        x = _np(seqs)
        if x.ndim == 3 and x.shape[2] == 3:
            raise ValueError(f"{name}: a {tuple(x.shape)} array is ambiguous; pass one sequence as a list [seq], "
                             "a batch as (B, T, V*3) or (B, T, V, 3)")
        if x.ndim == 3 and x.shape[2] % 3 == 0:
            x = x.reshape(x.shape[0], x.shape[1], -1, 3)               # (B, T, V, 3)
        elif not (x.ndim == 4 and x.shape[3] == 3):
            raise ValueError(f"{name}: expected padded (B, T, V*3) or (B, T, V, 3), got {tuple(x.shape)}")
        if mask is None:
            m = np.ones(x.shape[:2], dtype=bool)
        else:
            m = mask.detach().cpu().numpy() if isinstance(mask, torch.Tensor) else np.asarray(mask)
            if m.shape != x.shape[:2]:
                raise ValueError(f"{name}: mask shape {m.shape} does not match (B, T) = {x.shape[:2]}")
            m = m.astype(bool)
        out = [x[b][m[b]] for b in range(x.shape[0])]                  # (T_b, V, 3) each
    if not out:
        raise ValueError(f"{name}: no sequences")
    if len({s.shape[1] for s in out}) > 1:
        raise ValueError(f"{name}: sequences have different vertex counts {sorted({s.shape[1] for s in out})}")
    return out


def _pair(preds: Seqs, gts: Seqs, mask) -> tuple[list[np.ndarray], list[np.ndarray]]:
    P, G = as_sequences(preds, mask, "preds"), as_sequences(gts, mask, "gts")
    if len(P) != len(G):
        raise ValueError(f"{len(P)} predicted sequences but {len(G)} ground-truth sequences")
    for i, (p, g) in enumerate(zip(P, G)):
        if p.shape != g.shape:
            raise ValueError(f"sequence {i}: preds {p.shape} vs gts {g.shape} (T, V, 3); "
                             "lengths must match (truncate explicitly if intended)")
    return P, G


def _index(idx, n_vertices: int, name: str) -> np.ndarray:
    idx = (idx.detach().cpu().numpy() if isinstance(idx, torch.Tensor) else np.asarray(idx)).reshape(-1)
    if idx.size == 0:
        raise ValueError(f"{name}: empty vertex index set")
    if not np.issubdtype(idx.dtype, np.integer):
        raise ValueError(f"{name}: vertex indices must be integers, got dtype {idx.dtype}")
    if idx.min() < 0 or idx.max() >= n_vertices:
        raise ValueError(f"{name}: vertex indices must lie in [0, {n_vertices}), got [{idx.min()}, {idx.max()}]")
    return idx.astype(np.int64)


def _templates(templates, n_seq: int, n_vertices: int) -> list[np.ndarray]:
    """One shared template (V*3,)/(V, 3), or one per sequence: list, (B, V*3) or (B, V, 3) -> list of (V, 3)."""
    if isinstance(templates, (list, tuple)):
        ts = [_np(t) for t in templates]
    else:
        t = _np(templates)
        if t.shape in ((n_vertices * 3,), (n_vertices, 3)):
            ts = [t] * n_seq                                          # one template shared by all sequences
        elif t.ndim in (2, 3):
            ts = list(t)                                              # (B, V*3) or (B, V, 3)
        else:
            raise ValueError(f"templates: expected (V*3,), (V, 3), (B, V*3) or (B, V, 3) with V={n_vertices}, "
                             f"got {t.shape}")
    if len(ts) != n_seq:
        raise ValueError(f"templates: expected 1 or {n_seq} templates, got {len(ts)}")
    for i, t in enumerate(ts):
        if t.size != n_vertices * 3:
            raise ValueError(f"templates[{i}]: expected {n_vertices * 3} values (V={n_vertices}), got shape {t.shape}")
    return [t.reshape(n_vertices, 3) for t in ts]


# ---------------------------------------------------------------- LVE / EVE: max over a region, mean over frames
def _region_error(preds, gts, idx, mask, unit, squared: bool) -> float:
    s = _scale(unit)
    P, G = _pair(preds, gts, mask)
    idx = _index(idx, P[0].shape[1], "region")
    per_frame = []
    for p, g in zip(P, G):
        sq = (((p[:, idx] - g[:, idx]) * s) ** 2).sum(-1)            # (T, |region|) squared error
        worst = sq.max(axis=1)                                        # (T,) max over vertices
        per_frame.append(worst if squared else np.sqrt(worst))        # sqrt is monotone: max of norms
    return float(np.concatenate(per_frame).mean())                    # pooled over all frames


def lve_published(preds: Seqs, gts: Seqs, lip_idx, *, mask=None, unit: str = "mm") -> float:
    """LVE as in the published tables: pooled mean over frames of max over lip vertices of the SQUARED error.
    Returns unit^2 (mm^2 by default; unit="m" gives m^2, the number printed as "x10^-5 mm" for VOCASET)."""
    return _region_error(preds, gts, lip_idx, mask, unit, squared=True)


def lve_euclidean(preds: Seqs, gts: Seqs, lip_idx, *, mask=None, unit: str = "mm") -> float:
    """LVE as the papers' text reads: pooled mean over frames of max over lip vertices of the L2 error (unit, mm)."""
    return _region_error(preds, gts, lip_idx, mask, unit, squared=False)


def eve(preds: Seqs, gts: Seqs, eye_forehead_idx, *, convention: str = "published", mask=None,
        unit: str = "mm") -> float:
    """EmoFace's emotional vertex error: the LVE computation on eye + forehead vertices.
    convention="published" -> unit^2 (squared, as the tables); "euclidean" -> unit (paper text)."""
    if convention not in ("published", "euclidean"):
        raise ValueError(f"convention must be 'published' or 'euclidean', got {convention!r}")
    return _region_error(preds, gts, eye_forehead_idx, mask, unit, squared=convention == "published")


# ---------------------------------------------------------------- FDD (DualTalker eq. 12)
def _fdd(preds, gts, templates, upper_idx, mask, unit, squared: bool) -> float:
    s = _scale(unit)
    P, G = _pair(preds, gts, mask)
    H = _templates(templates, len(P), P[0].shape[1])
    idx = _index(upper_idx, P[0].shape[1], "upper_idx")
    per_seq = []
    for p, g, h in zip(P, G, H):
        dyn = []
        for x in (g, p):                                              # ground truth first: FDD = dyn(M) - dyn(M^)
            norm2 = (((x[:, idx] - h[idx]) * s) ** 2).sum(-1)         # (T, |S_U|) squared displacement norm
            norm = norm2 if squared else np.sqrt(norm2)
            dyn.append(norm.std(axis=0, ddof=0).mean())               # std over time, mean over S_U
        per_seq.append(dyn[0] - dyn[1])
    return float(np.mean(per_seq))                                    # average over sequences


def fdd_published(preds: Seqs, gts: Seqs, templates, upper_idx, *, mask=None, unit: str = "mm") -> float:
    """FDD as in the published tables: dyn = temporal std (ddof=0) of the SQUARED displacement norm; unit^2 (mm^2).
    Signed, ground truth minus prediction, mean over upper-face vertices, then over sequences."""
    return _fdd(preds, gts, templates, upper_idx, mask, unit, squared=True)


def fdd_paper(preds: Seqs, gts: Seqs, templates, upper_idx, *, mask=None, unit: str = "mm") -> float:
    """FDD as eq. 12's text reads: dyn = temporal std (ddof=0) of the displacement L2 norm; unit (mm). Signed."""
    return _fdd(preds, gts, templates, upper_idx, mask, unit, squared=False)


# ---------------------------------------------------------------- plots: lip distance, per-vertex error map
def lip_distance(vertices: Array, upper_mid, lower_mid, *, unit: str = "mm") -> np.ndarray:
    """DualTalker Fig. 5: Euclidean distance between the upper- and lower-lip midpoints per frame -> (T,).
    ``upper_mid``/``lower_mid``: a vertex index, or several whose mean position is the midpoint."""
    v = _as_vertices(vertices, "vertices")                            # (T, V, 3)
    up = v[:, _index(upper_mid, v.shape[1], "upper_mid")].mean(1)     # (T, 3)
    lo = v[:, _index(lower_mid, v.shape[1], "lower_mid")].mean(1)     # (T, 3)
    return np.linalg.norm(up - lo, axis=-1) * _scale(unit)


def mean_vertex_error(preds: Seqs, gts: Seqs, *, mask=None, unit: str = "mm") -> np.ndarray:
    """CorrTalk Fig. 5: per-vertex Euclidean error averaged over all (pooled) frames -> (V,), in ``unit``."""
    P, G = _pair(preds, gts, mask)
    err = np.concatenate([np.linalg.norm(p - g, axis=-1) for p, g in zip(P, G)])  # (sum T_i, V)
    return err.mean(axis=0) * _scale(unit)


# ---------------------------------------------------------------- everything for a test set
def _region_name(regions: Mapping, name: str) -> str:
    if name not in regions:
        raise KeyError(f"region {name!r} not found; available: {sorted(regions)}")
    return name


def _region(regions: Mapping[str, Sequence[int]], names) -> np.ndarray:
    names = [_region_name(regions, n) for n in ([names] if isinstance(names, str) else names)]
    return np.unique(np.concatenate([np.asarray(regions[n], dtype=np.int64).reshape(-1) for n in names]))


def evaluate(preds: Seqs, gts: Seqs, templates, regions: Mapping[str, Sequence[int]], *, mask=None,
             unit: str = "mm", lip: str | None = "lips", upper: str | None = "upper_face",
             eye_forehead: str | Sequence[str] | None = "auto",
             lip_mid: tuple | str | None = None) -> dict:
    """All metrics for a test set. ``lip``/``upper``/``eye_forehead`` name entries of ``regions`` (None skips that
    metric; ``eye_forehead="auto"`` takes the corpus's ``eyes_forehead`` region (eyes, brows, forehead) when there
    is one, else ``("eyes", "forehead")``); ``lip_mid=(upper_mid, lower_mid)``, or the name of a region holding those two indices, adds
    per-sequence lip-distance curves (pred and gt). ``out["units"]`` gives the unit of every entry."""
    P, G = _pair(preds, gts, mask)                                     # convert once; lists pass through below
    sq = f"{unit}^2"
    out: dict = {"n_sequences": len(P), "n_frames": int(sum(len(p) for p in P)), "unit": unit,
                 "vertex_error_map": mean_vertex_error(P, G, unit=unit)}
    units = {"vertex_error_map": unit}
    if lip is not None:
        idx = _region(regions, lip)
        out["lve_published"] = lve_published(P, G, idx, unit=unit)
        out["lve_euclidean"] = lve_euclidean(P, G, idx, unit=unit)
        units.update(lve_published=sq, lve_euclidean=unit)
    if upper is not None:
        idx = _region(regions, upper)
        out["fdd_published"] = fdd_published(P, G, templates, idx, unit=unit)
        out["fdd_paper"] = fdd_paper(P, G, templates, idx, unit=unit)
        units.update(fdd_published=sq, fdd_paper=unit)
    if eye_forehead == "auto":
        eye_forehead = "eyes_forehead" if "eyes_forehead" in regions else ("eyes", "forehead")
    if eye_forehead is not None:
        idx = _region(regions, eye_forehead)
        out["eve_published"] = eve(P, G, idx, convention="published", unit=unit)
        out["eve_euclidean"] = eve(P, G, idx, convention="euclidean", unit=unit)
        units.update(eve_published=sq, eve_euclidean=unit)
    if lip_mid is not None:
        if isinstance(lip_mid, str):                                  # a region listing (upper_mid, lower_mid)
            lip_mid = tuple(np.asarray(regions[_region_name(regions, lip_mid)]).reshape(-1))
        if len(lip_mid) != 2:
            raise ValueError(f"lip_mid: expected (upper_mid, lower_mid), got {len(lip_mid)} entries")
        out["lip_distance_pred"] = [lip_distance(p, *lip_mid, unit=unit) for p in P]
        out["lip_distance_gt"] = [lip_distance(g, *lip_mid, unit=unit) for g in G]
        units.update(lip_distance_pred=unit, lip_distance_gt=unit)
    out["units"] = units
    return out


# ---------------------------------------------------------------- lip sync: closures at /p b m/, opening on vowels
# espeak-ng en-us mnemonics as stored in the corpus metadata (stress marks stripped), i.e. the phonemes the rig maps
# to its "PP" viseme (lips pressed) and to its "aa" viseme (jaw_open 0.62, the widest); tests check they agree with
# ``face.visemes.PHONEME_TO_VISEME``. Seen in the shipped sample: p b m (bilabials); a a# aa A: 0 V A@ aI aU (open).
BILABIALS = ("p", "b", "m", "m-")
OPEN_VOWELS = ("a", "a#", "aa", "A:", "A", "0", "V", "A@", "aI", "aU", "aI3", "aU3", "aI@", "aU@")
CLOSURE_THRESHOLDS_MM = (2.0, 1.0)
_STRESS_MARKS = "'\",%=!"


def _symbol(s) -> str:
    return "".join(ch for ch in str(s) if ch not in _STRESS_MARKS).strip()


def segment_frames(start_s: float, end_s: float, n_frames: int, fps: float = 30.0, *,
                   tolerance_frames: int = 0) -> np.ndarray:
    """Frame indices of a phoneme segment [start_s, end_s): the frames f whose time f/fps lies in it.

    Frame f is at time f/fps (FaceFormer's convention, as the corpus). A segment that contains no frame time
    (shorter than a frame, or between two frames) gets the single frame nearest its midpoint.
    ``tolerance_frames`` widens the segment by that many frames on each side (0 = exact timing, the default).
    A segment that starts more than a frame after the last frame is an error (segments of another clip?)."""
    start_s, end_s = float(start_s), float(end_s)
    if not (np.isfinite(start_s) and np.isfinite(end_s)) or end_s < start_s:
        raise ValueError(f"phoneme segment [{start_s}, {end_s}) s is not a finite interval with start <= end")
    if n_frames < 1:
        raise ValueError("segment_frames: the track has no frames")
    if start_s * fps > n_frames:                                      # more than a frame after frame n_frames-1
        raise ValueError(f"phoneme segment [{start_s:.3f}, {end_s:.3f}) s starts after the end of a "
                         f"{n_frames}-frame track ({n_frames / fps:.3f} s at {fps:g} fps): segments of another clip?")
    first = int(np.ceil(start_s * fps - 1e-9))                        # first f with f/fps >= start
    last = int(np.ceil(end_s * fps - 1e-9)) - 1                       # last f with f/fps < end
    if last < first:                                                  # no frame time inside: nearest to the middle
        first = last = int(np.floor(0.5 * (start_s + end_s) * fps + 0.5))
    first, last = first - tolerance_frames, last + tolerance_frames
    return np.arange(max(first, 0), min(last, n_frames - 1) + 1)


def _segments_of(segments, symbols) -> list[tuple[float, float]]:
    want = {_symbol(s) for s in symbols}
    out = []
    for k, seg in enumerate(segments):
        if len(seg) != 3:
            raise ValueError(f"phoneme segment {k}: expected [phoneme, start_s, end_s], got {seg!r}")
        if _symbol(seg[0]) in want:
            out.append((float(seg[1]), float(seg[2])))
    return out


def segment_extrema(curve, segments, symbols, *, reduce: str = "min", fps: float = 30.0,
                    tolerance_frames: int = 0) -> np.ndarray:
    """Per matching segment, the min (or max) of a per-frame ``curve`` (T,) over its frames -> (n_segments,).

    ``segments``: one clip's [[phoneme, start_s, end_s], ...] (corpus ``meta(clip)["phonemes"]``); ``symbols``:
    the phonemes to keep (stress marks ignored), e.g. :data:`BILABIALS`. Frames as in :func:`segment_frames`."""
    if reduce not in ("min", "max"):
        raise ValueError(f"reduce must be 'min' or 'max', got {reduce!r}")
    c = _np(curve).reshape(-1)
    fn = np.min if reduce == "min" else np.max
    return np.array([fn(c[segment_frames(a, b, len(c), fps, tolerance_frames=tolerance_frames)])
                     for a, b in _segments_of(segments, symbols)], dtype=np.float64)


def closure_rate(minima_mm, threshold_mm: float) -> float:
    """Fraction of bilabial segments whose minimum lip distance is strictly under ``threshold_mm`` (nan if none)."""
    m = np.asarray(minima_mm, dtype=np.float64).reshape(-1)
    return float((m < threshold_mm).mean()) if m.size else float("nan")


def curve_correlation(pred_curves, gt_curves) -> float:
    """Mean over clips of the Pearson correlation of predicted and true lip-distance curves.

    Per clip (not pooled), so speakers' different rest gaps do not inflate it. A clip whose predicted curve is
    constant (std < 1e-9) counts as correlation 0: it carries no timing (a collapsed model). Clips whose true
    curve is constant are skipped (nan if all are)."""
    rs = []
    for i, (p, g) in enumerate(zip(pred_curves, gt_curves)):
        p, g = _np(p).reshape(-1), _np(g).reshape(-1)
        if p.shape != g.shape:
            raise ValueError(f"curve {i}: predicted length {p.size} vs true length {g.size}")
        if p.size < 2 or g.std() < 1e-9:
            continue
        rs.append(0.0 if p.std() < 1e-9 else float(np.corrcoef(p, g)[0, 1]))
    return float(np.mean(rs)) if rs else float("nan")


def motion_ratio(preds: Seqs, gts: Seqs, idx, *, mask=None) -> float:
    r"""How much the prediction moves compared with the ground truth on the vertices ``idx``.

    ratio_i = \sum_{v} σ_t(p_{tv}) / \sum_{v} σ_t(g_{tv}),   σ_t(x_{tv}) = \sqrt{\sum_{xyz} Var_t(x_{tv})}  (ddof 0)

    σ_t is the temporal standard deviation of vertex v's 3-D position (the template cancels). Returns the mean
    of ratio_i over sequences whose ground truth moves. 1 = as much motion as the ground truth; < 1 =
    over-smoothed (0 for the static template); > 1 = more motion than the ground truth. Unitless."""
    P, G = _pair(preds, gts, mask)
    idx = _index(idx, P[0].shape[1], "motion_ratio idx")
    ratios = []
    for p, g in zip(P, G):
        sg = np.sqrt(g[:, idx].var(axis=0).sum(-1)).sum()
        if sg > 0:
            ratios.append(np.sqrt(p[:, idx].var(axis=0).sum(-1)).sum() / sg)
    return float(np.mean(ratios)) if ratios else float("nan")


def _per_sequence_segments(segments, n_seq: int) -> list:
    if isinstance(segments, (list, tuple)) and segments and isinstance(segments[0], (list, tuple)) \
            and segments[0] and isinstance(segments[0][0], str):
        if n_seq != 1:
            raise ValueError(f"segments: got one clip's phoneme list for {n_seq} sequences; pass one list of "
                             "[phoneme, start_s, end_s] per sequence")
        return [segments]                                             # one clip's segments, one sequence
    if not isinstance(segments, (list, tuple)) or len(segments) != n_seq:
        raise ValueError(f"segments: expected one list of [phoneme, start_s, end_s] per sequence ({n_seq}), "
                         f"got {len(segments) if isinstance(segments, (list, tuple)) else type(segments).__name__}")
    return list(segments)


def lip_sync_metrics(preds: Seqs, gts: Seqs, segments, regions: Mapping | None = None, *, mask=None,
                     lip_mid=None, lips=None, fps: float = 30.0, bilabials=BILABIALS, open_vowels=OPEN_VOWELS,
                     thresholds_mm=CLOSURE_THRESHOLDS_MM, tolerance_frames: int = 0) -> dict:
    """Lip-sync metrics of a test set from the phoneme timing (DualTalker Fig. 5 made quantitative).

    preds, gts: vertices in metres, as the other metrics (list of (T_i, V*3)/(T_i, V, 3), or padded + ``mask``).
    segments:   per sequence, the clip's phoneme segments [[phoneme, start_s, end_s], ...]
                (``corpus.meta(name)["phonemes"]``); a single clip's list is accepted for a single sequence.
    regions:    the corpus regions; ``regions["lip_midpoints"]`` = (upper, lower) lip-midpoint vertices and
                ``regions["lips"]`` the lip vertices. ``lip_mid=(upper, lower)`` / ``lips=idx`` override them.

    Lip distance = Euclidean distance between the upper- and lower-lip midpoints per frame, mm
    (:func:`lip_distance`). A segment's frames: :func:`segment_frames` (frames at f/fps inside [start, end);
    the nearest frame for a segment shorter than a frame). Returned dict (plain floats; mm unless noted):

    ========================  ===============================================================================
    ``bilabial_closure_2mm``  fraction of /p b m/ segments whose minimum predicted lip distance is < 2 mm
    ``bilabial_closure_1mm``  the same under 1 mm (one key per entry of ``thresholds_mm``, ``{t:g}`` in the name)
    ``bilabial_min_mm``       mean over /p b m/ segments of the minimum predicted lip distance
    ``open_vowel_max_mm``     mean over open-vowel segments of the maximum predicted lip distance
    ``lip_distance_corr``     mean over clips of the Pearson correlation of the predicted and true curves
    ``lip_motion_ratio``      :func:`motion_ratio` on the lip vertices (1 = as lively as the ground truth)
    ``*_gt``                  the first four computed on the ground truth (what a perfect model scores)
    ``n_bilabials``, ``n_open_vowels``  segment counts (ints)
    ========================  ===============================================================================

    Empty segment sets give nan for their entries. ``tolerance_frames`` widens every segment (default 0)."""
    P, G = _pair(preds, gts, mask)
    regions = regions or {}
    if lip_mid is None:
        if "lip_midpoints" not in regions:
            raise KeyError("lip_sync_metrics: pass regions with 'lip_midpoints' or lip_mid=(upper, lower)")
        lip_mid = regions["lip_midpoints"]
    lip_mid = tuple(np.asarray(lip_mid).reshape(-1)) if not isinstance(lip_mid, tuple) else lip_mid
    if len(lip_mid) != 2:
        raise ValueError(f"lip_mid: expected (upper_mid, lower_mid), got {len(lip_mid)} entries")
    if lips is None:
        if "lips" not in regions:
            raise KeyError("lip_sync_metrics: pass regions with 'lips' or lips=vertex indices")
        lips = regions["lips"]
    segs = _per_sequence_segments(segments, len(P))
    out: dict = {}
    curves = {"": [lip_distance(p, *lip_mid) for p in P], "_gt": [lip_distance(g, *lip_mid) for g in G]}
    for suffix, cs in curves.items():
        mins = np.concatenate([segment_extrema(c, s, bilabials, reduce="min", fps=fps,
                                               tolerance_frames=tolerance_frames) for c, s in zip(cs, segs)])
        maxs = np.concatenate([segment_extrema(c, s, open_vowels, reduce="max", fps=fps,
                                               tolerance_frames=tolerance_frames) for c, s in zip(cs, segs)])
        for t in thresholds_mm:
            out[f"bilabial_closure_{t:g}mm{suffix}"] = closure_rate(mins, t)
        out[f"bilabial_min_mm{suffix}"] = float(mins.mean()) if mins.size else float("nan")
        out[f"open_vowel_max_mm{suffix}"] = float(maxs.mean()) if maxs.size else float("nan")
    out["lip_distance_corr"] = curve_correlation(curves[""], curves["_gt"])
    out["lip_motion_ratio"] = motion_ratio(P, G, lips)
    out["n_bilabials"], out["n_open_vowels"] = int(mins.size), int(maxs.size)
    return out
