"""Live lip sync (issue 33): cost and agreement of the streaming viseme track, and of the whole live path.

    OMP_NUM_THREADS=1 python benchmarks/live.py                          # the track, a few settings, both clips
    OMP_NUM_THREADS=1 python benchmarks/live.py --checkpoint runs/m.pt   # + the model: lip-distance correlation
    OMP_NUM_THREADS=1 python benchmarks/live.py --checkpoint runs/m.pt --latency   # + through the server, in real time

For each setting (look-ahead, past context, hop) and each shipped real clip (``notebooks/data/real/*.flac``, 8 kHz
telephone speech upsampled to 16 kHz as ``animate`` does), the clip is fed to
:class:`~dualtalker_lite.live.stream.StreamingVisemes` in 100 ms pieces (what the page sends) and compared with the
offline track that ``animate`` feeds the model (:meth:`RecogniserExtractor.viseme_ids`: 24 s cores, 2 s context):

* ``agree``: the fraction of mesh frames whose viseme class is the offline one;
* ``cpu/s``: CPU seconds (``time.process_time``, one thread) per second of audio; below 1 = faster than real time
  on one core. Wall time is printed too (other jobs on the machine inflate it).

With ``--checkpoint`` (a model trained on the viseme track, e.g. ``dualtalker-lite train --clips 16 --epochs 1``),
the whole :class:`~dualtalker_lite.live.stream.LiveSession` (track + incremental decoder) runs on each clip and its
lip distance (upper to lower lip midpoint) is correlated with the offline ``animate`` output of the same clip.
With ``--latency`` too, each clip is streamed through the live server (in-process, aiohttp's test server on
127.0.0.1) in real time, 100 ms messages as the page sends them, and the latency of every frame is recorded: the
time from sending the message that completes frame f's audio (sample ``(f + 1) 16000 / 30``) to receiving its
vertices. That is the page's figure minus the browser's own buffering; it includes the algorithmic latency
(``LiveSettings.latency_s``), waiting for the next hop and the compute, so it grows on a busy machine.
Nothing here is a pass/fail test; the figures are quoted in ``docs/live.md``.

Issue 33 item 4, the live path against its targets (``figures``; each step writes ``runs/live_figures/<step>.json``,
``report`` joins them into ``results/live.md`` / ``.json``):

    OMP_NUM_THREADS=1 python benchmarks/live.py figures quality --checkpoint runs/live_dt.pt --every 3
    OMP_NUM_THREADS=1 python benchmarks/live.py figures keepup --checkpoint runs/live_dt.pt --minutes 10
    OMP_NUM_THREADS=1 python benchmarks/live.py figures latency --checkpoint runs/live_dt.pt
    OMP_NUM_THREADS=1 python benchmarks/live.py figures report

With ``--ears student`` the ``quality``, ``keepup`` and ``page`` steps run the live path with the project's own
student as its ears (``live --ears student``; ``quality`` also adds ``animate --front-end student``), each into
``<step>_student.json``, and ``report --ears student`` joins those into ``results/live_student.json``.

* ``quality``: the real-voice benchmark's prompts (``benchmarks/real_voices.py``: asterisk recordings, pocketsphinx
  alignment, the rig driven by the aligned phones as reference; every ``--every``-th prompt in name order), each
  run through the live path (a :class:`LiveSession` built from :func:`~dualtalker_lite.live.server.load_config`,
  fed 100 ms pieces, then ``flush``, as the server does on ``stop``) at look-ahead 100 and 200 ms, and through
  ``animate``'s path (:func:`~dualtalker_lite.inference.animate_wave`); closure < 2 / < 1 mm, vowel frames shut and
  r from ``real_voices.curve_metrics`` (bilabial windows widened by ``real_voices.REAL_TOL`` frames, as there).
* ``keepup``: ``--minutes`` of real speech (the prompts concatenated, cycled) through a :class:`LiveSession` with
  the server's scheduling (:func:`simulate`: 100 ms messages arrive on a virtual clock at real-time pace; the worker
  takes everything that arrived, at most ``MAX_BATCH_S``, and the clock moves by the push's measured wall time),
  so 10 minutes take the compute's time, not 10 minutes. Per push: wall and thread-CPU seconds, the backlog
  (audio arrived, not yet pushed), RSS now and peak (``resource.getrusage``) at 1, 5 and 10 minutes of audio.
* ``latency``: per frame, the time from the arrival of the message completing its audio (sample
  ``ceil((f + 1) 16000 / 30)``) to its vertices leaving the session, at look-ahead 0, 100 and 200 ms, from
  :func:`simulate` on ``--latency-minutes`` of the same speech; plus through the real server (aiohttp test server,
  in real time) on the shipped clips. Neither includes the network, the browser's 100 ms worklet messages or
  its rendering.
* ``page``: the whole page, end to end: the live server (``dualtalker-lite live``, its own process) and the page
  in headless Chromium, whose fake microphone plays ``--page-seconds`` of the same real speech
  (``--use-fake-device-for-media-stream --use-file-for-fake-audio-capture``), at each ``--lookaheads``. Per frame
  drawn: from its newest sample entering the page (the worklet's message time, less the samples after it) to the
  animation callback that draws it (``dtlLive.shownLatencyMs``; the screen's next refresh, up to 17 ms, is not in
  it); frames of the first 3 s (the page's playout delay adapting) are left out. Software WebGL draws only a few
  frames a second on a busy 2-core machine (``draws_per_s``): each drawn frame is timed, the others are skipped
  by the page as they would be on a slow screen. Needs chromium and playwright, as the
  page's test does. Also counted: the server's ``behind`` messages and the audio they dropped (catching up,
  ``LiveConnection.catch_up``). With ``--synced`` the page's synced box is ticked (the sound played back through a
  DelayNode set to the measured latency, ``docs/live.md``) and per frame drawn the audio/face offset is taken
  (``dtlLive.syncOffsetMs``: the draw minus the time the frame's sound (sample ``f 16000 / 30``) left the delay
  line and the context's reported output latency, by the page's clocks; + = the face after the sound): median,
  p95 of its size, and the share within the +-45 ms target. The screen's refresh and audio device latency the
  browser does not report are not in it.
* ``diagnose``: where the live path loses closures (:func:`fig_diagnose`): the offline track through the
  incremental decoder, and the live track through the offline decoder, on every ``--every``-th prompt.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from dualtalker_lite.files import atomic_write_text  # noqa: E402
from dualtalker_lite.provenance import provenance  # noqa: E402

SETTINGS = [  # (lookahead_s, past_s, hop_s)
    (0.2, 0.6, 0.2), (0.2, 1.0, 0.1), (0.2, 0.4, 0.3), (0.1, 0.6, 0.2), (0.3, 0.6, 0.2), (0.0, 0.6, 0.2)]


def feed(obj, wave: np.ndarray, piece: int = 1600):
    """Push ``wave`` in ``piece``-sample pieces, then flush -> (outputs, cpu seconds, wall seconds)."""
    out, c0, w0 = [], time.process_time(), time.perf_counter()
    for i in range(0, len(wave), piece):
        out.append(obj.push(wave[i:i + piece]))
    out.append(obj.flush())
    return out, time.process_time() - c0, time.perf_counter() - w0


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["figures"]:
        return figures(argv[1:])
    import torch

    from dualtalker_lite.audio import load_audio
    from dualtalker_lite.live.stream import LiveSession, LiveSettings, StreamingVisemes, new_extractor

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", default=None, help="a viseme-track model: also the whole live path")
    ap.add_argument("--speaker", default="SPK01")
    ap.add_argument("--latency", action="store_true", help="with --checkpoint: through the server, in real time")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    clips = sorted((ROOT / "notebooks" / "data" / "real").glob("*.flac"))
    import warnings

    waves = {}
    for p in clips:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            waves[p.name] = load_audio(p)  # 8 kHz files: upsampled (a warning on stderr), as animate does
    ex = new_extractor()
    offline = {n: ex.viseme_ids(w, max(1, int(round(len(w) * 30 / 16000)))) for n, w in waves.items()}
    seconds = sum(len(w) for w in waves.values()) / 16000
    print(f"streaming viseme track vs offline, {len(waves)} clips, {seconds:.1f} s of speech, 100 ms pieces")
    print(f"{'ahead ms':>8} {'past s':>6} {'hop s':>5} {'latency ms':>10} {'agree':>6} {'cpu/s':>6} {'wall/s':>6}")
    for ahead, past, hop in SETTINGS:
        same = total = 0
        cpu = wall = 0.0
        for name, wave in waves.items():
            track = StreamingVisemes(ex, ahead, past, hop)
            out, c, w = feed(track, wave)
            ids = np.concatenate(out)
            assert len(ids) == len(offline[name]), (name, len(ids), len(offline[name]))
            same, total, cpu, wall = same + int((ids == offline[name]).sum()), total + len(ids), cpu + c, wall + w
        latency = (ahead + ex.lag_s + ex.window_s) * 1000
        print(f"{ahead * 1000:8.0f} {past:6.1f} {hop:5.1f} {latency:10.0f} {same / total:6.3f} {cpu / seconds:6.2f} "
              f"{wall / seconds:6.2f}")
    if args.checkpoint:
        from dualtalker_lite.checkpoints import load_checkpoint
        from dualtalker_lite.front_ends import from_settings
        from dualtalker_lite.data import sample_path
        from dualtalker_lite.data.corpus import Corpus
        from dualtalker_lite.inference import animate_wave, resolve_speaker
        from dualtalker_lite.metrics import lip_distance

        model, ckpt = load_checkpoint(args.checkpoint)
        extractor = from_settings(ckpt.get("features"), args.checkpoint)
        corpus = Corpus(sample_path())
        speaker, _ = resolve_speaker(ckpt, args.speaker, corpus)
        template = corpus.template(args.speaker)
        up, lo = corpus.regions["lip_midpoints"]
        print(f"\nwhole live path ({Path(args.checkpoint).name}) vs offline animate; encoder context in frames")
        print(f"{'clip':>22} {'past':>4} {'ahead':>5} {'frames':>6} {'lip corr':>8} {'live std mm':>11} "
              f"{'offline std mm':>14} {'cpu/s':>6}")
        offline_verts = {name: animate_wave(model, wave, template, speaker, front_end=extractor)
                         for name, wave in waves.items()}
        for past, ahead in [(60, 3), (60, 0), (30, 3), (120, 6)]:   # the first: the default until 4868760
            for name, wave in waves.items():
                session = LiveSession(model, extractor, template, speaker,
                                      LiveSettings(past_frames=past, ahead_frames=ahead, ears="hama"))
                out, c, _ = feed(session, wave)
                live = np.concatenate([v for _, v in out])
                a, b = lip_distance(live, [up], [lo]), lip_distance(offline_verts[name], [up], [lo])
                print(f"{name:>22} {past:4d} {ahead:5d} {len(live):6d} {np.corrcoef(a, b)[0, 1]:8.3f} "
                      f"{a.std():11.4f} {b.std():14.4f} {c / (len(wave) / 16000):6.2f}")

        if args.latency:
            print("\nthrough the server in real time (100 ms messages): latency per frame, ms")
            print(f"{'clip':>22} {'median':>7} {'p95':>7} {'max':>7}")
            for name, wave in waves.items():
                lat = np.array(asyncio_run_latency(args.checkpoint, args.speaker, wave)) * 1000
                print(f"{name:>22} {np.median(lat):7.0f} {np.percentile(lat, 95):7.0f} {lat.max():7.0f}")


def asyncio_run_latency(checkpoint: str, speaker: str, wave: np.ndarray, lookahead_s: float | None = None
                        ) -> list[float]:
    """Stream ``wave`` through the live server in real time -> seconds from the message completing each frame's
    audio to that frame's arrival (frames flushed by the final ``stop`` are left out)."""
    import asyncio
    import json

    from aiohttp.test_utils import TestClient, TestServer

    from dualtalker_lite.live.server import HEADER, load_config, make_app

    from dualtalker_lite.live.stream import LiveSettings

    config = load_config(checkpoint, speaker, settings=LiveSettings(ears="hama") if lookahead_s is None else
                         LiveSettings(lookahead_s, ears="hama"))
    pcm = np.round(np.clip(wave, -1, 1) * 32767).astype("<i2")

    async def main():
        client = TestClient(TestServer(make_app(config), host="127.0.0.1", handler_cancellation=True))
        await client.start_server()
        sent, arrived = [], {}
        try:
            ws = await client.ws_connect("/ws", headers={"Origin": f"http://127.0.0.1:{client.server.port}"})
            await ws.receive()

            async def reader():
                async for msg in ws:
                    if msg.type.name == "BINARY":
                        first, n, _ = HEADER.unpack_from(msg.data)
                        now = time.perf_counter()
                        arrived.update({first + i: now for i in range(n)})
            task = asyncio.create_task(reader())
            t0 = time.perf_counter()
            for k, i in enumerate(range(0, len(pcm), 1600)):
                await asyncio.sleep(max(0.0, t0 + (k + 1) * 0.1 - time.perf_counter()))  # as captured
                await ws.send_bytes(pcm[i:i + 1600].tobytes())
                sent.append((i + len(pcm[i:i + 1600]), time.perf_counter()))
            await asyncio.sleep(1.5)                          # frames still in flight (no flush: not live)
            await ws.close()
            task.cancel()
        finally:
            await client.close()
        lat = []
        for f, t in arrived.items():
            need = int(np.ceil((f + 1) * 16000 / 30))
            when = next((ts for n, ts in sent if n >= need), None)
            if when is not None:
                lat.append(t - when)
        return lat

    return asyncio.run(main())


# ------------------------------------------------------------------------- issue 33 item 4: the figures
FIG_DIR = ROOT / "runs" / "live_figures"
TARGETS = {"latency_median_ms": 250, "latency_p95_ms": 400, "closure_gap": 0.05, "vowel_shut": 0.06}


def _rss_mb() -> tuple[float, float]:
    """(RSS now, peak RSS) of this process, MB."""
    import resource

    now = 0.0
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            now = int(line.split()[1]) / 1024
    return now, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _real_prompts(every: int = 1, references: bool = True):
    """The real-voice benchmark's prompts (every ``every``-th, name order): [{name, wave, segments, ref_curve}]."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import real_voices as rv
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus, read_json
    from dualtalker_lite.face import FaceRig, Speaker
    from dualtalker_lite.metrics import lip_distance

    corpus = Corpus(sample_path())
    subject = corpus.train_speakers[0]
    lip_mid = tuple(corpus.regions["lip_midpoints"])
    prompts = rv.read_prompts()
    chosen = prompts[::every]
    if not references:
        return chosen, subject, lip_mid, len(prompts), []
    speaker = Speaker.from_dict(read_json(corpus.root / "speakers.json")[subject])
    rig = FaceRig(speaker)
    items, failed = [], []
    for p in chosen:
        segs = rv.align(p["wave"], p["words"])
        if segs is None:
            failed.append(p["name"])
            continue
        n = max(1, int(round(len(p["wave"]) * 30 / 16000)))
        ref = rv.rig_vertices(segs, n, speaker, rig, p["wave"])
        items.append({"name": p["name"], "wave": p["wave"], "segments": segs,
                      "ref_curve": lip_distance(ref, *lip_mid)})
    return items, subject, lip_mid, len(prompts), failed


def fig_quality(args) -> dict:
    """Live (look-ahead 100, 200 ms) and offline (animate) on the real prompts, real_voices' metrics."""
    from dualtalker_lite.checkpoints import load_checkpoint
    from dualtalker_lite.front_ends import at_test, from_settings
    from dualtalker_lite.inference import animate_wave
    from dualtalker_lite.live.server import load_config
    from dualtalker_lite.live.stream import LiveSession, LiveSettings
    from dualtalker_lite.metrics import lip_distance

    items, subject, lip_mid, n_all, failed = _real_prompts(args.every)
    import real_voices as rv  # importable now: _real_prompts put benchmarks/ on the path

    student = args.ears == "student"
    config = load_config(args.checkpoint, subject, settings=LiveSettings(ears=args.ears))
    _, ckpt = load_checkpoint(args.checkpoint)
    offline_ex = from_settings(ckpt.get("features"), args.checkpoint, cache=False)
    rows = {"reference rig (aligned phones)": [], "offline (animate)": []}
    if student:   # the student's ears offline too (animate --front-end student)
        rows["offline, student (animate --front-end student)"] = []
        student_ex = at_test(ckpt.get("features"), "student", args.checkpoint)
    aheads = args.ahead_frames or [LiveSettings.ahead_frames]

    def live_key(la: int, ahead: int, ears: str) -> str:  # the default encoder look-ahead keeps the rows' old names
        extra = "" if aheads == [LiveSettings.ahead_frames] else f", encoder look-ahead {ahead} frames"
        if ears == "student":
            return f"live, student (look-ahead {config.student.cfg.lookahead * 20} ms){extra}"
        return f"live, look-ahead {la} ms{extra}"
    # with --ears student: hama's live path at its default look-ahead beside the student's, on the same prompts
    looks = [(round(LiveSettings.lookahead_s * 1000), "hama"), (0, "student")] if student else \
        [(la, "hama") for la in args.lookaheads]
    configs = [(la, a, live_key(la, a, ears), ears) for la, ears in looks for a in aheads]
    rows.update({key: [] for _, _, key, _ in configs})
    cpu = {k: 0.0 for k in rows}
    corr = {key: [] for _, _, key, _ in configs}
    mismatched = 0
    hop = {"hop_s": args.hop} if args.hop else {}       # else LiveSettings' default
    if args.past:
        hop["past_s"] = args.past
    t_start = time.time()
    for i, it in enumerate(items):
        n = len(it["ref_curve"])
        rows["reference rig (aligned phones)"].append(it["ref_curve"])
        c0 = time.process_time()
        off = lip_distance(animate_wave(config.model, it["wave"], config.template, config.speaker,
                                        front_end=offline_ex), *lip_mid)
        cpu["offline (animate)"] += time.process_time() - c0
        mismatched += len(off) != n
        rows["offline (animate)"].append(off[:n])
        if student:
            c0 = time.process_time()
            off_s = lip_distance(animate_wave(config.model, it["wave"], config.template, config.speaker,
                                              front_end=student_ex), *lip_mid)
            cpu["offline, student (animate --front-end student)"] += time.process_time() - c0
            rows["offline, student (animate --front-end student)"].append(off_s[:n])
        for la, ahead, key, ears in configs:
            session = LiveSession(config.model, config.front_end, config.template, config.speaker,
                                  LiveSettings(lookahead_s=la / 1000, ahead_frames=ahead, ears=ears, **hop),
                                  student=config.student)
            out, c, _ = feed(session, it["wave"])
            cpu[key] += c
            live = lip_distance(np.concatenate([v for _, v in out]), *lip_mid)
            mismatched += len(live) != n
            rows[key].append(live[:n])
            m = min(len(live), len(off))
            if m > 2 and live[:m].std() > 0 and off[:m].std() > 0:
                corr[key].append(float(np.corrcoef(live[:m], off[:m])[0, 1]))
        if (i + 1) % 10 == 0:
            print(f"  {i + 1}/{len(items)} prompts, {time.time() - t_start:.0f} s", flush=True)
    audio_s = sum(len(it["wave"]) for it in items) / 16000
    segs = [it["segments"] for it in items]
    refs = [it["ref_curve"] for it in items]
    metrics = {k: rv.curve_metrics(v, refs, segs, rv.REAL_TOL) for k, v in rows.items()}
    for k in rows:
        metrics[k]["cpu_s_per_audio_s"] = cpu[k] / audio_s if cpu[k] else None
        if k in corr:
            metrics[k]["lip_corr_with_offline_mean"] = float(np.mean(corr[k]))
    return {"prompts_used": len(items), "prompts_total": n_all, "every": args.every, "failed_alignments": failed,
            "hop_s": hop.get("hop_s", LiveSettings.hop_s), "past_s": hop.get("past_s", LiveSettings.past_s),
            "ahead_frames": aheads,
            "audio_s": audio_s, "frame_count_mismatches": mismatched,
            "speaker": subject, "rows": metrics}


def simulate(session, wave: np.ndarray, piece: int = 1600, clock: str = "wall", marks_s=(60, 300, 600)) -> dict:
    """The server's scheduling on a virtual clock: message k (``piece`` samples) arrives when its last sample is
    captured (real-time pace); when idle, the worker pushes everything arrived so far (at most MAX_BATCH_S) and the
    clock moves on by the push's measured time (``clock``: "wall" = perf_counter, "cpu" = this thread's CPU time).
    -> per push (audio end s, clock s, wall s, cpu s, backlog s, frames) and per frame (output time, latency)."""
    from dualtalker_lite.live.server import MAX_BATCH_S

    N, rate = len(wave), 16000
    K = -(-N // piece)
    arrive = np.minimum((np.arange(K) + 1) * piece, N) / rate      # arrival of message k
    now, k, pushes, out_t, out_end, rss = 0.0, 0, [], [], [], {}
    marks = list(marks_s)
    while k < K:
        now = max(now, arrive[k])
        m = int(np.searchsorted(arrive, now, side="right"))           # messages arrived by now
        j, n = k, 0
        while j < m and n < MAX_BATCH_S * rate:
            n += min((j + 1) * piece, N) - j * piece
            j += 1
        backlog = (min(m * piece, N) - k * piece) / rate
        batch = wave[k * piece:min(j * piece, N)]
        w0, c0 = time.perf_counter(), time.thread_time()
        _, verts = session.push(batch)
        dw, dc = time.perf_counter() - w0, time.thread_time() - c0
        now += dw if clock == "wall" else dc
        out_t += [now] * len(verts)
        end_s = min(j * piece, N) / rate
        out_end += [end_s] * len(verts)
        pushes.append((end_s, now, dw, dc, backlog, len(verts)))
        while marks and end_s >= marks[0]:
            rss[marks.pop(0)] = _rss_mb()
        k = j
    out_t = np.asarray(out_t)
    need = np.ceil((np.arange(len(out_t)) + 1) * rate / 30).astype(np.int64)     # samples frame f needs
    done_at = np.minimum(np.ceil(need / piece) * piece, N) / rate                # message completing them arrives
    return {"pushes": np.asarray(pushes), "latency": out_t - done_at, "rss": rss, "out_t": out_t,
            "sample_s": need / rate, "message_s": done_at, "push_audio_end_s": np.asarray(out_end)}


def _speech(minutes: float) -> tuple[np.ndarray, int]:
    """``minutes`` of real speech: the real-voice prompts concatenated in name order, cycled."""
    prompts, *_ = _real_prompts(1, references=False)
    one = np.concatenate([p["wave"] for p in prompts]).astype(np.float32)
    need = int(minutes * 60 * 16000)
    return np.resize(one, need) if need > len(one) else one[:need], len(one)


def _lat(x: np.ndarray) -> dict:
    x = np.asarray(x) * 1000
    return {"frames": int(x.size), "median_ms": float(np.median(x)), "p95_ms": float(np.percentile(x, 95)),
            "max_ms": float(x.max())}


def fig_keepup(args) -> dict:
    from dualtalker_lite.live.server import load_config
    from dualtalker_lite.live.stream import LiveSession, LiveSettings

    wave, one = _speech(args.minutes)
    rss0 = _rss_mb()
    config = load_config(args.checkpoint, "SPK01", settings=LiveSettings(ears=args.ears))
    session = LiveSession(config.model, config.front_end, config.template, config.speaker, config.settings,
                          student=config.student)
    rss_loaded = _rss_mb()
    c0, w0 = time.process_time(), time.perf_counter()
    sim = simulate(session, wave, clock=args.clock,
                   marks_s=[s for s in (60, 300, 600, 900, 1200) if s <= len(wave) / 16000])
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    p = sim["pushes"]
    minute = (p[:, 0] // 60).astype(int)
    per_min = []
    for mi in range(minute.max() + 1):
        q = p[minute == mi]
        per_min.append({"minute": mi + 1, "pushes": len(q), "wall_s": float(q[:, 2].sum()),
                        "cpu_s": float(q[:, 3].sum()), "backlog_max_s": float(q[:, 4].max()),
                        "backlog_mean_s": float(q[:, 4].mean()), "behind_max_s": float((q[:, 1] - q[:, 0]).max()),
                        "push_wall_p95_ms": float(np.percentile(q[:, 2], 95) * 1000)})
    return {"audio_s": len(wave) / 16000, "source_s": one / 16000, "clock": args.clock, "pushes": len(p),
            "wall_s": wall, "cpu_s": cpu, "latency": _lat(sim["latency"]),
            "rss_mb_before_model": rss0, "rss_mb_loaded": rss_loaded,
            "rss_mb_at": {f"{int(s) // 60} min": {"now": v[0], "peak": v[1]} for s, v in sim["rss"].items()},
            "per_minute": per_min, "frames": int(len(sim["latency"])),
            "decoder_window": getattr(config.model.cfg, "decoder_window", None)}


def _live_server(checkpoint, lookahead_ms: int, ahead: int, ears: str = "hama"):
    """``dualtalker-lite live`` in its own process on a free port, once it listens -> (the process, the port)."""
    import os
    import socket
    import subprocess

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = subprocess.Popen([sys.executable, "-m", "dualtalker_lite.cli", "live", "--checkpoint",
                               str(checkpoint), "--port", str(port), "--lookahead-ms", str(lookahead_ms),
                               "--encoder-ahead-frames", str(ahead), "--ears", ears],
                              cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"})
    for _ in range(600):                       # up to 60 s for the model to load
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.1).close()
            return server, port
        except OSError:
            if server.poll() is not None:
                raise SystemExit(f"figures page: the live server exited: {server.stderr.read()[-500:]}")
            time.sleep(0.1)
    server.terminate()
    raise SystemExit("figures page: the live server did not listen within 60 s")


def _page_run(exe: str, wav: Path, port: int, seconds: float, synced: bool) -> dict:
    """The page in headless Chromium, its fake microphone playing ``wav`` (``seconds`` long), Start pressed (and
    the synced box ticked first, if ``synced``) -> the page's ``shownLatencyMs``, ``syncOffsetMs``, ``behind``
    and ``droppedFrames`` once all but the last second's frames are drawn."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, args=[
            "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
            "--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream",
            f"--use-file-for-fake-audio-capture={wav}%noloop", "--autoplay-policy=no-user-gesture-required"])
        try:
            page = browser.new_page(viewport={"width": 800, "height": 600})
            page.goto(f"http://127.0.0.1:{port}/")
            page.wait_for_function("() => window.dtlLive && (dtlLive.ready || dtlLive.error)", timeout=60000)
            if synced:
                page.check("input.synced")
            page.click("button.start")
            page.wait_for_function("() => dtlLive.running", timeout=60000)
            n = int(seconds * 30) - 30                 # all but the last second's frames
            page.wait_for_function(f"() => dtlLive.shown >= {n}", timeout=int(1000 * (2 * seconds + 60)))
            return page.evaluate("() => ({shown: dtlLive.shownLatencyMs, sync: dtlLive.syncOffsetMs, "
                                 "behind: dtlLive.behind, dropped: dtlLive.droppedFrames})")
        finally:
            browser.close()


def fig_page(args) -> dict:
    """The page's own latency in headless Chromium with a fake microphone (module docstring, ``page``); with
    ``--synced``, also the synced mode's audio/face offset per frame drawn."""
    import os
    import shutil
    import tempfile

    import soundfile as sf

    from dualtalker_lite.live.stream import LiveSettings

    exe = os.environ.get("DTL_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        raise SystemExit("figures page: no chromium (apt-get install chromium, or set DTL_CHROMIUM)")
    wave, _ = _speech(args.page_seconds / 60)
    warm = 3 * 30                                          # frames: the playout delay adapts over the first 3 s
    out = {"audio_s": len(wave) / 16000, "warm_up_frames_left_out": warm, "synced": bool(args.synced),
           "ears": args.ears, "lookaheads": {}}
    with tempfile.TemporaryDirectory() as tmp:
        wav = Path(tmp) / "speech.wav"
        sf.write(wav, wave, 16000, subtype="PCM_16")
        aheads = args.ahead_frames or [LiveSettings.ahead_frames]
        for la, ahead in [(la, ahead) for la in args.lookaheads for ahead in aheads]:
            key = str(la) if aheads == [LiveSettings.ahead_frames] else f"{la} ms, encoder look-ahead {ahead} frames"
            server, port = _live_server(args.checkpoint, la, ahead, args.ears)
            try:
                got = _page_run(exe, wav, port, len(wave) / 16000, args.synced)
            finally:
                server.terminate()
                server.wait(timeout=30)
            drawn = np.asarray(got["shown"], float).reshape(-1, 2)        # (frame, ms) per frame drawn
            kept = drawn[drawn[:, 0] >= warm]
            if len(kept) < 10:
                raise SystemExit(f"figures page: only {len(kept)} frames drawn after the warm-up at look-ahead {key}")
            row = {"page": _lat(kept[:, 1] / 1000), "frames_drawn": len(drawn),
                   "draws_per_s": len(drawn) / (len(wave) / 16000), "behind_messages": len(got["behind"]),
                   "dropped_ms": sum(m["dropped_ms"] for m in got["behind"]), "frames_not_drawn": got["dropped"]}
            if args.synced:
                row["sync_offset"] = _sync_offset(np.asarray(got["sync"], float).reshape(-1, 2), warm)
            out["lookaheads"][key] = row
            print(f"  look-ahead {key}: {row}", flush=True)
    return out


def _sync_offset(offsets: np.ndarray, warm: int) -> dict:
    """Synced mode's (frame, ms) offsets (the frame's draw minus the time its sound was heard, by the page's
    clocks; + = the face after the sound), warm-up frames left out -> median, p95 of |offset|, and the share
    within the +-45 ms target (ITU-R BT.1359)."""
    x = offsets[offsets[:, 0] >= warm, 1]
    if not len(x):
        raise SystemExit("figures page --synced: no synced frames drawn after the warm-up")
    return {"frames": int(len(x)), "median_ms": float(np.median(x)), "mean_ms": float(x.mean()),
            "p5_ms": float(np.percentile(x, 5)), "p95_ms": float(np.percentile(x, 95)),
            "p95_abs_ms": float(np.percentile(np.abs(x), 95)), "within_45ms": float(np.mean(np.abs(x) <= 45))}


def fig_latency(args) -> dict:
    from dualtalker_lite.audio import load_audio
    from dualtalker_lite.live.server import load_config
    from dualtalker_lite.live.stream import LiveSession, LiveSettings

    wave, _ = _speech(args.latency_minutes)
    config = load_config(args.checkpoint, "SPK01")
    out = {"audio_s": len(wave) / 16000, "clock": args.clock, "lookaheads": {}}
    import warnings
    clips = []
    for p in sorted((ROOT / "notebooks" / "data" / "real").glob("*.flac")):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            clips.append(load_audio(p))
    for la in sorted({0, 100, 200, round(1000 * LiveSettings.lookahead_s)}):     # and the default's
        s = LiveSettings(lookahead_s=la / 1000, ears="hama")
        session = LiveSession(config.model, config.front_end, config.template, config.speaker, s)
        sim = simulate(session, wave, clock=args.clock)
        algo = s.latency_s(config.front_end.fps, config.front_end.lag_s, config.front_end.window_s)
        lat = np.concatenate([asyncio_run_latency(args.checkpoint, "SPK01", w, la / 1000) for w in clips])
        out["lookaheads"][str(la)] = {"algorithmic_ms": algo * 1000, "hop_ms": s.hop_s * 1000,
                                      "session": _lat(sim["latency"]),
                                      "push_wall_median_ms": float(np.median(sim["pushes"][:, 2]) * 1000),
                                      "server_real_time_shipped_clips": _lat(lat)}
        print(f"  look-ahead {la} ms: {out['lookaheads'][str(la)]}", flush=True)
    return out


def fig_breakdown(args) -> dict:
    """Where a frame's latency goes, server side, sample captured -> vertices out (issue 33 item 4), paired: every
    configuration (message size ``piece``, recogniser hop) runs on the same speech, interleaved, ``--reps`` times, so
    the load is shared. Per frame f (newest sample at t = ceil((f + 1) 16000 / 30) / 16000 s):

        message  = arrival of the message holding t  - t        (the page's chunking: up to piece / 16000)
        budget   = look-ahead + lag + spike window + encoder look-ahead frames / fps   (fixed, LiveSettings.latency_s)
        hop      = end of the audio of the push that emitted f - (t + message + budget)   (waiting for a hop, and
                   rounding to whole messages and recogniser frames)
        compute  = vertices out - end of that push's audio     (hama + the decoder step, and any queue behind them)

    The parts sum to the total. The page's own share (playout buffer, one screen refresh) is outside this process."""
    import os

    from dualtalker_lite.live.server import load_config
    from dualtalker_lite.live.stream import LiveSession, LiveSettings

    wave, _ = _speech(args.latency_minutes)
    config = load_config(args.checkpoint, "SPK01")
    fe = config.front_end
    configs = [(la, piece, hop) for la in args.lookaheads for piece, hop in ((1600, 0.2), (640, 0.2), (1600, 0.1),
                                                                            (640, 0.1))]
    runs = {c: [] for c in configs}
    for rep in range(args.reps):
        for la, piece, hop in configs:
            s = LiveSettings(lookahead_s=la / 1000, hop_s=hop, ears="hama")
            session = LiveSession(config.model, fe, config.template, config.speaker, s)
            c0 = time.process_time()
            sim = simulate(session, wave, piece=piece, clock=args.clock)
            cpu = time.process_time() - c0
            budget = s.latency_s(fe.fps, fe.lag_s, fe.window_s)
            t, msg, end, out = sim["sample_s"], sim["message_s"], sim["push_audio_end_s"], sim["out_t"]
            n = min(len(out), len(t))
            t, msg, end, out = t[:n], msg[:n], end[:n], out[:n]
            parts = {"message": msg - t, "budget": np.full(n, budget), "hop": end - msg - budget,
                     "compute": out - end, "total": out - t}
            runs[(la, piece, hop)].append({
                "load_avg_1min": os.getloadavg()[0], "cpu_s_per_audio_s": cpu / (len(wave) / 16000),
                "mean_ms": {k: float(v.mean() * 1000) for k, v in parts.items()},
                "total": _lat(parts["total"])})
            r = runs[(la, piece, hop)][-1]
            print(f"  rep {rep + 1} look-ahead {la} piece {piece} hop {hop}: total median/p95 "
                  f"{r['total']['median_ms']:.0f}/{r['total']['p95_ms']:.0f} ms, cpu {r['cpu_s_per_audio_s']:.2f} "
                  f"s/s, load {r['load_avg_1min']:.2f}", flush=True)
    res = {"audio_s": len(wave) / 16000, "clock": args.clock, "reps": args.reps,
           "runs": [{"lookahead_ms": la, "piece": piece, "hop_s": hop, "reps": runs[(la, piece, hop)]}
                    for la, piece, hop in configs]}
    res["table_md"] = breakdown_table(res)
    print(res["table_md"])
    return res


def breakdown_table(res: dict) -> str:
    """The breakdown as a markdown table: each part's mean and the total's median / p95, as the median over the
    repetitions (one row per configuration), with the 1-minute load average of each repetition."""
    head = ("| look-ahead ms | message (samples) | hop s | message wait | fixed budget | hop wait | compute "
            "| total mean | total median / p95 | CPU s per s | load avg per rep |\n|" + "---:|" * 11)
    rows = [head]
    for r in res["runs"]:
        reps = r["reps"]
        m = {k: np.median([x["mean_ms"][k] for x in reps]) for k in reps[0]["mean_ms"]}
        med = np.median([x["total"]["median_ms"] for x in reps])
        p95 = np.median([x["total"]["p95_ms"] for x in reps])
        cpu = np.median([x["cpu_s_per_audio_s"] for x in reps])
        load = " / ".join(f"{x['load_avg_1min']:.1f}" for x in reps)
        rows.append(f"| {r['lookahead_ms']} | {r['piece']} | {r['hop_s']} | {m['message']:.0f} | {m['budget']:.0f} | "
                    f"{m['hop']:.0f} | {m['compute']:.0f} | {m['total']:.0f} | {med:.0f} / {p95:.0f} | {cpu:.2f} | "
                    f"{load} |")
    return "\n".join(rows)


def fig_diagnose(args) -> dict:
    """Which approximation costs the live path its closures: the causal viseme track or the encoder's bounded
    context? On every ``--every``-th prompt: offline; the offline track through the incremental decoder; the live
    track (look-ahead 200 ms) through the offline decoder (``animate_wave`` fed that track); the live path."""
    import torch

    from dualtalker_lite.checkpoints import load_checkpoint
    from dualtalker_lite.front_ends import from_settings
    from dualtalker_lite.inference import animate_wave
    from dualtalker_lite.live.server import load_config
    from dualtalker_lite.live.stream import IncrementalDecoder, LiveSession, LiveSettings, StreamingVisemes
    from dualtalker_lite.metrics import lip_distance

    items, subject, lip_mid, n_all, failed = _real_prompts(args.every)
    import real_voices as rv

    config = load_config(args.checkpoint, subject)
    _, ckpt = load_checkpoint(args.checkpoint)
    offline_ex = from_settings(ckpt.get("features"), args.checkpoint, cache=False)
    eye = np.eye(config.front_end.dim, dtype=np.float32)
    names = ["offline (animate)", "offline track -> incremental decoder (encoder 60 back / 3 ahead)",
             "live track (200 ms) -> offline decoder", "live, look-ahead 200 ms"]
    rows = {k: [] for k in names}
    for i, it in enumerate(items):
        wave, n = it["wave"], len(it["ref_curve"])
        off_ids = offline_ex.viseme_ids(wave, n)
        rows[names[0]].append(lip_distance(animate_wave(config.model, wave, config.template, config.speaker,
                                                        front_end=lambda w, k: torch.from_numpy(eye[off_ids])),
                                           *lip_mid)[:n])
        dec = IncrementalDecoder(config.model, config.template, config.speaker, 60, 3)
        v = np.concatenate([dec.push(eye[off_ids]), dec.flush()])
        rows[names[1]].append(lip_distance(v, *lip_mid)[:n])
        track = StreamingVisemes(config.front_end, 0.2)
        out, _, _ = feed(track, wave)
        live_ids = np.concatenate(out)[:n]
        rows[names[2]].append(lip_distance(animate_wave(config.model, wave, config.template, config.speaker,
                                                        front_end=lambda w, k: torch.from_numpy(eye[live_ids])),
                                           *lip_mid)[:n])
        session = LiveSession(config.model, config.front_end, config.template, config.speaker,
                              LiveSettings(lookahead_s=0.2, ears="hama"))
        out, _, _ = feed(session, wave)
        rows[names[3]].append(lip_distance(np.concatenate([v for _, v in out]), *lip_mid)[:n])
        if (i + 1) % 10 == 0:
            print(f"  {i + 1}/{len(items)} prompts", flush=True)
    segs, refs = [it["segments"] for it in items], [it["ref_curve"] for it in items]
    return {"prompts_used": len(items), "prompts_total": n_all, "every": args.every, "failed_alignments": failed,
            "rows": {k: rv.curve_metrics(v, refs, segs, rv.REAL_TOL) for k, v in rows.items()}}


def figures(argv) -> None:
    import torch

    ap = argparse.ArgumentParser(prog="benchmarks/live.py figures")
    ap.add_argument("step", choices=["quality", "keepup", "latency", "breakdown", "diagnose", "page", "report"])
    ap.add_argument("--checkpoint", default="runs/live_dt.pt")
    ap.add_argument("--every", type=int, default=3, help="quality: every n-th real prompt")
    ap.add_argument("--lookaheads", type=int, nargs="+", default=[100, 200])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--latency-minutes", type=float, default=2.0)
    ap.add_argument("--page-seconds", type=float, default=60.0,
                    help="page: seconds of speech the fake microphone plays")
    ap.add_argument("--synced", action="store_true",
                    help="page: tick the page's synced box and measure the audio/face offset (target +-45 ms)")
    ap.add_argument("--clock", choices=["wall", "cpu"], default="wall")
    ap.add_argument("--hop", type=float, default=None, help="quality: the recogniser hop (LiveSettings' default)")
    ap.add_argument("--past", type=float, default=None,
                    help="quality: the recogniser's past context in s (LiveSettings' default)")
    ap.add_argument("--ahead-frames", type=int, nargs="+", default=None,
                    help="quality, page: the audio encoder's look-ahead(s) in mesh frames (LiveSettings' default)")
    ap.add_argument("--reps", type=int, default=2, help="breakdown: interleaved repetitions of every configuration")
    ap.add_argument("--ears", choices=["hama", "student"], default="hama",
                    help="quality, keepup, page: who hears the visemes live (student: its own look-ahead; quality "
                         "adds hama's live path at its default); the step's file is <step>_student.json")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "live")
    ap.add_argument("--keep-earlier", type=Path, default=None, help="report: keep this earlier report whole")
    ap.add_argument("--earlier-key", default=None, help="report: the key it is kept under")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    FIG_DIR.mkdir(parents=True, exist_ok=True)
    if args.step == "report" and args.ears == "student":   # the student's steps only, beside the hama report
        return report(ROOT / "results" / "live_student", steps=tuple(k for k in FIG_STEPS if k.endswith("_student")),
                      command="python benchmarks/live.py figures report --ears student")
    if args.step == "report":
        return report(args.out, args.keep_earlier, args.earlier_key,
                      steps=tuple(k for k in FIG_STEPS if not k.endswith("_student")))
    t0, c0 = time.time(), time.process_time()
    stamp = provenance("OMP_NUM_THREADS=1 python benchmarks/live.py figures " + " ".join(argv))  # the code measured
    res = {"quality": fig_quality, "keepup": fig_keepup, "latency": fig_latency,
           "breakdown": fig_breakdown, "diagnose": fig_diagnose, "page": fig_page}[args.step](args)
    res["meta"] = {"command": stamp["command"], "commit": stamp["commit"], "machine": stamp["machine"],
                   "checkpoint": args.checkpoint, "wall_s": time.time() - t0,
                   "cpu_s": time.process_time() - c0, "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                   "load_avg": list(__import__("os").getloadavg())}
    path = FIG_DIR / f"{args.step}{'_student' if args.ears == 'student' else ''}.json"
    path.write_text(json.dumps(res, indent=1, default=float))
    print(json.dumps({k: v for k, v in res.items() if k not in ("per_minute",)}, indent=1, default=float)[:6000])
    print(f"-> {path}")


FIG_STEPS = ("quality", "keepup", "latency", "breakdown", "diagnose", "page", "quality_student", "keepup_student",
             "page_student")


def report(out: Path, earlier: Path | None = None, key: str | None = None, steps: tuple = FIG_STEPS,
           command: str = "python benchmarks/live.py figures report") -> None:
    """Join the steps' files into ``out``.json; ``earlier``: a previous report kept whole under ``key`` (figures of
    an older default that the page still quotes), or, when that report already has ``key`` (it is the current
    ``out`` itself, re-made after a step changed), its entry under ``key``: the same command re-makes the file."""
    parts = {k: json.loads((FIG_DIR / f"{k}.json").read_text()) for k in steps if (FIG_DIR / f"{k}.json").is_file()}
    out.parent.mkdir(parents=True, exist_ok=True)
    if earlier is not None:
        doc = json.loads(Path(earlier).read_text())
        parts[key or "earlier"] = doc.get(key or "earlier", doc)
        command += f" --keep-earlier {earlier} --earlier-key {key or 'earlier'}"
    parts["report"] = provenance(command)  # each step's stamp is in its meta
    atomic_write_text(out.with_suffix(".json"), json.dumps(parts, indent=1))
    print(f"-> {out.with_suffix('.json')} ({', '.join(parts)})")

if __name__ == "__main__":
    main()
