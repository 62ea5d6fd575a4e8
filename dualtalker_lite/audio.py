"""Audio I/O and per-mesh-frame speech features A_{1:T} (design.md, "Units and rates").

Pipeline, for a mono 16 kHz wave of N samples and a clip of T mesh frames at 30 fps:

1. STFT: Hann window of 400 samples (25 ms), hop 160 (10 ms), n_fft 512, ``center=True`` with zero
   padding -> ``1 + N // 160`` frames at 100 Hz; power spectrum ``|X|^2``.
2. Mel: ``80`` triangular filters on the **HTK** mel scale ``mel(f) = 2595 log10(1 + f / 700)``;
   ``log(mel + 1e-6)`` (the epsilon keeps digital silence finite: log(1e-6) = -13.8).
3. Linear interpolation in time (``align_corners=True``, as FaceFormer does for wav2vec 2.0 features)
   to exactly ``2 T`` frames (60 Hz), then stacking two frames per mesh frame -> ``A``: ``(T, 160)``.

Extractors are pluggable (:class:`FeatureExtractor`): anything with ``sample_rate``, ``dim`` and
``__call__(wave, n_frames) -> (n_frames, dim)`` can replace :class:`LogMelExtractor`.
"""
from __future__ import annotations

import contextlib
import math
import os
import struct
import sys
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np
import torch
import torch.nn.functional as F

from .checks import file_kind

__all__ = [
    "SAMPLE_RATE", "N_FFT", "WIN_LENGTH", "HOP_LENGTH", "N_MELS", "LOG_EPS",
    "MAX_AMPLITUDE", "load_audio", "AudioStream", "resample", "validate_wave", "check_wav_header",
    "check_audio_header", "peak_warning", "MIN_SAMPLE_RATE", "MAX_SAMPLE_RATE", "hz_to_mel", "mel_to_hz",
    "mel_filterbank",
    "log_mel_spectrogram", "interpolate_frames", "FeatureExtractor", "LogMelExtractor", "Wav2Vec2Extractor",
]

SAMPLE_RATE = 16000  # Hz
N_FFT = 512          # FFT size (257 frequency bins)
WIN_LENGTH = 400     # 25 ms analysis window
HOP_LENGTH = 160     # 10 ms hop -> 100 feature frames per second
N_MELS = 80
LOG_EPS = 1e-6       # log(mel + LOG_EPS)
STFT_BLOCK = 6000    # STFT frames per block (60 s): bounded memory for hour-long waves
# Audio lives in [-1, 1]. Float files may overshoot a little (clipping-free mastering): up to MAX_AMPLITUDE
# they are peak-normalised with a warning; beyond it (e.g. 1e19, a float WAV of raw integers or garbage) the
# power spectrum would overflow float32, so they are refused.
MAX_AMPLITUDE = 1e3


# ----------------------------------------------------------------------------------------- I/O
def resample(wave: np.ndarray, orig_sr: int, target_sr: int) -> np.ndarray:
    """Polyphase resampling by the rational factor ``target_sr / orig_sr`` (reduced with gcd)."""
    if orig_sr == target_sr:
        return np.asarray(wave, dtype=np.float32)
    from scipy.signal import resample_poly  # scipy import is slow-ish; only pay when needed

    g = math.gcd(int(orig_sr), int(target_sr))
    return resample_poly(wave, target_sr // g, orig_sr // g, axis=0).astype(np.float32)


def upsampled_warning(path, file_sr: int, sample_rate: int, front_end: str = "logmel") -> str:
    """The one ``warning:`` line for a recording sampled below ``sample_rate`` (upsampled: nothing above
    ``file_sr / 2`` is there), worded for the model's audio ``front_end`` (a name of
    :data:`dualtalker_lite.front_ends.FRONT_ENDS`): ``"logmel"`` (its upper mel bands are empty, and log-mel models
    know only full-band speech), ``"visemes"`` (the phoneme recogniser: it copes with telephone-band speech, the
    real-voice benchmark's voice is 8 kHz, but has less to go on for the consonants whose energy lies above 4 kHz) or
    ``"visemes+logmel"`` (both: EmoFace's emotion branch reads log-mel); the recogniser's other outputs
    (``"logprobs"``...) are worded as ``"visemes"``."""
    head = f"warning: {path}: sampled at {file_sr} Hz, below {sample_rate} Hz: upsampled"
    top = f"{file_sr / 2000:g} kHz"
    if front_end != "logmel":  # a recogniser front end
        text = (f"{head}, so nothing above {top} is there; this model's phoneme recogniser copes with telephone-band "
                f"speech (docs/front-ends.md) but has less to go on for s, f and th, whose energy lies above {top}")
        if front_end.endswith("+logmel"):
            text += f", and the log-mel features of its emotion branch are empty above {top}"
        return text
    return (f"{head}, so the mel bands above {top} are empty; log-mel models were trained on "
            f"{sample_rate / 1000:g} kHz speech and may animate it poorly (the recogniser front-end, --features "
            f"visemes, copes with telephone audio)")


def load_audio(path: str | os.PathLike, sample_rate: int = SAMPLE_RATE, resample: bool = True,
               mono: str = "error", front_end: str = "logmel") -> np.ndarray:
    """Read a WAV/FLAC file as float32 ``(N,)`` in [-1, 1] at ``sample_rate``.

    ``mono="error"`` (default) refuses multichannel files; ``mono="mean"`` averages the channels.
    A different file rate is resampled (``resample=True``) or refused; a rate below ``sample_rate`` is upsampled
    with a one-line ``warning:`` on stderr (:func:`upsampled_warning`, worded for ``front_end``). Truncated files
    are refused: a WAV whose header promises more samples (:func:`check_wav_header`), an MP3 that decodes short of
    its length header or has none (:func:`check_mp3_length`). Every error names the file.
    """
    import soundfile as sf

    if mono not in ("error", "mean"):
        raise ValueError(f"mono must be 'error' or 'mean', got {mono!r}")
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, not an audio file; name a WAV or FLAC file")
    _refuse_special(path)
    if not path.is_file():
        raise FileNotFoundError(f"audio file not found: {path}")
    check_wav_header(path)
    mp3 = _looks_like_mp3(path)
    try:
        with _quiet_stderr(mp3), sf.SoundFile(str(path)) as f:  # mpg123 prints its own warnings on fd 2
            declared, file_sr, fmt = f.frames, f.samplerate, f.format
            check_audio_header(path, f)
            data = f.read(dtype="float32", always_2d=True)  # (N, C)
    except (sf.SoundFileError, RuntimeError) as e:  # LibsndfileError: corrupt / unsupported format
        raise ValueError(f"could not decode audio file {path} (corrupt or not WAV/FLAC?): {e}") from e
    if fmt == "MP3":
        check_mp3_length(path, declared, data.shape[0], file_sr)
    if data.shape[1] > 1:
        if mono != "mean":
            raise ValueError(f"{path} has {data.shape[1]} channels; downmix it to mono "
                             f"(e.g. `sox in.wav -c 1 out.wav`) or pass mono='mean'")
        data = data.mean(axis=1, keepdims=True)
    wave = data[:, 0]
    if wave.size == 0:
        raise ValueError(f"{path} contains no audio samples")
    if not np.isfinite(wave).all():
        raise ValueError(f"{path} contains NaN or infinite samples")
    peak = float(np.abs(wave).max())
    if peak > MAX_AMPLITUDE:
        raise ValueError(f"{path}: sample amplitudes reach {peak:.3g}, far outside [-1, 1] (a float WAV holding "
                         f"unscaled or corrupt data?); rescale it to [-1, 1]")
    if peak > 1.0:
        print(peak_warning(path, peak), file=sys.stderr)
        wave = wave / peak
    if file_sr != sample_rate:
        if not resample:
            raise ValueError(f"{path} is sampled at {file_sr} Hz, expected {sample_rate} Hz "
                             f"(pass resample=True to resample)")
        if file_sr < sample_rate:  # upsampled: everything above file_sr / 2 stays empty (one line, not an error)
            print(upsampled_warning(path, file_sr, sample_rate, front_end), file=sys.stderr)
        wave = _resample(wave, file_sr, sample_rate)
    return np.ascontiguousarray(wave, dtype=np.float32)


_resample = resample  # `load_audio` has a parameter called `resample`


def _read_blocks(f, n: int):
    """Blocks of up to ``n`` frames (float32, (n, C)) until the decoder stops: what is really there.
    (``SoundFile.blocks`` trusts the declared length: a truncated MP3's missing part came back as zeros.)"""
    while True:
        data = f.read(n, dtype="float32", always_2d=True)
        if not len(data):
            return
        yield data


class AudioStream:
    """A recording read block by block: memory flat in its length (an hour of 16 kHz float32 is 230 MB whole).

    The same checks and messages as :func:`load_audio` (mono only), made in a first pass over the file that keeps
    nothing but the peak and the length; :meth:`blocks` then reads it again and yields float32 blocks at
    ``sample_rate`` (peak-normalised like ``load_audio``; another rate resampled block by block with enough
    context on both sides for the polyphase filter, so the samples equal ``load_audio``'s up to float rounding).
    ``len(stream)`` is the number of samples at ``sample_rate``; :meth:`read` joins the blocks (the whole wave).
    ``front_end``: the model's audio front-end, for the wording of the below-16-kHz warning (:func:`upsampled_warning`).
    """

    def __init__(self, path: str | os.PathLike, sample_rate: int = SAMPLE_RATE, block_s: float = 60.0,
                 front_end: str = "logmel"):
        import soundfile as sf

        self.path, self.sample_rate = Path(path), int(sample_rate)
        path = self.path
        if path.is_dir():
            raise IsADirectoryError(f"{path}: is a folder, not an audio file; name a WAV or FLAC file")
        _refuse_special(path)
        if not path.is_file():
            raise FileNotFoundError(f"audio file not found: {path}")
        check_wav_header(path)
        self.mp3 = _looks_like_mp3(path)
        peak, decoded, finite = 0.0, 0, True
        try:
            with _quiet_stderr(self.mp3), sf.SoundFile(str(path)) as f:
                declared, self.file_sr, fmt, channels = f.frames, f.samplerate, f.format, f.channels
                check_audio_header(path, f)
                if channels > 1:
                    raise ValueError(f"{path} has {channels} channels; downmix it to mono "
                                     f"(e.g. `sox in.wav -c 1 out.wav`)")
                self.block = max(1, int(block_s * self.file_sr))
                for data in _read_blocks(f, self.block):
                    if not np.isfinite(data).all():
                        finite = False  # said after the length checks, in load_audio's order
                    elif len(data):
                        peak = max(peak, float(np.abs(data).max()))
                    decoded += len(data)
        except (sf.SoundFileError, RuntimeError) as e:
            raise ValueError(f"could not decode audio file {path} (corrupt or not WAV/FLAC?): {e}") from e
        if fmt == "MP3":
            check_mp3_length(path, declared, decoded, self.file_sr)
        if decoded == 0:
            raise ValueError(f"{path} contains no audio samples")
        if not finite:
            raise ValueError(f"{path} contains NaN or infinite samples")
        if peak > MAX_AMPLITUDE:
            raise ValueError(f"{path}: sample amplitudes reach {peak:.3g}, far outside [-1, 1] (a float WAV holding "
                             f"unscaled or corrupt data?); rescale it to [-1, 1]")
        self.peak = 1.0  # the divisor of every sample, as in load_audio
        if peak > 1.0:
            print(peak_warning(path, peak), file=sys.stderr)
            self.peak = peak
        if self.file_sr < self.sample_rate:
            print(upsampled_warning(path, self.file_sr, self.sample_rate, front_end), file=sys.stderr)
        g = math.gcd(self.file_sr, self.sample_rate)
        self.up, self.down = self.sample_rate // g, self.file_sr // g
        self.n_file = decoded
        self.n_samples = -(-decoded * self.up // self.down)  # resample_poly's output length

    def __len__(self) -> int:
        return self.n_samples

    def blocks(self):
        """Yield the wave as float32 blocks of about ``block_s`` seconds at ``sample_rate``."""
        import soundfile as sf

        with _quiet_stderr(self.mp3), sf.SoundFile(str(self.path)) as f:
            if self.up == self.down:
                for data in _read_blocks(f, self.block):
                    yield np.ascontiguousarray(data[:, 0] / self.peak if self.peak != 1.0 else data[:, 0])
                return
            # blocks of whole multiples of `down` input samples, each read with `context` samples on both sides
            # (more than the polyphase filter's half-length, 10 max(up, down) taps at the upsampled rate)
            step = self.down * max(1, self.block // self.down)
            context = self.down * (-(-(20 * max(self.up, self.down) // self.up + 64) // self.down))
            for s in range(0, self.n_file, step):
                e = min(self.n_file, s + step)
                lo, hi = max(0, s - context), min(self.n_file, e + context)
                f.seek(lo)
                piece = f.read(hi - lo, dtype="float32", always_2d=True)[:, 0]
                piece = piece / self.peak if self.peak != 1.0 else piece
                out = resample(piece, self.file_sr, self.sample_rate)
                first = (s - lo) * self.up // self.down
                keep = (e - s) * self.up // self.down if e < self.n_file else \
                    self.n_samples - s * self.up // self.down
                yield np.ascontiguousarray(out[first:first + keep], dtype=np.float32)

    def read(self) -> np.ndarray:
        """The whole wave (N,) float32 at ``sample_rate``."""
        return np.concatenate(list(self.blocks()))


def _looks_like_mp3(path: Path) -> bool:
    """An ID3v2 tag or an MPEG audio frame sync at the start of the file."""
    with open(path, "rb") as f:
        head = f.read(3)
    return head[:3] == b"ID3" or (len(head) >= 2 and head[0] == 0xFF and head[1] & 0xE0 == 0xE0)


@contextlib.contextmanager
def _quiet_stderr(active: bool):
    """Silence file descriptor 2 while libsndfile's MP3 decoder (mpg123) runs: it prints e.g. "Warning: Xing
    stream size off by more than 1%" itself, which would break the one-line rule; the problems it means are
    reported by :func:`check_mp3_length` instead."""
    try:
        saved = os.dup(2) if active else None
    except OSError:  # no file descriptor 2 at all: nothing to silence
        saved = None
    if saved is None:
        yield
        return
    if sys.stderr is not None:
        sys.stderr.flush()
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _mp3_declares_length(path: Path) -> bool:
    """Whether an MP3's first frame carries a length header: Xing/Info with its frame count, or VBRI."""
    with open(path, "rb") as f:
        head = f.read(10)
        start = 0
        if head[:3] == b"ID3" and len(head) == 10:  # ID3v2: syncsafe size, optional footer
            start = 10 + (((head[6] & 0x7F) << 21) | ((head[7] & 0x7F) << 14) | ((head[8] & 0x7F) << 7)
                          | (head[9] & 0x7F)) + (10 if head[5] & 0x10 else 0)
        f.seek(start)
        frame = f.read(64)
    if len(frame) < 40 or frame[0] != 0xFF or frame[1] & 0xE0 != 0xE0:
        return False
    for tag in (b"Xing", b"Info"):
        i = frame.find(tag, 4)
        if 0 <= i and i + 8 <= len(frame):
            return bool(frame[i + 7] & 0x01)  # flags: the frame-count field is present
    return frame[36:40] == b"VBRI"


def check_mp3_length(path: str | os.PathLike, declared: int, decoded: int, sample_rate: int) -> None:
    """Raise ValueError unless an MP3 is whole: its length header (Xing/Info/VBRI) must declare the number of
    samples, and all of them (within one MPEG frame, 1152 samples) must decode.

    libsndfile decodes whatever frames are there, so a truncated MP3 would otherwise give a shorter animation
    with exit 0. Without a length header (some streaming encoders) truncation cannot be detected, so such a file
    is refused too: convert it to WAV or FLAC (e.g. ``ffmpeg -i in.mp3 out.flac``).
    """
    path = Path(path)
    if not _mp3_declares_length(path):
        raise ValueError(f"{path}: this MP3 has no length header (Xing/Info/VBRI), so a truncated file cannot be "
                         f"detected; convert it to WAV or FLAC (e.g. ffmpeg -i in.mp3 out.flac)")
    if decoded < declared - 1152:
        raise ValueError(f"{path}: MP3 header declares {declared / sample_rate:.2f} s but only "
                         f"{decoded / sample_rate:.2f} s decode (truncated copy or download?)")


MIN_SAMPLE_RATE, MAX_SAMPLE_RATE = 4000, 384000  # Hz: telephone speech is 8 kHz, studio audio at most 384 kHz
_PCM_BITS = {"PCM_S8": 8, "PCM_U8": 8, "PCM_16": 16, "PCM_24": 24, "PCM_32": 32, "FLOAT": 32, "DOUBLE": 64,
             "ULAW": 8, "ALAW": 8}
_UNCOMPRESSED = ("WAV", "WAVEX", "W64", "RF64", "AIFF", "AU", "RAW")  # containers of samples as they are


def _refuse_special(path: Path) -> None:
    """One line for a FIFO, device or socket given as a recording (reading one would wait or never end)."""
    kind = file_kind(path)
    if kind:
        raise ValueError(f"{path}: is {kind}, not an audio file; name a WAV or FLAC file (save a stream to a file "
                         f"first)")


def peak_warning(path: str | os.PathLike, peak: float) -> str:
    """The one ``warning:`` line for a recording whose samples exceed 1 (it is peak-normalised, not refused)."""
    return f"warning: {path}: peak amplitude {peak:.3g} exceeds 1; the audio was peak-normalised to [-1, 1]"


def check_audio_header(path: str | os.PathLike, info) -> None:
    """One ValueError line unless the header of an open ``soundfile.SoundFile`` ``info`` is plausible, before a
    sample is read: a sample rate from :data:`MIN_SAMPLE_RATE` to :data:`MAX_SAMPLE_RATE` (a WAV declaring 1 Hz
    made 200 kB of samples into 27.8 hours of audio), and for uncompressed audio a length the file can hold (the
    declared frames times the bytes of a frame, at most the file's size)."""
    rate, frames, channels = info.samplerate, info.frames, info.channels
    if not MIN_SAMPLE_RATE <= rate <= MAX_SAMPLE_RATE:
        raise ValueError(f"{path}: its header declares a sample rate of {rate} Hz, outside {MIN_SAMPLE_RATE // 1000}"
                         f"-{MAX_SAMPLE_RATE // 1000} kHz (a damaged or forged header?)")
    bits = _PCM_BITS.get(info.subtype) if info.format in _UNCOMPRESSED else None  # FLAC says PCM_16 too
    size = os.path.getsize(path)
    if bits and frames * channels * bits // 8 > size:
        raise ValueError(f"{path}: its header declares {frames / rate:.1f} s of {bits}-bit audio "
                         f"({frames * channels * bits // 8:,} bytes), but the file holds {size:,} bytes (a damaged "
                         f"or forged header?)")


def check_wav_header(path: str | os.PathLike) -> None:
    """Raise ValueError if a RIFF/WAVE file's ``data`` chunk promises more bytes than the file holds.

    libsndfile silently reads what is there, so a truncated copy or download would otherwise give a
    shorter clip than the header says without a word. Non-WAV files (FLAC, ...) are left to soundfile.
    """
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(12)
        if len(head) < 12 or head[:4] != b"RIFF" or head[8:12] != b"WAVE":
            return
        block_align, pos = None, 12
        while pos + 8 <= size:
            f.seek(pos)
            chunk_id, chunk_size = struct.unpack("<4sI", f.read(8))
            if chunk_id == b"fmt ":
                fmt = f.read(min(chunk_size, 16))
                if len(fmt) >= 14:
                    block_align = struct.unpack("<H", fmt[12:14])[0]
            elif chunk_id == b"data":
                if chunk_size in (0, 0xFFFFFFFF):  # streaming writers leave the size unset
                    return
                present = size - (pos + 8)
                if chunk_size > present:
                    ba = block_align or 1
                    raise ValueError(f"{path}: WAV header promises {chunk_size // ba} sample frames but the file "
                                     f"holds only {present // ba} (truncated copy or download?)")
                return
            pos += 8 + chunk_size + (chunk_size & 1)


def validate_wave(wave: np.ndarray | torch.Tensor, sample_rate: int, expected: int = SAMPLE_RATE) -> None:
    """Raise ValueError unless ``wave`` is a non-empty, finite, 1-D (mono) signal at ``expected`` Hz."""
    if sample_rate != expected:
        raise ValueError(f"wave sampled at {sample_rate} Hz, this extractor expects {expected} Hz; "
                         f"resample it first (dualtalker_lite.audio.resample)")
    if wave.ndim != 1:
        raise ValueError(f"wave must be 1-D mono (N,), got shape {tuple(wave.shape)}; downmix stereo first")
    if wave.shape[0] == 0:
        raise ValueError("wave is empty")
    finite = torch.isfinite(wave).all() if isinstance(wave, torch.Tensor) else np.isfinite(wave).all()
    if not finite:
        raise ValueError("wave contains NaN or infinite samples")
    peak = float(wave.abs().max()) if isinstance(wave, torch.Tensor) else float(np.abs(wave).max())
    if peak > MAX_AMPLITUDE:
        raise ValueError(f"wave amplitudes reach {peak:.3g}, far outside [-1, 1]; rescale it first "
                         f"(e.g. wave / abs(wave).max())")


# ---------------------------------------------------------------------------------- log-mel
def hz_to_mel(f):
    """HTK mel scale: ``2595 log10(1 + f / 700)`` (1000 Hz -> 1000 mel)."""
    return 2595.0 * np.log10(1.0 + np.asarray(f, dtype=np.float64) / 700.0)


def mel_to_hz(m):
    """Inverse of :func:`hz_to_mel`."""
    return 700.0 * (10.0 ** (np.asarray(m, dtype=np.float64) / 2595.0) - 1.0)


def mel_filterbank(n_fft: int = N_FFT, n_mels: int = N_MELS, sample_rate: int = SAMPLE_RATE,
                   f_min: float = 0.0, f_max: float | None = 8000.0, slaney_norm: bool = False) -> torch.Tensor:
    """Triangular mel filters ``(n_mels, n_fft // 2 + 1)`` on the HTK mel scale.

    ``n_mels + 2`` points equally spaced in mel between ``f_min`` and ``f_max`` give filter m its left
    edge, centre (peak 1) and right edge; each triangle is evaluated at the FFT bin frequencies
    ``k * sample_rate / n_fft`` (torchaudio ``melscale_fbanks(mel_scale="htk")`` convention).
    ``slaney_norm=True`` scales filter m by ``2 / (f_right - f_left)`` (equal area instead of equal peak).
    """
    f_max = sample_rate / 2 if f_max is None else f_max
    if not 0 <= f_min < f_max <= sample_rate / 2:
        raise ValueError(f"need 0 <= f_min < f_max <= sample_rate/2, got f_min={f_min}, f_max={f_max}")
    freqs = np.linspace(0, sample_rate / 2, n_fft // 2 + 1)                       # (K,) bin frequencies
    edges = mel_to_hz(np.linspace(hz_to_mel(f_min), hz_to_mel(f_max), n_mels + 2))  # (M+2,)
    edges[0], edges[-1] = f_min, f_max                                              # exact, no round-off
    left, centre, right = edges[:-2, None], edges[1:-1, None], edges[2:, None]      # (M, 1) each
    up = (freqs - left) / (centre - left)                                           # rising slope
    down = (right - freqs) / (right - centre)                                       # falling slope
    fb = np.maximum(0.0, np.minimum(up, down))                                      # (M, K)
    if slaney_norm:
        fb *= 2.0 / (right - left)
    return torch.from_numpy(fb.astype(np.float32))


_FB_CACHE: dict[tuple, torch.Tensor] = {}
_WIN_CACHE: dict[int, torch.Tensor] = {}


def log_mel_spectrogram(wave: np.ndarray | torch.Tensor, sample_rate: int = SAMPLE_RATE, n_fft: int = N_FFT,
                        win_length: int = WIN_LENGTH, hop_length: int = HOP_LENGTH, n_mels: int = N_MELS,
                        f_min: float = 0.0, f_max: float | None = None, slaney_norm: bool = False) -> torch.Tensor:
    """``log(mel(|STFT|^2) + 1e-6)`` as float32 ``(1 + N // hop_length, n_mels)`` (time first).

    Hann window (periodic, ``win_length`` samples, zero-padded to ``n_fft``), ``center=True`` with zero
    padding of ``n_fft // 2`` on both sides, so frame t is centred on sample ``t * hop_length``.
    """
    validate_wave(wave, sample_rate, expected=sample_rate)
    x = torch.as_tensor(wave, dtype=torch.float32)
    if win_length not in _WIN_CACHE:
        _WIN_CACHE[win_length] = torch.hann_window(win_length)
    key = (n_fft, n_mels, sample_rate, f_min, f_max, slaney_norm)
    if key not in _FB_CACHE:
        _FB_CACHE[key] = mel_filterbank(n_fft, n_mels, sample_rate, f_min, f_max, slaney_norm)
    n_frames = 1 + x.shape[0] // hop_length
    out = torch.empty(n_frames, n_mels)                                         # (L, M)
    # Long waves (issue 11): the complex STFT of an hour is ~0.7 GB, so frames are computed in blocks of
    # STFT_BLOCK, each from its own zero-padded slice of the wave (center=True, pad_mode="constant" exactly).
    pad = n_fft // 2
    for a in range(0, n_frames, STFT_BLOCK):
        b = min(n_frames, a + STFT_BLOCK)
        lo, hi = a * hop_length - pad, (b - 1) * hop_length + pad               # samples [lo, hi) of frames a..b-1
        piece = x[max(lo, 0):min(hi, x.shape[0])]
        piece = F.pad(piece, (max(0, -lo), max(0, hi - x.shape[0])))          # zeros outside the wave
        out[a:b] = _log_mel_piece(piece, n_fft, hop_length, win_length, key)   # (b - a, M)
    return out                                                                  # (L, M)


def _log_mel_piece(piece: torch.Tensor, n_fft: int, hop_length: int, win_length: int, key: tuple) -> torch.Tensor:
    """Frames of one zero-padded slice of the wave (``center=False``) -> their log-mel (frames, M)."""
    spec = torch.stft(piece, n_fft, hop_length=hop_length, win_length=win_length,
                      window=_WIN_CACHE[win_length], center=False, return_complex=True)  # (K, frames)
    power = spec.real ** 2 + spec.imag ** 2                                     # |X|^2
    return torch.log(_FB_CACHE[key] @ power + LOG_EPS).T                       # (frames, M)


def interpolate_frames(x: torch.Tensor, n_out: int) -> torch.Tensor:
    """Linearly resample a feature sequence ``(L, d) -> (n_out, d)`` in time (``align_corners=True``)."""
    if n_out < 1:
        raise ValueError(f"n_out must be >= 1, got {n_out}")
    if x.shape[0] == n_out:
        return x
    return F.interpolate(x.T[None], size=n_out, mode="linear", align_corners=True)[0].T.contiguous()


# ------------------------------------------------------------------------------- extractors
@runtime_checkable
class FeatureExtractor(Protocol):
    """Maps a mono wave ``(N,)`` to per-mesh-frame features ``(n_frames, dim)`` float32."""

    sample_rate: int
    dim: int

    def __call__(self, wave: np.ndarray | torch.Tensor, n_frames: int) -> torch.Tensor: ...


class LogMelExtractor:
    """Log-mel A_{1:T}: ``(T, frames_per_mesh_frame * n_mels)`` = ``(T, 160)`` by default.

    ``mean``/``std`` (per band, ``(n_mels,)``) optionally standardise each band with *fixed* statistics,
    e.g. from :meth:`band_statistics` over the training split. Default: raw log-mel (no normalisation).
    ``front_end``: its name in :data:`dualtalker_lite.front_ends.FRONT_ENDS`.
    """

    front_end = "logmel"

    def __init__(self, n_mels: int = N_MELS, frames_per_mesh_frame: int = 2, fps: int = 30,
                 sample_rate: int = SAMPLE_RATE, n_fft: int = N_FFT, win_length: int = WIN_LENGTH,
                 hop_length: int = HOP_LENGTH, f_min: float = 0.0, f_max: float | None = None,
                 mean=None, std=None):
        self.n_mels, self.frames_per_mesh_frame, self.fps = n_mels, frames_per_mesh_frame, fps
        self.sample_rate, self.n_fft, self.win_length, self.hop_length = sample_rate, n_fft, win_length, hop_length
        self.f_min, self.f_max = f_min, f_max
        self.dim = frames_per_mesh_frame * n_mels
        self.mean = None if mean is None else torch.as_tensor(mean, dtype=torch.float32).reshape(n_mels)
        self.std = None if std is None else torch.as_tensor(std, dtype=torch.float32).reshape(n_mels)

    def log_mel(self, wave: np.ndarray | torch.Tensor) -> torch.Tensor:
        """The 100 Hz log-mel ``(1 + N // hop, n_mels)`` before interpolation and stacking."""
        return log_mel_spectrogram(wave, self.sample_rate, self.n_fft, self.win_length, self.hop_length,
                                   self.n_mels, self.f_min, self.f_max)

    def __call__(self, wave: np.ndarray | torch.Tensor, n_frames: int) -> torch.Tensor:
        validate_wave(wave, self.sample_rate, expected=self.sample_rate)
        return self.stream([wave], int(wave.shape[0]), n_frames)

    def stream(self, blocks, n_samples: int, n_frames: int) -> torch.Tensor:
        """The features ``(n_frames, dim)`` of a wave of ``n_samples`` given as consecutive blocks (an iterable, or
        a zero-argument callable returning one, e.g. :meth:`AudioStream.blocks` itself), holding neither the wave
        nor its 100 Hz log-mel whole: memory is the result (69 MB per hour) plus one STFT block. The same numbers
        for one block or many: the log-mel of :func:`log_mel_spectrogram` (the same STFT blocks), linearly
        interpolated (``align_corners=True``) to ``k * n_frames`` rows, output block by output block
        (:meth:`stream_rows`)."""
        out = torch.empty(self.frames_per_mesh_frame * n_frames, self.n_mels)
        for done, feats in self.stream_rows(blocks, n_samples, n_frames):
            out[done:done + len(feats)] = feats
        return out.reshape(n_frames, self.dim)                                  # (T, k * n_mels)

    def stream_rows(self, blocks, n_samples: int, n_frames: int):
        """:meth:`stream` without the result: yields ``(first, rows)``, consecutive pieces of its ``(k * n_frames,
        n_mels)`` rows before the final reshape (row-major, so their bytes in order are those of the
        ``(n_frames, dim)`` features); for writers that keep nothing whole (``streaming.SpooledFeatures``)."""
        k, hop, pad = self.frames_per_mesh_frame, self.hop_length, self.n_fft // 2
        if self.win_length not in _WIN_CACHE:
            _WIN_CACHE[self.win_length] = torch.hann_window(self.win_length)
        key = (self.n_fft, self.n_mels, self.sample_rate, self.f_min, self.f_max, False)
        if key not in _FB_CACHE:
            _FB_CACHE[key] = mel_filterbank(self.n_fft, self.n_mels, self.sample_rate, self.f_min, self.f_max)
        n_rows, n_out = 1 + n_samples // hop, k * n_frames                      # 100 Hz rows, k * fps rows
        src = torch.arange(n_out, dtype=torch.float32) * (
            torch.tensor(float(n_rows - 1)) / (n_out - 1) if n_out > 1 else torch.tensor(0.0))
        i0 = src.long().clamp(max=n_rows - 1)                                   # left neighbour of each output
        lam = (src - i0).clamp(0, 1)[:, None]
        i1 = (i0 + 1).clamp(max=n_rows - 1)
        wave, w0 = torch.empty(0), 0                    # samples [w0, w0 + len(wave)) of the wave
        rows, r0 = torch.empty(0, self.n_mels), 0       # log-mel rows [r0, r0 + len(rows))
        blocks, done = iter(blocks() if callable(blocks) else blocks), 0   # outputs written
        for a in range(0, n_rows, STFT_BLOCK):
            b = min(n_rows, a + STFT_BLOCK)
            lo, hi = a * hop - pad, (b - 1) * hop + pad                         # samples [lo, hi) of rows a..b-1
            while w0 + len(wave) < min(hi, n_samples):
                block = next(blocks, None)
                if block is None:
                    raise ValueError(f"the audio ended after {w0 + len(wave)} of {n_samples} samples")
                wave = torch.cat([wave, torch.as_tensor(np.asarray(block), dtype=torch.float32).reshape(-1)])
            piece = wave[max(lo, 0) - w0:min(hi, n_samples) - w0]
            piece = F.pad(piece, (max(0, -lo), max(0, hi - n_samples)))      # zeros outside the wave
            rows = torch.cat([rows, _log_mel_piece(piece, self.n_fft, hop, self.win_length, key)])
            keep = max(0, b * hop - pad)                                        # the next block's first sample
            wave, w0 = wave[keep - w0:], keep
            end = n_out if b == n_rows else int(torch.searchsorted(i1, b))     # outputs whose neighbours are in
            if end > done:
                feats = (1 - lam[done:end]) * rows[i0[done:end] - r0] + lam[done:end] * rows[i1[done:end] - r0]
                if self.mean is not None:
                    feats = feats - self.mean
                if self.std is not None:
                    feats = feats / self.std
                if not bool(torch.isfinite(feats).all()):
                    raise ValueError("log-mel features are not finite (audio amplitudes too large?)")
                yield done, feats                                               # (end - done, n_mels)
                done = end
            if done < n_out:
                rows, r0 = rows[int(i0[done]) - r0:], int(i0[done])

    def band_statistics(self, waves) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-band mean and std ``(n_mels,)`` of the raw log-mel pooled over ``waves`` (for ``mean``/``std``)."""
        feats = torch.cat([self.log_mel(w) for w in waves])             # (sum L, n_mels)
        return feats.mean(0), feats.std(0).clamp_min(1e-5)


class Wav2Vec2Extractor:
    """Placeholder showing how to plug in wav2vec 2.0 (FaceFormer / DualTalker's audio encoder input).

    ``model_dir`` is a *local* Hugging Face directory (``config.json`` + weights); nothing is ever
    downloaded (``local_files_only=True``). Hidden states (50 Hz) of layer ``layer`` are linearly
    interpolated to ``frames_per_mesh_frame * n_frames`` and stacked like :class:`LogMelExtractor`.
    Needs the optional ``transformers`` package. Untested with real weights in this repo.
    """

    def __init__(self, model_dir: str | os.PathLike, fps: int = 30, frames_per_mesh_frame: int = 1,
                 layer: int = -1, sample_rate: int = SAMPLE_RATE):
        model_dir = Path(model_dir)
        if not model_dir.is_dir():
            raise FileNotFoundError(f"wav2vec 2.0 model directory not found: {model_dir} "
                                    f"(a local folder with config.json and weights; nothing is downloaded)")
        try:
            from transformers import Wav2Vec2Model
        except ImportError as e:
            raise ImportError("Wav2Vec2Extractor needs the optional package 'transformers' "
                              "(pip install transformers); LogMelExtractor needs nothing extra") from e
        self.model = Wav2Vec2Model.from_pretrained(str(model_dir), local_files_only=True).eval()
        self.fps, self.frames_per_mesh_frame, self.layer, self.sample_rate = fps, frames_per_mesh_frame, layer, sample_rate
        self.dim = frames_per_mesh_frame * self.model.config.hidden_size

    @torch.no_grad()
    def __call__(self, wave: np.ndarray | torch.Tensor, n_frames: int) -> torch.Tensor:
        validate_wave(wave, self.sample_rate, expected=SAMPLE_RATE)
        x = torch.as_tensor(wave, dtype=torch.float32)
        x = (x - x.mean()) / (x.std() + 1e-7)                         # Wav2Vec2FeatureExtractor normalisation
        out = self.model(x[None], output_hidden_states=True)
        hidden = out.hidden_states[self.layer][0]                     # (L, hidden) at 50 Hz
        k = self.frames_per_mesh_frame
        return interpolate_frames(hidden.float(), k * n_frames).reshape(n_frames, self.dim)
