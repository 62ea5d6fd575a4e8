"""Hour-long audio in bounded memory (issue 11): peak memory and real-time factor of features + encode + generate
for 1, 10 and 60 minutes of speech on the tiny DualTalker, and the speed of video rendering. Prints a table;
nothing here is a pass/fail test (targets: peak memory < 2 GB at 60 min, generation >= 20x real time,
video >= 3x real time).

    python benchmarks/long_audio.py                      # 1 and 10 minutes, video on 60 s
    python benchmarks/long_audio.py --minutes 1 10 60    # the hour too (about 3-5 min of CPU)
    python benchmarks/long_audio.py --window-check 60    # trained model: windowed vs unbounded decoding, 3 min
    python benchmarks/long_audio.py --cli                # the `dualtalker-lite animate` command end to end:
                                                         # 1 and 10 min --no-video, 1 min with the mp4
    python benchmarks/long_audio.py --cli --minutes 60 --cli-video   # the hour through the CLI (heavy)
    python benchmarks/long_audio.py --cli --minutes 60 120 --no-cli-video --results results/long_audio.md
        # the README's peak memory for one and two hours (about 5 CPU minutes)

Each length runs in a fresh process (``--one``), so its peak resident memory (``ru_maxrss``: every numpy and torch
allocation, plus the interpreter and libraries) is its own. The speech is the shipped sample's clips concatenated
until the length is reached. Untrained weights (speed and memory do not depend on them). Vertices are streamed to a
.npy (``dualtalker_lite.streaming``): held in memory, an hour of 1,558-vertex frames would be 2.0 GB by itself.
CPU time (``time.process_time``, one torch thread) is reported beside wall time, which other jobs inflate.

``--cli`` measures what a user runs instead: ``python -m dualtalker_lite.cli animate`` on a WAV of that length
(16-bit PCM, 16 kHz) with a self-describing checkpoint of the same untrained model, as a child process. Its
peak RSS and CPU time come from ``os.wait4`` (the process and the children it waited for, i.e. ffmpeg: the
peak is the larger of the two, the CPU time their sum); the real-time factor is CPU seconds per second of audio.
Everything the command does is included: imports, checkpoint, audio loading, features, generation streamed
to ``vertices.npy``, ``frame0.obj`` and, with video, rendering and muxing the mp4.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dualtalker_lite.provenance import machine_line, provenance  # no torch: the parent stays small

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: kilobytes


def speech(seconds: float, sample_rate: int = 16000):
    """The sample's clips, concatenated (and repeated) to ``seconds`` of speech: float32 (N,)."""
    import numpy as np
    import soundfile as sf

    from dualtalker_lite.data import sample_path

    folder = Path(sample_path()) / "audio"
    files = sorted([*folder.rglob("*.flac"), *folder.rglob("*.wav")])
    n, out, i = int(seconds * sample_rate), [], 0
    total = 0
    while total < n:
        wave, sr = sf.read(str(files[i % len(files)]), dtype="float32")
        assert sr == sample_rate, (files[i % len(files)], sr)
        out.append(wave)
        total += len(wave)
        i += 1
    return np.concatenate(out)[:n]


def one(minutes: float, out_dir: Path, video_seconds: float, threads: int) -> dict:
    import numpy as np
    import torch

    from dualtalker_lite.audio import LogMelExtractor
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus
    from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
    from dualtalker_lite.streaming import generate_to_npy

    torch.set_num_threads(threads)
    corpus = Corpus(sample_path())
    torch.manual_seed(0)
    cfg = DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=160,
                                n_speakers=len(corpus.train_speakers))
    model = DualTalker(cfg).eval()
    torch.nn.init.normal_(model.decoder.motion_decoder.weight, std=0.01)  # untrained, but not a constant template
    template = corpus.template(corpus.train_speakers[0]).reshape(-1)
    faces = corpus.faces
    rss_ready = peak_rss_mb()
    wave = speech(60 * minutes)
    n_frames = int(round(len(wave) * 30 / 16000))
    row = {"minutes": minutes, "frames": n_frames, "rss_after_imports_mb": rss_ready}

    cpu, wall = time.process_time(), time.perf_counter()
    with torch.no_grad():
        audio = LogMelExtractor()(wave, n_frames)  # (T, 160)
    row["features_cpu_s"], row["features_wall_s"] = time.process_time() - cpu, time.perf_counter() - wall

    timing = {}
    encode = model.encode_audio

    def timed_encode(*args, **kwargs):
        t0 = time.process_time()
        result = encode(*args, **kwargs)
        timing["encode_cpu_s"] = time.process_time() - t0
        return result

    model.encode_audio = timed_encode
    path = out_dir / f"vertices_{minutes:g}min.npy"
    cpu, wall = time.process_time(), time.perf_counter()
    generate_to_npy(model, audio, torch.from_numpy(template), 0, path)
    row["generate_cpu_s"], row["generate_wall_s"] = time.process_time() - cpu, time.perf_counter() - wall
    row["encode_cpu_s"] = timing["encode_cpu_s"]
    row["decode_cpu_s"] = row["generate_cpu_s"] - row["encode_cpu_s"]
    row["result_gb_if_in_memory"] = n_frames * template.size * 4 / 1e9
    row["peak_rss_mb"] = peak_rss_mb()
    verts = np.load(path, mmap_mode="r")
    assert verts.shape == (n_frames, template.size) and np.isfinite(verts[-100:]).all()

    if video_seconds > 0:
        from dualtalker_lite.export.video import render_video

        n = min(n_frames, int(video_seconds * 30))
        for renderer, frames in (("raster", n), ("matplotlib", min(n, 300))):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu, wall = time.process_time(), time.perf_counter()
            render_video(verts[:frames], faces, out_dir / f"video_{renderer}.mp4", wave=wave[: frames * 16000 // 30],
                         renderer=renderer, progress=False)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            row[f"video_{renderer}"] = {
                "frames": frames, "wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu,
                "ffmpeg_cpu_s": (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)}
    path.unlink()
    return row


def report(rows: list[dict]) -> None:
    print("\nlong audio, tiny DualTalker (V = 1558), 1 torch thread; CPU seconds (wall in brackets)")
    print(f"{'audio':>7} | {'frames':>7} | {'features':>13} | {'encode':>7} | {'decode':>8} | "
          f"{'total':>14} | {'x real time':>11} | {'RTF':>6} | {'peak RSS':>9} | {'result in RAM':>13}")
    for r in rows:
        total = r["features_cpu_s"] + r["generate_cpu_s"]
        wall = r["features_wall_s"] + r["generate_wall_s"]
        secs = 60 * r["minutes"]
        print(f"{r['minutes']:>5g} m | {r['frames']:>7} | {r['features_cpu_s']:6.1f} ({r['features_wall_s']:4.1f}) | "
              f"{r['encode_cpu_s']:7.1f} | {r['decode_cpu_s']:8.1f} | {total:6.1f} ({wall:5.1f}) | "
              f"{secs / total:10.1f}x | {total / secs:6.4f} | {r['peak_rss_mb']:6.0f} MB | "
              f"{r['result_gb_if_in_memory']:9.2f} GB")
    print(f"(peak RSS includes about {rows[0]['rss_after_imports_mb']:.0f} MB of interpreter, torch and the corpus "
          f"before any audio; 'result in RAM' is what generate() would hold, streamed to .npy instead)")
    for r in rows:
        for renderer in ("raster", "matplotlib"):
            v = r.get(f"video_{renderer}")
            if v:
                fps = v["frames"] / v["wall_s"]
                print(f"video ({renderer}, 256x256, {v['frames']} frames, from the {r['minutes']:g} min run): "
                      f"{fps:.0f} frames/s wall = {fps / 30:.1f}x real time; render CPU {v['cpu_s']:.1f} s "
                      f"+ ffmpeg CPU {v['ffmpeg_cpu_s']:.1f} s")


def make_checkpoint(path: Path) -> None:
    """The benchmark's untrained tiny DualTalker as a self-describing checkpoint (sample speakers and faces)."""
    import torch

    from dualtalker_lite.checkpoints import save_checkpoint
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus
    from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig

    corpus = Corpus(sample_path())
    torch.manual_seed(0)
    cfg = DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=160,
                                n_speakers=len(corpus.train_speakers))
    model = DualTalker(cfg).eval()
    torch.nn.init.normal_(model.decoder.motion_decoder.weight, std=0.01)
    save_checkpoint(path, model, cfg, speakers=corpus.train_speakers, faces=corpus.faces)


def make_cli_inputs(tmp: Path, minutes: list[float]) -> None:
    """The checkpoint and one 16-bit WAV per length in ``tmp`` (run in its own process, see :func:`cli_case`)."""
    import soundfile as sf

    make_checkpoint(tmp / "model.pt")
    for m in minutes:
        with sf.SoundFile(str(tmp / f"speech_{m:g}min.wav"), "w", 16000, 1, subtype="PCM_16") as f:
            for start in range(0, int(60 * m), 60):  # a minute at a time: nothing big in memory
                f.write(speech(min(60, 60 * m - start)))


def cli_case(minutes: float, video: bool, tmp: Path, env: dict, fmt: str = "npy") -> dict:
    """One ``animate`` run as a child process -> wall, CPU (with ffmpeg) and peak RSS.

    A child's ``ru_maxrss`` starts at its parent's peak (Linux keeps the high-water mark across fork + exec), so
    the parent must stay small: the inputs are made by another process, and this one imports no torch."""
    ckpt, wav = tmp / "model.pt", tmp / f"speech_{minutes:g}min.wav"
    out = tmp / f"anim_{minutes:g}min_{'video' if video else 'novideo'}_{fmt}"
    cmd = [sys.executable, "-m", "dualtalker_lite.cli", "animate", "--checkpoint", str(ckpt), "--wav", str(wav),
           "--speaker", "SPK01", "--out", str(out), "--format", "npy,mp4" if video else fmt, "--no-progress"]
    log_out, log_err = tmp / "stdout.txt", tmp / "stderr.txt"
    with open(log_out, "wb") as fo, open(log_err, "wb") as fe:
        wall = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, stdout=fo, stderr=fe)
        _, status, usage = os.wait4(proc.pid, 0)  # reaps the child with its own rusage (Popen.wait cannot)
        wall = time.perf_counter() - wall
    proc.returncode = os.waitstatus_to_exitcode(status)
    stdout, stderr = log_out.read_bytes(), log_err.read_bytes()
    if proc.returncode != 0:
        sys.exit(f"{' '.join(cmd)}\nfailed with status {proc.returncode}:\n{stderr.decode()[-3000:]}")
    files = {p.name: p.stat().st_size for p in out.iterdir()}
    for p in out.iterdir():
        p.unlink()
    out.rmdir()
    return {"minutes": minutes, "video": video, "format": "npy,mp4" if video else fmt, "wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime,
            "peak_rss_mb": usage.ru_maxrss / 1024, "files_mb": {k: v / 1e6 for k, v in files.items()},
            "stdout": stdout.decode().strip().replace(str(tmp), "<tmp>")}  # no machine-specific path in results/


def cli_report(rows: list[dict]) -> list[str]:
    """Print the ``--cli`` table -> its lines."""
    lines = ["`dualtalker-lite animate` end to end (child process; tiny DualTalker, V = 1558, OMP_NUM_THREADS=1)",
             f"{'audio':>7} | {'format':>7} | {'wall s':>7} | {'CPU s':>7} | {'RTF (CPU)':>9} | {'x real time':>11} | "
             f"{'peak RSS':>9} | files"]
    for r in rows:
        secs = 60 * r["minutes"]
        files = ", ".join(f"{k} {v:.1f} MB" for k, v in sorted(r["files_mb"].items()))
        lines.append(f"{r['minutes']:>5g} m | {r['format']:>7} | {r['wall_s']:7.1f} | {r['cpu_s']:7.1f} | "
                     f"{r['cpu_s'] / secs:9.4f} | {secs / r['cpu_s']:10.1f}x | {r['peak_rss_mb']:6.0f} MB | {files}")
    lines.append("(CPU = the command plus ffmpeg; RTF = CPU seconds per second of audio; wall time is inflated by "
                 "other jobs on a shared machine)")
    print("\n" + "\n".join(lines))
    return lines


def write_results(path: Path, stamp: dict, lines: list[str], rows: list[dict]) -> None:
    """``--results MD``: the ``--cli`` table as a results page (command, commit, machine) and its rows as MD's
    .json, each written atomically."""
    page = ["# Long recordings through `dualtalker-lite animate`: peak memory and CPU time", "",
            f"Command: `{stamp['command']}`; commit {stamp['commit']}; {stamp['created']}; "
            f"{machine_line(stamp['machine'])}. Peak RSS: `ru_maxrss` of the `animate` child process "
            "(`os.wait4`); the inputs are a 16 kHz 16-bit WAV of the sample's speech and the benchmark's untrained "
            "tiny log-mel DualTalker.", "", "```", *lines, "```", ""]
    for target, text in ((path, "\n".join(page)),
                         (path.with_suffix(".json"), json.dumps({**stamp, "git": stamp["commit"], "rows": rows},
                                                                indent=1) + "\n")):
        target.with_suffix(".tmp").write_text(text)
        os.replace(target.with_suffix(".tmp"), target)


def window_check(train_seconds: float, minutes: float, threads: int) -> None:
    """How far the sliding decoder window moves a *trained* model's output on a clip longer than the window:
    the tiny DualTalker trained for ``train_seconds`` on the sample, then the test-A clips' features
    concatenated to ``minutes``, generated with the unbounded cache (window=None) and with the default window."""
    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from common import load_sample, tiny_dualtalker
    from dualtalker_lite.data.dataset import make_loader
    from dualtalker_lite.train import TrainConfig, train

    torch.set_num_threads(threads)
    corpus, ds = load_sample(("train", "test_a"))
    model = tiny_dualtalker(corpus, 0)
    cfg = TrainConfig.tiny(epochs=10_000, time_budget_s=train_seconds, seed=0, validate_every=0, progress=False)
    hist = train(model, make_loader(ds["train"], cfg.batch_size, shuffle=True, seed=0), cfg)
    model.eval()
    longest = max(len(ds["train"][i]["audio"]) for i in range(len(ds["train"])))
    items = [ds["test_a"][i] for i in range(len(ds["test_a"]))]
    n = int(minutes * 60 * 30)
    audio = torch.cat([it["audio"] for it in items])
    audio = audio.repeat(n // len(audio) + 1, 1)[:n][None]  # (1, T, 160)
    template, speaker = items[0]["template"][None], torch.tensor([0])
    window = model.cfg.decoder_window
    t0 = time.process_time()
    full = model.generate(audio, template, speaker, window=None)[0]  # (T, V*3) unbounded cache
    t1 = time.process_time()
    windowed = model.generate(audio, template, speaker)[0]
    t2 = time.process_time()
    diff = (full - windowed).view(n, -1, 3).norm(dim=-1) * 1000  # (T, V) mm
    motion = (full - template).view(n, -1, 3).norm(dim=-1) * 1000
    print(f"\nwindow check: tiny DualTalker trained {len(hist.terms)} epochs ({train_seconds:g} s budget; longest "
          f"training clip {longest} frames), {minutes:g} min of test-A features, decoder_window = {window} frames")
    print(f"  unbounded cache {t1 - t0:.1f} s CPU, windowed {t2 - t1:.1f} s CPU")
    print(f"  frames <= window: max |difference| {diff[:window].max():.2e} mm (exact up to float rounding)")
    print(f"  frames > window: max {diff[window:].max():.4f} mm, mean {diff[window:].mean():.5f} mm per vertex; "
          f"mean motion {motion.mean():.3f} mm, max {motion.max():.2f} mm")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, nargs="+", default=[1, 10])
    ap.add_argument("--video-seconds", type=float, default=60, help="render this much of the first length (0: none)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--one", type=float, help=argparse.SUPPRESS)  # internal: one length in this process
    ap.add_argument("--out", help=argparse.SUPPRESS)
    ap.add_argument("--json", help="also write the figures to this JSON file")
    ap.add_argument("--window-check", type=float, metavar="SECONDS",
                    help="instead: train the tiny model this long, compare windowed vs unbounded decoding")
    ap.add_argument("--check-minutes", type=float, default=3.0, help="clip length for --window-check")
    ap.add_argument("--cli", action="store_true",
                    help="instead: time `dualtalker-lite animate` end to end for each --minutes, with --no-video")
    ap.add_argument("--cli-video", type=float, nargs="*", default=[1], metavar="MINUTES",
                    help="with --cli: also run these lengths with the mp4 (default: 1; bare flag: every length)")
    ap.add_argument("--cli-formats", nargs="+", default=["npy"], choices=["npy", "gltf"],
                    help="with --cli: the --format of the runs without video (gltf: the engine export, .glb + .wav)")
    ap.add_argument("--no-cli-video", action="store_true", help="with --cli: no run with the mp4")
    ap.add_argument("--make-cli-inputs", nargs="+", help=argparse.SUPPRESS)  # internal: DIR MINUTES...
    ap.add_argument("--results", type=Path, metavar="MD", help="with --cli: also write the table to MD (e.g. "
                    "results/long_audio.md) and its rows to MD's .json, with the command, commit and machine")
    args = ap.parse_args()
    stamp = provenance("python benchmarks/long_audio.py " + shlex.join(sys.argv[1:]))
    if args.make_cli_inputs:
        make_cli_inputs(Path(args.make_cli_inputs[0]), [float(m) for m in args.make_cli_inputs[1:]])
        return
    if args.cli:
        root = Path(__file__).resolve().parents[1]
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
        video = [] if args.no_cli_video else args.minutes if args.cli_video == [] else args.cli_video
        cases = [(m, False, f) for f in args.cli_formats for m in args.minutes] + [(m, True, "npy") for m in video]
        rows = []
        with tempfile.TemporaryDirectory(prefix="long-audio-cli-") as tmp:
            lengths = sorted({m for m, _, _ in cases})
            subprocess.run([sys.executable, __file__, "--make-cli-inputs", tmp, *map(str, lengths)], env=env,
                           check=True)
            for minutes, with_video, fmt in cases:
                rows.append(cli_case(minutes, with_video, Path(tmp), env, fmt))
                r = rows[-1]
                print(f"{minutes:g} min --format {r['format']}: {r['wall_s']:.1f} s wall, "
                      f"{r['cpu_s']:.1f} s CPU, peak {r['peak_rss_mb']:.0f} MB", flush=True)
        lines = cli_report(rows)
        if args.results:
            write_results(args.results, stamp, lines, rows)
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=1))
        return
    if args.window_check is not None:
        window_check(args.window_check, args.check_minutes, args.threads)
        return
    if args.one is not None:
        print(json.dumps(one(args.one, Path(args.out), args.video_seconds, args.threads)))
        return
    rows = []
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
    with tempfile.TemporaryDirectory(prefix="long-audio-") as tmp:
        for i, minutes in enumerate(args.minutes):
            video = args.video_seconds if i == 0 else 0
            cmd = [sys.executable, __file__, "--one", str(minutes), "--out", tmp, "--video-seconds", str(video),
                   "--threads", str(args.threads)]
            result = subprocess.run(cmd, capture_output=True, text=True, env=env)
            if result.returncode != 0:
                sys.exit(f"{minutes} min run failed:\n{result.stderr[-3000:]}")
            rows.append(json.loads(result.stdout.strip().splitlines()[-1]))
            print(f"{minutes:g} min done: {rows[-1]['generate_cpu_s'] + rows[-1]['features_cpu_s']:.1f} s CPU, "
                  f"peak {rows[-1]['peak_rss_mb']:.0f} MB", flush=True)
    report(rows)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
