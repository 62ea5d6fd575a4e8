"""The ears student's training data (issue 47, item 2): manifest, package fetching, augmentation, teacher, shards.

Nothing here downloads: the manifest is checked as a file, package handling runs on a tiny .deb built here with
``dpkg-deb -b`` (skipped without dpkg-deb), and the teacher runs on the shipped sample clips."""
from __future__ import annotations

import hashlib
import json
import math
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from dualtalker_lite.ears import augment, sources
from dualtalker_lite.face.visemes import VISEMES

try:
    from hypothesis import given, settings, strategies as st
except ImportError:                       # property tests need the test extra; the fixed-grid versions still run
    given = None

SAMPLES = Path(__file__).resolve().parents[1] / "data_samples" / "audio"
SR = 16000


# ---------------------------------------------------------------------------------------------- manifest
def test_manifest_schema_and_sources():
    m = sources.load_manifest()
    names = [s["name"] for s in m["sources"]]
    assert len(names) == len(set(names))
    kinds = {s["kind"] for s in m["sources"] if s["use"]}
    assert kinds == {"deb", "espeak", "flite"}
    for s in m["sources"]:
        assert s["licence"] and s["language"]
        if s["use"]:
            assert s["files"] > 0 and s["minutes"] > 0
        else:
            assert s["why"]
    # the packages: the three core prompt sets and their wideband versions are all listed
    packages = {s["package"] for s in m["sources"]}
    for lang in ("fr", "it", "ru"):
        assert {f"asterisk-core-sounds-{lang}-wav", f"asterisk-core-sounds-{lang}-g722"} <= packages


def test_manifest_never_names_allison():
    """The held-out benchmark voice (asterisk en/es) appears nowhere in the manifest file, in any field."""
    text = sources.MANIFEST.read_text()
    for s in json.loads(text)["sources"]:
        for value in [s.get("package", ""), *s.get("packages", []), s.get("pattern", "")]:
            assert not re.match(r"asterisk-(core-sounds|prompt)-(en|es)", value), value
            assert "en_US" not in value and "es_MX" not in value and "/en/" not in value, value
    assert not re.search(r"asterisk-(core-sounds|prompt)-(en|es)", text.split('"sources"', 1)[1])  # after "never"


@pytest.mark.parametrize("package", ["asterisk-core-sounds-en-wav", "asterisk-core-sounds-es-g722",
                                     "asterisk-prompt-es-co", "asterisk-core-sounds-en"])
def test_allison_refused(package, tmp_path):
    m = json.loads(sources.MANIFEST.read_text())
    m["sources"].append(dict(m["sources"][0], name="x", package=package))
    with pytest.raises(ValueError, match="held-out benchmark voice"):
        sources.check_manifest(m)
    with pytest.raises(sources.SourceError, match="held-out benchmark voice"):
        sources.fetch_package(package, "1", tmp_path)                 # refused before apt is asked


def test_manifest_errors_are_one_line():
    m = json.loads(sources.MANIFEST.read_text())
    bad = dict(m["sources"][0])
    del bad["licence"]
    with pytest.raises(ValueError, match=r"^manifest source 0 .*'licence' missing"):
        sources.check_manifest({**m, "sources": [bad]})
    unused = dict(m["sources"][0], use=False)
    unused.pop("why", None)
    with pytest.raises(ValueError, match="must say why"):
        sources.check_manifest({**m, "sources": [unused]})


# ---------------------------------------------------------------------------------------------- packages
needs_dpkg = pytest.mark.skipif(shutil.which("dpkg-deb") is None, reason="dpkg-deb is not installed")


def _fake_deb(tmp_path: Path, package="fake-prompts", version="1.0-1") -> tuple[Path, float]:
    """A .deb holding two 8 kHz wav prompts (0.5 s and 0.25 s) and a readme: (path, seconds of audio)."""
    import soundfile as sf

    tree = tmp_path / "tree"
    (tree / "DEBIAN").mkdir(parents=True)
    (tree / "DEBIAN" / "control").write_text(
        f"Package: {package}\nVersion: {version}\nArchitecture: all\nMaintainer: t <t@example.org>\n"
        "Description: test prompts\n")
    sounds = tree / "usr" / "share" / "sounds" / "xx"
    (sounds / "digits").mkdir(parents=True)
    sf.write(sounds / "hello.wav", np.zeros(4000, np.int16), 8000, subtype="PCM_16")
    sf.write(sounds / "digits" / "1.wav", np.zeros(2000, np.int16), 8000, subtype="PCM_16")
    (sounds / "README").write_text("not audio")
    deb = tmp_path / f"{package}_{version}_all.deb"
    subprocess.run(["dpkg-deb", "--root-owner-group", "-b", str(tree), str(deb)], check=True, capture_output=True)
    return deb, 0.75


@needs_dpkg
def test_fake_deb_fields_extract_match_verify(tmp_path):
    deb, seconds = _fake_deb(tmp_path)
    assert sources.deb_fields(deb) == {"Package": "fake-prompts", "Version": "1.0-1"}
    cache = tmp_path / "cache"
    (cache / "debs").mkdir(parents=True)
    shutil.copy(deb, cache / "debs")                                   # already downloaded: apt is not asked
    root = sources.fetch_package("fake-prompts", "1.0-1", cache)
    assert root == cache / "root" / "fake-prompts"
    files = sources.matching(root, "usr/share/sounds/xx/*.wav")
    assert [f.relative_to(root).as_posix() for f in files] == ["usr/share/sounds/xx/digits/1.wav",
                                                              "usr/share/sounds/xx/hello.wav"]
    entry = {"name": "fake", "kind": "deb", "use": True, "package": "fake-prompts", "version": "1.0-1",
             "pattern": "usr/share/sounds/xx/*.wav", "format": "wav", "language": "xx", "licence": "CC0",
             "files": 2, "minutes": seconds / 60}
    got = sources.fetch_source(entry, cache)
    assert got.minutes == pytest.approx(seconds / 60)
    sources.verify(got)
    with pytest.raises(sources.SourceError, match="^fake: 2 files, manifest says 3$"):
        sources.verify(sources.Fetched(dict(entry, files=3), got.files, "1.0-1"))
    with pytest.raises(sources.SourceError, match="version '1.0-1', manifest says '1.0-2'"):
        sources.verify(sources.Fetched(dict(entry, version="1.0-2"), got.files, "1.0-1"))
    with pytest.raises(sources.SourceError, match="minutes, manifest says"):
        sources.verify(sources.Fetched(dict(entry, minutes=1.0), got.files, "1.0-1"))
    assert sources.read_audio(files[1]).shape == (8000,)               # 0.5 s at 8 kHz -> 16 kHz


def test_apt_unreachable_is_one_line(tmp_path, monkeypatch):
    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "apt-get").write_text("#!/bin/sh\necho 'E: Failed to fetch http://deb.debian.org/x  Temporary failure "
                                  "resolving deb.debian.org' >&2\nexit 100\n")
    (fake / "apt-get").chmod(0o755)
    monkeypatch.setenv("PATH", str(fake))
    with pytest.raises(sources.SourceError) as err:
        sources.fetch_package("asterisk-core-sounds-fr-wav", "1.6.1-1", tmp_path / "cache")
    message = str(err.value)
    assert "\n" not in message and "Temporary failure resolving" in message and "apt archive reachable" in message


def test_gsm_duration_from_size(tmp_path):
    f = tmp_path / "a.gsm"
    f.write_bytes(b"\0" * 33 * 50)                                     # 50 frames of 20 ms
    assert sources.duration_s(f) == pytest.approx(1.0)


# ---------------------------------------------------------------------------------------------- augmentation
def _sine(freq, seconds=1.0, sr=SR, amp=0.3):
    return amp * np.sin(2 * np.pi * freq * np.arange(int(seconds * sr)) / sr)


def _peak_hz(x, sr=SR):
    spec = np.abs(np.fft.rfft(x * np.hanning(len(x))))
    return np.fft.rfftfreq(len(x), 1 / sr)[spec.argmax()]


def test_speed_halves_length_and_doubles_frequency():
    x = _sine(440, 1.0)
    y = augment.speed(x, 2.0)
    assert y.shape == (8000,)
    assert _peak_hz(y) == pytest.approx(880, abs=3)
    assert augment.speed(x, 0.8).shape == (20000,)


def test_vtlp_moves_a_tone_by_alpha_below_the_knee():
    assert np.array_equal(augment.vtlp(_sine(1000), 1.0), _sine(1000))
    assert _peak_hz(augment.vtlp(_sine(1000), 1.1)) == pytest.approx(1100, abs=40)
    assert augment.vtlp(_sine(1000), 0.9).shape == (SR,)


def test_pitch_shift_octave_keeps_length():
    y = augment.pitch_shift(_sine(300), 12.0)
    assert y.shape == (SR,)
    assert _peak_hz(y[2000:-2000]) == pytest.approx(600, abs=15)


def _band_energy(x, lo, hi):
    f = np.fft.rfftfreq(len(x), 1 / SR)
    p = np.abs(np.fft.rfft(x)) ** 2
    return p[(f > lo) & (f <= hi)].sum()


@pytest.mark.parametrize("band, low, high", [(augment.telephone, 300, 3400), (augment.wideband, 50, 7000)])
def test_band_limits_remove_out_of_band_energy(band, low, high):
    noise = np.random.default_rng(0).standard_normal(2 * SR) * 0.1
    out = band(noise)
    assert out.shape == noise.shape
    above = 10 * math.log10(_band_energy(out, high, SR / 2) / _band_energy(noise, high, SR / 2))
    below = 10 * math.log10(_band_energy(out, 0, low) / _band_energy(noise, 0, low))
    inside = 10 * math.log10(_band_energy(out, low + 200, high - 200) / _band_energy(noise, low + 200, high - 200))
    assert above < -40 and below < -40 and abs(inside) < 0.5


@pytest.mark.parametrize("snr", [0.0, 10.0, 25.0])
@pytest.mark.parametrize("colour", ["white", "pink"])
def test_noise_at_the_set_snr(snr, colour):
    x = _sine(200) + 0.5 * _sine(1300)
    y = augment.add_noise(x, snr, np.random.default_rng(1), colour)
    measured = 10 * math.log10(np.mean(x ** 2) / np.mean((y - x) ** 2))
    assert abs(measured - snr) < 0.5


@pytest.mark.parametrize("rt60", [0.2, 0.5, 1.0])
def test_room_impulse_response_rt60(rt60):
    """Schroeder's energy decay curve, a line fitted from -5 to -25 dB (T20), extrapolated to -60 dB."""
    h = augment.room_impulse_response(rt60, np.random.default_rng(2), length_s=1.5 * rt60)
    edc = np.cumsum((h[1:] ** 2)[::-1])[::-1]                          # the tail after the direct path
    db = 10 * np.log10(edc / edc[0])
    t = np.arange(len(db)) / SR
    sel = (db <= -5) & (db >= -25)
    slope = np.polyfit(t[sel], db[sel], 1)[0]                          # dB per second
    assert -60 / slope == pytest.approx(rt60, rel=0.1)
    assert h[0] == 1.0


def test_reverberate_keeps_length_and_level():
    x = _sine(300, 0.5)
    y = augment.reverberate(x, 0.4, np.random.default_rng(3))
    assert y.shape == x.shape
    assert augment.level_dbfs(y) == pytest.approx(augment.level_dbfs(x), abs=1e-6)


@pytest.mark.parametrize("dbfs", [-40.0, -20.0, -6.0])
def test_level_in_dbfs(dbfs):
    y = augment.set_level(_sine(500), dbfs)
    assert 20 * math.log10(np.sqrt(np.mean(y ** 2))) == pytest.approx(dbfs, abs=1e-6)
    assert augment.level_dbfs(np.ones(100)) == pytest.approx(0.0)      # a full-scale square wave
    assert augment.level_dbfs(_sine(500, amp=1.0)) == pytest.approx(-3.01, abs=0.01)


def test_same_seed_same_result():
    x = _sine(220) + 0.1 * np.random.default_rng(4).standard_normal(SR)
    runs = []
    for _ in range(2):
        rng = np.random.default_rng(7)
        aug = augment.draw(rng, {"p_room": 1.0, "p_noise": 1.0})
        runs.append((aug, *augment.apply(x, aug, rng)))
    assert runs[0][0] == runs[1][0]
    assert np.array_equal(runs[0][1], runs[1][1]) and runs[0][2] == runs[1][2] == runs[0][0].speed
    other = augment.draw(np.random.default_rng(8))
    assert other != runs[0][0]


@pytest.mark.parametrize("factor", [0.5, 0.85, 1.0, 1.15, 1.37, 2.0, 3.0])
@pytest.mark.parametrize("n", [1, 321, 16000])
def test_speed_length_grid(factor, n):
    assert augment.speed(np.ones(n), factor).shape == (round(n / factor),)


if given is not None:
    @settings(max_examples=30, deadline=None)
    @given(st.floats(0.5, 2.0), st.integers(10, 20000))
    def test_speed_length_property(factor, n):
        assert augment.speed(np.ones(n), factor).shape == (round(n / factor),)

    @settings(max_examples=20, deadline=None)
    @given(st.floats(-10.0, 40.0), st.integers(0, 2 ** 31))
    def test_snr_property(snr, seed):
        x = np.random.default_rng(seed).standard_normal(4000)
        y = augment.add_noise(x, snr, np.random.default_rng(seed + 1))
        assert 10 * math.log10(np.mean(x ** 2) / np.mean((y - x) ** 2)) == pytest.approx(snr, abs=0.5)

    @settings(max_examples=20, deadline=None)
    @given(st.floats(-60.0, -3.0), st.integers(100, 5000))
    def test_level_property(dbfs, n):
        y = augment.set_level(np.random.default_rng(n).standard_normal(n), dbfs)
        assert augment.level_dbfs(y) == pytest.approx(dbfs, abs=1e-6)


# ---------------------------------------------------------------------------------------------- teacher
def test_track_reads_the_nearest_spike_like_spike_track():
    """Random spikes: the teacher's hard track at 30 fps is recogniser.spike_track's (written independently)."""
    from dualtalker_lite.ears.teacher import TeacherTrack
    from dualtalker_lite.recogniser import spike_track

    rng = np.random.default_rng(5)
    for _ in range(20):
        times = np.sort(rng.choice(np.arange(200) / 50, size=rng.integers(0, 30), replace=False)) - 0.02
        vis = rng.integers(1, 15, size=len(times))
        post = np.full((len(times), 15), 0.01, np.float32)
        post[np.arange(len(times)), vis] = 1.0
        post /= post.sum(1, keepdims=True)
        track = TeacherTrack(times, post, 4.0, window_s=0.1)
        p, hard = track.frames(120, hop_s=1 / 30)
        assert np.array_equal(hard, spike_track(times, vis, 120, 30.0, 0.1))
        assert np.allclose(p.sum(1), 1) and np.array_equal(p.argmax(1), hard)


def test_track_on_a_faster_copy_reads_the_clean_clock():
    """A spike at 0.40 s of the clean recording is at 0.20 s in a copy played twice as fast: frame 10 at 20 ms."""
    from dualtalker_lite.ears.teacher import TeacherTrack

    post = np.zeros((1, 15), np.float32)
    post[0, VISEMES.index("PP")] = 1.0
    track = TeacherTrack(np.array([0.40]), post, 1.0, window_s=0.005)
    _, hard = track.frames(30, time_scale=2.0)
    assert np.nonzero(hard)[0].tolist() == [10] and hard[10] == VISEMES.index("PP")
    _, hard = track.frames(51)                                         # the clean copy: frame 20
    assert np.nonzero(hard)[0].tolist() == [20]


@pytest.fixture(scope="module")
def teacher():
    pytest.importorskip("hama", reason="the [phonetic] extra (hama) is not installed")
    from dualtalker_lite.ears.teacher import Teacher

    return Teacher(cache=False)


def _clip(name):
    import soundfile as sf

    wave, sr = sf.read(SAMPLES / name, dtype="float32")
    assert sr == SR
    return wave


def test_teacher_posteriors_agree_with_the_recogniser(teacher, tmp_path):
    from dualtalker_lite.ears.teacher import Teacher
    from dualtalker_lite.recogniser import RecogniserExtractor

    wave = _clip("SPK01_s00-angry1.flac")
    post, hard = teacher.frames(wave)
    assert post.shape == (1 + len(wave) // 320, 15) and hard.shape == (1 + len(wave) // 320,)
    assert post.dtype == np.float32 and np.allclose(post.sum(1), 1, atol=1e-5) and (post >= 0).all()
    assert np.array_equal(post.argmax(1), hard)
    assert (hard > 0).sum() >= 5                                       # speech: visemes other than sil
    # at the mesh rate, the hard track is the `visemes` front end's own
    n_mesh = int(len(wave) / SR * 30)
    mesh = RecogniserExtractor(recogniser=teacher.recogniser).viseme_ids(wave, n_mesh)
    _, hard_mesh = teacher.track(wave).frames(n_mesh, hop_s=1 / 30)
    assert np.array_equal(hard_mesh, mesh)
    # the sum collapse is a proper marginal too; cached tracks come back equal
    summed = Teacher(collapse="sum", recogniser=teacher.recogniser).frames(wave)[0]
    assert np.allclose(summed.sum(1), 1, atol=1e-5)
    cached = Teacher(recogniser=teacher.recogniser, cache_dir=tmp_path)
    first = cached.track(wave)
    assert len(list(tmp_path.rglob("*.npz"))) == 1
    again = cached.track(wave)
    assert np.array_equal(first.times, again.times) and np.array_equal(first.posteriors, again.posteriors)


# ---------------------------------------------------------------------------------------------- dataset
def test_build_a_tiny_dataset(teacher, tmp_path):
    from dualtalker_lite.ears import dataset

    clips = [dataset.Recording("sample", n, _clip(n)) for n in ("SPK01_s00-angry1.flac", "SPK01_s00-angry2.flac")]
    fast = {"speed": (2.0, 2.0), "vtlp": (1.0, 1.0), "semitones": (0.0, 0.0), "p_room": 0.0, "p_noise": 0.0,
            "p_telephone": 0.0, "p_wideband": 0.0}
    path = dataset.build_dataset(clips, tmp_path / "a", teacher, copies=2, seed=3, ranges=fast, shard_frames=100)
    meta = json.loads(path.read_text())
    assert [(i["recording"], i["copy"]) for i in meta["items"]] == [(0, 0), (0, 1), (1, 0), (1, 1)]
    assert meta["hop_s"] == 0.02 and meta["teacher"]["collapse"] == "max"
    shards = [dataset.load_shard(tmp_path / "a" / s["name"]) for s in meta["shards"]]
    for s, arrays in zip(meta["shards"], shards):
        assert hashlib.sha256((tmp_path / "a" / s["name"]).read_bytes()).hexdigest() == s["sha256"]
        assert arrays["offsets"][-1] == len(arrays["features"]) == len(arrays["hard"]) == s["frames"]
        assert arrays["features"].shape[1] == 80 and arrays["posteriors"].shape[1] == 15
        assert np.allclose(arrays["posteriors"].astype(np.float32).sum(1), 1, atol=1e-2)
    for clip, (clean, fast_copy) in zip(clips, zip(meta["items"][0::2], meta["items"][1::2])):
        n = len(clip.wave)
        assert clean["frames"] == 1 + n // 320 and clean["augmentation"]["speed"] == 1.0
        assert fast_copy["frames"] == 1 + round(n / 2) // 320 and fast_copy["time_scale"] == 2.0

        def arrays_of(item):
            a = shards[item["shard"]]
            lo, hi = a["offsets"][item["index"]:item["index"] + 2]
            return a["features"][lo:hi], a["hard"][lo:hi]

        feats, hard = arrays_of(clean)
        assert np.array_equal(hard, teacher.frames(clip.wave)[1])      # copy 0: the clean teacher track
        _, hard2 = arrays_of(fast_copy)
        assert np.array_equal(hard2, hard[0:2 * len(hard2):2][:len(hard2)])  # twice as fast: every other frame
    again = dataset.build_dataset(clips, tmp_path / "b", teacher, copies=2, seed=3, ranges=fast, shard_frames=100)
    assert [s["sha256"] for s in json.loads(again.read_text())["shards"]] == [s["sha256"] for s in meta["shards"]]
