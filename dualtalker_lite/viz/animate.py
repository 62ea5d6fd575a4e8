"""Talking-face videos with the speech audio in a notebook: ``animate_clip`` renders, encodes and embeds.

``animate_clip`` draws each (V, 3) frame with ``render.MeshRenderer`` (one or several panels side by side) and
writes the mp4 with the package's mp4 writer (:mod:`dualtalker_lite.export.video`: H.264 via ffmpeg, the speech
muxed in as AAC, atomically). The returned ``ClipAnimation`` shows itself in a notebook as a ``<video controls>``
whose source is a base64 data URI, so committed notebooks keep a playable video with sound. A 3 s single-panel clip
at 256x256 and crf 28 is well under 300 KB.

Without ffmpeg (``imageio-ffmpeg`` missing, or ``use_ffmpeg=False``) it falls back to a silent
``matplotlib.animation`` JavaScript player with JPEG frames.

Long clips (issue 11) and the ``animate`` command use :func:`dualtalker_lite.export.video.render_video` (Pillow
renderer, x264 ``veryfast``, frame by frame from a memory-mapped ``.npy``, a progress bar).
"""
from __future__ import annotations

import hashlib
import tempfile
from pathlib import Path
from typing import Mapping

import numpy as np

from ..export.video import ClipAnimation, clip_panels, ffmpeg_exe, write_mp4

__all__ = ["ClipAnimation", "animate_clip"]


def _default_path(arrays, settings) -> Path:
    """``runs/videos/clip-<hash>.mp4``: the same clip and settings always map to the same file."""
    digest = hashlib.sha1(repr(settings).encode())
    for array in arrays:
        if array is not None:
            digest.update(np.ascontiguousarray(array, dtype=np.float32).tobytes())
    name = f"clip-{digest.hexdigest()[:12]}.mp4"
    try:
        from ..files import runs_dir

        return runs_dir("videos") / name
    except (ImportError, OSError):
        return Path(tempfile.mkdtemp(prefix="dualtalker-video-")) / name


def animate_clip(clips: np.ndarray | Mapping[str, np.ndarray], faces: np.ndarray, wave: np.ndarray | None = None,
                 sample_rate: int = 16000, fps: float = 30, path: str | Path | None = None, size: int = 256,
                 view: str | None = "front", colors=None, cmap: str = "viridis",
                 vmin: float | None = None, vmax: float | None = None,
                 azimuth: float | None = None, elevation: float | None = None,
                 crf: int = 28, use_ffmpeg: bool | None = None, renderer: str = "matplotlib",
                 preset: str = "medium", progress: bool = False) -> ClipAnimation:
    """Render a (T, V, 3) (or (T, V*3)) clip, or a dict label -> clip shown side by side, to an mp4 with the
    speech ``wave``.

    All panels share one camera framing; shorter clips hold their last frame. ``colors``: per-vertex values
    (V,) or (T, V), or a dict of them per label, shared colour scale. ``size`` is the pixel size of one square
    panel. ``path`` defaults to ``runs/videos/clip-<hash>.mp4``. ``use_ffmpeg=None`` uses ffmpeg when available.
    ``renderer``: "matplotlib" (Agg, :class:`MeshRenderer`) or "raster" (Pillow, :class:`RasterRenderer`,
    ~4x faster); ``preset``: x264's speed/size trade-off; ``progress``: a tqdm bar over the frames.
    """
    panels = clip_panels(clips, faces, size=size, view=view, colors=colors, cmap=cmap, vmin=vmin, vmax=vmax,
                         azimuth=azimuth, elevation=elevation, renderer=renderer)
    exe = ffmpeg_exe() if use_ffmpeg is not False else None
    if use_ffmpeg and exe is None:
        raise RuntimeError("use_ffmpeg=True but no ffmpeg was found: pip install imageio-ffmpeg")
    if exe is None:
        reason = "use_ffmpeg=False" if use_ffmpeg is False else "ffmpeg is not available (pip install imageio-ffmpeg)"
        print(f"Note: {reason}; showing a silent JavaScript animation instead of an mp4 with sound.")
        return _jshtml_animation(panels.frame, panels.n_frames, fps, panels.size)
    if path is None:
        d = panels.settings
        settings = (d["labels"], view, azimuth, elevation, d["size"], fps, crf, cmap, d["lo"], d["hi"], sample_rate)
        path = _default_path([*panels.arrays, faces, wave], settings)
    return write_mp4(panels, path, wave, sample_rate, fps, crf, preset, progress, exe)


def _jshtml_animation(frame, n_frames: int, fps: float, size: tuple[int, int],
                      jpeg_quality: int = 70) -> ClipAnimation:
    """Silent fallback: ``FuncAnimation.to_jshtml`` with JPEG frames embedded in the HTML."""
    import matplotlib.pyplot as plt
    from matplotlib import animation

    width, height = size
    dpi = 100
    fig = plt.figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    plt.close(fig)  # never shown by pyplot; only its frames are embedded
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_axis_off()
    image = ax.imshow(frame(0), interpolation="nearest")

    def update(t: int):
        image.set_data(frame(t))
        return (image,)

    anim = animation.FuncAnimation(fig, update, frames=n_frames, interval=1000.0 / fps, blit=True)
    # What Animation.to_jshtml does, plus a JPEG quality setting to keep the notebook small.
    writer = animation.HTMLWriter(fps=fps, embed_frames=True, default_mode="once", embed_limit=100.0)
    writer.frame_format = "jpeg"
    with tempfile.TemporaryDirectory(prefix="dualtalker-jshtml-") as tmp:
        page = Path(tmp) / "animation.html"
        anim.save(str(page), writer=writer, dpi=dpi, savefig_kwargs={"pil_kwargs": {"quality": jpeg_quality}})
        html = page.read_text()
    return ClipAnimation(path=None, n_frames=n_frames, fps=fps, size=size, has_audio=False, html=html)
