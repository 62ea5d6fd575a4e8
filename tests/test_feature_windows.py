"""Block-wise audio encoding for long audio (issue 23, ``blocks.feature_windows``): every model's ``generate_chunks``
equals the whole-clip encoding + reference decoding loop when the encoder windows hold the receptive field, and a
margin one frame short, or windows not aligned to the positional encoding's period, change the numbers.

Small encoder radii (6 frames) and blocks (16 frames) over ~100 frames: many windows, interior and at both edges."""
import numpy as np
import pytest
import soundfile as sf
import torch

from dualtalker_lite.audio import AudioStream, LogMelExtractor, load_audio

from dualtalker_lite.blocks.audio_encoder import AudioFeatureExtractor
from dualtalker_lite.blocks.decoder import autoregressive_reference, zero_padding
from dualtalker_lite.blocks.feature_windows import FeatureWindows, encoder_window
from dualtalker_lite.models.baselines import VocaConfig, VocaStyle
from dualtalker_lite.models.corrtalk import CorrTalk, CorrTalkConfig
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.models.emoface import EmoFace, EmoFaceConfig
from dualtalker_lite.models.faceformer import FaceFormer, FaceFormerConfig
from dualtalker_lite.streaming import SpooledFeatures, predict_chunks
from builders import grid_faces as _grid_faces, perturbed as _perturbed

V, DA, NS, NE = 20, 12, 3, 5
T, CHUNK = 100, 16

pytestmark = pytest.mark.usefixtures("one_thread")  # conftest.py


def _inputs(b=2, t=T, seed=0, pad=9):
    """Audio (B, T, D_a), template (B, V*3), speaker (B,), mask (B, T): the second clip has ``pad`` padded frames."""
    g = torch.Generator().manual_seed(seed)
    mask = torch.ones(b, t, dtype=torch.bool)
    mask[1:, t - pad:] = False
    return (torch.randn(b, t, DA, generator=g), torch.randn(b, V * 3, generator=g) * 0.1,
            torch.arange(b) % NS, mask)


def _far(a, b):
    return float((a - b).abs().amax()) > 1e-4


# ---- the helper, on the encoder alone -------------------------------------------------------------------
def _encoder():
    torch.manual_seed(0)
    return AudioFeatureExtractor(DA, 16, n_heads=2, conv_layers=2, kernel_size=5, n_layers=2, period=4,
                                 radius=3).eval()  # receptive field 2 * 2 + 2 * 3 = 10


def test_encoder_window_by_hand():
    assert encoder_window(16, 32, 100, 10, 4) == (4, 42)  # 6 rounded down to a multiple of 4
    assert encoder_window(16, 32, 100, 10, 1) == (6, 42)
    assert encoder_window(3, 95, 100, 10, 4) == (0, 100)  # clipped to the clip
    with pytest.raises(ValueError, match="margin >= 0"):
        encoder_window(0, 1, 10, -1)


@pytest.mark.parametrize("chunk,left,right", [(16, 0, 0), (7, 2, 1), (100, 0, 0)])
def test_windows_give_the_whole_clip_encoding(chunk, left, right):
    enc = _encoder()
    audio, _, _, mask = _inputs()
    audio = zero_padding(audio, mask)
    with torch.no_grad():
        whole = enc(audio, mask)  # (B, T, C)
        stream = FeatureWindows(lambda a, m: [enc(a, m)], audio, mask, enc.receptive_field(), enc.ppe.period,
                                left, right)
        for start in range(0, T, chunk):
            stop = min(T, start + chunk)
            lo, (got,) = stream.load(start, stop)
            assert lo == max(0, start - left) and got.shape[1] == min(T, stop + right) - lo
            torch.testing.assert_close(got, whole[:, lo:lo + got.shape[1]], atol=1e-5, rtol=0)
            torch.testing.assert_close(stream.frames(start, stop)[0], whole[:, start:stop], atol=1e-5, rtol=0)
        if chunk + left < T:  # the last block does not reach back to frame 0
            with pytest.raises(IndexError, match="outside the loaded block"):
                stream.frames(0, 1)
        blocks = torch.cat([f for _, (f,) in stream.blocks(chunk)], dim=1)
        torch.testing.assert_close(blocks, whole, atol=1e-5, rtol=0)


@pytest.mark.parametrize("margin,period", [(9, 4), (10, 1)])  # one frame short; windows not aligned to PPE's period
def test_a_short_margin_or_an_unaligned_window_changes_the_features(margin, period):
    enc = _encoder()
    audio, _, _, _ = _inputs()
    with torch.no_grad():
        whole = enc(audio)
        stream = FeatureWindows(lambda a, m: [enc(a, m)], audio, None, margin, period)
        got = torch.cat([f for _, (f,) in stream.blocks(CHUNK)], dim=1)
    assert _far(got, whole)


def test_no_receptive_field_encodes_the_whole_clip_once():
    calls = []

    def encode(a, m):
        calls.append(a.shape[1])
        return [a * 2]

    audio = torch.randn(1, 30, 3)
    stream = FeatureWindows(encode, audio, margin=None)
    got = torch.cat([f for _, (f,) in stream.blocks(8)], dim=1)
    assert calls == [30] and torch.equal(got, audio * 2)


# ---- every model: generate_chunks = whole-clip encoding + the reference loop ----------------------------
def _dualtalker(**kw):
    torch.manual_seed(0)
    cfg = DualTalkerConfig.tiny(n_vertices=V, audio_dim=DA, n_speakers=NS, d_model=32, d_ff=64, audio_hidden=32,
                                motion_scale=1.0, motion_dropout=0.0, audio_radius=6, period=8, **kw)
    return _perturbed(DualTalker(cfg))


def _faceformer():
    torch.manual_seed(0)
    cfg = FaceFormerConfig.tiny(n_vertices=V, audio_dim=DA, n_speakers=NS, d_model=32, d_ff=64, audio_hidden=32,
                                motion_scale=1.0, motion_dropout=0.0, audio_radius=6, period=8)
    return _perturbed(FaceFormer(cfg))


def _single_decoder_reference(model, audio, template, speaker, mask):
    """The old path: X of the whole clip, then the O(T^2) reference loop (exact: decoder_window > T)."""
    with torch.no_grad():
        audio = zero_padding(audio, mask)
        x = model.encode_audio(audio, mask)  # (B, T, d)
        return autoregressive_reference([model.decoder], [x], [model.decoder.speaker_style(speaker)], template,
                                        mask=mask)


SINGLE = {"dualtalker": lambda: _dualtalker(),  # queries from the audio: X_t (eq. 6)
          "dualtalker-centred": lambda: _dualtalker(query_from="decoder", align_window=3),  # reads X_{t+1}
          "faceformer": _faceformer}


@pytest.mark.parametrize("name", list(SINGLE))
def test_single_decoder_models_block_wise_equal_the_whole_clip(name):
    model = SINGLE[name]()
    audio, template, speaker, mask = _inputs()
    assert model.extractor.receptive_field() == 10  # two k=5 convolutions + one band of 6
    want = _single_decoder_reference(model, audio, template, speaker, mask)
    got = torch.cat(list(model.generate_chunks(audio, template, speaker, mask=mask, chunk=CHUNK)), dim=1)
    torch.testing.assert_close(got, want, atol=1e-5, rtol=0)


@pytest.mark.parametrize("name", list(SINGLE))
def test_single_decoder_models_need_the_whole_receptive_field(name, monkeypatch):
    model = SINGLE[name]()
    audio, template, speaker, mask = _inputs()
    want = _single_decoder_reference(model, audio, template, speaker, mask)
    monkeypatch.setattr(model.extractor, "receptive_field", lambda: 9)
    got = torch.cat(list(model.generate_chunks(audio, template, speaker, mask=mask, chunk=CHUNK)), dim=1)
    assert _far(got, want)


def _corrtalk(**kw):
    torch.manual_seed(0)
    cfg = CorrTalkConfig.tiny(n_vertices=V, audio_dim=DA, n_speakers=NS, d_model=32, d_ff=64, encoder_ff=64,
                              audio_hidden=32, motion_dropout=0.0, motion_scale=1.0, audio_radius=6, utterance_radius=5,
                              period=8,
                              **kw)
    return _perturbed(CorrTalk(cfg))


def _corrtalk_reference(model, audio, template, speaker, mask):
    """The old path: both branches' features of the whole clip, the reference loop, eq. 8 summed."""
    with torch.no_grad():
        audio = zero_padding(audio, mask)
        enc = model.encode_audio(audio, mask)
        decoders = [b for b in (model.strong, model.weak) if b is not None]
        feats = [enc["strong"], enc["weak"]][:len(decoders)]
        combine = lambda t, raw: model.combine(raw[0], raw[1] if len(raw) > 1 else None)[0]  # noqa: E731
        style = model.speaker_style(speaker)
        return autoregressive_reference(decoders, feats, [style] * len(decoders), template, combine, mask)


@pytest.mark.parametrize("kw", [{}, {"dual_branch": False}])
def test_corrtalk_block_wise_equals_the_whole_clip(kw):
    model = _corrtalk(**kw)
    audio, template, speaker, mask = _inputs()
    assert model.receptive_field() == 10 + 3 + 15 + 5  # front-end, then phoneme, word, utterance bands
    want = _corrtalk_reference(model, audio, template, speaker, mask)
    got = torch.cat(list(model.generate_chunks(audio, template, speaker, mask=mask, chunk=CHUNK)), dim=1)
    torch.testing.assert_close(got, want, atol=1e-5, rtol=0)


@pytest.mark.parametrize("kw", [{}, {"dual_branch": False}])
def test_corrtalk_needs_the_whole_receptive_field(kw, monkeypatch):
    # Through four stacked bands a frame at the edge of the receptive field moves the output by ~1e-9 only: float64
    # makes that visible (the block-wise result is within 1e-15 of the whole clip's there).
    model = _corrtalk(**kw).double()
    audio, template, speaker, mask = _inputs()
    audio, template = audio.double(), template.double()
    want = _corrtalk_reference(model, audio, template, speaker, mask)
    run = lambda: torch.cat(list(model.generate_chunks(audio, template, speaker, mask=mask, chunk=CHUNK)), 1)  # noqa
    torch.testing.assert_close(run(), want, atol=1e-12, rtol=0)
    monkeypatch.setattr(model, "receptive_field", lambda: 32)  # one frame short of 33
    assert float((run() - want).abs().amax()) > 1e-10


def _emoface(fusion="mesh_attention", **kw):
    torch.manual_seed(0)
    cfg = EmoFaceConfig.tiny(n_vertices=V, audio_dim=DA, n_speakers=NS, n_emotions=NE, d_model=32, d_ff=64,
                             audio_hidden=32, motion_scale=1.0, fusion=fusion, audio_radius=6, period=8, **kw)
    return _perturbed(EmoFace(cfg, faces=_grid_faces() if fusion == "mesh_attention" else None))


EMOFACE = [("mesh_attention", None, {}), ("sum", 3, {}), ("mesh_attention", None, {"content_dims": 4}),
           ("sum", None, {"emotion_layers": 2})]


@pytest.mark.parametrize("fusion,emotion,kw", EMOFACE)
def test_emoface_block_wise_equals_the_whole_clip(fusion, emotion, kw):
    model = _emoface(fusion, **kw)
    audio, template, speaker, mask = _inputs()
    rf = 10 + 6 * model.cfg.emotion_layers  # F_e: front-end + one band per emotion layer (F_c: 10)
    assert model.receptive_field() == rf
    want = model.generate(audio, template, speaker, emotion=emotion, level=2, mask=mask, use_cache=False)
    got = torch.cat(list(model.generate_chunks(audio, template, speaker, mask=mask, emotion=emotion, level=2,
                                               chunk=CHUNK)), dim=1)
    torch.testing.assert_close(got, want, atol=1e-5, rtol=0)


def test_emoface_recognises_the_same_emotion_in_a_streaming_pass():
    model = _emoface()
    audio, _, _, mask = _inputs()
    whole = model.emotion_logits(audio, mask)  # (B, N_e): F_e of the whole clip, pooled
    streamed = model.emotion_logits(audio, mask, chunk=CHUNK)
    torch.testing.assert_close(streamed, whole, atol=1e-5, rtol=0)
    assert torch.equal(streamed.argmax(-1), whole.argmax(-1))
    assert (whole.softmax(-1).amax(-1) < 0.99).all()  # a real distribution: p conditions the emotion branch


@pytest.mark.parametrize("fusion,emotion,kw", EMOFACE[:2])
def test_emoface_needs_the_whole_receptive_field(fusion, emotion, kw, monkeypatch):
    model = _emoface(fusion, **kw).double()
    audio, template, speaker, mask = _inputs()
    audio, template = audio.double(), template.double()
    run = lambda: torch.cat(list(model.generate_chunks(audio, template, speaker, mask=mask, emotion=emotion,  # noqa
                                                       chunk=CHUNK)), 1)
    want = model.generate(audio, template, speaker, emotion=emotion, mask=mask, use_cache=False)
    torch.testing.assert_close(run(), want, atol=1e-12, rtol=0)
    monkeypatch.setattr(model, "receptive_field", lambda: 15)  # one frame short of 16
    assert float((run() - want).abs().amax()) > 1e-10


def test_voca_style_block_wise_equals_forward():
    torch.manual_seed(0)
    model = _perturbed(VocaStyle(VocaConfig.tiny(n_vertices=V, n_speakers=NS, audio_dim=DA)))
    audio, template, speaker, mask = _inputs()
    want = model({"audio": audio, "template": template, "speaker": speaker, "mask": mask})["vertices"]
    got = torch.cat(list(model.generate_chunks(audio, template, speaker, mask=mask, chunk=CHUNK)), dim=1)
    torch.testing.assert_close(got, want, atol=1e-6, rtol=0)


# ---- the input features on disk (streaming.SpooledFeatures): what `animate` feeds the models ------------------
def _wav(tmp_path, seconds=4.0):
    t = np.arange(int(seconds * 16000)) / 16000
    noise = np.random.default_rng(0).standard_normal(t.size)
    wave = (0.3 * np.sin(2 * np.pi * 180 * t) * (np.sin(2 * np.pi * 3 * t) > 0) + 0.01 * noise).astype(np.float32)
    path = tmp_path / "speech.wav"
    sf.write(path, wave, 16000, subtype="PCM_16")
    return path


def test_spooled_features_read_back_the_stream(tmp_path):
    path, n = _wav(tmp_path), 120
    ex, stream = LogMelExtractor(n_mels=DA // 2), AudioStream(path)
    want = ex.stream(stream.blocks, len(stream), n)  # (T, 12) in memory
    spool = SpooledFeatures.write(ex.stream_rows(stream.blocks, len(stream), n), n, ex.dim, directory=tmp_path)
    assert list(tmp_path.iterdir()) == [path]  # the file is unlinked at creation: nothing to leave behind
    assert tuple(spool.shape) == (1, n, DA) and spool.dim() == 3 and spool.to("cpu") is spool
    assert torch.equal(spool[:, 0:n], want[None]) and torch.equal(spool[0, 17:45], want[17:45])
    assert tuple(spool[:, n - 2:n + 5].shape) == (1, 2, DA) and tuple(spool[:, 50:40].shape) == (1, 0, DA)
    with pytest.raises(IndexError, match="only"):
        spool[:, ::2]
    with pytest.raises(ValueError, match="CPU"):
        spool.to("cuda")
    with pytest.raises(ValueError, match=f"expected 121 x {DA}"):
        SpooledFeatures.write(ex.stream_rows(stream.blocks, len(stream), n), 121, ex.dim, directory=tmp_path)
    assert list(tmp_path.iterdir()) == [path]


SPOOLED = {"dualtalker": _dualtalker, "faceformer": _faceformer, "corrtalk": _corrtalk,
           "emoface (emotion recognised)": _emoface, "emoface (sum, content dims)": lambda: _emoface("sum",
                                                                                                   content_dims=4),
           "voca": lambda: _perturbed(VocaStyle(VocaConfig.tiny(n_vertices=V, n_speakers=NS, audio_dim=DA)))}


@pytest.mark.parametrize("name", list(SPOOLED))
def test_animate_from_spooled_features_equals_in_memory(tmp_path, name, monkeypatch):
    """A recording read as an AudioStream: its log-mel goes to disk and the model reads it window by window;
    the vertices are those of the in-memory wave and features, bit for bit."""
    model, path = SPOOLED[name](), _wav(tmp_path)
    ex = LogMelExtractor(n_mels=DA // 2)
    template = np.random.default_rng(1).normal(0, 0.1, V * 3).astype(np.float32)
    spooled, write = [], SpooledFeatures.write.__func__
    monkeypatch.setattr(SpooledFeatures, "write", classmethod(lambda cls, *a, **k: spooled.append(1) or
                                                                write(cls, *a, **k)))
    n, blocks = predict_chunks(model, AudioStream(path), template, 1, front_end=ex, chunk=CHUNK)
    got = np.concatenate(list(blocks))
    assert spooled == [1]
    n_mem, blocks = predict_chunks(model, load_audio(path), template, 1, front_end=ex, chunk=CHUNK)
    assert spooled == [1] and n == n_mem == 120 and got.shape == (120, V * 3)
    np.testing.assert_array_equal(got, np.concatenate(list(blocks)))
