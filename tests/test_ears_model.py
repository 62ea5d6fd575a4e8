"""The student (dualtalker_lite.ears.model), its streaming state, its distillation loop and its front end (issue 47).

What is checked, and against what: the receptive field by perturbing the future (exact); streaming against the
whole-utterance forward of the same net (any chunking, audio or features, each frame once); the log-mel stream
against ``audio.log_mel_spectrogram``; the loss against a KL written out by hand; the metrics on a hand-made
example whose answers are counted in the comments; save/load and the front end on a random student in a temp file.
"""
from __future__ import annotations

import math
import random

import numpy as np
import pytest
import torch

from dualtalker_lite import front_ends
from dualtalker_lite.ears import distil as D
from dualtalker_lite.ears.model import (SILENCE, WEIGHTS_ENV, Student, StudentConfig, StudentExtractor,
                                        StudentStream, StudentWeightsError, _LogMelStream, calibrate_student,
                                        load_student, save_student, student_features, to_mesh_rate)
from dualtalker_lite.face.visemes import VISEMES

torch.set_num_threads(1)


def _student(seed: int = 0, **overrides) -> Student:
    torch.manual_seed(seed)
    s = Student(StudentConfig.tiny(**overrides)).eval()
    with torch.no_grad():  # a non-trivial normalisation, so the stream must apply it too
        s.mean.uniform_(-8, -4)
        s.std.uniform_(1, 3)
    return s


def _wave(n: int, seed: int = 0) -> np.ndarray:
    return (0.1 * np.random.default_rng(seed).standard_normal(n)).astype(np.float32)


# ------------------------------------------------------------------------------------------------- the network
def test_sizes_and_presets():
    cfg = StudentConfig()
    n = sum(p.numel() for p in Student(cfg).parameters())
    assert n <= 300_000 and 4 * n <= 3e6  # the budget: <= ~300 k parameters, <= 3 MB in float32
    assert cfg.n_visemes == len(VISEMES) == 15 and cfg.n_mels == 80 and cfg.lookahead == 3  # 60 ms at 20 ms
    assert cfg.receptive_field == 1 + 4 * (1 + 2 + 4 + 8)
    assert StudentConfig.tiny().channels < cfg.channels and StudentConfig.tiny(lookahead=0).lookahead == 0


@pytest.mark.parametrize("lookahead", [0, 3])
def test_output_at_t_reads_no_input_after_t_plus_lookahead(lookahead):
    s = _student(lookahead=lookahead)
    x = torch.randn(2, 40, 80) - 6
    y = s(x)
    assert y.shape == (2, 40, 15)
    for t in (0, 7, 20, 39 - lookahead):
        x2 = x.clone()
        x2[:, t + lookahead + 1:] = torch.randn_like(x2[:, t + lookahead + 1:]) * 50  # the future after t + L
        assert torch.equal(s(x2)[:, :t + 1], y[:, :t + 1])  # exactly: frames <= t see no change
        x3 = x.clone()
        x3[:, t + lookahead] += 1.0  # frame t + L itself is read by y_t
        assert not torch.equal(s(x3)[:, t], y[:, t])


def test_the_end_is_padded_with_silence():
    s = _student(lookahead=3)
    x = torch.randn(1, 10, 80)
    padded = torch.cat([x, torch.full((1, 5, 80), SILENCE)], dim=1)
    torch.testing.assert_close(s(padded)[:, :10], s(x), rtol=0, atol=1e-6)  # silence after the end, as streamed


# ------------------------------------------------------------------------------------------------- streaming
def _stream_features(s: Student, x: torch.Tensor, sizes) -> tuple[torch.Tensor, StudentStream]:
    stream, outs, i = StudentStream(s), [], 0
    for n in sizes:
        before = stream.frames_computed
        outs.append(stream.push(x[i:i + n]))
        assert stream.frames_computed - before == len(x[i:i + n])  # O(chunk): only the new frames run
        i += n
    outs.append(stream.finish())
    return torch.cat(outs), stream


def _check_feature_stream(seed: int, T: int, lookahead: int, sizes: list[int]) -> None:
    s = _student(seed, lookahead=lookahead)
    x = torch.randn(T, 80) * 2 - 6
    whole = s(x[None])[0].softmax(-1)
    sizes = sizes + [T]  # the rest, if the sizes fall short
    out, stream = _stream_features(s, x, sizes)
    assert out.shape == (T, 15)
    torch.testing.assert_close(out, whole, rtol=0, atol=1e-5)
    assert stream.frames_computed == T + lookahead  # every frame once, plus the L silence frames at the end


def test_streamed_features_equal_the_whole_utterance_for_random_chunks():
    rng = random.Random(0)
    for case in range(12):
        T = rng.randint(1, 120)
        _check_feature_stream(case, T, rng.choice([0, 1, 2, 6]), [rng.randint(0, 17) for _ in range(40)])


def test_streamed_features_property():
    hypothesis = pytest.importorskip("hypothesis", reason="hypothesis is not installed")
    st = hypothesis.strategies

    @hypothesis.settings(max_examples=30, deadline=None)
    @hypothesis.given(T=st.integers(1, 90), lookahead=st.integers(0, 6),
                      sizes=st.lists(st.integers(0, 25), max_size=30))
    def prop(T, lookahead, sizes):
        _check_feature_stream(0, T, lookahead, sizes)

    prop()


def test_log_mel_stream_equals_the_whole_log_mel():
    rng = random.Random(1)
    for n in (1, 100, 255, 256, 257, 319, 320, 5000, 16000 + 37):
        w = _wave(n, n)
        mel, parts, i = _LogMelStream(), [], 0
        while i < n:
            k = rng.randint(1, 900)
            parts.append(mel.push(w[i:i + k]))
            i += k
        parts.append(mel.push(np.zeros(0, np.float32), final=True))
        torch.testing.assert_close(torch.cat(parts), student_features(w), rtol=1e-5, atol=1e-4)


def test_streamed_audio_equals_the_whole_utterance_and_counts_each_frame_once():
    s = _student(3, lookahead=4)
    w = _wave(16000 + 77)
    whole = s.posteriors(w)
    stream, parts, i, rng = StudentStream(s), [], 0, random.Random(2)
    while i < len(w):
        k = rng.randint(1, 2500)
        parts.append(stream.push_audio(w[i:i + k]))
        i += k
    parts.append(stream.finish())
    out = torch.cat(parts)
    assert out.shape == whole.shape == (1 + len(w) // 320, 15)
    torch.testing.assert_close(out, whole, rtol=0, atol=1e-5)
    assert stream.frames_computed == len(out) + 4 and stream.frames_out == len(out)


# ------------------------------------------------------------------------------------------------- distillation
def test_loss_is_the_kl_to_the_smoothed_targets():
    logits = torch.tensor([[2.0, 0.0, -1.0]])
    q = torch.tensor([[0.0, 1.0, 0.0]])
    eps = 0.3
    qs = [0.1, 0.8, 0.1]  # (1 - 0.3) * q + 0.3 / 3
    z = math.log(math.exp(2) + 1 + math.exp(-1))
    logp = [2 - z, 0 - z, -1 - z]
    expected = sum(a * (math.log(a) - b) for a, b in zip(qs, logp))
    assert D.distillation_loss(logits, q, eps).item() == pytest.approx(expected, rel=1e-6)
    assert D.distillation_loss(torch.log(torch.tensor([[0.2, 0.5, 0.3]])), torch.tensor([[0.2, 0.5, 0.3]])) \
        .item() == pytest.approx(0.0, abs=1e-6)  # a perfect student scores 0
    mask = torch.tensor([1.0, 0.0])
    two = torch.cat([logits, torch.zeros(1, 3)])
    assert D.distillation_loss(two, torch.cat([q, q]), eps, mask).item() == pytest.approx(expected, rel=1e-6)


def test_frame_weights_lean_on_the_teachers_pp_mass():
    # three frames over (sil, PP, aa): q_PP = 0, 0.5, 1; the third frame is padding (mask 0)
    q = torch.tensor([[[1.0, 0.0, 0.0], [0.25, 0.5, 0.25], [0.0, 1.0, 0.0]]])
    mask = torch.tensor([[1.0, 1.0, 0.0]])
    assert D.frame_weights(q, mask, 0.0).tolist() == [[1.0, 1.0, 0.0]]       # a plain mean
    assert D.frame_weights(q, mask, 2.0).tolist() == [[1.0, 2.0, 0.0]]       # 1 + 2 * 0.5 on the second
    # the loss with those weights is the weighted mean of the per-frame KLs, (1 * kl_0 + 2 * kl_1) / 3
    logits = torch.zeros(1, 3, 3)                                            # p = 1/3 everywhere
    kl = [math.log(3), 0.25 * math.log(0.75) + 0.5 * math.log(1.5) + 0.25 * math.log(0.75)]
    got = D.distillation_loss(logits, q, 0.0, D.frame_weights(q, mask, 2.0)).item()
    assert got == pytest.approx((kl[0] + 2 * kl[1]) / 3, rel=1e-6)


def test_metrics_on_a_hand_made_example():
    PP, sil, aa = VISEMES.index("PP"), VISEMES.index("sil"), VISEMES.index("aa")
    assert D.PP == PP == 1
    teacher = [sil, PP, PP, aa, aa, aa, aa, aa, PP, aa, aa, aa, aa, aa, aa, PP, PP, sil]  # 3 PP runs
    student = [sil, sil, sil, PP, aa, aa, aa, aa, aa, aa, aa, aa, aa, aa, aa, aa, aa, sil]
    # run 1 (frames 1-2): student PP at frame 3, 1 frame after it -> found with tolerance >= 1, not with 0
    # run 2 (frame 8): no student PP within 8 +- 3 (5..11) -> missed
    # run 3 (frames 15-16): nearest student PP is frame 3 -> missed
    # agreement: frames 0, 4-7, 9-14, 17 agree = 1 + 4 + 6 + 1 = 12 of 18
    one_hot = lambda ids: torch.nn.functional.one_hot(torch.tensor(ids), 15).float()  # noqa: E731
    s, t = one_hot(student), one_hot(teacher)
    assert D.runs_of(np.array(teacher), PP) == [(1, 3), (8, 9), (15, 17)]
    assert D.pp_recall(s, t, tolerance=3) == (1, 3)
    assert D.pp_recall(s, t, tolerance=0) == (0, 3)
    assert D.frame_agreement(s, t) == pytest.approx(12 / 18)


def _pairs(n: int = 3, T: int = 60, seed: int = 0) -> list:
    """Clips whose 'teacher' is a function of the features: PP where mel band 0 is loud, else aa or sil."""
    g = torch.Generator().manual_seed(seed)
    pairs = []
    for _ in range(n):
        x = torch.randn(T, 80, generator=g) - 6
        ids = torch.where(x[:, 0] > -5.5, 1, torch.where(x[:, 1] > -6, VISEMES.index("aa"), 0))
        pairs.append((x.numpy(), torch.nn.functional.one_hot(ids, 15).float().numpy()))
    return pairs


def test_the_loss_falls_when_overfitting_one_batch():
    torch.manual_seed(0)
    s = Student(StudentConfig.tiny(lookahead=0, dropout=0.0))
    cfg = D.DistilConfig(epochs=3, steps_per_epoch=40, batch_size=2, crop=60, lr=1e-2, warmup=5, seed=0)
    history = D.distil(s, _pairs(2), cfg, log=lambda _: None)
    assert history[-1]["loss"] < 0.5 * history[0]["loss"]
    assert history[-1]["agreement"] > history[0]["agreement"] - 1e-9
    assert set(history[0]) >= {"epoch", "loss", "agreement", "pp_recall", "pp_runs", "seconds", "cpu_seconds"}


def test_same_seed_same_result():
    runs = []
    for _ in range(2):
        torch.manual_seed(0)
        s = Student(StudentConfig.tiny())
        cfg = D.DistilConfig(epochs=2, steps_per_epoch=5, batch_size=3, crop=25, seed=7)
        h = D.distil(s, _pairs(), cfg, log=lambda _: None)
        runs.append(([r["loss"] for r in h], s.state_dict()))
    assert runs[0][0] == runs[1][0]
    for k, v in runs[0][1].items():
        assert torch.equal(v, runs[1][1][k]), k


def test_the_command_seeds_the_initial_weights_too(tmp_path):
    # the weights a command writes depend on --seed only, not on what ran before it in the process (the imports of
    # another commit drew from the global RNG: the same command then gave other weights)
    _shard(tmp_path / "shard.npz", _pairs(2, T=40))
    argv = ["--data", str(tmp_path), "--tiny", "--epochs", "1", "--steps-per-epoch", "3", "--batch-size", "2",
            "--crop", "20", "--seed", "3"]
    states = []
    for i, disturb in enumerate((0, 1000)):
        torch.rand(disturb)                                   # the global RNG left elsewhere
        assert D.main(argv + ["--out", str(tmp_path / f"w{i}.pt")]) == 0
        states.append(torch.load(tmp_path / f"w{i}.pt", weights_only=True)["state_dict"])
    for k, v in states[0].items():
        assert torch.equal(v, states[1][k]), k


def _shard(path, clips) -> None:
    """A shard in ears.dataset's format (i47-b's docs/ears.md, 'Training audio'): clips concatenated, float16."""
    np.savez(path, features=np.concatenate([x for x, _ in clips]).astype(np.float16),
             posteriors=np.concatenate([q for _, q in clips]).astype(np.float16),
             hard=np.concatenate([q.argmax(1) for _, q in clips]).astype(np.int8),
             offsets=np.cumsum([0] + [len(q) for _, q in clips]).astype(np.int64))


def test_load_pairs_reads_shards(tmp_path):
    (x, q), (x2, q2) = _pairs(2, T=9)
    q2 = np.full_like(q2, 1 / 15)  # soft rows: float16 rounds them, load_pairs renormalises
    _shard(tmp_path / "shard-00000.npz", [(x, q)])
    _shard(tmp_path / "shard-00001.npz", [(x2, q2), (x[:4], q[:4])])
    got = D.load_pairs(tmp_path)
    assert [len(p[0]) for p in got] == [9, 9, 4]
    np.testing.assert_allclose(got[0][0], x, atol=0.01)  # float16 of values around -6
    np.testing.assert_array_equal(got[0][1], q)
    np.testing.assert_allclose(got[1][1].sum(1), 1, atol=1e-6)
    with pytest.raises(ValueError, match="no training clips under"):
        D.load_pairs(tmp_path / "empty")
    np.savez(tmp_path / "other.npz", features=x)
    with pytest.raises(ValueError, match=r"other\.npz: not an ears shard \(no posteriors, offsets\)"):
        D.load_pairs(tmp_path)


# ------------------------------------------------------------------------------------------------- weights
def test_save_and_load_round_trip_with_provenance(tmp_path):
    s = _student(5)
    path = save_student(s, tmp_path / "w" / "student.pt", "python -m dualtalker_lite.ears.distil --x")
    torch.load(path, weights_only=True)  # plain tensors and values only
    again, prov = load_student(path)
    assert prov["command"].endswith("--x") and prov["commit"]
    x = torch.randn(1, 20, 80)
    assert torch.equal(again(x), s(x)) and again.cfg == s.cfg


def test_missing_or_corrupt_weights_are_one_line(tmp_path):
    with pytest.raises(StudentWeightsError, match=r"^student weights not found at .*nope\.pt: train them") as e:
        load_student(tmp_path / "nope.pt")
    assert "\n" not in str(e.value)
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a torch file")
    with pytest.raises(StudentWeightsError, match=r"corrupt or not a student's") as e:
        load_student(bad)
    assert "\n" not in str(e.value)
    torch.save({"format": 1, "config": {}, "state_dict": {"x": torch.zeros(1)}}, tmp_path / "other.pt")
    with pytest.raises(StudentWeightsError, match=r"corrupt or not a student's"):
        load_student(tmp_path / "other.pt")


def test_the_pp_bias_multiplies_pp_odds_by_exp_b_whole_and_streamed(tmp_path):
    s = _student(6)
    path = save_student(s, tmp_path / "s.pt", "train")
    out = calibrate_student(path, 0.7, tmp_path / "c.pt", "calibrate --pp-bias 0.7")
    cal, prov = load_student(out)
    assert cal.cfg.pp_bias == 0.7 and prov["pp_bias"] == 0.7 and prov["trained"]["command"] == "train"
    assert all(torch.equal(a, b) for a, b in zip(cal.state_dict().values(), s.state_dict().values()))
    wave = _wave(9000, 3)
    p, q = s.posteriors(wave).double(), cal.posteriors(wave).double()     # (T, 15) each
    pp = VISEMES.index("PP")
    # by hand: q_PP / q_k = e^0.7 p_PP / p_k for every other k; q_j / q_k = p_j / p_k when neither is PP
    assert torch.allclose((q[:, pp, None] / q) / (p[:, pp, None] / p), torch.full_like(p, math.exp(0.7)).index_fill(
        1, torch.tensor([pp]), 1.0), rtol=1e-4)
    assert torch.allclose(q[:, 0] / q[:, 3], p[:, 0] / p[:, 3], rtol=1e-4)
    stream = StudentStream(cal)
    streamed = torch.cat([stream.push_audio(wave[:4000]), stream.push_audio(wave[4000:]), stream.finish()])
    assert torch.allclose(streamed, q.float(), atol=1e-5)
    again = calibrate_student(out, 0.2, tmp_path / "d.pt", "again")                 # absolute, not added
    assert load_student(again)[0].cfg.pp_bias == 0.2 and load_student(again)[1]["trained"]["command"] == "train"
    with pytest.raises(ValueError, match=r"^pp_bias must be a finite number within \+-10, got nan$"):
        calibrate_student(path, float("nan"), tmp_path / "e.pt", "x")
    assert not (tmp_path / "e.pt").exists()


# ------------------------------------------------------------------------------------------------- front end
def test_front_end_without_weights_says_so_in_one_line(tmp_path, monkeypatch):
    monkeypatch.setenv(WEIGHTS_ENV, str(tmp_path / "missing.pt"))
    with pytest.raises(ValueError, match=r"^student weights not found at .*: train them with") as e:
        front_ends.build("student")
    assert "\n" not in str(e.value)
    assert "student" in front_ends.FRONT_ENDS and "student" not in front_ends.CHOICES
    assert front_ends.DEFAULT == "visemes"


def test_front_end_with_a_random_student(tmp_path, monkeypatch):
    path = save_student(_student(1, lookahead=2), tmp_path / "student.pt", "test")
    monkeypatch.setenv(WEIGHTS_ENV, str(path))
    ex = front_ends.build("student", fps=25)
    assert isinstance(ex, StudentExtractor) and (ex.dim, ex.fps, ex.front_end) == (15, 25, "student")
    w = _wave(16000 * 2)
    feats = ex(w, 50)
    assert feats.shape == (50, 15)
    torch.testing.assert_close(feats.sum(1), torch.ones(50))
    post = ex.student.posteriors(w)
    torch.testing.assert_close(feats[10], post[20])  # mesh frame 10 at 25 fps = 0.4 s = student frame 20
    torch.testing.assert_close(ex.stream([w[:7000], w[7000:]], len(w), 50), feats, rtol=0, atol=1e-5)
    settings = front_ends.settings("student")
    assert settings["name"] == "student" and settings["settings"]["lookahead"] == 2
    assert isinstance(front_ends.from_settings(settings), StudentExtractor)
    save_student(_student(2), path, "test")  # other weights than the checkpoint's
    with pytest.raises(ValueError, match=r"^m\.pt: trained with the student's weights"):
        front_ends.from_settings(settings, "m.pt")


def test_to_mesh_rate_interpolates_between_student_frames():
    p = torch.zeros(5, 15)
    p[:, 0] = torch.tensor([1.0, 0.0, 1.0, 0.0, 1.0])
    p[:, 1] = 1 - p[:, 0]
    out = to_mesh_rate(p, 3, fps=100)  # mesh frames at 0, 10, 20 ms = student frames 0, 0.5, 1
    torch.testing.assert_close(out[:, 0], torch.tensor([1.0, 0.5, 0.0]))
    assert to_mesh_rate(p, 40, fps=30)[-1, 0] == 1.0  # past the end: the last frame held


def test_the_distil_command_trains_and_saves_a_loadable_student(tmp_path, capsys):
    _shard(tmp_path / "shard-00000.npz", _pairs(2, T=40))
    out = tmp_path / "student.pt"
    assert D.main(["--data", str(tmp_path), "--out", str(out), "--tiny", "--epochs", "1", "--steps-per-epoch", "2",
                   "--batch-size", "2", "--crop", "20", "--lookahead", "2"]) == 0
    student, prov = load_student(out)
    assert student.cfg.lookahead == 2 and student.cfg == StudentConfig.tiny(lookahead=2)
    assert prov["command"].startswith("python -m dualtalker_lite.ears.distil --data") and "last_epoch" in prov
    assert not torch.equal(student.mean, torch.zeros(80))  # the normalisation travels with the weights
    assert "epoch 0:" in capsys.readouterr().out


def test_the_cpu_budget_stops_training():
    torch.manual_seed(0)
    cfg = D.DistilConfig(epochs=50, steps_per_epoch=3, batch_size=2, crop=20, cpu_budget_s=0.0)
    history = D.distil(Student(StudentConfig.tiny()), _pairs(2), cfg, log=lambda _: None)
    assert len(history) == 1 and history[0]["step"] == 1  # a budget of 0: one step, then it stops
