"""Spirals on the face (EmoFace section 3.2, eq. 1): a few centres' spiral sequences over a rendered mesh.

Each spiral's vertices are coloured by their ring (graph distance from the centre: 0 = the centre, 1 = its
one-ring, ...) and joined by a thin line in spiral order, so one sees both the k-disk and the order SpiralConv3D
reads it in. ``zoom`` adds a close-up of the first centre with every slot's number written next to its vertex.
"""
from __future__ import annotations

from typing import Sequence

import matplotlib.pyplot as plt
import numpy as np
import torch
from matplotlib.figure import Figure

from ..blocks.spiral import spiral_ring_index
from .plots import _axis_labels, _detach
from ..export.render import camera_rotation, draw_mesh, mesh_extent, project

__all__ = ["plot_spirals"]


def plot_spirals(vertices: np.ndarray, faces: np.ndarray, spirals, centres: Sequence[int],
                 view: str = "front", zoom: float | None = None, title: str = "Spirals on the template",
                 panel_size: float = 4.6) -> Figure:
    """Spirals (V, L) of ``centres`` on the (V, 3) mesh in metres (axes in mm); ``zoom``: close-up half-width (m)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    spirals = torch.as_tensor(spirals)
    n = len(vertices)
    if spirals.ndim != 2 or spirals.shape[0] != n:
        raise ValueError(f"spirals: expected shape ({n}, L), got {tuple(spirals.shape)}")
    bad = [c for c in centres if not 0 <= int(c) < n]
    if bad or not len(centres):
        raise ValueError(f"centres: need 1+ vertex ids in [0, {n}), got {list(centres)}")
    rot = camera_rotation(view)
    cam = project(vertices, rot) * 1e3  # (V, 3) mm, image x/y first
    rings = {int(c): spiral_ring_index(spirals, faces, n, int(c)) for c in centres}
    n_rings = max(int(r.max()) for r in rings.values()) + 1
    colours = plt.get_cmap("viridis")(np.linspace(0.0, 0.9, max(n_rings, 2)))
    panels = 2 if zoom is not None else 1
    fig, axes = plt.subplots(1, panels, figsize=(panel_size * panels + 0.4, panel_size + 0.4), squeeze=False,
                             layout="constrained")
    for p, ax in enumerate(axes[0]):
        draw_mesh(ax, vertices, faces, view, extent=mesh_extent(vertices), scale=1e3)
        shown = list(rings) if p == 0 else [int(centres[0])]
        for c in shown:
            row, ring = spirals[c].numpy(), rings[c]
            keep = ring >= 0  # padded slots are not drawn
            xy = cam[row[keep], :2]
            ax.plot(xy[:, 0], xy[:, 1], color="0.15", lw=0.8, zorder=3)
            ax.scatter(xy[:, 0], xy[:, 1], c=colours[ring[keep]], s=22 if p == 0 else 60, zorder=4,
                       edgecolors="k", linewidths=0.4)
            if p == 1:
                for slot, (x, y) in enumerate(xy):
                    ax.annotate(str(slot), (x, y), xytext=(4, 4), textcoords="offset points", fontsize=8, zorder=5)
        if p == 1:
            cx, cy = cam[int(centres[0]), :2]
            ax.set_xlim(cx - 1e3 * zoom, cx + 1e3 * zoom)
            ax.set_ylim(cy - 1e3 * zoom, cy + 1e3 * zoom)
            ax.set_title(f"vertex {int(centres[0])}: slot numbers in spiral order", fontsize=9)
        else:
            ax.set_title(f"{view} view, {len(shown)} centres", fontsize=9)
        xlabel, ylabel = _axis_labels(view, "mm")
        ax.set(xlabel=xlabel, ylabel=ylabel)
        ax.tick_params(labelsize=7)
    handles = [plt.Line2D([], [], ls="", marker="o", color=colours[k], markeredgecolor="k",
                          label="centre" if k == 0 else f"ring {k}") for k in range(n_rings)]
    axes[0, -1].legend(handles=handles, fontsize=8, loc="lower right")
    fig.suptitle(title)
    return _detach(fig)
