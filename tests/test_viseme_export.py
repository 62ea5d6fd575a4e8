"""``animate --format visemes`` (issue 33): the 15 standard viseme curves (viseme_sil .. viseme_U) as JSON and CSV,
coarticulated as the rig does, timed by the phoneme recogniser, and driving a differently shaped head."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dualtalker_lite.export.visemes import (CLASSES, COLUMN, NAMES, RIG_VISEME, VisemeCurves, _class_shares,
                                            apply_viseme_weights, phoneme_segments, read_visemes, retarget_offsets,
                                            rig_viseme_offsets, track_segments, viseme_weights, write_visemes)
from dualtalker_lite.face.mesh import lip_distance
from dualtalker_lite.face.rig import CONTROL_INDEX, CONTROL_NAMES, FaceRig
from dualtalker_lite.face.visemes import VISEME_PARAMS, VISEMES, coarticulate

REPO = Path(__file__).resolve().parents[1]
SCRIPT = Path(sys.executable).with_name("dualtalker-lite")
CLIP = REPO / "notebooks" / "data" / "real" / "agent-pass"
OCULUS = ("viseme_sil viseme_PP viseme_FF viseme_TH viseme_DD viseme_kk viseme_CH viseme_SS viseme_nn viseme_RR "
          "viseme_aa viseme_E viseme_I viseme_O viseme_U").split()
# "m a p a b u n" between pauses: three bilabials between open vowels, /u:/ rounded, /n/ -> viseme_nn.
PHONES = [("_", 0.0, 0.2), ("m", 0.2, 0.3), ("A:", 0.3, 0.5), ("p", 0.5, 0.58), ("A:", 0.58, 0.8), ("b", 0.8, 0.86),
          ("u:", 0.86, 1.1), ("n", 1.1, 1.2), ("_", 1.2, 1.6)]
T = 48  # 1.6 s at 30 fps


def frame(t, fps=30):
    return int(round(t * fps))


def test_the_names_are_the_oculus_set_and_every_class_has_one():
    assert list(NAMES) == OCULUS
    assert set(COLUMN) == set(CLASSES) == set(VISEMES) | {"nn"}
    assert set(COLUMN.values()) == set(NAMES)                      # every name is reached
    assert COLUMN["WW"] == COLUMN["U"] == "viseme_U" and COLUMN["KK"] == "viseme_kk" and COLUMN["nn"] == "viseme_nn"
    assert RIG_VISEME["nn"] == "DD"
    # docs/exports.md documents the mapping in a table, one row per class
    doc = (REPO / "docs" / "exports.md").read_text()
    for cls, name in COLUMN.items():
        assert f"| `{cls}` |" in doc and f"`{name}`" in doc, cls


def test_segments_by_hand():
    # espeak phones: diphthongs split as the rig does, /n l/ -> nn
    assert phoneme_segments([("m", 0, .1), ("aI", .1, .3), ("n", .3, .4)]) == [
        ("PP", 0.0, 0.1), ("aa", 0.1, 0.2), ("I", 0.2, 0.3), ("nn", 0.3, 0.4)]
    # a per-frame track at 10 fps: runs, edges half way between frames
    assert track_segments(np.array([0, 0, 1, 1, 1]), 10) == [("sil", -0.05, 0.15), ("PP", 0.15, 0.45)]
    assert track_segments(np.array([15]), 30) == [("nn", -0.5 / 30, 0.5 / 30)]


def test_csv_and_json_layout_by_hand(tmp_path):
    w = np.zeros((3, 15), np.float32)
    w[0, 0] = 1.0                                   # frame 0: silence
    w[1, 1], w[1, 10] = 0.25, 0.75                  # frame 1: a quarter PP, three quarters aa
    w[2, 14], w[2, 0] = 0.123456, 0.876544          # frame 2: U rounded to 4 decimals
    curves = VisemeCurves(w, 30.0, [("WW", 0.0, 0.05), ("sil", 0.05, 0.1)], {"route": "test"})
    js, csv = write_visemes(tmp_path, curves)
    assert (js.name, csv.name) == ("visemes.json", "visemes.csv")
    zeros = ",".join(["0.0000"] * 13)
    assert csv.read_text().splitlines() == [
        "time," + ",".join(OCULUS),
        "0.000000,1.0000," + ",".join(["0.0000"] * 14),
        "0.033333,0.0000,0.2500," + ",".join(["0.0000"] * 8) + ",0.7500,0.0000,0.0000,0.0000,0.0000",
        "0.066667,0.8765," + zeros + ",0.1235",
    ]
    doc = json.loads(js.read_text())
    assert doc["format"] == "dualtalker-lite viseme curves 1" and doc["fps"] == 30.0 and doc["n_frames"] == 3
    assert doc["names"] == OCULUS and doc["times"] == [0.0, 0.033333, 0.066667] and doc["channel"] == "lips"
    assert doc["weights"]["viseme_PP"] == [0.0, 0.25, 0.0] and doc["weights"]["viseme_U"] == [0.0, 0.0, 0.1235]
    assert doc["segments"] == [["viseme_U", 0.0, 0.05], ["viseme_sil", 0.05, 0.1]]   # WW is written as viseme_U
    assert doc["source"] == {"route": "test"}
    for path in (js, csv):                           # both read back to the same rounded numbers
        back = read_visemes(path)
        assert back.fps == 30.0 and np.allclose(back.weights, np.round(w, 4), atol=1e-6)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "temporary files left behind"


def test_bad_inputs_are_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown viseme class 'XX'"):
        viseme_weights([("XX", 0.0, 0.1)], 10)
    with pytest.raises(ValueError, match="end >= start"):
        viseme_weights([("PP", 0.2, 0.1)], 10)
    with pytest.raises(ValueError, match=r"in \[0, 1\]"):
        write_visemes(tmp_path, VisemeCurves(np.full((2, 15), 1.5, np.float32), 30.0))
    with pytest.raises(ValueError, match=r"expected shape \(T >= 1, 15\)"):
        write_visemes(tmp_path, VisemeCurves(np.zeros((2, 14), np.float32), 30.0))
    assert not list(tmp_path.iterdir())
    bad = tmp_path / "visemes.csv"
    bad.write_text("time,a,b\n0,1,2\n")
    with pytest.raises(ValueError, match=f"{bad}: not a viseme curves file"):
        read_visemes(bad)
    bad.write_text("time," + ",".join(OCULUS) + "\n0.0,1.0\n")
    with pytest.raises(ValueError, match="rows of 16 numbers"):
        read_visemes(bad)
    (tmp_path / "visemes.json").write_text("{}")
    with pytest.raises(ValueError, match="not a 'dualtalker-lite viseme curves 1' file"):
        read_visemes(tmp_path / "visemes.json")


def test_weights_sum_to_one_ramp_in_and_out_and_are_the_rigs_coarticulation():
    segments = phoneme_segments(PHONES)
    w = viseme_weights(segments, T)
    assert w.shape == (T, 15) and w.dtype == np.float32
    assert np.abs(w.sum(1) - 1).max() < 1e-5 and w.min() >= 0 and w.max() <= 1
    pp, aa = w[:, NAMES.index("viseme_PP")], w[:, NAMES.index("viseme_aa")]
    for start, end in ((0.2, 0.3), (0.5, 0.58), (0.8, 0.86)):     # each bilabial: PP dominates at its centre
        assert pp[frame((start + end) / 2)] > 0.75
    assert aa[frame(0.4)] > 0.7 and aa[frame(0.69)] > 0.6          # the vowels between them
    assert w[frame(1.0), NAMES.index("viseme_U")] > 0.8 and w[frame(1.15), NAMES.index("viseme_nn")] > 0.1
    assert w[0, 0] > 0.95 and w[-1, 0] > 0.95                       # silence at both ends
    # ramps, not switches: PP rises over >= 3 frames before /m/ (anticipation) and falls after /b/ (carry-over)
    rise = pp[frame(0.1):frame(0.25) + 1]
    assert np.all(np.diff(rise) > 0) and np.sum((rise > 0.05) & (rise < 0.7)) >= 3, rise
    fall = pp[frame(0.83):frame(1.0) + 1]
    assert np.all(np.diff(fall) < 0) and np.sum((fall > 0.05) & (fall < 0.7)) >= 2, fall
    assert np.abs(np.diff(w, axis=0)).max() < 0.45                  # no weight jumps between frames
    # the rig's own controls are exactly the weights' blend of the targets (lips and jaw channels)
    targets = np.array([[VISEME_PARAMS[RIG_VISEME[c]].target.get(n, 0.0) for n in CONTROL_NAMES] for c in CLASSES])
    controls = coarticulate([(RIG_VISEME[c], a, b) for c, a, b in segments], T)
    lips = [CONTROL_INDEX[n] for n in ("lip_press", "lip_pucker", "lip_stretch", "smile_left", "smile_right",
                                       "upper_lip_raise", "lower_lip_depress")]
    assert np.abs(_class_shares(segments, T, 30.0, "lips") @ targets - controls)[:, lips].max() < 1e-5
    jaw = CONTROL_INDEX["jaw_open"]
    assert np.abs(_class_shares(segments, T, 30.0, "jaw") @ targets - controls)[:, jaw].max() < 1e-5
    # a segment far outside the clip changes nothing (the dominance window), and one far away inside neither
    assert np.array_equal(viseme_weights(segments + [("aa", 60.0, 60.2)], T), w)


def _warp(p):
    """A differently shaped head: 30 % wider, 20 % shorter, 15 % deeper, with curved rows and a bulging middle."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    return np.stack([1.3 * x, 0.8 * y + 2.0 * x ** 2, 1.15 * z + 1.5 * y ** 2], axis=1)


def test_the_curves_drive_a_differently_shaped_head():
    rig = FaceRig()
    offsets = rig_viseme_offsets(rig)                               # the rig's 15 shapes, (15, V, 3)
    assert offsets.shape == (15,) + rig.template.shape and not offsets[0].any()
    base, toy = retarget_offsets(rig.template, offsets, _warp)
    size = np.ptp(base, axis=0) / np.ptp(rig.template, axis=0)
    assert size[0] > 1.25 and size[1] < 0.85                        # really another shape
    w = viseme_weights(phoneme_segments(PHONES), T)
    gap = lip_distance(apply_viseme_weights(w, base, toy), rig.mesh) * 1000    # mouth opening, mm, (T,)
    rest = gap[-1]
    vowels = [gap[frame(0.3):frame(0.5)].max(), gap[frame(0.58):frame(0.8)].max()]
    assert min(vowels) > 10.0 and rest < 2.0                        # measured: 14.0, 12.7 mm; rest 1.6 mm
    for start, end in ((0.2, 0.3), (0.5, 0.58), (0.8, 0.86)):       # /m p b/: the lips close between the vowels
        f = frame((start + end) / 2)
        near = gap[f - 1:f + 2].min()
        assert near < 0.2 * min(vowels) and near < 1.5 * rest, (start, near)   # measured: 1.2, 2.2, 1.7 mm
    # the same curves on the rig's own head approximate the rig's nonlinear animation (jaw arc, lip closure)
    controls = coarticulate([(RIG_VISEME[c], a, b) for c, a, b in phoneme_segments(PHONES)], T)
    controls[:, CONTROL_INDEX["lip_press"]] = np.clip(controls[:, CONTROL_INDEX["lip_press"]], 0, 1)
    own = rig.animate(controls)
    linear = apply_viseme_weights(w, rig.template, offsets)
    assert np.abs(linear - own).max() < 0.005                       # measured: 4.0 mm at most


def _run(*argv, env=None):
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg", **(env or {})}
    return subprocess.run([str(SCRIPT), *map(str, argv)], capture_output=True, text=True, env=env, timeout=300)


def test_animate_writes_viseme_curves_peaking_at_the_recordings_bilabials(tmp_path, monkeypatch):
    pytest.importorskip("hama")
    env = {"DUALTALKER_CACHE": str(tmp_path / "cache")}
    ckpt = tmp_path / "voca.pt"
    proc = _run("train", "--model", "voca", "--epochs", "1", "--clips", "16", "--out", ckpt, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = tmp_path / "out"
    proc = _run("animate", "--checkpoint", ckpt, "--wav", CLIP.with_suffix(".flac"), "--out", out,
                "--format", "npy,visemes", env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "15 viseme curves x 99 frames (30 fps)" in proc.stdout and "hama 1.7.0 phoneme recogniser" in proc.stdout
    assert sorted(p.name for p in out.iterdir()) == [".dualtalker-output.json", "frame0.obj", "vertices.npy",
                                                     "visemes.csv", "visemes.json"]
    curves = read_visemes(out / "visemes.json")
    assert len(curves.weights) == len(np.load(out / "vertices.npy")) == 99       # one row per mesh frame
    assert np.array_equal(read_visemes(out / "visemes.csv").weights, curves.weights)
    assert np.abs(curves.weights.sum(1) - 1).max() < 1e-3
    source = json.loads((out / "visemes.json").read_text())["source"]
    assert source["route"] == "recogniser" and source["name"] == "hama"
    # "Please enter your password followed by the pound key": p, p, b, p in the forced alignment
    phones = json.loads(CLIP.with_suffix(".json").read_text())["phones"]
    bilabials = [(s, e) for p, s, e in phones if p in ("p", "b", "m")]
    assert len(bilabials) == 4
    pp, t = curves["viseme_PP"], curves.times
    for s, e in bilabials:
        near = (t >= s - 0.1) & (t <= e + 0.1)
        peak = np.argmax(np.where(near, pp, -1))
        assert pp[peak] > 0.7 and abs(t[peak] - (s + e) / 2) <= 0.1, (s, e, t[peak], pp[peak])
        # measured: 0.95, 0.83, 0.81, 0.77, at 2 / 20 / 10 / 85 ms from the aligned centre
    far = np.all([(t < s - 0.15) | (t > e + 0.15) for s, e in bilabials], axis=0)
    assert pp[far].max() < 0.3                                      # measured: 0.15
    # and the vowels open: a vowel viseme has most of the weight somewhere inside /i: a A: aU/
    open_ = sum(curves[n] for n in ("viseme_aa", "viseme_E", "viseme_I", "viseme_O", "viseme_U"))
    for p, s, e in phones:
        if p in ("i:", "a", "A:", "aU"):
            assert open_[(t >= s) & (t < e)].max() > 0.6, p
    # no model needed: the same curves from the file (streamed) and from the wave in memory
    from dualtalker_lite.audio import load_audio
    from dualtalker_lite.export.visemes import viseme_curves

    monkeypatch.setenv("DUALTALKER_CACHE", str(tmp_path / "cache"))
    streamed, whole = viseme_curves(CLIP.with_suffix(".flac")), viseme_curves(load_audio(CLIP.with_suffix(".flac")))
    assert len(streamed.weights) == 99 and streamed.segments == whole.segments
    written = json.loads((out / "visemes.json").read_text())["segments"]                      # 6 decimals
    assert [[COLUMN[c], round(a, 6), round(b, 6)] for c, a, b in streamed.segments] == written
    assert np.array_equal(streamed.weights, whole.weights)
    from dualtalker_lite.audio import AudioStream                  # a stream at another rate is reopened at 16 kHz
    assert np.array_equal(viseme_curves(AudioStream(CLIP.with_suffix(".flac"), 22050), 99).weights, whole.weights)
    with pytest.raises(ValueError, match="needs 16000 Hz audio, got sample_rate=8000"):
        viseme_curves(np.zeros(8000, np.float32), sample_rate=8000)
    assert np.abs(streamed.weights - curves.weights).max() <= 5e-5 + 1e-7      # the files hold 4 decimals


def test_visemes_is_listed_in_help_and_unknown_formats_name_it(tmp_path):
    from dualtalker_lite.cli import animate_parser
    from dualtalker_lite.inference import FORMATS

    assert "visemes" in FORMATS and "visemes" in animate_parser().format_help()
    proc = _run("animate", "--checkpoint", tmp_path / "none.pt", "--wav", CLIP.with_suffix(".flac"),
                "--out", tmp_path / "o", "--format", "viseme")
    assert proc.returncode == 2 and "unknown format(s) ['viseme']" in proc.stderr and "visemes" in proc.stderr


def test_without_the_recogniser_visemes_is_refused_before_any_work(tmp_path, monkeypatch, capsys):
    import dualtalker_lite.recogniser as recogniser
    from dualtalker_lite.cli import animate_main as main

    def missing():
        raise ImportError("the phoneme recogniser front-end needs the optional package hama (pip install hama)")

    monkeypatch.setattr(recogniser, "_import_hama", missing)
    with pytest.raises(SystemExit) as e:     # the checkpoint does not even exist: refused before it is read
        main(["--checkpoint", str(tmp_path / "none.pt"), "--wav", str(CLIP.with_suffix(".flac")),
              "--out", str(tmp_path / "o"), "--format", "npy,visemes"])
    assert e.value.code == 2
    line = capsys.readouterr().err.strip().splitlines()[0]
    assert line.startswith("error: --format visemes: the viseme timing comes from the phoneme recogniser") and \
        "pip install hama" in line
    assert not (tmp_path / "o").exists()


def test_no_segments_is_silence():
    w = viseme_weights([], 5)
    assert np.array_equal(w[:, 0], np.ones(5, np.float32)) and not w[:, 1:].any()
