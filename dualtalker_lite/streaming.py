"""Hour-long audio in bounded memory (issue 11): stream generated frames straight to a ``.npy`` file.

An hour at 30 fps is 108,000 frames. The models decode it with bounded caches (``generate_chunks``, see
:mod:`dualtalker_lite.blocks.windowed`), but the *result* alone is T x V*3 float32: 2.0 GB for the sample's
1,558-vertex face, the whole memory budget. So long clips are written block by block to a ``.npy`` file (a
valid numpy file: ``np.load(path, mmap_mode="r")`` reads it back lazily, and ``export.video.render_video``
renders it frame by frame).

    from dualtalker_lite.streaming import animate_wave_to_npy
    animate_wave_to_npy(model, wave, template, speaker=0, path="runs/long/vertices.npy")

:func:`predict_chunks` is the single inference path of the package: it validates the inputs, extracts the
features and yields the prediction block by block; ``inference.animate_wave`` joins the blocks in memory,
:func:`animate_wave_to_npy` and the ``dualtalker-lite animate`` command stream them to disk.

Files are written to a temporary name beside the target and renamed when complete; the temporary file is
removed on failure, Ctrl-C and SIGTERM, and a non-finite frame stops the run with a message naming the frames.
"""
from __future__ import annotations

import contextlib
import errno
import os
from contextlib import nullcontext
from pathlib import Path

import numpy as np
import torch

from .audio import AudioStream, LogMelExtractor, validate_wave
from .checks import NonFiniteError, check_finite, resolve_device
from .files import ResourceError, sigterm_as_exit  # noqa: F401 - sigterm_as_exit's home is files (export/ too)
from .models.contract import conditions as model_conditions, hook

__all__ = ["sigterm_as_exit", "write_npy_stream", "generate_to_npy", "SpooledFeatures", "predict_chunks",
           "animate_wave_to_npy", "fixed_mmap_threshold"]


def fixed_mmap_threshold(nbytes: int = 4 << 20) -> bool:
    """Ask glibc to serve every allocation of ``nbytes`` or more with its own ``mmap`` (returned to the system when
    freed) -> whether it could (glibc only; elsewhere nothing changes).

    By default glibc raises that threshold to the size of the largest block freed so far (up to 32 MB), so after
    the first block of features the next ones come from the heap, which fragments and keeps growing: measured
    (``animate --format npy``, one thread), 370 MB peak for 5 minutes of audio without it, 339 MB with 4 MB and
    344 MB for 10 minutes, i.e. flat. 1 MB costs a third more CPU time (a fresh mapping for every decoded block)
    for 14 MB less. Setting the threshold also turns that adjustment off.
    """
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return bool(libc.mallopt(-3, int(nbytes)))  # M_MMAP_THRESHOLD
    except (OSError, AttributeError):
        return False


def write_npy_stream(path: str | os.PathLike, chunks, n_frames: int, n_values: int) -> Path:
    """Write (n, n_values) blocks (arrays or tensors, batch dim 1 allowed) as one float32 (n_frames, n_values) .npy.

    Memory: one block at a time. Atomic: ``<name>.partial`` beside the target, renamed at the end; removed on any
    failure or interruption. Non-finite values and a frame count other than ``n_frames`` are errors.
    """
    path = Path(path)
    tmp = path.with_name(path.name + ".partial")
    header = {"descr": np.lib.format.dtype_to_descr(np.dtype(np.float32)), "fortran_order": False,
              "shape": (int(n_frames), int(n_values))}
    written = 0
    try:
        with sigterm_as_exit(), open(tmp, "wb") as f:
            np.lib.format.write_array_header_2_0(f, header)
            for block in chunks:
                block = block.detach().cpu().numpy() if isinstance(block, torch.Tensor) else np.asarray(block)
                block = np.ascontiguousarray(block.reshape(-1, n_values), dtype=np.float32)  # (n, V*3)
                if not np.isfinite(block).all():
                    bad = written + np.flatnonzero(~np.isfinite(block).all(1))
                    raise ValueError(f"{path}: non-finite values in frames {bad[:5].tolist()}"
                                     f"{' ...' if len(bad) > 5 else ''}; nothing was written")
                if written + len(block) > n_frames:
                    raise ValueError(f"{path}: more than the announced {n_frames} frames")
                f.write(block.tobytes())
                written += len(block)
            if written != n_frames:
                raise ValueError(f"{path}: got {written} frames, expected {n_frames}; nothing was written")
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def generate_to_npy(model: torch.nn.Module, audio: torch.Tensor, template: torch.Tensor, speaker: int,
                    path: str | os.PathLike, chunk: int = 900) -> Path:
    """``model.generate_chunks`` for one clip, audio (T, D_a) or (1, T, D_a), template (V*3,) -> (T, V*3) .npy."""
    audio = audio if audio.dim() == 3 else audio[None]  # (1, T, D_a)
    template = torch.as_tensor(template, dtype=torch.float32).reshape(1, -1)  # (1, V*3)
    model.eval()
    chunks = model.generate_chunks(audio, template, torch.tensor([int(speaker)]), chunk=chunk)
    return write_npy_stream(path, chunks, audio.shape[1], template.shape[1])


class SpooledFeatures:
    """The features A (1, T, D) of a long recording kept in an anonymous temporary file, read back a window of
    frames at a time: with them, memory no longer grows with the audio length (69 MB per hour of log-mel).

    The models' ``generate_chunks`` never need A whole: they check its shape, then encode it block by block in
    overlapping windows (:class:`~dualtalker_lite.blocks.feature_windows.FeatureWindows`, which slices
    ``A[:, a:b]``). So this object offers only what they use of a (1, T, D) float32 CPU tensor: ``shape``,
    ``dim()``, ``dtype``, ``device``, ``to()`` (CPU only) and ``[:, a:b]`` (or ``[0, a:b]``), which returns a real
    tensor read from the file (``os.pread``, no memory map: mapped pages would count as resident once read).
    The file is unlinked at creation (``tempfile.TemporaryFile``): nothing is left behind, even after SIGKILL.

        spool = SpooledFeatures.write(extractor.stream_rows(wave.blocks, len(wave), T), T, extractor.dim)
        spool[:, 100:200]   # (1, 100, D) float32 tensor, the same numbers as extractor(wave, T)[None, 100:200]
    """

    def __init__(self, file, n_frames: int, dim: int):
        self.file, self.n_frames, self.n_values = file, int(n_frames), int(dim)
        self.shape = torch.Size((1, self.n_frames, self.n_values))
        self.dtype, self.device = torch.float32, torch.device("cpu")

    @classmethod
    def write(cls, pieces, n_frames: int, dim: int, directory: str | os.PathLike | None = None,
              source: str | os.PathLike = "the recording") -> "SpooledFeatures":
        """Spool consecutive (first_row, rows) pieces (e.g. ``LogMelExtractor.stream_rows``), whose bytes in
        order are the (n_frames, dim) float32 features; fewer or more bytes than that is an error. The file lies in
        ``directory`` (default: ``$TMPDIR``, else ``/tmp``); when it cannot be made or written there (a full disk,
        a quota, a file-size limit, a read-only folder), one :class:`~dualtalker_lite.files.ResourceError` line
        names ``source`` (the recording), the folder and how to move it (:func:`_spool_error`)."""
        import tempfile

        folder = directory or tempfile.gettempdir()
        try:
            f = tempfile.TemporaryFile(dir=directory)
        except OSError as e:
            raise _spool_error(e, folder, source, 4 * n_frames * dim) from e
        try:
            for _, rows in pieces:
                f.write(np.ascontiguousarray(np.asarray(rows), dtype=np.float32).tobytes())
            f.flush()
            if f.tell() != 4 * n_frames * dim:
                raise ValueError(f"spooled {f.tell() // 4} feature values, expected {n_frames} x {dim}")
        except BaseException as e:
            with contextlib.suppress(OSError):  # its buffer's rest cannot be written either
                f.close()
            if isinstance(e, OSError) and not isinstance(e, ResourceError):
                raise _spool_error(e, folder, source, 4 * n_frames * dim) from e
            raise
        return cls(f, n_frames, dim)

    def dim(self) -> int:
        return 3

    def to(self, device=None, *args, **kwargs) -> "SpooledFeatures":
        if device is not None and torch.device(device).type != "cpu":
            raise ValueError("SpooledFeatures live on the CPU; read a window and move that")
        return self

    def __getitem__(self, index) -> torch.Tensor:
        batch, frames = index if isinstance(index, tuple) else (index, slice(None))
        if not isinstance(frames, slice) or frames.step not in (None, 1) or \
                not (batch == slice(None) or batch == 0 or batch == -1):
            raise IndexError("SpooledFeatures supports [:, a:b] and [0, a:b] only")
        a, b, _ = frames.indices(self.n_frames)
        b = max(a, b)
        nbytes = 4 * self.n_values * (b - a)
        data = os.pread(self.file.fileno(), nbytes, 4 * self.n_values * a) if nbytes else b""
        if len(data) != nbytes:
            raise OSError(f"spooled features: read {len(data)} of {nbytes} bytes")
        rows = torch.from_numpy(np.frombuffer(bytearray(data), dtype=np.float32).reshape(b - a, self.n_values))
        return rows[None] if batch == slice(None) else rows  # (1, b - a, D) or (b - a, D)

    def close(self) -> None:
        self.file.close()

    def __repr__(self) -> str:
        return f"SpooledFeatures(1 x {self.n_frames} frames x {self.n_values})"


def _spool_error(e: OSError, folder, source, nbytes: int) -> ResourceError:
    """The features of ``source`` could not be spooled into ``folder`` -> one line naming both, the system's reason
    and what to do: make room there or move the spool elsewhere with ``TMPDIR`` (issue 48); under a file-size
    limit, which holds in every folder, raise the limit."""
    reason = os.strerror(e.errno) if e.errno else (str(e).strip().splitlines() or [type(e).__name__])[0]
    import resource

    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    if e.errno == errno.EFBIG and limit != resource.RLIM_INFINITY:
        advice = f"the file-size limit (ulimit -f) is {limit} bytes: raise it (ulimit -f unlimited)"
    else:
        advice = (f"free some space there, or set TMPDIR to a folder on a disk with room (TMPDIR=/big/tmp "
                  f"dualtalker-lite animate ...) to move it")
    return ResourceError(e.errno or errno.EIO, f"{source}: its features could not be spooled to the temporary "
                                               f"folder {folder} ({reason}; they take {nbytes / 1e6:.1f} MB "
                                               f"there); {advice}")


def predict_chunks(model: torch.nn.Module, wave: np.ndarray, template: np.ndarray, speaker: int = 0,
                   sample_rate: int = 16000, front_end=None, device: str | torch.device | None = None,
                   amp: bool = False, chunk: int = 900, fps: int = 30, conditions: dict | None = None):
    """Validate, extract features and return ``(T, blocks)``: ``blocks`` yields the predicted vertices as float32
    (n, V*3) numpy blocks of at most ``chunk`` frames, T = N fps / sample_rate frames in all.

    ``conditions``: extra keyword arguments of the model's ``generate_chunks`` (EmoFace: ``emotion``, ``level``);
    None values are dropped, and a condition the model does not name (``models.contract.conditions``) is refused
    with one line.

    The one code path of every inference entry point (``inference.animate_wave`` joins the blocks,
    :func:`animate_wave_to_npy` and the ``animate`` command stream them to disk). All input checks run here,
    before the first block (bad wave, non-finite template, wrong vertex count, speaker outside the style
    table, missing CUDA); memory beyond the model is the wave, its features (T x D_a) and one block. ``wave``
    may be an :class:`~dualtalker_lite.audio.AudioStream` (what ``animate`` passes): features are then computed
    block by block by the front end's ``stream`` method (log-mel and the phoneme recogniser have one) and the
    wave is never in memory whole; on the CPU, log-mel features (``stream_rows``) go straight to a
    :class:`SpooledFeatures` file, so neither are they (the models read them window by window). With all three,
    memory no longer grows with the audio length beyond the recogniser's small (T, 15) viseme track.
    ``device="cuda"`` runs on the GPU, ``amp=True`` adds float16 autocast there. A block with a NaN/inf raises
    :class:`~dualtalker_lite.checks.NonFiniteError` naming its first bad frame.
    """
    streamed = _check_wave(wave, sample_rate)
    conditions = _check_conditions(model, conditions)
    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise ValueError(f"chunk must be a positive number of frames, got {chunk!r}")
    front_end = front_end or LogMelExtractor(fps=fps)  # a front end of front_ends.FRONT_ENDS (default: log-mel)
    if getattr(front_end, "fps", fps) != fps:  # its frames would be written at fps: the motion stretched in time
        raise ValueError(f"the front end makes features at {front_end.fps} frames per second, but fps is {fps}")
    template = _check_template(model, template, speaker)  # (V*3,)
    if device is not None:
        dev = resolve_device(device, option="device")
    else:
        dev = next(model.parameters(), torch.empty(0)).device
    n_frames = max(1, int(round(len(wave) * fps / sample_rate)))
    audio = _features(front_end, wave, streamed, n_frames, dev)  # (1, T, D_a)
    model.eval().to(dev)
    return n_frames, _predicted_blocks(model, audio, template, speaker, dev, chunk, amp, conditions)


def _check_wave(wave, sample_rate: int) -> bool:
    """Refuse a bad wave (or an :class:`~dualtalker_lite.audio.AudioStream` read at another rate) with one line
    -> whether it is such a stream (a file read block by block, checked when it was opened)."""
    streamed = isinstance(wave, AudioStream)
    if streamed and wave.sample_rate != sample_rate:
        raise ValueError(f"{wave.path}: read at {wave.sample_rate} Hz, but sample_rate is {sample_rate}")
    if not streamed:
        validate_wave(wave, sample_rate)
    return streamed


def _check_conditions(model: torch.nn.Module, conditions: dict | None) -> dict:
    """The given conditions without None values; one line for any the model does not name
    (``models.contract.conditions``: its ``generation_conditions`` and ``chosen_conditions``)."""
    conditions = {k: v for k, v in (conditions or {}).items() if v is not None}
    refused = sorted(k for k in conditions if k not in model_conditions(model))
    if refused:
        raise ValueError(f"this {type(model).__name__} model takes no {'/'.join(refused)} condition "
                         f"(only emotion-aware models such as EmoFace do)")
    return conditions


def _check_template(model: torch.nn.Module, template: np.ndarray, speaker: int) -> np.ndarray:
    """The template as float32 (V*3,), refused with one line when non-finite, of another vertex count than the
    model's or when ``speaker`` is outside its style table (the ``cfg`` hook's ``n_vertices``, ``n_speakers``)."""
    template = np.asarray(template, dtype=np.float32).reshape(-1)  # (V*3,)
    check_finite(template, "template")
    cfg = hook(model, "cfg")
    n_vertices = getattr(cfg, "n_vertices", None)
    if n_vertices is not None and template.size != 3 * n_vertices:
        raise ValueError(f"template has {template.size // 3} vertices but the model was trained on {n_vertices}")
    n_speakers = getattr(cfg, "n_speakers", None)
    if n_speakers is not None and not 0 <= speaker < n_speakers:
        raise ValueError(f"speaker index {speaker} is outside the model's {n_speakers} style embeddings")
    return template


def _features(front_end, wave, streamed: bool, n_frames: int, dev: torch.device):
    """The front end's features A (1, T, D_a) of the wave: a :class:`SpooledFeatures` file for a streamed wave
    and log-mel on the CPU, the recogniser's stream for a streamed wave, else the front end on the whole wave."""
    with torch.no_grad():
        if streamed and hasattr(front_end, "stream_rows") and dev.type == "cpu":  # log-mel: not even A whole
            return SpooledFeatures.write(front_end.stream_rows(wave.blocks, len(wave), n_frames), n_frames,
                                         front_end.dim, source=wave.path)  # (1, T, D_a) on disk, by windows
        if streamed and hasattr(front_end, "stream"):  # the recogniser: never the whole wave in memory
            # the callable, not an iterator: the recogniser reads the file more than once (cache key, then hama)
            return front_end.stream(wave.blocks, len(wave), n_frames)[None]  # (1, T, D_a)
        # front-ends without a stream method (wav2vec 2.0) take the whole wave
        return front_end(wave.read() if streamed else wave, n_frames)[None]


def _predicted_blocks(model: torch.nn.Module, audio, template: np.ndarray, speaker: int, dev: torch.device,
                      chunk: int, amp: bool, conditions: dict):
    """Yield ``model.generate_chunks``' blocks as float32 (n, V*3) numpy arrays; a NaN/inf is a
    :class:`~dualtalker_lite.checks.NonFiniteError` naming its first frame."""
    gen = model.generate_chunks(audio.to(dev), torch.from_numpy(template)[None].to(dev),
                                torch.tensor([int(speaker)], device=dev), chunk=chunk, **conditions)
    done = 0
    while True:
        # no_grad/autocast around each step only: they must not leak into the caller between blocks
        autocast = torch.autocast("cuda", dtype=torch.float16) if amp and dev.type == "cuda" else nullcontext()
        with torch.no_grad(), autocast:
            block = next(gen, None)
            if block is None:
                return
            block = block[0].float().cpu().numpy()  # (n, V*3)
        bad = ~np.isfinite(block).all(1)  # (n,)
        if bad.any():
            raise NonFiniteError(f"model output contains NaN/infinite values (first at frame "
                                 f"{done + int(np.flatnonzero(bad)[0])}): the checkpoint's weights or "
                                 f"the input produce NaN; nothing was written")
        done += len(block)
        yield block


def animate_wave_to_npy(model: torch.nn.Module, wave: np.ndarray, template: np.ndarray, speaker: int,
                        path: str | os.PathLike, sample_rate: int = 16000, front_end=None, fps: int = 30,
                        chunk: int = 900, device: str | torch.device | None = None, amp: bool = False) -> Path:
    """16 kHz mono speech (N,) of any length -> predicted vertices (T, V*3) float32 in ``path``, T = N fps / sr.

    The streaming counterpart of ``inference.animate_wave`` (same checks and numbers, see :func:`predict_chunks`):
    block-wise STFT features, banded audio encoding and bounded-cache decoding keep the memory far below the
    size of the result. ``path`` appears only when complete.
    """
    n_frames, blocks = predict_chunks(model, wave, template, speaker, sample_rate, front_end, device, amp,
                                      chunk, fps)
    return write_npy_stream(path, blocks, n_frames, np.asarray(template).size)
