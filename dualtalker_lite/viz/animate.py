"""Talking-face videos with the speech audio: render frames, encode H.264, mux AAC, embed in the notebook.

``animate_clip`` renders each (V, 3) frame with ``render.MeshRenderer`` (one or several panels side by side),
pipes the frames to ffmpeg (``imageio_ffmpeg.write_frames``: H.264, yuv420p, even sizes), then muxes the speech
in with one more ffmpeg call (AAC). The returned ``ClipAnimation`` shows itself in a notebook as a
``<video controls>`` whose source is a base64 data URI, so committed notebooks keep a playable video with sound.
A 3 s single-panel clip at 256x256 and crf 28 is well under 300 KB.

Without ffmpeg (``imageio-ffmpeg`` missing, or ``use_ffmpeg=False``) it falls back to a silent
``matplotlib.animation`` JavaScript player with JPEG frames.

Long clips (issue 11): :func:`render_video` renders with ``render.RasterRenderer`` (Pillow, ~4x faster than
Agg) and x264's ``veryfast`` preset, shows a tqdm progress bar, and reads the vertices frame by frame (a
memory-mapped ``.npy`` works: nothing is converted as a whole). The temporary ``dualtalker-video-*`` folder is
removed on success, on failure, on Ctrl-C and on SIGTERM, and the mp4 only appears once complete.
"""
from __future__ import annotations

import base64
import hashlib
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from ..streaming import sigterm_as_exit
from .render import MeshRenderer, RasterRenderer, mesh_extent

__all__ = ["ClipAnimation", "animate_clip", "render_video", "ffmpeg_exe", "stream_info"]


@dataclass
class ClipAnimation:
    """A rendered clip: an mp4 file (``path``) or, without ffmpeg, a JavaScript player (``html``)."""

    path: Path | None  # H.264 (+ AAC when audio was given) mp4; None for the JavaScript fallback
    n_frames: int
    fps: float
    size: tuple[int, int]  # (width, height) in pixels
    has_audio: bool
    html: str | None = field(default=None, repr=False)  # the JavaScript fallback player

    def _repr_html_(self) -> str:
        if self.path is None:
            return self.html or ""
        data = base64.b64encode(Path(self.path).read_bytes()).decode("ascii")
        width, height = self.size
        return (f'<video controls width="{width}" height="{height}" preload="metadata" '
                f'src="data:video/mp4;base64,{data}"></video>')


def ffmpeg_exe() -> str | None:
    """Path of the ffmpeg binary shipped with ``imageio-ffmpeg`` (or on PATH), None if there is none."""
    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):
        return shutil.which("ffmpeg")


def stream_info(path: str | Path) -> str:
    """The stream lines ffmpeg prints for ``ffmpeg -i path`` (e.g. "Stream #0:0...: Video: h264 ..."); ffprobe-free."""
    out = subprocess.run([ffmpeg_exe(), "-hide_banner", "-i", str(path)], capture_output=True, text=True).stderr
    return "\n".join(line.strip() for line in out.splitlines() if "Stream #" in line)


def _as_panels(clips, colors) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray | None]]:
    """Normalise ``clips`` and ``colors`` to dicts label -> (T, V, 3) and label -> (T, V) or None."""
    def frames(v) -> np.ndarray:  # no float64 copy of a whole (possibly memory-mapped) clip: per frame later
        v = v.detach().cpu().numpy() if hasattr(v, "detach") else v
        v = v if isinstance(v, np.ndarray) and v.dtype.kind == "f" else np.asarray(v, dtype=np.float64)
        return v.reshape(len(v), -1, 3) if v.ndim == 2 and v.shape[1] > 3 and v.shape[1] % 3 == 0 else v

    if isinstance(clips, Mapping):
        panels = {str(k): frames(v) for k, v in clips.items()}
    else:
        panels = {"": frames(clips)}
    for label, clip in panels.items():
        if clip.ndim != 3 or clip.shape[2] != 3:
            raise ValueError(f"clip {label!r}: expected shape (T, V, 3), got {clip.shape}")
    if colors is None or not isinstance(colors, Mapping):
        colors = {label: colors for label in panels}
    values = {}
    for label, clip in panels.items():
        c = colors.get(label)
        values[label] = None if c is None else np.broadcast_to(np.asarray(c, dtype=np.float64), clip.shape[:2])
    return panels, values


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
    panels, values = _as_panels(clips, colors)
    n_frames = max(len(clip) for clip in panels.values())
    size = int(size) + int(size) % 2  # H.264 with yuv420p needs even sizes
    width, height = size * len(panels), size
    sample = [clip[:: max(1, len(clip) // 16)].reshape(-1, 3) for clip in panels.values()]  # ~16 frames each
    sample = np.concatenate(sample)
    sample = sample[np.isfinite(sample).all(1)]  # a non-finite frame is reported when it is reached
    extent = mesh_extent(sample if len(sample) else np.zeros((1, 3)))  # one framing for every panel and frame
    given = [v for v in values.values() if v is not None]
    lo = min(float(np.nanmin(v)) for v in given) if given and vmin is None else vmin
    hi = max(float(np.nanmax(v)) for v in given) if given and vmax is None else vmax
    if renderer not in ("matplotlib", "raster"):
        raise ValueError(f"renderer must be 'matplotlib' or 'raster', got {renderer!r}")
    renderer = MeshRenderer((size, size)) if renderer == "matplotlib" else RasterRenderer((size, size))

    def frame(t: int) -> np.ndarray:
        images = []
        for label, clip in panels.items():
            i = min(t, len(clip) - 1)
            c = None if values[label] is None else values[label][i]
            if not np.isfinite(clip[i]).all():  # checked per frame: clips may be memory-mapped and long
                name = f"clip {label!r}" if label else "the clip"
                raise ValueError(f"frame {i} of {name} has non-finite vertices (NaN or inf); nothing was rendered")
            images.append(renderer.render(clip[i], faces, view, azimuth, elevation, colors=c, cmap=cmap,
                                          vmin=lo, vmax=hi, extent=extent, label=label))
        return np.concatenate(images, axis=1)  # (H, W, 3)

    exe = ffmpeg_exe() if use_ffmpeg is not False else None
    if use_ffmpeg and exe is None:
        raise RuntimeError("use_ffmpeg=True but no ffmpeg was found: pip install imageio-ffmpeg")
    if exe is None:
        reason = "use_ffmpeg=False" if use_ffmpeg is False else "ffmpeg is not available (pip install imageio-ffmpeg)"
        print(f"Note: {reason}; showing a silent JavaScript animation instead of an mp4 with sound.")
        return _jshtml_animation(frame, n_frames, fps, (width, height))

    settings = (sorted(panels), view, azimuth, elevation, size, fps, crf, cmap, lo, hi, sample_rate)
    if path is None:
        path = _default_path([*panels.values(), *values.values(), faces, wave], settings)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frames = (frame(t) for t in range(n_frames))
    if progress:
        from tqdm.auto import tqdm

        frames = tqdm(frames, total=n_frames, desc="rendering", unit="frame", dynamic_ncols=True)
    # A temporary folder beside the target: removed on success, failure, Ctrl-C and SIGTERM; the finished mp4
    # is renamed into place (atomic on one file system), so ``path`` never holds a partial video.
    with sigterm_as_exit(), tempfile.TemporaryDirectory(prefix="dualtalker-video-", dir=path.parent) as tmp:
        video = Path(tmp) / "video.mp4"
        _write_video(video, frames, (width, height), fps, crf, preset)
        if wave is not None:
            audio = Path(tmp) / "audio.wav"
            _write_wav(audio, wave, sample_rate, n_samples=int(round(n_frames / fps * sample_rate)))
            muxed = Path(tmp) / "muxed.mp4"
            _mux(exe, video, audio, muxed)
            video = muxed
        os.replace(video, path)
    return ClipAnimation(path=path, n_frames=n_frames, fps=fps, size=(width, height), has_audio=wave is not None)


def render_video(vertices, faces: np.ndarray, path: str | Path, wave: np.ndarray | None = None,
                 sample_rate: int = 16000, fps: float = 30, size: int = 256, progress: bool = True,
                 renderer: str = "raster", preset: str = "veryfast", **kwargs) -> ClipAnimation:
    """An mp4 of a predicted clip, for long clips: ``vertices`` (T, V*3) or (T, V, 3), an array, a tensor or
    the path of a ``.npy`` (memory-mapped, never loaded whole); the speech ``wave`` (an array or an
    ``audio.AudioStream``, read block by block) is muxed in (AAC).

    Fast defaults (Pillow renderer, x264 ``veryfast``) and a progress bar; ``kwargs`` go to :func:`animate_clip`
    (``view``, ``colors``, ``crf``...). The temporary folder is removed on failure and on interruption.
    """
    name = f"{vertices}" if isinstance(vertices, (str, Path)) else "vertices"
    if isinstance(vertices, (str, Path)):
        vertices = np.load(vertices, mmap_mode="r", allow_pickle=False)
    vertices = vertices.detach().cpu().numpy() if hasattr(vertices, "detach") else vertices
    for start in range(0, len(vertices), 4096):  # before any work: an hour would otherwise fail near its end
        block = np.asarray(vertices[start:start + 4096])
        bad = ~np.isfinite(block.reshape(len(block), -1)).all(1)  # (n,) per frame
        if bad.any():
            raise ValueError(f"{name}: frame {start + int(np.flatnonzero(bad)[0])} has non-finite vertices "
                             f"(NaN or inf); nothing was rendered")
    return animate_clip(vertices, faces, wave=wave, sample_rate=sample_rate, fps=fps, path=path, size=size,
                        renderer=renderer, preset=preset, progress=progress, use_ffmpeg=True, **kwargs)


def _write_video(path: Path, frames, size: tuple[int, int], fps: float, crf: int, preset: str = "medium") -> None:
    """H.264 yuv420p via ``imageio_ffmpeg.write_frames`` (frames piped as raw RGB)."""
    import imageio_ffmpeg

    writer = imageio_ffmpeg.write_frames(
        str(path), size, fps=fps, codec="libx264", pix_fmt_in="rgb24", pix_fmt_out="yuv420p", quality=None,
        macro_block_size=2, ffmpeg_log_level="error",
        output_params=["-crf", str(crf), "-preset", preset, "-tune", "animation", "-movflags", "+faststart"])
    writer.send(None)  # start the generator
    try:
        for image in frames:
            writer.send(np.ascontiguousarray(image, dtype=np.uint8))
    finally:
        writer.close()


def _write_wav(path: Path, wave: np.ndarray, sample_rate: int, n_samples: int) -> None:
    """The speech trimmed or zero-padded to exactly the video's duration, 16-bit PCM. ``wave``: an array, or
    anything with a ``blocks()`` method (an ``audio.AudioStream``: copied block by block, never whole)."""
    import soundfile as sf

    pieces = wave.blocks() if hasattr(wave, "blocks") else [np.asarray(wave, dtype=np.float32).ravel()]
    written = 0
    with sf.SoundFile(str(path), "w", sample_rate, 1, subtype="PCM_16", format="WAV") as f:
        for piece in pieces:
            piece = np.asarray(piece, dtype=np.float32).ravel()[:n_samples - written]
            f.write(np.clip(piece, -1.0, 1.0))
            written += len(piece)
            if written == n_samples:
                break
        if written < n_samples:
            f.write(np.zeros(n_samples - written, np.float32))


def _mux(exe: str, video: Path, audio: Path, out: Path) -> None:
    """Copy the video stream, encode the audio to AAC, one mp4 (moov atom first for streaming)."""
    cmd = [exe, "-y", "-v", "error", "-i", str(video), "-i", str(audio), "-map", "0:v:0", "-map", "1:a:0",
           "-c:v", "copy", "-c:a", "aac", "-b:a", "48k", "-movflags", "+faststart", str(out)]
    result = subprocess.run(cmd, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"ffmpeg failed to mux the audio:\n{' '.join(cmd)}\n{result.stderr}")


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
