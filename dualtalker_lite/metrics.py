"""Evaluation metrics: lip vertex error (LVE), upper-face dynamics deviation (FDD), emotional vertex error (EVE).

DualTalker sec. IV-C (LVE; FDD, eq. 12; lip distance, Fig. 5), CorrTalk Fig. 5 (per-vertex mean error map),
EmoFace sec. 4.2 (EVE = the lip error on eye and forehead vertices).

Two readings of each metric
---------------------------
The papers' *text* says LVE is "the maximal L2 error of all lip vertices for each frame, averaged over all frames" and
that dyn(.) in eq. 12 is "the standard deviation of the element-wise L2 norm along the temporal axis". The numbers in
their *tables* come from the public evaluation code of MeshTalk/FaceFormer/CodeTalker, which never takes a square root:

    LVE_pub = mean_{all test frames t, pooled} max_{v in lips} ||p_tv - g_tv||^2                      (squared length)
    FDD_pub = mean_seq [ mean_{v in S_U} std_t ||g_tv - h_v||^2  -  mean_{v in S_U} std_t ||p_tv - h_v||^2 ]

with std over time (ddof=0), h the template, g the ground truth, p the prediction. Both are *squared lengths*.
VOCASET stores metres, so EmoFace's VOCASET LVE "2.8669 x 10^-5 mm" is really 2.8669e-5 m^2 = 28.669 mm^2: its root,
5.35 mm, is the RMS over frames of the worst lip-vertex error (read as a plain length it would be an implausible
0.03 mm). The "10^-4 mm" / "10^-5 mm" column labels of DualTalker and CorrTalk name a scale factor, not a unit; the
number is in the square of the unit the dataset's meshes are stored in.

| function          | formula                                             | unit="mm" | unit="m" |
|-------------------|-----------------------------------------------------|-----------|----------|
| `lve_published`   | pooled mean_t max_v ||p - g||^2                     | mm^2      | m^2      |
| `lve_euclidean`   | pooled mean_t max_v ||p - g||        (paper text)   | mm        | m        |
| `fdd_published`   | mean_seq mean_v [std_t ||g-h||^2 - std_t ||p-h||^2] | mm^2      | m^2      |
| `fdd_paper`       | mean_seq mean_v [std_t ||g-h||   - std_t ||p-h||]   | mm        | m        |
| `eve`             | either LVE on eye + forehead vertices               |           |          |

Inputs are vertices in **metres** (docs/design.md); ``unit`` only picks the output length unit (x1000 for "mm").
Use ``unit="m"`` with the ``*_published`` functions to compare with the papers' VOCASET tables.
Pooling: LVE/EVE average over all frames of the test set (long clips weigh more); FDD averages per sequence.
FDD is signed: positive = ground truth moves more than the prediction (over-smoothing).

Accepted inputs (numpy or torch, any float dtype; computed in float64 numpy, returned as Python floats):
a list of (T_i, V, 3) or (T_i, V*3) sequences, or a padded (B, T, V*3) / (B, T, V, 3) array with a (B, T) bool ``mask``.
Predictions and ground truth must have the same length: the published code silently truncates to the shorter one;
here a mismatch is an error (truncate explicitly if that is what you want).
"""
from __future__ import annotations

from typing import Mapping, Sequence, Union

import numpy as np
import torch

__all__ = ["as_sequences", "lve_published", "lve_euclidean", "fdd_published", "fdd_paper", "eve",
           "lip_distance", "mean_vertex_error", "evaluate"]

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
