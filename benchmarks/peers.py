"""Peers, measured: two published audio-to-viseme tools beside this project's three paths, one yardstick (issue 47.5).

Usage (repository root):

    apt-get install -y asterisk-core-sounds-en-wav asterisk-core-sounds-en chromium   # recordings, prompt texts
    npm ci --prefix benchmarks/peers          # HeadAudio 0.1.0 (package-lock.json; node_modules is git-ignored)
    pip install -e '.[peers]'                 # pylipsync 0.2.1, pocketsphinx 5.1.1 (the alignments)
    python benchmarks/peers.py [--every 4] [--student-weights W] [--paths offline live student pylipsync headaudio]

pylipsync pins numpy < 2.4; where the project's environment has a newer numpy, give pylipsync an environment of its
own and name its python: ``DTL_PEERS_PYTHON=ENV/bin/python`` (or ``--pylipsync-python``). It runs there as a
worker process (``--pylipsync-worker IN OUT``), reading the waves and writing its weights and CPU time.

Recordings and reference: those of ``benchmarks/real_voices.py`` (imported, not copied: ``read_prompts``,
``align``): the Allison prompts of Debian's asterisk-core-sounds-en-wav (8 kHz telephone band, upsampled to 16 kHz,
the same wave for every path), phones force-aligned by pocketsphinx. ``--every k`` keeps every k-th prompt in name
order (a fixed subset, said in the results file).

Paths, each giving weights over the 15 visemes of ``face.visemes.VISEMES`` at its own frame times (the audio time
a frame describes; how much later audio it waits for is the "waits" column, not part of the metrics):

* ``offline``: hama over the whole recording, the ``visemes`` front end's class track (30 fps, one-hot).
* ``live``: ``live.stream.StreamingVisemes`` at the server's defaults (``LiveSettings``: 0.25 s look-ahead, 2 s past,
  0.2 s hops), fed 0.1 s pieces as ``benchmarks/live.py`` does (30 fps, one-hot).
* ``student``: ``ears.model.load_student`` posteriors on the whole wave (20 ms frames; streamed is the same numbers).
* ``pylipsync`` (PyPI 0.2.1, a uLipSync port): its defaults (64 ms window, 60 fps, cosine similarity to its five
  Japanese vowel templates A E I O U and silence, volume-weighted). Its recordings are ``A_female ... U_female``, so
  aa -> aa, ee -> E, ih -> I, oh -> O, ou -> U, silence -> sil. It has no PP: its recall is 0 by construction.
* ``headaudio`` (npm ``@met4citizen/headaudio`` 0.1.0): its AudioWorklet in headless Chromium, an
  OfflineAudioContext at 16 kHz per recording, its shipped model and default parameters (VAD gate -40/-50 dB, no
  silence calibration). Two rows: the classifier's viseme per MFCC vector (stamped at the vector's centre, ``t``),
  and the blend-shape values a page shows, the library's own ``update(dt)`` easing replayed at 100 Hz from those
  events. Oculus -> project: ``viseme_X`` -> X for the 13 shared names, ``kk`` -> KK, ``nn`` -> DD (the project
  puts /n l/ on DD); no WW.

Weights -> a distribution per frame (:func:`fill_neutral`): what the weights leave of 1 goes to sil (a blend-shape
at rest is the neutral mouth), then rows are scaled to sum 1. Every path is read on a 10 ms grid (linear in time
between its frames). Metrics (:func:`score`): /p b m/ recall = fraction of aligned bilabials with PP the largest
at some grid frame within the phone +- 33 ms; vowel PP = fraction of grid frames inside aligned vowels with PP
largest, and the same over vowel frames > 50 ms from any /p b m/ ("far"); openness r = Pearson of ``1 - sil - PP``
with the reference (vowel 1, /p b m/ 0, silence 0, other consonants 0.5) per clip, mean over clips; lag = the
shift (ms, -100..300 in 10 ms steps) of the path's curve that maximises that mean (positive: the path is late).
CPU s per s of audio: ``time.process_time`` of the path's own computation in its process (one torch thread; the
features included, loading excluded). HeadAudio: the CPU time (utime + stime, /proc) of every Chromium process
while rendering all recordings, joined by 0.5 s gaps, in one OfflineAudioContext with its node, minus the same
without it (source to destination): the worklet's cost (a JS call per 128-sample quantum, MFCC, classifier, its
messages), not the browser's; the per-recording renders, each also setting up a context, the worklet module and
the model, are reported beside it.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PEERS = ROOT / "benchmarks" / "peers"
VISEMES = ('sil', 'PP', 'FF', 'TH', 'DD', 'KK', 'CH', 'SS', 'RR', 'WW', 'aa', 'E', 'I', 'O', 'U')  # face.visemes
SIL, PP = 0, 1
GRID_S = 0.01
TOLERANCE_S = 0.033
FAR_S = 0.05
LAGS_MS = tuple(range(-100, 301, 10))
BILABIALS = ("p", "b", "m", "m-")                     # metrics.BILABIALS
OCULUS = ('viseme_aa', 'viseme_E', 'viseme_I', 'viseme_O', 'viseme_U', 'viseme_PP', 'viseme_SS', 'viseme_TH',
          'viseme_DD', 'viseme_FF', 'viseme_kk', 'viseme_nn', 'viseme_RR', 'viseme_CH', 'viseme_sil')  # its order
OCULUS_TO_VISEME = {"viseme_kk": "KK", "viseme_nn": "DD", **{o: o[7:] for o in OCULUS if o[7:] in VISEMES}}
PYLIPSYNC_TO_VISEME = {"aa": "aa", "ee": "E", "ih": "I", "oh": "O", "ou": "U", "silence": "sil"}
PATHS = ("offline", "live", "student", "pylipsync", "headaudio")


# ------------------------------------------------------------------------------------------- metrics (pure numpy)
def fill_neutral(weights: np.ndarray) -> np.ndarray:
    """(T, 15) non-negative weights -> (T, 15) rows summing to 1: what they leave of 1 is added to sil, then each
    row is divided by its sum (rows already summing to 1 are unchanged)."""
    w = np.clip(np.asarray(weights, dtype=np.float64), 0, None).copy()
    if w.ndim != 2 or w.shape[1] != len(VISEMES):
        raise ValueError(f"weights must be (T, {len(VISEMES)}), got {w.shape}")
    w[:, SIL] += np.clip(1.0 - w.sum(1), 0, None)
    return w / w.sum(1, keepdims=True)


def to_grid(times: np.ndarray, weights: np.ndarray, duration_s: float) -> np.ndarray:
    """Weights at their frame ``times`` (s, increasing) -> (n, 15) on the grid k x 10 ms, k < duration / 10 ms,
    linear in time between frames (held before the first and after the last)."""
    n = int(np.ceil(duration_s / GRID_S - 1e-9))
    grid = np.arange(n) * GRID_S
    w = np.asarray(weights, dtype=np.float64)
    return np.stack([np.interp(grid, times, w[:, j]) for j in range(w.shape[1])], axis=1)


def _phone_at(segments, n: int) -> list:
    """The aligned phone at each grid frame (None outside every segment); a segment [a, b) holds k x 10 ms."""
    out = [None] * n
    for p, a, b in segments:
        for k in range(max(0, int(np.ceil(a / GRID_S - 1e-9))), min(n, int(np.ceil(b / GRID_S - 1e-9)))):
            out[k] = p
    return out


def openness_reference(segments, n: int, vowels) -> np.ndarray:
    """(n,) reference openness on the grid: vowel 1, /p b m/ 0, silence ("_" or no phone) 0, other phones 0.5."""
    return np.array([0.0 if p is None or p == "_" or p in BILABIALS else 1.0 if p in vowels else 0.5
                     for p in _phone_at(segments, n)])


def bilabial_hits(p: np.ndarray, segments) -> list[bool]:
    """Per aligned /p b m/: is PP the largest viseme of ``p`` (n, 15) at a grid frame within [a - 33 ms, b + 33 ms]?"""
    pp = p.argmax(1) == PP
    hits = []
    for ph, a, b in segments:
        if ph in BILABIALS:
            lo = max(0, int(np.ceil((a - TOLERANCE_S) / GRID_S - 1e-9)))
            hi = min(len(pp) - 1, int(np.floor((b + TOLERANCE_S) / GRID_S + 1e-9)))
            hits.append(bool(pp[lo:hi + 1].any()))
    return hits


def vowel_pp_counts(p: np.ndarray, segments, vowels) -> tuple[int, int, int, int]:
    """(vowel frames with PP largest, vowel frames, the same two over vowel frames > 50 ms from any /p b m/)."""
    phones = _phone_at(segments, len(p))
    t = np.arange(len(p)) * GRID_S
    bil = [(a, b) for ph, a, b in segments if ph in BILABIALS]
    near = np.zeros(len(p), bool)
    for a, b in bil:
        near |= (t >= a - FAR_S - 1e-9) & (t <= b + FAR_S + 1e-9)       # exactly 50 ms away: near
    vowel = np.array([ph in vowels for ph in phones], bool)
    pp = p.argmax(1) == PP
    return int((pp & vowel).sum()), int(vowel.sum()), int((pp & vowel & ~near).sum()), int((vowel & ~near).sum())


def openness(p: np.ndarray) -> np.ndarray:
    """1 - sil - PP per frame of a distribution (n, 15)."""
    return 1.0 - p[:, SIL] - p[:, PP]


def pearson(x: np.ndarray, y: np.ndarray) -> float:
    """Pearson correlation; NaN when either is constant."""
    x, y = np.asarray(x, float) - np.mean(x), np.asarray(y, float) - np.mean(y)
    d = np.sqrt((x * x).sum() * (y * y).sum())
    return float((x * y).sum() / d) if d > 1e-12 else float("nan")


def shifted_correlation(curves, refs, lag_ms: int) -> float:
    """Mean over clips of pearson(curve[k + lag], ref[k]) over the frames both have (a late curve: lag > 0)."""
    s = int(round(lag_ms / (GRID_S * 1000)))
    rs = []
    for c, r in zip(curves, refs):
        c2, r2 = (c[s:], r[:len(r) - s]) if s >= 0 else (c[:len(c) + s], r[-s:])
        m = min(len(c2), len(r2))
        rs.append(pearson(c2[:m], r2[:m]) if m >= 2 else float("nan"))
    return float(np.nanmean(rs)) if np.isfinite(rs).any() else float("nan")


def best_lag(curves, refs, lags_ms=LAGS_MS) -> tuple[int, float]:
    """(lag in ms, mean correlation there): the shift of the curves that maximises :func:`shifted_correlation`
    (a tie goes to the smaller shift; (0, NaN) when no shift gives a number)."""
    best = (0, float("nan"))
    for lag in sorted(lags_ms, key=lambda x: (abs(x), x)):
        r = shifted_correlation(curves, refs, lag)
        if np.isfinite(r) and not r <= best[1]:
            best = (int(lag), r)
    return best


def score(grids, segments, vowels) -> dict:
    """The metrics of one path: ``grids`` = per clip (n, 15) distributions on the grid, ``segments`` the aligned
    phones [[phone, start_s, end_s]] per clip."""
    hits = [h for p, s in zip(grids, segments) for h in bilabial_hits(p, s)]
    counts = np.sum([vowel_pp_counts(p, s, vowels) for p, s in zip(grids, segments)], axis=0)
    curves = [openness(p) for p in grids]
    refs = [openness_reference(s, len(p), vowels) for p, s in zip(grids, segments)]
    lag, r_lag = best_lag(curves, refs)
    return {"pp_recall": float(np.mean(hits)) if hits else float("nan"), "n_bilabials": len(hits),
            "vowel_pp": counts[0] / max(counts[1], 1), "n_vowel_frames": int(counts[1]),
            "vowel_pp_far": counts[2] / max(counts[3], 1), "n_vowel_frames_far": int(counts[3]),
            "far_share_of_vowel_pp": counts[2] / counts[0] if counts[0] else float("nan"),
            "openness_r": shifted_correlation(curves, refs, 0), "lag_ms": lag, "openness_r_at_lag": r_lag}


# ------------------------------------------------------------------------------------------- this project's paths
def one_hot(ids: np.ndarray) -> np.ndarray:
    return np.eye(len(VISEMES))[np.asarray(ids, dtype=np.int64)]


def run_offline(waves) -> tuple[list, float]:
    """hama over each whole wave, the ``visemes`` front end's class track -> ([(times, weights)], CPU s)."""
    from dualtalker_lite.recogniser import PhonemeRecogniser, RecogniserExtractor

    ex = RecogniserExtractor("visemes", recogniser=PhonemeRecogniser(cache=False, threads=1))
    out, cpu = [], 0.0
    for w in waves:
        n = max(1, int(round(len(w) * ex.fps / 16000)))
        c0 = time.process_time()
        ids = ex.viseme_ids(w, n)
        cpu += time.process_time() - c0
        out.append((np.arange(n) / ex.fps, one_hot(ids)))
    return out, cpu


def run_live(waves, piece: int = 1600) -> tuple[list, float]:
    """The live server's track (``StreamingVisemes`` at ``LiveSettings``' defaults), fed ``piece`` samples at a
    time, then flushed."""
    from dualtalker_lite.live.stream import LiveSettings, StreamingVisemes, new_extractor

    s = LiveSettings(ears="hama")
    out, cpu = [], 0.0
    for w in waves:
        ex = new_extractor()
        c0 = time.process_time()
        track = StreamingVisemes(ex, s.lookahead_s, s.past_s, s.hop_s)
        ids = np.concatenate([track.push(w[i:i + piece]) for i in range(0, len(w), piece)] + [track.flush()])
        cpu += time.process_time() - c0
        out.append((np.arange(len(ids)) / ex.fps, one_hot(ids)))
    return out, cpu


def run_student(waves, weights: Path) -> tuple[list, float, dict]:
    """The student's posteriors on each whole wave (frame t at 20 ms x t) -> (tracks, CPU s, its provenance)."""
    import torch

    from dualtalker_lite.ears.model import load_student

    student, prov = load_student(weights)
    out, cpu = [], 0.0
    with torch.no_grad():
        for w in waves:
            c0 = time.process_time()
            p = student.posteriors(w).numpy()
            cpu += time.process_time() - c0
            out.append((np.arange(len(p)) * 0.02, p))
    import hashlib

    digest = hashlib.sha256(Path(weights).read_bytes()).hexdigest()[:16]
    shown = Path(weights).resolve()
    shown = shown.relative_to(ROOT) if shown.is_relative_to(ROOT) else Path(weights).name   # no machine's path
    trained = prov.get("trained", prov)           # a calibrated file keeps its training's provenance there
    return out, cpu, {"weights": str(shown), "sha256": digest, "lookahead_frames": student.cfg.lookahead,
                      "pp_bias": student.cfg.pp_bias, "trained_by": trained.get("command"),
                      "trained_at_commit": trained.get("commit")}


# ------------------------------------------------------------------------------------------- pylipsync
def pylipsync_worker(src: str, dst: str) -> None:
    """In pylipsync's environment: the waves of ``src`` (npz, 16 kHz) -> ``dst`` (npz: per clip its frame times and
    (T, 15) weights, and the CPU seconds of the analysis; one second of noise first, not counted: librosa's JIT)."""
    from pylipsync import PhonemeAnalyzer

    data = np.load(src)
    analyzer = PhonemeAnalyzer()
    analyzer.extract_phoneme_segments(np.random.default_rng(0).normal(0, 0.1, 16000).astype(np.float32), 16000)
    out, cpu = {}, 0.0
    for key in sorted(data.files, key=int):
        w = data[key]
        c0 = time.process_time()
        segs = analyzer.extract_phoneme_segments(w, 16000)
        cpu += time.process_time() - c0
        weights = np.zeros((len(segs), len(VISEMES)))
        for i, seg in enumerate(segs):
            for ph in seg.phonemes:
                weights[i, VISEMES.index(PYLIPSYNC_TO_VISEME[ph.name])] += ph.target
        out[f"t{key}"] = np.array([(s.start + s.end) / 2 / 16000 for s in segs])  # the window's centre
        out[f"w{key}"] = weights
    from importlib.metadata import version

    np.savez(dst, cpu=cpu, version=version("pylipsync"), **out)


def run_pylipsync(waves, python: str) -> tuple[list, float, str]:
    """:func:`pylipsync_worker` in ``python``'s environment -> (tracks, CPU s, its version)."""
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(src, **{str(i): w for i, w in enumerate(waves)})
        subprocess.run([python, str(Path(__file__).resolve()), "--pylipsync-worker", str(src), str(dst)], check=True,
                       env={**os.environ, "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"})
        d = np.load(dst)
        return [(d[f"t{i}"], d[f"w{i}"]) for i in range(len(waves))], float(d["cpu"]), str(d["version"])


# ------------------------------------------------------------------------------------------- HeadAudio (Chromium)
def _tree_cpu() -> float:
    """CPU seconds (utime + stime) of every process descended from this one (the playwright driver, Chromium)."""
    tick, parent, cpu = os.sysconf("SC_CLK_TCK"), {}, {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            parent[int(d.name)], cpu[int(d.name)] = int(fields[1]), (int(fields[11]) + int(fields[12])) / tick
    mine, total = {os.getpid()}, 0.0
    changed = True                                   # a child may have a smaller pid: grow to a fixed point
    while changed:
        new = {p for p, pp in parent.items() if pp in mine and p not in mine}
        mine |= new
        changed = bool(new)
    for p in mine - {os.getpid()}:
        total += cpu[p]
    return total


def _serve(folder: Path):
    """A loopback HTTP server of ``folder`` in a thread (module scripts need http, not file://) -> (server, url)."""
    import functools
    import http.server
    import threading

    class Quiet(http.server.SimpleHTTPRequestHandler):
        extensions_map = {**http.server.SimpleHTTPRequestHandler.extensions_map, ".mjs": "text/javascript"}

        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(folder)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, f"http://127.0.0.1:{server.server_address[1]}/"


def headaudio_classes(messages, n: int) -> np.ndarray:
    """HeadAudio's classifier per grid frame: the last viseme event at or before it ("ended": silence)."""
    events = sorted((m["t"], SIL if m["event"] == "ended" else VISEMES.index(OCULUS_TO_VISEME[OCULUS[m["viseme"]]]))
                    for m in messages if m["event"] == "ended" or (m["event"] == "viseme" and m["viseme"] is not None))
    ids = np.full(n, SIL)
    times = np.array([t for t, _ in events])
    for k in range(n):
        i = int(np.searchsorted(times, k * GRID_S + 1e-9)) - 1
        ids[k] = events[i][1] if i >= 0 else SIL
    return one_hot(ids)


def _render_cpu(page, urls: list[str], with_node: bool) -> tuple[list, float]:
    """Render each url (float32 16 kHz samples) in the page -> (its results, CPU seconds of the browser)."""
    c0 = _tree_cpu()
    runs = [page.evaluate("([u, w]) => render(u, w)", [u, with_node]) for u in urls]
    return runs, _tree_cpu() - c0


def run_headaudio(waves, chromium: str) -> tuple[dict, float, dict]:
    """Each wave through HeadAudio in headless Chromium, an OfflineAudioContext per recording -> ({"values":
    tracks, "classes": tracks}, CPU s, facts). CPU: every recording in one render (0.5 s of silence between
    them), with the node minus without, the second of two such pairs (so one set-up, not one per recording); the
    per-recording renders' CPU (set-up of a context, its worklet module and its model each time) is in the facts."""
    from playwright.sync_api import sync_playwright

    out = {"values": [], "classes": []}
    gap = np.zeros(8000, np.float32)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "node_modules").symlink_to(PEERS / "node_modules")
        (folder / "index.html").write_text((PEERS / "headaudio.html").read_text())
        for i, w in enumerate(waves):
            np.asarray(w, dtype="<f4").tofile(folder / f"{i}.f32")
        np.concatenate([x for w in waves for x in (np.asarray(w, np.float32), gap)]).astype("<f4").tofile(
            folder / "all.f32")
        server, url = _serve(folder)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium, args=["--no-sandbox", "--disable-gpu"])
            page = browser.new_page()
            page.goto(url + "index.html")
            page.wait_for_function("window.ready === true")
            urls = [f"{url}{i}.f32" for i in range(len(waves))]
            _, plain_each = _render_cpu(page, urls, False)
            runs, node_each = _render_cpu(page, urls, True)
            for i, (w, run) in enumerate(zip(waves, runs)):
                msgs = [{**m, "t": m["t"] - (0.016 if m["event"] == "ended" else 0.0)} for m in run["messages"]]
                n = int(np.ceil(len(w) / 16000 / GRID_S - 1e-9))
                rep = page.evaluate("([m, n, fps]) => replay(m, n, fps)", [msgs, n, round(1 / GRID_S)])
                values = np.zeros((n, len(VISEMES)))
                for j, name in enumerate(rep["names"]):
                    values[:, VISEMES.index(OCULUS_TO_VISEME[name])] += np.array(rep["values"])[:, j]
                out["values"].append((np.arange(n) * GRID_S, values))
                out["classes"].append((np.arange(n) * GRID_S, headaudio_classes(msgs, n)))
            whole = {}
            for with_node in (False, True, False, True):
                whole[with_node] = _render_cpu(page, [f"{url}all.f32"], with_node)[1]
            version = page.evaluate("navigator.userAgent")
            browser.close()
        server.shutdown()
    return out, whole[True] - whole[False], {
        "user_agent": version, "cpu_whole_with_node_s": whole[True], "cpu_whole_plain_s": whole[False],
        "cpu_each_with_node_s": node_each, "cpu_each_plain_s": plain_each,
        "whole_s": sum(len(w) + len(gap) for w in waves) / 16000}


# ------------------------------------------------------------------------------------------- the run
ROWS = {  # row key -> (label, algorithmic wait for future audio)
    "offline": ("this project, offline (hama over the whole recording, `visemes` front end)", "whole recording"),
    "live": ("this project, live (hama windowed as the live server, 0.25 s look-ahead)", None),
    "student": ("this project, student (causal net, `ears`)", None),
    "pylipsync": ("pylipsync (uLipSync port, vowels only)", "32 ms"),
    "offline_curves": ("this project, offline, as the viseme curves it exports (`animate --format visemes`)",
                       "whole recording"),
    "live_curves": ("this project, live, as viseme curves (the live page's second head)", None),
    "student_curves": ("this project, student, as viseme curves", None),
    "headaudio_values": ("HeadAudio, blend-shape values (its update loop)", "24 ms + easing"),
    "headaudio_classes": ("HeadAudio, classifier's viseme per vector", "24 ms"),
}


def load_clips(every: int, limit: int | None) -> tuple[list[dict], set, list[str], int]:
    """Every ``every``-th usable prompt of ``benchmarks/real_voices.py`` (name order) with its aligned phones ->
    (clips, the vowel phones, prompts whose alignment failed, usable prompts in all)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import real_voices as rv

    clips, failed, prompts = [], [], rv.read_prompts()
    for p in prompts[::every][:limit]:
        segs = rv.align(p["wave"], p["words"])
        if segs is None:
            failed.append(p["name"])
        else:
            clips.append({"name": p["name"], "wave": p["wave"], "segments": segs})
    return clips, set(rv.VOWELS), failed, len(prompts)


def default_student() -> Path:
    own = ROOT / "dualtalker_lite" / "ears" / "weights" / "student.pt"
    return own if own.is_file() else ROOT / "runs" / "ears" / "student_la3.pt"


def as_curves(times: np.ndarray, weights: np.ndarray, fps: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """A path's track -> the 15 standard viseme curves this project exports for other avatars
    (``export.visemes.viseme_weights`` of the class track's runs: the rig's dominance functions, coarticulated),
    at ``fps``, in :data:`VISEMES` order (``viseme_nn``, /n l/, folded into DD; WW has no column: 0). The class
    track at the mesh rate is the argmax of the path's weights interpolated at the frame times (a hard track
    stays itself), as ``animate`` and the live page do."""
    from dualtalker_lite.export.visemes import COLUMN, NAMES, track_segments, viseme_weights

    n = max(1, int(round((times[-1] + (times[1] - times[0] if len(times) > 1 else 0)) * fps)))
    at = np.arange(n) / fps
    w = np.stack([np.interp(at, times, weights[:, k]) for k in range(weights.shape[1])], 1)     # (n, 15)
    curves = viseme_weights(track_segments(w.argmax(1), fps), n, fps)                        # (n, 15) NAMES order
    owner = {**{COLUMN[v]: v for v in VISEMES if v != "WW"}, "viseme_nn": "DD"}    # WW's column is U's
    out = np.zeros((n, len(VISEMES)))
    for j, name in enumerate(NAMES):
        out[:, VISEMES.index(owner[name])] += curves[:, j]
    return at, out


def run_paths(args, waves) -> tuple[dict, dict, dict]:
    """Every chosen path -> ({row: tracks}, {row: CPU s}, extra facts)."""
    import torch

    torch.set_num_threads(1)
    tracks, cpu, info = {}, {}, {}
    for path in args.paths:
        t0 = time.time()
        if path == "offline":
            tracks[path], cpu[path] = run_offline(waves)
        elif path == "live":
            tracks[path], cpu[path] = run_live(waves)
        elif path == "student":
            tracks[path], cpu[path], info["student"] = run_student(waves, args.student_weights)
        elif path == "pylipsync":
            tracks[path], cpu[path], info["pylipsync_version"] = run_pylipsync(waves, args.pylipsync_python)
        else:
            both, c, info["headaudio"] = run_headaudio(waves, args.chromium)
            for kind in ("values", "classes"):
                tracks[f"headaudio_{kind}"], cpu[f"headaudio_{kind}"] = both[kind], c
        if path in ("offline", "live", "student"):                  # what an avatar is driven with
            c0 = time.process_time()
            tracks[f"{path}_curves"] = [as_curves(t, w) for t, w in tracks[path]]
            cpu[f"{path}_curves"] = cpu[path] + time.process_time() - c0
        print(f"{path}: {time.time() - t0:.0f} s wall", flush=True)
    return tracks, cpu, info


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--every", type=int, default=1, help="every k-th usable prompt, in name order (default: all)")
    ap.add_argument("--limit", type=int, default=None, help="at most N prompts (smoke runs)")
    ap.add_argument("--paths", nargs="+", default=list(PATHS), choices=PATHS)
    ap.add_argument("--student-weights", type=Path, default=default_student())
    ap.add_argument("--pylipsync-python", default=os.environ.get("DTL_PEERS_PYTHON", sys.executable))
    ap.add_argument("--chromium", default=os.environ.get("DTL_CHROMIUM") or shutil.which("chromium")
                    or shutil.which("chromium-browser"))
    ap.add_argument("--no-report", action="store_true", help="print, do not write results/ (smoke runs)")
    ap.add_argument("--pylipsync-worker", nargs=2, metavar=("IN", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.pylipsync_worker:
        return pylipsync_worker(*args.pylipsync_worker)
    if args.every < 1:
        raise SystemExit(f"--every must be >= 1, got {args.every}")
    if "headaudio" in args.paths and not (PEERS / "node_modules" / "@met4citizen" / "headaudio").is_dir():
        raise SystemExit("HeadAudio missing: npm ci --prefix benchmarks/peers")
    if "headaudio" in args.paths and not args.chromium:
        raise SystemExit("no chromium: apt-get install chromium, or set DTL_CHROMIUM")
    if "student" in args.paths and not args.student_weights.is_file():
        raise SystemExit(f"student weights not found at {args.student_weights}: give --student-weights")
    sys.path.insert(0, str(ROOT))
    clips, vowels, failed, usable = load_clips(args.every, args.limit)
    waves = [c["wave"] for c in clips]
    seconds = sum(len(w) for w in waves) / 16000
    print(f"{len(clips)} prompts ({len(failed)} alignments failed), {seconds / 60:.1f} min", flush=True)
    stamp = _stamp(argv if argv is not None else sys.argv[1:])     # the code measured: stamped before the run
    tracks, cpu, info = run_paths(args, waves)
    segments = [c["segments"] for c in clips]
    results = {}
    for row, tr in tracks.items():
        grids = [fill_neutral(to_grid(t, w, len(x) / 16000)) for (t, w), x in zip(tr, waves)]
        results[row] = {**score(grids, segments, vowels), "cpu_s_per_s": cpu[row] / seconds}
        print(row, json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in results[row].items()}),
              flush=True)
    meta = {"clips": [c["name"] for c in clips], "failed_alignments": failed, "minutes": seconds / 60,
            "every": args.every, "usable_prompts": usable, "info": info}
    if args.no_report:
        return
    write_report(results, meta, stamp)


def _f(v, digits: int = 2) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v:.{digits}f}"


def _stamp(argv: list[str]) -> dict:
    """The command and the commit (``provenance``), taken when the run starts: a commit made while it runs is not
    the code it measured."""
    from dualtalker_lite.provenance import provenance

    env = " ".join(f"{k}={os.environ[k]}" for k in ("PYTHONPATH", "DTL_PEERS_PYTHON") if os.environ.get(k))
    return provenance((env + " " if env else "") + "python benchmarks/peers.py " + shlex.join(argv))


def write_report(results: dict, meta: dict, stamp: dict) -> None:
    """results/peers.json and results/peers.md."""
    from dualtalker_lite.files import atomic_write_text
    from dualtalker_lite.provenance import machine_line

    meta = {"command": stamp["command"], "commit": stamp["commit"], "machine": stamp["machine"],
            "date": time.strftime("%Y-%m-%d"), **meta}
    atomic_write_text(ROOT / "results" / "peers.json", json.dumps({"meta": meta, "rows": results}, indent=1))
    student = meta["info"].get("student", {})
    waits = {k: w for k, (_, w) in ROWS.items()}
    from dualtalker_lite.live.stream import LiveSettings

    waits["live"] = waits["live_curves"] = f"{LiveSettings(ears='hama').latency_s() * 1000:.0f} ms"
    if student:
        waits["student"] = waits["student_curves"] = f"{student['lookahead_frames'] * 20 + 16} ms"
    any_row = next(iter(results.values()))
    lines = ["# Peers, measured (issue 47, item 5)", "",
             f"Made by `{meta['command']}` ({meta['date']}, commit {meta['commit']}; {machine_line(meta['machine'])})"
             "; `benchmarks/peers.py` says how each path runs and how each figure is computed. Recordings: "
             f"{len(meta['clips'])} Allison prompts (" + ("all the usable prompts" if meta["every"] == 1 else
                                                   f"every k-th, k = {meta['every']}, of the "
                                                   f"{meta['usable_prompts']} usable prompts") +
             " of `benchmarks/real_voices.py`, in name order; one professional US voice, 8 kHz "
             f"telephone band), {meta['minutes']:.1f} min, {any_row['n_bilabials']} /p b m/, "
             f"{any_row['n_vowel_frames']} vowel frames of 10 ms ({any_row['n_vowel_frames_far']} of them > 50 ms "
             "from any /p b m/), phones force-aligned by pocketsphinx 5.1.1.", "",
             "| path | /p b m/ recall | vowel frames PP | vowel frames PP, far | openness r | lag ms | r at lag "
             "| CPU s per s | waits for |", "|---|---|---|---|---|---|---|---|---|"]
    for row, r in results.items():
        lines.append(f"| {ROWS[row][0]} | {_f(r['pp_recall'])} | {_f(r['vowel_pp'], 3)} | {_f(r['vowel_pp_far'], 3)} "
                     f"| {_f(r['openness_r'])} | {r['lag_ms']} | {_f(r['openness_r_at_lag'])} "
                     f"| {_f(r['cpu_s_per_s'], 4)} | {waits[row]} |")
    lines += ["", "Columns: /p b m/ recall = PP the largest viseme at some 10 ms frame within the aligned phone "
              "+- 33 ms; vowel frames PP = frames inside aligned vowels with PP largest (far: only those > 50 ms "
              "from any /p b m/); openness r = Pearson of 1 - sil - PP with the aligned openness (vowel 1, /p b m/ "
              "0, silence 0, other consonants 0.5), per clip, mean; lag = the shift of the path's curve (-100..300 "
              "ms) that maximises it (positive: late), r at lag = the mean there; CPU s per s = process time of the "
              "path's own computation per second of audio (HeadAudio: Chromium's CPU with its worklet minus "
              "without, see the script); waits for = future audio a frame needs (the algorithmic latency, not in "
              "the metrics: every path is scored at the audio time its frames describe)."]
    if student:
        lines += ["", f"Student weights: `{student['weights']}` (sha256 {student['sha256']}..., look-ahead "
                  f"{student['lookahead_frames']} frames of 20 ms; trained by: {student['trained_by']}, at "
                  f"{student['trained_at_commit']}; PP decision bias {student.get('pp_bias', 0.0):g}, "
                  f"`python -m dualtalker_lite.ears calibrate`)."]
    info = meta["info"]
    if "headaudio" in info:
        h = info["headaudio"]
        lines += ["", f"HeadAudio 0.1.0 (npm, shipped model `model-en-mixed.bin`, default parameters) in "
                  f"{h['user_agent'].split(') ')[-1]}. Its CPU (Chromium's processes): every recording in one "
                  f"OfflineAudioContext ({h['whole_s']:.0f} s with 0.5 s gaps) {h['cpu_whole_with_node_s']:.2f} s "
                  f"with the node, {h['cpu_whole_plain_s']:.2f} s without (the table's figure: the difference per "
                  f"second of speech); one context per recording, as scored, {h['cpu_each_with_node_s']:.2f} s "
                  f"with, {h['cpu_each_plain_s']:.2f} s without (a new context, worklet module and model each "
                  f"time: {(h['cpu_each_with_node_s'] - h['cpu_each_plain_s']) / meta['minutes'] / 60:.3f} s per "
                  "s with that set-up)."]
    if "pylipsync_version" in info:
        lines += ["", f"pylipsync {info['pylipsync_version']} (PyPI), its defaults."]
    lines += ["", "Not measured here: the issue's two telephone-band points (other voices; every recording here is "
              "already telephone band)."]
    atomic_write_text(ROOT / "results" / "peers.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
