"""The notebook microphone (issue 33, item 2): ``dualtalker_lite/viz/microphone.py`` and its ``microphone.js``.

- the kernel side: the widget's bytes (float32 LE from the browser, or WAV bytes) -> a checked 16 kHz wave; bad
  audio -> one ``error: recording: ...`` line in the panel, no animation; good audio -> the notebook's animate
  function runs and its result is shown;
- the browser side, in headless chromium with a fake microphone playing a clip: the front end loaded into a
  stand-in for the widget's model (``get``/``set``/``save_changes``/``on``, what anywidget hands ``render``)
  records, resamples to 16 kHz and sends float32 bytes whose envelope follows the clip; a refused permission is
  one status line. The bytes then go through the panel as a real recording would.
"""
import io
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from dualtalker_lite.viz.microphone import ESM, MicrophonePanel, decode_recording, encode_recording

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT / "notebooks" / "data" / "real" / "agent-pass.flac"
SR = 16000


def _tone(seconds=0.5, hz=440.0, rate=SR, amp=0.5):
    t = np.arange(int(seconds * rate)) / rate
    return (amp * np.sin(2 * np.pi * hz * t)).astype(np.float32)


def _peak_hz(wave, rate=SR):
    spec = np.abs(np.fft.rfft(wave * np.hanning(len(wave))))
    return np.fft.rfftfreq(len(wave), 1 / rate)[spec.argmax()]


def test_float32_bytes_decode_to_the_same_samples():
    wave = _tone()
    data = encode_recording(wave)
    assert len(data) == 4 * len(wave) and data[:4] == np.float32(wave[0]).tobytes()   # little-endian float32
    np.testing.assert_array_equal(decode_recording(data), wave)
    np.testing.assert_array_equal(decode_recording(memoryview(data)), wave)           # what ipywidgets hands over


def test_wav_bytes_of_another_rate_and_two_channels_become_16khz_mono():
    buf = io.BytesIO()
    left = _tone(1.0, 440.0, rate=8000, amp=0.4)
    sf.write(buf, np.stack([left, np.zeros_like(left)], 1), 8000, format="WAV", subtype="FLOAT")
    wave = decode_recording(buf.getvalue())
    assert len(wave) == 16000                                   # 1 s at 16 kHz
    assert abs(_peak_hz(wave) - 440.0) < 2.0                    # the tone is still 440 Hz
    assert abs(np.abs(wave[2000:-2000]).max() - 0.2) < 0.01     # the mean of the channels: 0.4 / 2


@pytest.mark.parametrize("data, message", [
    (b"", "recording: no audio received (press Record, speak, then Stop)"),
    (encode_recording(_tone())[:-1], "recording: 31999 bytes is not a whole number of float32 samples"),
    (encode_recording(np.r_[_tone(), np.nan]), "recording: 1 of 8001 samples are NaN or infinite"),
    (encode_recording(_tone(0.1)), "recording: 0.10 s is too short (at least 0.25 s of speech)"),
    (encode_recording(_tone(12.0)), "recording: 12.0 s is longer than the 10 s this panel animates"),
    (encode_recording(np.zeros(8000, np.float32)), "recording: silent (peak 0.0e+00)"),
    (encode_recording(_tone(amp=5e3)), "recording: amplitudes reach 5e+03, far outside [-1, 1]"),
    (b"RIFF" + bytes(40), "recording: WAV bytes that cannot be decoded"),
])
def test_bad_audio_is_one_clear_line(data, message):
    with pytest.raises(ValueError) as e:
        decode_recording(data, max_seconds=10)
    assert str(e.value).startswith(message) and "\n" not in str(e.value)


def test_loud_audio_is_scaled_to_one():
    assert np.abs(decode_recording(encode_recording(_tone(amp=2.0)))).max() == pytest.approx(1.0, abs=1e-6)


def _panel(calls):
    pytest.importorskip("anywidget", reason="the microphone needs anywidget: pip install 'dualtalker-lite[notebooks]'")

    def animate(wave):
        calls.append(wave)
        return f"animation of {len(wave)} samples"

    return MicrophonePanel(animate, max_seconds=10)


def test_panel_animates_a_recording_and_reports_bad_audio_in_one_line():
    calls = []
    panel = _panel(calls)
    assert panel.recorder._esm == ESM.read_text() or Path(str(panel.recorder._esm)) == ESM
    assert panel.recorder.sample_rate == SR and panel.recorder.max_seconds == 10.0
    wave = _tone(1.0)
    panel.recorder.audio = encode_recording(wave)               # what the browser does on Stop
    assert len(calls) == 1 and np.array_equal(calls[0], wave)
    assert panel.status.value.startswith("1.0 s of speech animated in ")
    assert panel.result == "animation of 16000 samples" and panel.widget.children[-1] is panel.output  # shown
    assert panel.run(b"\x00\x00\x80") is None and len(calls) == 1      # bad audio: no animation, one line
    assert panel.status.value == ("error: recording: 3 bytes is not a whole number of float32 samples (4 bytes "
                                  "each): a truncated message")
    with pytest.raises(TypeError, match="MicrophonePanel needs animate"):
        MicrophonePanel("not a function")


def test_panel_turns_a_real_clip_into_an_animation_with_the_speech():
    """Bytes of a shipped real recording -> the recogniser's viseme track -> the rig -> a video with the audio:
    the notebook 02a path, end to end (small and short: 1 s at 64 px)."""
    pytest.importorskip("anywidget", reason="the microphone needs anywidget")
    from dualtalker_lite.audio import load_audio
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus
    from dualtalker_lite.export.visemes import rig_viseme_offsets, viseme_curves
    from dualtalker_lite.face import FaceRig
    from dualtalker_lite.viz import animate_clip

    corpus = Corpus(sample_path())
    rig = FaceRig()
    offsets = rig_viseme_offsets(rig)                           # (15, V, 3)

    def animate(wave):
        curves = viseme_curves(wave)
        verts = rig.template[None] + np.einsum("tc,cvk->tvk", curves.weights, offsets)
        return animate_clip(verts, corpus.faces, wave=wave, sample_rate=SR, size=64, renderer="raster")

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        wave = load_audio(CLIP)[:SR]
    panel = MicrophonePanel(animate)
    anim = panel.run(encode_recording(wave))
    html = anim._repr_html_()
    assert "<video" in html and panel.status.value.startswith("1.0 s of speech animated")


# ------------------------------------------------------------------------------------------------ a real browser
HARNESS = """<!doctype html><html><body><div id="w"></div><script type="module">
import widget from '/microphone.js';
const values = {sample_rate: 16000, max_seconds: %(max)s, audio: null, status: ''};
const handlers = {};
const model = {
  get: (k) => values[k],
  set: (k, v) => { values[k] = v; (handlers['change:' + k] || []).forEach((f) => f()); },
  save_changes: () => { window.saved = (window.saved || 0) + 1; },
  on: (e, f) => { (handlers[e] = handlers[e] || []).push(f); },
  off: (e, f) => { handlers[e] = (handlers[e] || []).filter((g) => g !== f); },
};
window.values = values;
widget.render({model, el: document.getElementById('w')});
window.ready = true;
</script></body></html>"""


def _chromium():
    exe = os.environ.get("DTL_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("no chromium: `apt-get install chromium` (Debian) or set DTL_CHROMIUM")
    from playwright.sync_api import sync_playwright

    return exe, sync_playwright


def _envelope(wave, rate=SR, fps=50):
    hop = rate // fps
    n = len(wave) // hop
    return np.sqrt((wave[:n * hop].reshape(n, hop) ** 2).mean(1))


def _best_lag_corr(a, b, max_lag=50):
    """Highest correlation of b with a shifted by -max_lag..max_lag frames (the fake microphone starts playing
    before the recorder runs: an unknown offset)."""
    best = -1.0
    for lag in range(-max_lag, max_lag + 1):
        x, y = (a[lag:], b) if lag >= 0 else (a, b[-lag:])
        k = min(len(x), len(y))
        if k >= 50 and x[:k].std() > 0:
            best = max(best, float(np.corrcoef(x[:k], y[:k])[0, 1]))
    return best


@pytest.mark.tools
def test_front_end_records_a_fake_microphone_in_headless_chromium(tmp_path):
    exe, sync_playwright = _chromium()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from dualtalker_lite.audio import load_audio

        clip = load_audio(CLIP)
    wav = tmp_path / "clip.wav"
    sf.write(wav, np.tile(clip, 3), SR, subtype="PCM_16")         # loops: the recorder may start mid-clip
    origin = "http://127.0.0.1:9/"                               # never contacted: every request is answered below
    files = {"": ("text/html", HARNESS % {"max": 10}), "denied": ("text/html", HARNESS % {"max": 10}),
             "microphone.js": ("text/javascript", ESM.read_text())}
    requests = []

    def serve(route):
        requests.append(route.request.url)
        name = route.request.url[len(origin):].split("?")[0]
        kind, body = files.get(name, ("text/plain", None))
        route.fulfill(status=200 if body is not None else 404, content_type=kind, body=body or "not here")

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, args=[
            "--no-sandbox", "--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream",
            f"--use-file-for-fake-audio-capture={wav}", "--autoplay-policy=no-user-gesture-required"])
        try:
            page = browser.new_page()
            page.route("**/*", serve)
            page.goto(origin)
            page.wait_for_function("() => window.ready", timeout=30000)
            page.click("button.dtl-rec")
            page.wait_for_function("() => values.status.startsWith('recording')", timeout=30000)
            page.wait_for_timeout(3000)
            page.click("button.dtl-rec")                                # stop
            page.wait_for_function("() => values.audio !== null || values.status.startsWith('cannot')",
                                   timeout=30000)
            status = page.evaluate("() => values.status")
            data = bytes(page.evaluate("() => Array.from(new Uint8Array(values.audio.buffer))"))
            shown = page.evaluate("() => document.querySelector('.dtl-status').textContent")
            denied = browser.new_page()
            denied.route("**/*", serve)
            denied.add_init_script("navigator.mediaDevices.getUserMedia = () => "
                                   "Promise.reject(new DOMException('denied', 'NotAllowedError'));")
            denied.goto(origin + "denied")
            denied.wait_for_function("() => window.ready", timeout=30000)
            denied.click("button.dtl-rec")
            denied.wait_for_function("() => values.status !== ''", timeout=30000)
            no_mic = denied.evaluate("() => [values.status, values.audio]")
        finally:
            browser.close()
    assert status.startswith("recorded ") and status.endswith(" s, sent to the kernel"), status
    assert shown == status
    wave = decode_recording(data)                                  # what the kernel receives
    assert 2.5 < len(wave) / SR < 4.0, len(wave) / SR               # about the 3 s between Record and Stop
    ref = _envelope(np.tile(clip, 3))
    corr = _best_lag_corr(_envelope(wave), ref, max_lag=len(ref))
    assert corr > 0.8, corr                                         # it is the clip, at 16 kHz
    assert no_mic == ["No microphone permission: allow the microphone for this page, then press Record again.",
                      None]
    assert requests and all(u.startswith(origin) for u in requests), requests
    calls = []
    panel = _panel(calls)
    panel.run(data)
    assert len(calls) == 1 and np.array_equal(calls[0], wave)
