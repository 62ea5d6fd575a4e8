"""Per-vertex heat maps side by side, and spectrograms of vertex displacements (CorrTalk Figs. 1, 5 and 9).

- ``plot_vertex_maps``: any number of per-vertex scalars (V,) painted on one mesh, one column per map and one row
  per view (front, side), with one shared colour scale (``shared_scale=True``: maps comparable by colour, as the
  error maps of CorrTalk's Fig. 9) or one scale per map (each map's own range, as the FAI map of Fig. 1(b)).
- ``plot_vertex_spectrograms``: for a few named vertices of one clip, the displacement from the template over time
  next to its amplitude spectrogram (CorrTalk Fig. 1(a, c): a mouth vertex against a forehead vertex), computed with
  :func:`dualtalker_lite.blocks.fai.displacement_stft`, on one colour scale.
- ``plot_branch_error_maps``: the Fig. 9 analogue, per-vertex errors of the strong branch, the weak branch and
  their sum on one colour scale; ``branch_mean_errors`` computes those errors from the branch outputs.

Fig. 9 is read as follows (the symbols were lost in extraction: "we visualize the synthetic sequences [strong],
[weak] and [output] with the ground truth mean error"): each branch's sequence is the template plus the part of
the motion that branch contributes (``mask * M^s`` and ``(1 - mask) * M^w``, CorrTalk's ``motion_strong`` and
``motion_weak``, which sum to the output), and its error is the per-vertex Euclidean distance to the ground truth,
averaged over all frames (``metrics.mean_vertex_error``). This matches the text's observation that the weak branch
has large errors at the mouth (it carries almost none of the mouth's motion) and small ones elsewhere. The other
reading, each branch's raw output before the mask, can be passed in the same way.

Figures are returned detached from pyplot (see ``viz.plots``): make the call a cell's last expression.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

from .plots import _SCALE, _axis_labels, _detach, add_colorbar
from ..export.render import draw_mesh, mesh_extent

__all__ = ["plot_vertex_maps", "plot_vertex_spectrograms", "plot_branch_error_maps", "branch_mean_errors"]


def _bar_label(label: str, units: str) -> str:
    return f"{label} ({units})" if units else label


def _named_maps(maps, titles: Sequence[str] | None, n_vertices: int) -> list[tuple[str, np.ndarray]]:
    if isinstance(maps, Mapping):
        items = [(str(k), v) for k, v in maps.items()]
    else:
        arrays = [maps] if np.ndim(maps) == 1 else list(maps)
        names = list(titles) if titles is not None else [f"map {i}" for i in range(len(arrays))]
        if len(names) != len(arrays):
            raise ValueError(f"titles: {len(names)} given for {len(arrays)} maps")
        items = list(zip(names, arrays))
    if not items:
        raise ValueError("plot_vertex_maps: no maps given")
    out = []
    for name, values in items:
        values = np.asarray(values, dtype=np.float64)
        if values.shape != (n_vertices,):
            raise ValueError(f"map {name!r}: expected shape ({n_vertices},) (one value per mesh vertex), "
                             f"got {values.shape}")
        if not np.isfinite(values).all():
            raise ValueError(f"map {name!r}: {int((~np.isfinite(values)).sum())} NaN/infinite value(s)")
        out.append((name, values))
    return out


def plot_vertex_maps(vertices: np.ndarray, faces: np.ndarray, maps, titles: Sequence[str] | None = None,
                     shared_scale: bool = True, views: str | Sequence[str] = ("front", "side"),
                     cmap: str = "viridis", vmin: float | None = None, vmax: float | None = None,
                     label: str = "value", units: str = "mm", suptitle: str = "Per-vertex maps",
                     panel_size: float = 2.6) -> Figure:
    """Per-vertex scalars painted on one (V, 3) mesh (metres): one column per map, one row per view.

    ``maps``: a dict ``{title: (V,)}``, a list of (V,) arrays with ``titles``, or one (V,) array. ``units`` are
    those of the values (colour bar "label (units)", just "label" if ``units`` is empty); the mesh axes are in
    mm. ``shared_scale=True``: one colour range (``vmin``/``vmax``, default the min/max over all maps) and one
    colour bar; ``False``: one per map.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices: expected shape (V, 3), got {vertices.shape}")
    named = _named_maps(maps, titles, len(vertices))
    views = [views] if isinstance(views, str) else list(views)
    every = np.concatenate([v for _, v in named])
    shared = Normalize(every.min() if vmin is None else vmin, every.max() if vmax is None else vmax)
    extra = 1.0 if shared_scale else 0.9 * len(named)
    fig, axes = plt.subplots(len(views), len(named), squeeze=False, layout="constrained",
                             figsize=(panel_size * len(named) + extra, panel_size * len(views) + 0.6))
    extent = mesh_extent(vertices)
    for j, (name, values) in enumerate(named):
        norm = shared if shared_scale else Normalize(values.min() if vmin is None else vmin,
                                                     values.max() if vmax is None else vmax)
        for i, view in enumerate(views):
            ax = axes[i, j]
            draw_mesh(ax, vertices, faces, view, colors=values, cmap=cmap, vmin=norm.vmin, vmax=norm.vmax,
                      extent=extent, scale=_SCALE["mm"])
            xlabel, ylabel = _axis_labels(view, "mm")
            ax.set_xlabel(xlabel if i == len(views) - 1 else "", fontsize=8)
            ax.set_ylabel(ylabel if j == 0 else "", fontsize=8)
            ax.set_title(f"{name} ({view})", fontsize=9)
            ax.tick_params(labelsize=7)
        if not shared_scale:
            add_colorbar(fig, axes[:, j].tolist(), norm, cmap, _bar_label(label, units))
    if shared_scale:
        add_colorbar(fig, axes.ravel().tolist(), shared, cmap, _bar_label(label, units))
    fig.suptitle(suptitle)
    return _detach(fig)


def plot_branch_error_maps(vertices: np.ndarray, faces: np.ndarray, strong: np.ndarray, weak: np.ndarray,
                           total: np.ndarray, units: str = "mm", cmap: str = "magma",
                           suptitle: str = "Mean per-vertex error of each branch (CorrTalk Fig. 9 analogue)",
                           views: str | Sequence[str] = ("front", "side")) -> Figure:
    """Fig. 9 analogue: mean per-vertex errors (V,) of the strong branch, the weak branch and their sum (the model's
    output), each against the ground truth, on one shared colour scale (values already in ``units``)."""
    return plot_vertex_maps(vertices, faces, {"strong branch": strong, "weak branch": weak, "sum (output)": total},
                            shared_scale=True, views=views, cmap=cmap, vmin=0.0, label="mean error",
                            units=units, suptitle=suptitle)


def branch_mean_errors(strong, weak, total, gt, *, mask=None, unit: str = "mm") -> dict[str, np.ndarray]:
    """Per-vertex mean Euclidean errors (V,) in ``unit`` of the strong part, the weak part and their sum against the
    ground truth: ``{"strong branch", "weak branch", "sum (output)"}``, for :func:`plot_branch_error_maps`.

    All four are motions (offsets from the template; the template cancels in the distance) in any layout
    ``metrics.mean_vertex_error`` takes: a list of (T, V*3) / (T, V, 3) sequences, or padded (B, T, V*3) with
    ``mask`` (B, T). With CorrTalk: ``out["motion_strong"], out["motion_weak"], out["motion"]`` and
    ``batch["vertices"] - batch["template"][:, None]``.
    """
    from ..metrics import mean_vertex_error

    return {label: mean_vertex_error(pred, gt, mask=mask, unit=unit)
            for label, pred in (("strong branch", strong), ("weak branch", weak), ("sum (output)", total))}


def plot_vertex_spectrograms(disp: np.ndarray, fps: float, vertices: Mapping[str, int], n_fft: int = 32,
                             hop: int = 2, units: str = "mm", max_hz: float | None = None,
                             shared_scale: bool = True,
                             suptitle: str = "Vertex displacement and its STFT amplitude",
                             figsize=(9.0, None)) -> Figure:
    """CorrTalk Fig. 1(a, c): per named vertex, its displacement d_{t,v} (left) and amplitude spectrogram (right).

    ``disp`` (T, V) in metres (:func:`dualtalker_lite.blocks.fai.vertex_displacements`); ``vertices`` ``{name: index}``;
    displacement and amplitude are shown in ``units``. ``shared_scale=True``: all spectrograms on one colour scale
    (honest comparison; a weak vertex may look black); ``False``: one scale per vertex (its pattern is visible).
    A small ``hop`` gives a smooth picture; the FAI itself uses the package's default STFT.
    """
    import torch

    from ..blocks.fai import displacement_stft

    disp = np.asarray(disp, dtype=np.float64)
    if disp.ndim != 2:
        raise ValueError(f"displacements: expected shape (T, V), got {disp.shape}")
    if not vertices:
        raise ValueError("plot_vertex_spectrograms: no vertices given")
    bad = {k: i for k, i in vertices.items() if not (0 <= int(i) < disp.shape[1])}
    if bad:
        raise ValueError(f"vertex index out of range 0..{disp.shape[1] - 1}: {bad}")
    scale = _SCALE[units]
    cols = [int(i) for i in vertices.values()]
    freqs, amp = displacement_stft(torch.from_numpy(disp[:, cols]), fps, n_fft, hop)   # (F, M, K)
    freqs, amp = freqs.numpy(), amp.numpy() * scale
    starts = (np.arange(amp.shape[1]) * hop + n_fft / 2) / fps              # STFT frame centres, seconds
    top = freqs[-1] if max_hz is None else max_hz
    def norm_of(a: np.ndarray) -> Normalize:
        return Normalize(0.0, float(a.max()) if a.max() > 0 else 1.0)

    norm = norm_of(amp)
    height = figsize[1] if figsize[1] is not None else 2.2 * len(cols) + 0.6
    fig, axes = plt.subplots(len(cols), 2, squeeze=False, figsize=(figsize[0], height), layout="constrained",
                             gridspec_kw={"width_ratios": [1.0, 1.3]})
    times = np.arange(disp.shape[0]) / fps
    for r, (name, v) in enumerate(vertices.items()):
        ax = axes[r, 0]
        ax.plot(times, disp[:, int(v)] * scale, lw=1.0)
        ax.set(xlim=(times[0], times[-1]), ylabel=f"displacement ({units})", title=f"{name} (vertex {int(v)})")
        ax.set_ylim(bottom=0.0)
        ax.grid(alpha=0.3)
        ax = axes[r, 1]
        own = norm if shared_scale else norm_of(amp[:, :, r])
        ax.pcolormesh(starts, freqs, amp[:, :, r], shading="nearest", cmap="magma", norm=own)
        ax.set(ylim=(-0.5 * freqs[1], top), ylabel="frequency (Hz)", title=f"{name}: STFT amplitude")
        if not shared_scale:
            add_colorbar(fig, ax, own, "magma", f"amplitude ({units})")
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    if shared_scale:
        add_colorbar(fig, axes[:, 1].tolist(), norm, "magma", f"amplitude ({units})")
    fig.suptitle(suptitle)
    return _detach(fig)
