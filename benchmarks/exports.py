"""Exports that other tools play (issue 22): size, time, peak memory and error of each format, 60 s and 60 min.

    python benchmarks/exports.py                         # 1 and 60 minutes -> results/exports.md (+ .json)
    python benchmarks/exports.py --minutes 1 --no-write  # a quick look, nothing written to results/
    python benchmarks/exports.py --browser               # also load each page in headless chromium (Playwright)

Motion: the procedural rig's ground truth (``Corpus.vertices``) of the sample's three long multi-sentence clips
(SPK01_long01, SPK04_long02, SPK07_long03: 47.4 s of speech and motion), each clip's offsets from its own
speaker's template added to SPK01's template, joined and repeated until the length is reached; the audio is the
clips' speech, joined the same way. The rig's motion needs more components than a tiny trained model's output
(12 principal components against 4 for the 2-epoch DualTalker on SPK07_long03: the harder case for size and
error). The hour repeats the same 47 s, so its PCA finds the same subspace; what the hour measures is time and
memory. The frames are written to a ``.npy`` under ``runs/bench_exports/`` first (the hour: 2.0 GB), as the
``animate`` command streams them, and every export reads that memory map in blocks.

Each (length, format) is exported by a fresh Python process (``--one``), so the peak resident memory
(``resource.getrusage(RUSAGE_SELF).ru_maxrss``) is that export's own, interpreter and numpy included (the
baseline row shows the import alone). ``gltf`` is ``animation.glb`` + ``animation.wav``
(:func:`dualtalker_lite.export.gltf.write_gltf`); ``html`` writes its .glb (without the .wav) and then the page
(:func:`dualtalker_lite.export.html.write_html`), as ``animate --format html`` does. Errors are the exporter's
own measurement (max and mean Euclidean vertex error of ``template + weights @ targets`` against the raw frames,
over every vertex of every frame). ``npy`` (the raw float32 prediction) is the size reference; the removed
one-node-per-frame glb held the same positions plus ~0.6 kB of JSON per frame (npy size + 1.1 MB per minute).
CPU time is ``time.process_time`` (one BLAS thread); wall time is inflated by other jobs on the machine.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import subprocess
import sys
import time
from pathlib import Path

from dualtalker_lite.provenance import machine_line, provenance  # no torch: the parent stays small

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
WORK = ROOT / "runs" / "bench_exports"
CLIPS = ("SPK01_long01", "SPK04_long02", "SPK07_long03")
FPS, SR = 30, 16000
FORMATS = ("baseline", "gltf", "html")


def _vertices() -> int | None:
    """``--vertices V`` (passed to the child processes in DTL_BENCH_VERTICES): a mesh of V vertices."""
    return int(os.environ.get("DTL_BENCH_VERTICES", 0)) or None


def _work() -> Path:
    return WORK / f"v{_vertices()}" if _vertices() else WORK


def prepare(minutes: float) -> tuple[Path, Path]:
    """Write the rig's motion and the speech for ``minutes`` (repeated long clips) -> (.npy, .wav) paths.

    With ``--vertices V`` (e.g. VOCASET's 5,023) vertex i of the bigger mesh is the rig's vertex i mod 1,558,
    shifted by a fixed random 2 mm for every copy after the first, with that vertex's motion: the same motion
    subspace (same K) on a mesh of V vertices, to measure time and memory at that size.
    """
    import numpy as np
    import soundfile as sf

    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus

    work = _work()
    work.mkdir(parents=True, exist_ok=True)
    npy, wav = work / f"{minutes:g}min.npy", work / f"{minutes:g}min.wav"
    T = int(round(minutes * 60 * FPS))
    corpus = Corpus(sample_path())
    base = corpus.template("SPK01").reshape(-1, 3)
    idx = np.arange(_vertices() or len(base)) % len(base)
    shift = np.random.default_rng(0).normal(0, 2e-3, (len(idx), 3)) * (np.arange(len(idx)) >= len(base))[:, None]
    big = (base[idx] + shift).astype(np.float32).reshape(-1)
    np.save(work / "template.npy", big)  # the workers read these, not the corpus (which imports torch)
    np.save(work / "faces.npy", corpus.faces)
    if npy.is_file() and wav.is_file() and np.load(npy, mmap_mode="r").shape[0] == T:
        return npy, wav
    offsets = np.concatenate([corpus.vertices(c) - corpus.template(c.split("_")[0]) for c in CLIPS])
    motion = offsets.reshape(len(offsets), -1, 3)[:, idx].reshape(len(offsets), -1) + big
    speech = np.concatenate([corpus.wave(c)[:len(corpus.vertices(c)) * SR // FPS] for c in CLIPS])
    out = np.lib.format.open_memmap(npy, mode="w+", dtype=np.float32, shape=(T, motion.shape[1]))
    for s in range(0, T, len(motion)):
        n = min(len(motion), T - s)
        out[s:s + n] = motion[:n]
    out.flush()
    del out
    reps = -(-T * SR // FPS // len(speech))
    sf.write(wav, np.tile(speech, reps)[:T * SR // FPS], SR, subtype="PCM_16")
    return npy, wav


def one(fmt: str, npy: str, wav: str, out: str) -> dict:
    """Run one export in this (fresh) process -> its figures (printed as JSON by ``--one``)."""
    import numpy as np
    import soundfile as sf

    from dualtalker_lite.export.gltf import write_gltf
    from dualtalker_lite.export.html import write_html

    t0, c0 = time.perf_counter(), time.process_time()
    row = {"format": fmt}
    if fmt != "baseline":
        template, faces = np.load(_work() / "template.npy"), np.load(_work() / "faces.npy")
        clip = np.load(npy, mmap_mode="r")
        wave = sf.read(wav, dtype="float32")[0]
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        glb = out / "animation.glb"
        report = write_gltf(glb, clip, faces, template,
                            wave=wave if fmt == "gltf" else None, sample_rate=SR)
        files = [glb] + ([report.audio] if fmt == "gltf" else [])
        if fmt == "html":
            files = [write_html(out / "animation.html", glb, wave, SR)]
            glb.unlink()
        row.update(bytes=sum(p.stat().st_size for p in files), files={p.name: p.stat().st_size for p in files},
                   max_error_mm=report.max_error * 1e3, mean_error_mm=report.mean_error * 1e3,
                   components=report.components, targets=report.targets, frames=report.frames)
        for p in files:
            if not (fmt == "html" and os.environ.get("DTL_KEEP_HTML")):
                p.unlink()
    row.update(wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0,
               peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    return row


def browse(page: Path) -> dict:
    """Open ``page`` in headless chromium, wait until the viewer is ready, press Play for 2 s -> figures."""
    import shutil

    from playwright.sync_api import sync_playwright

    viewer = "Object.values(window.dtlViewers)[0]"
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=shutil.which("chromium"), args=[
            "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"])
        tab = browser.new_page(viewport={"width": 800, "height": 600})
        t0 = time.perf_counter()
        tab.goto(page.as_uri(), timeout=600_000)
        tab.wait_for_function(f"() => window.dtlViewers && ({viewer}.ready || {viewer}.error)", timeout=600_000)
        ready = time.perf_counter() - t0
        before = tab.evaluate(f"() => Array.from({viewer}.mesh.morphTargetInfluences)")
        tab.click("button.play")
        time.sleep(2)
        t_audio, after = tab.evaluate(f"() => [{viewer}.audio.currentTime, "
                                      f"Array.from({viewer}.mesh.morphTargetInfluences)]")
        browser.close()
    return {"ready_s": ready, "audio_s_after_2s": t_audio,
            "weights_moved": max(abs(a - b) for a, b in zip(before, after)) > 1e-3}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, nargs="+", default=[1, 60])
    ap.add_argument("--no-write", action="store_true", help="print only; leave results/ alone")
    ap.add_argument("--browser", action="store_true", help="also open each page in headless chromium (Playwright): "
                    "seconds until it is ready to play, and whether Play advances the audio and moves the face")
    ap.add_argument("--browse", help=argparse.SUPPRESS)
    ap.add_argument("--one", nargs=4, metavar=("FORMAT", "NPY", "WAV", "OUT"), help=argparse.SUPPRESS)
    ap.add_argument("--prepare", type=float, help=argparse.SUPPRESS)
    ap.add_argument("--vertices", type=int, help="a mesh of this many vertices (e.g. 5023, VOCASET's), built by "
                    "repeating the rig's vertices with their motion; writes results/exports_v<N>.md")
    args = ap.parse_args()
    if args.one:
        print(json.dumps(one(*args.one)))
        return
    if args.browse:
        print(json.dumps(browse(Path(args.browse))))
        return
    if args.prepare:
        print(json.dumps([str(p) for p in prepare(args.prepare)]))
        return
    if args.vertices:
        os.environ["DTL_BENCH_VERTICES"] = str(args.vertices)  # read by the child processes
    stamp = provenance("python benchmarks/exports.py " + shlex.join(sys.argv[1:]))  # the code measured, at the start
    rows = []
    for minutes in args.minutes:
        # in a child too: ru_maxrss survives fork + exec (getrusage(2)), so this parent stays small (no torch)
        res = subprocess.run([sys.executable, __file__, "--prepare", str(minutes)], capture_output=True, text=True,
                             check=True)
        npy, wav = map(Path, json.loads(res.stdout.strip().splitlines()[-1]))
        for fmt in FORMATS:
            env = {**os.environ, "DTL_KEEP_HTML": "1"} if args.browser else None
            res = subprocess.run([sys.executable, __file__, "--one", fmt, str(npy), str(wav), str(WORK / "out")],
                                 capture_output=True, text=True, check=True, env=env)
            row = json.loads(res.stdout.strip().splitlines()[-1])
            if fmt == "html" and args.browser:
                page = WORK / "out" / "animation.html"
                res = subprocess.run([sys.executable, __file__, "--browse", str(page)], capture_output=True,
                                     text=True, check=True)
                row["browser"] = json.loads(res.stdout.strip().splitlines()[-1])
                page.unlink()
            row["minutes"] = minutes
            rows.append(row)
            print(json.dumps(row), flush=True)
        rows.append({"minutes": minutes, "format": "npy (raw)", "bytes": npy.stat().st_size})
    lines = ["# Exports: glTF morph targets with sound, and the self-contained HTML viewer (issue 22)", "",
             f"Command: `{stamp['command']}`; commit {stamp['commit']}; {stamp['created']}; "
             f"{machine_line(stamp['machine'])}; one BLAS thread. "
             "Motion: the rig's ground truth of the three long sample clips, repeated (see the script's "
             f"docstring); {args.vertices or 1558:,} vertices"
             f"{' (the rig repeated, see prepare())' if args.vertices else ''}, 30 fps; speech 16 kHz. "
             "Peak memory: `ru_maxrss` of a fresh process per row (the baseline row is the interpreter with "
             "numpy, soundfile, pygltflib and the exporters imported). The .wav is 16-bit PCM (1.92 MB per "
             "minute); the html page holds the .glb and the .wav in base64 (x 4/3) and three.js r170 (1.2 MB).",
             "",
             "| length | format | size, MB | MB per minute | files, MB | morph targets (components) "
             "| max / mean error, mm | export CPU s (wall s) | peak memory, MB |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        size = r.get("bytes")
        mb = f"{size / 1e6:.2f}" if size else ""
        per_min = f"{size / 1e6 / r['minutes']:.2f}" if size else ""
        targets = f"{r['targets']} ({r['components']})" if "targets" in r else ""
        err = f"{r['max_error_mm']:.4f} / {r['mean_error_mm']:.4f}" if "max_error_mm" in r else ""
        times = f"{r['cpu_s']:.1f} ({r['wall_s']:.1f})" if "cpu_s" in r and r["format"] != "baseline" else ""
        rss = f"{r['peak_rss_mb']:.0f}" if "peak_rss_mb" in r else ""
        label = {"gltf": "gltf (.glb + .wav)", "html": "html (one page)"}.get(r["format"], r["format"])
        if "browser" in r:
            b = r["browser"]
            label += (f"; chromium: ready in {b['ready_s']:.1f} s, audio at {b['audio_s_after_2s']:.2f} s after 2 s "
                      f"of Play, face {'moves' if b['weights_moved'] else 'STILL'}")
        files = " + ".join(f"{k} {v / 1e6:.2f}" for k, v in r.get("files", {}).items())
        lines.append(f"| {r['minutes']:g} min | {label} | {mb} | {per_min} | {files} | {targets} | {err} | {times} "
                     f"| {rss} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if not args.no_write:
        (ROOT / "results").mkdir(exist_ok=True)
        name = f"exports_v{args.vertices}" if args.vertices else "exports"
        payload = {"command": stamp["command"], "git": stamp["commit"], "machine": stamp["machine"],
                   "created": stamp["created"], "rows": rows}
        for path, content in ((ROOT / "results" / f"{name}.json", json.dumps(payload, indent=1) + "\n"),
                              (ROOT / "results" / f"{name}.md", text)):  # atomic: a whole file or the old one
            path.with_suffix(".tmp").write_text(content)
            os.replace(path.with_suffix(".tmp"), path)


if __name__ == "__main__":
    main()
