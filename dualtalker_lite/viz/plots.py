"""Static figures: mesh frames, per-vertex maps, lip distance and waveform with phoneme segments.

Every function returns a ``matplotlib.figure.Figure`` with a title, axis labels with units and a fixed size.
Figures are detached from pyplot before they are returned, so a notebook shows each one exactly once:
make the call the cell's last expression (or ``display(fig)``); scripts use ``fig.savefig(...)``.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.transforms import blended_transform_factory

from ..export.render import draw_mesh, mesh_extent

__all__ = [
    "SILENCE",
    "plot_frames",
    "plot_vertex_map",
    "plot_lip_distance",
    "plot_waveform_and_phonemes",
    "shade_phonemes",
    "add_colorbar",
]

SILENCE = frozenset({"", "sil", "sp", "spn", "pau", "_", "#", "<sil>"})  # labels left unshaded and unlabelled
Segments = Sequence[Sequence]  # [[label, start_s, end_s], ...] as in metadata.json "phonemes" / "visemes"


def _detach(fig: Figure) -> Figure:
    plt.close(fig)  # the caller displays it; pyplot must not show it a second time
    return fig


def _axis_labels(view: str | None, units: str) -> tuple[str, str]:
    if view == "front":
        return f"x ({units})", f"y ({units})"
    return f"image horizontal ({units})", f"image vertical ({units})"


_SCALE = {"m": 1.0, "cm": 1e2, "mm": 1e3}


def add_colorbar(fig: Figure, axes, norm: Normalize, cmap: str, label: str):
    """A colour bar for values drawn with ``norm`` and ``cmap`` next to ``axes`` (one Axes or a list)."""
    return fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=axes, shrink=0.85, label=label)


def plot_frames(frames: np.ndarray, faces: np.ndarray, titles: Sequence[str] | None = None,
                view: str | None = "front", colors: np.ndarray | None = None, cmap: str = "viridis",
                vmin: float | None = None, vmax: float | None = None,
                color_label: str = "value", color_units: str = "mm",
                azimuth: float | None = None, elevation: float | None = None, ncols: int | None = None,
                panel_size: float = 2.4, units: str = "mm", suptitle: str = "Mesh frames") -> Figure:
    """A grid of K mesh frames (K, V, 3) with one camera and framing; ``colors`` (V,) or (K, V) adds a colour bar."""
    frames = np.asarray(frames, dtype=np.float64)
    if frames.ndim == 2:
        frames = frames[None]
    k = len(frames)
    ncols = min(k, 4) if ncols is None else ncols
    nrows = -(-k // ncols)
    values = None if colors is None else np.broadcast_to(np.asarray(colors, dtype=np.float64), frames.shape[:2])
    norm = None
    if values is not None:
        norm = Normalize(np.nanmin(values) if vmin is None else vmin, np.nanmax(values) if vmax is None else vmax)
    width = panel_size * ncols + (1.0 if values is not None else 0.0)
    fig, axes = plt.subplots(nrows, ncols, figsize=(width, panel_size * nrows + 0.6), squeeze=False,
                             layout="constrained")
    extent, scale = mesh_extent(frames), _SCALE[units]
    xlabel, ylabel = _axis_labels(view if azimuth is None and elevation is None else None, units)
    for i, ax in enumerate(axes.flat):
        if i >= k:
            ax.set_axis_off()
            continue
        draw_mesh(ax, frames[i], faces, view, azimuth, elevation,
                  colors=None if values is None else values[i], cmap=cmap,
                  vmin=None if norm is None else norm.vmin, vmax=None if norm is None else norm.vmax,
                  extent=extent, scale=scale)
        ax.set_title(titles[i] if titles is not None else f"frame {i}", fontsize=9)
        ax.tick_params(labelsize=7)
        ax.set_xlabel(xlabel if i + ncols >= k else "", fontsize=8)  # bottom panel of each column
        ax.set_ylabel(ylabel if i % ncols == 0 else "", fontsize=8)
    if norm is not None:
        add_colorbar(fig, axes.ravel().tolist(), norm, cmap, f"{color_label} ({color_units})")
    fig.suptitle(suptitle)
    return _detach(fig)


def plot_vertex_map(vertices: np.ndarray, faces: np.ndarray, values: np.ndarray, title: str = "Per-vertex map",
                    units: str = "mm", cmap: str = "viridis", vmin: float | None = None,
                    vmax: float | None = None, label: str = "value",
                    views: str | Sequence[str] = ("front", "side"), panel_size: float = 3.0) -> Figure:
    """Per-vertex scalar ``values`` (V,) painted on one (V, 3) mesh, e.g. an error map (CorrTalk Fig. 5).

    ``units`` are those of ``values`` (colour bar label: "label (units)"); the mesh axes are in mm.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if values.shape != (len(vertices),):
        raise ValueError(f"values: expected shape ({len(vertices)},), got {values.shape}")
    views = [views] if isinstance(views, str) else list(views)
    norm = Normalize(np.nanmin(values) if vmin is None else vmin, np.nanmax(values) if vmax is None else vmax)
    fig, axes = plt.subplots(1, len(views), figsize=(panel_size * len(views) + 1.2, panel_size + 0.5),
                             squeeze=False, layout="constrained")
    extent = mesh_extent(vertices)
    for ax, view in zip(axes[0], views):
        draw_mesh(ax, vertices, faces, view, colors=values, cmap=cmap, vmin=norm.vmin, vmax=norm.vmax,
                  extent=extent, scale=1e3)
        xlabel, ylabel = _axis_labels(view, "mm")
        ax.set(xlabel=xlabel, ylabel=ylabel)
        ax.set_title(f"{view} view", fontsize=9)
        ax.tick_params(labelsize=7)
    add_colorbar(fig, axes[0].tolist(), norm, cmap, f"{label} ({units})")
    fig.suptitle(title)
    return _detach(fig)


def shade_phonemes(ax, segments: Segments, silence=SILENCE, fontsize: float = 7.0) -> None:
    """Shade alternate non-silent segments along the time axis and write their labels at the top of ``ax``."""
    trans = blended_transform_factory(ax.transData, ax.transAxes)  # x in seconds, y in axes fraction
    n = 0
    for label, start, end in segments:
        if str(label) in silence:
            continue
        ax.axvspan(start, end, color="0.5" if n % 2 == 0 else "0.75", alpha=0.18, lw=0, zorder=0)
        ax.text(0.5 * (start + end), 0.97 - 0.06 * (n % 2), str(label), transform=trans, ha="center", va="top",
                fontsize=fontsize, color="0.2", clip_on=True)
        n += 1


def plot_lip_distance(times_s: np.ndarray, curves: Mapping[str, np.ndarray], phonemes: Segments | None = None,
                      title: str = "Lip distance", units: str = "mm", figsize=(9.0, 3.2)) -> Figure:
    """Upper-to-lower lip distance over time, one line per label (DualTalker Fig. 5); curves already in ``units``."""
    times_s = np.asarray(times_s, dtype=np.float64)
    fig, ax = plt.subplots(figsize=figsize, layout="constrained")
    for label, curve in curves.items():
        curve = np.asarray(curve, dtype=np.float64)
        if curve.shape != times_s.shape:
            raise ValueError(f"curve {label!r}: expected shape {times_s.shape}, got {curve.shape}")
        ax.plot(times_s, curve, label=label, lw=1.4)
    lo, hi = ax.get_ylim()
    if phonemes is not None:
        ax.set_ylim(lo, hi + 0.25 * (hi - lo))  # head room for the phoneme labels
        shade_phonemes(ax, phonemes)
    ax.set_xlim(times_s[0], times_s[-1])
    ax.set(xlabel="time (s)", ylabel=f"lip distance ({units})", title=title)
    ax.legend(loc="lower right", fontsize=8, ncols=min(len(curves), 4))
    ax.grid(alpha=0.3)
    return _detach(fig)


def plot_waveform_and_phonemes(wave: np.ndarray, sr: int, phonemes: Segments | None = None,
                               title: str = "Speech waveform and phonemes", figsize=(9.0, 2.8)) -> Figure:
    """Waveform (N,) at ``sr`` Hz over time, with phoneme segments [[label, start_s, end_s], ...] shaded."""
    wave = np.asarray(wave, dtype=np.float64).ravel()
    times = np.arange(len(wave)) / sr
    fig, ax = plt.subplots(figsize=figsize, layout="constrained")
    ax.plot(times, wave, lw=0.5, color="tab:blue")
    peak = max(float(np.abs(wave).max(initial=0.0)), 1e-3)
    ax.set_ylim(-1.1 * peak, 1.45 * peak)  # head room for the phoneme labels
    if phonemes is not None:
        shade_phonemes(ax, phonemes)
    ax.set_xlim(0.0, max(times[-1] if len(times) else 0.0, 1.0 / sr))
    ax.set(xlabel="time (s)", ylabel="amplitude (full scale)", title=title)
    ax.grid(alpha=0.3)
    return _detach(fig)
