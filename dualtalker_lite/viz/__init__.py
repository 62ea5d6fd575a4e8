"""Visualisation on plain arrays: vertices (V, 3) or (T, V, 3) in metres (y up, face towards +z), faces (F, 3).

- ``render``   matplotlib mesh renderer: orthographic views, back-face culling, painter's algorithm, Lambert shading,
               per-vertex colour maps; ``render_frame_rgb`` -> uint8 (H, W, 3); ``RasterRenderer`` (Pillow, ~4x faster)
- ``plots``    figures: mesh frame grids, per-vertex (error) maps, lip distance and waveform with phonemes
- ``heatmap``  several per-vertex maps side by side (shared colour scale option), vertex spectrograms (CorrTalk
               Figs. 1 and 9)
- ``animate``  ``animate_clip``: mp4 (H.264 + AAC speech) embedded in the notebook, JavaScript fallback (the mp4
               writer itself, and ``render_video`` for long clips, live in :mod:`dualtalker_lite.export.video`)
- ``viewer``   ``MeshViewer`` (live pythreejs widget) and ``static_html`` (self-contained three.js page)
- ``spirals``  ``plot_spirals``: EmoFace's spiral sequences on the face, coloured by ring, with a numbered close-up
- ``microphone`` ``MicrophonePanel``: record from the browser's microphone in a notebook (an anywidget) and animate
               the recording in the kernel (import it from the module: it needs the notebooks extra)
"""
from .animate import ClipAnimation, animate_clip
from .heatmap import branch_mean_errors, plot_branch_error_maps, plot_vertex_maps, plot_vertex_spectrograms
from .plots import plot_frames, plot_lip_distance, plot_vertex_map, plot_waveform_and_phonemes
from ..export.render import VIEWS, MeshRenderer, RasterRenderer, draw_mesh, render_frame_rgb
from .spirals import plot_spirals
from .viewer import MeshViewer, static_html

__all__ = [
    "VIEWS",
    "MeshRenderer",
    "RasterRenderer",
    "draw_mesh",
    "render_frame_rgb",
    "plot_frames",
    "plot_vertex_map",
    "plot_lip_distance",
    "plot_waveform_and_phonemes",
    "plot_vertex_maps",
    "plot_vertex_spectrograms",
    "plot_branch_error_maps",
    "branch_mean_errors",
    "plot_spirals",
    "ClipAnimation",
    "animate_clip",
    "MeshViewer",
    "static_html",
]
