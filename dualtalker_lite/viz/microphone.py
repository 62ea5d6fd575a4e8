"""Record from the browser's microphone in a notebook and animate the recording inline (issue 33, item 2).

Two parts, one per side of the notebook's connection:

* **the browser** (``microphone.js``, an `anywidget <https://anywidget.dev>`_ front end): a Record/Stop button, a
  level meter and a clock. ``getUserMedia`` + ``MediaRecorder`` record; on Stop the browser decodes the recording
  and resamples it to 16 kHz mono with an ``OfflineAudioContext`` (the browser's own resampler), and sends it to
  the kernel as float32 little-endian bytes in the widget's ``audio`` trait (one binary buffer, no base64).
  A refused permission is one status line; recordings stop at ``max_seconds``.
* **the kernel** (:class:`MicrophonePanel`): every new ``audio`` value goes through :func:`decode_recording`
  (bytes -> a checked (N,) float32 wave at 16 kHz; WAV bytes are accepted too) and then through the notebook's
  own ``animate(wave)``, whose result (e.g. :func:`~dualtalker_lite.viz.animate.animate_clip`'s video with the
  speech) is shown under the button. Bad audio (empty, truncated, silent, NaN, too short or too long) gives one
  ``error:`` line in the panel instead of an animation.

``animate`` is the notebook's: the recogniser driving the rig (notebook 02a), or a checkpoint through
:func:`~dualtalker_lite.viz.widgets.animate_recording` (``lambda w: animate_recording(w, path, "SPK01",
corpus)[0]``). :meth:`MicrophonePanel.run` does what a recording does, with bytes given in Python: a notebook run
without a microphone (nbval, CI) exercises the whole kernel side with a shipped clip.

anywidget and ipywidgets are imported when a panel is built, so importing this module needs only the core
dependencies (numpy; soundfile for WAV bytes).
"""
from __future__ import annotations

import io
import time
from pathlib import Path
from typing import Callable

import numpy as np

from ..audio import MAX_AMPLITUDE, SAMPLE_RATE, resample

__all__ = ["ESM", "decode_recording", "encode_recording", "recorder_widget", "MicrophonePanel"]

ESM = Path(__file__).with_name("microphone.js")   # the front end, shipped as package data
MIN_SECONDS = 0.25                                 # shorter is a click on Record then Stop, not speech
SILENT_PEAK = 1e-4                                 # -80 dBFS: a muted or missing microphone


def encode_recording(wave: np.ndarray) -> bytes:
    """(N,) samples -> the bytes the browser sends: float32 little-endian (what :func:`decode_recording` reads)."""
    return np.ascontiguousarray(wave, dtype="<f4").tobytes()


def decode_recording(data: bytes, max_seconds: float = 30.0, sample_rate: int = SAMPLE_RATE) -> np.ndarray:
    """The widget's bytes -> (N,) float32 wave at 16 kHz, checked; ValueError with one line otherwise.

    ``data``: float32 little-endian samples at ``sample_rate`` (what ``microphone.js`` sends), or a WAV file's
    bytes (any rate, any channel count: averaged to mono and resampled to 16 kHz). Refused: no bytes, a length
    that is not whole float32 samples, NaN/infinite samples, amplitudes beyond 1e3 (not audio), silence (peak
    below 1e-4: a muted microphone), less than 0.25 s or more than ``max_seconds``. Peaks between 1 and 1e3 are
    scaled to 1, as :func:`~dualtalker_lite.audio.load_audio` does."""
    data = bytes(data or b"")
    if not data:
        raise ValueError("recording: no audio received (press Record, speak, then Stop)")
    if data[:4] == b"RIFF":
        import soundfile as sf

        try:
            wav, rate = sf.read(io.BytesIO(data), dtype="float32", always_2d=True)       # (N, C)
        except (sf.SoundFileError, RuntimeError) as e:
            raise ValueError(f"recording: WAV bytes that cannot be decoded ({e})") from None
        wave = resample(wav.mean(axis=1), int(rate), SAMPLE_RATE) if wav.size else wav[:, 0]
    else:
        if len(data) % 4:
            raise ValueError(f"recording: {len(data)} bytes is not a whole number of float32 samples (4 bytes "
                             f"each): a truncated message")
        wave = np.frombuffer(data, dtype="<f4").astype(np.float32)
        wave = resample(wave, int(sample_rate), SAMPLE_RATE)
    seconds = len(wave) / SAMPLE_RATE
    if not np.isfinite(wave).all():
        raise ValueError(f"recording: {int((~np.isfinite(wave)).sum())} of {len(wave)} samples are NaN or infinite")
    if seconds < MIN_SECONDS:
        raise ValueError(f"recording: {seconds:.2f} s is too short (at least {MIN_SECONDS} s of speech)")
    if seconds > max_seconds:
        raise ValueError(f"recording: {seconds:.1f} s is longer than the {max_seconds:g} s this panel animates")
    peak = float(np.abs(wave).max())
    if peak > MAX_AMPLITUDE:
        raise ValueError(f"recording: amplitudes reach {peak:.3g}, far outside [-1, 1]: not audio samples")
    if peak < SILENT_PEAK:
        raise ValueError(f"recording: silent (peak {peak:.1e}): is the microphone muted or the wrong one chosen?")
    return np.ascontiguousarray(wave / peak if peak > 1.0 else wave, dtype=np.float32)


_RECORDER = None


def recorder_widget(max_seconds: float = 10.0):
    """The anywidget of ``microphone.js``: traits ``audio`` (bytes, float32 LE), ``status`` (the front end's last
    line), ``sample_rate`` (16000) and ``max_seconds``. The class is made on first use (anywidget imported then)."""
    global _RECORDER
    if _RECORDER is None:
        import anywidget
        import traitlets
        from ipywidgets.widgets.trait_types import bytes_serialization

        class MicrophoneRecorder(anywidget.AnyWidget):
            _esm = ESM
            audio = traitlets.Bytes(b"").tag(sync=True, **bytes_serialization)
            status = traitlets.Unicode("").tag(sync=True)
            sample_rate = traitlets.Int(SAMPLE_RATE).tag(sync=True)
            max_seconds = traitlets.Float(10.0).tag(sync=True)

            def __repr__(self):   # no memory address: stored notebook outputs stay the same from run to run
                return f"MicrophoneRecorder(max_seconds={self.max_seconds:g})"

        _RECORDER = MicrophoneRecorder
    return _RECORDER(max_seconds=float(max_seconds))


class MicrophonePanel:
    """Record in the browser, animate in the kernel: ``MicrophonePanel(animate).widget`` is the box to display.

    ``animate(wave)``: the notebook's function from 16 kHz speech (N,) to something ``display`` shows (an
    animation). ``panel.run(data)`` does what a finished recording does (``data``: the widget's bytes, see
    :func:`decode_recording`) and returns what ``animate`` returned, or None after bad audio (its one line is
    then in ``panel.status``; an error of ``animate`` itself is raised, not hidden)."""

    def __init__(self, animate: Callable[[np.ndarray], object], max_seconds: float = 10.0):
        import ipywidgets as widgets

        if not callable(animate):
            raise TypeError(f"MicrophonePanel needs animate(wave) -> animation, got {type(animate).__name__}")
        self.animate, self.max_seconds = animate, float(max_seconds)
        self.recorder = recorder_widget(max_seconds)
        self.status = widgets.Label(value=f"press Record and speak (up to {max_seconds:g} s)")
        self.output = widgets.Output()
        self.recorder.observe(lambda change: self.run(change["new"]), names="audio")
        self.widget = widgets.VBox([self.recorder, self.status, self.output])
        self.wave: np.ndarray | None = None                # the last recording animated, and its animation
        self.result = None

    def run(self, data: bytes):
        """Decode ``data``, animate it and show the result; see the class doc."""
        t0 = time.perf_counter()
        try:
            wave = decode_recording(data, self.max_seconds)
        except ValueError as e:
            self.status.value = f"error: {e}"
            return None
        self.status.value = f"animating {len(wave) / SAMPLE_RATE:.1f} s of speech..."
        result = self.animate(wave)
        self.wave, self.result = wave, result
        self.status.value = (f"{len(wave) / SAMPLE_RATE:.1f} s of speech animated in "
                             f"{time.perf_counter() - t0:.1f} s")
        with self.output:
            self.output.clear_output(wait=True)
            from IPython.display import display

            display(result)
        return result
