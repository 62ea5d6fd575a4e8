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
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

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
        from dualtalker_lite.checkpoints import extractor_from_settings, load_checkpoint
        from dualtalker_lite.data import sample_path
        from dualtalker_lite.data.corpus import Corpus
        from dualtalker_lite.inference import animate_wave, resolve_speaker
        from dualtalker_lite.metrics import lip_distance

        model, ckpt = load_checkpoint(args.checkpoint)
        extractor = extractor_from_settings(ckpt.get("features"), args.checkpoint)
        corpus = Corpus(sample_path())
        speaker, _ = resolve_speaker(ckpt, args.speaker, corpus)
        template = corpus.template(args.speaker)
        up, lo = corpus.regions["lip_midpoints"]
        print(f"\nwhole live path ({Path(args.checkpoint).name}) vs offline animate; encoder context in frames")
        print(f"{'clip':>22} {'past':>4} {'ahead':>5} {'frames':>6} {'lip corr':>8} {'live std mm':>11} "
              f"{'offline std mm':>14} {'cpu/s':>6}")
        offline_verts = {name: animate_wave(model, wave, template, speaker, extractor=extractor)
                         for name, wave in waves.items()}
        for past, ahead in [(60, 3), (60, 0), (30, 3), (120, 6)]:   # the first is LiveSettings' default
            for name, wave in waves.items():
                session = LiveSession(model, extractor, template, speaker,
                                      LiveSettings(past_frames=past, ahead_frames=ahead))
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


def asyncio_run_latency(checkpoint: str, speaker: str, wave: np.ndarray) -> list[float]:
    """Stream ``wave`` through the live server in real time -> seconds from the message completing each frame's
    audio to that frame's arrival (frames flushed by the final ``stop`` are left out)."""
    import asyncio
    import json

    from aiohttp.test_utils import TestClient, TestServer

    from dualtalker_lite.live.server import HEADER, load_config, make_app

    config = load_config(checkpoint, speaker)
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


if __name__ == "__main__":
    main()
