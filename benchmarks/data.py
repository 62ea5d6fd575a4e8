"""Data figures: the sample's size and splits, time to load all of it, time to generate it, upper-face probe.

    .venv/bin/python benchmarks/data.py [--processes 2] [--skip-generation]

Load time: ``Corpus`` + ``TalkingFaceDataset`` (rig reconstruction + log-mel features) of every split,
wall clock and CPU time of this process (one torch thread). Generation: the whole ``sample`` preset into a
temporary folder with ``--processes`` espeak-ng workers (wall clock: it waits on the workers). Timings on a
shared machine are inflated by other jobs; the CPU time of the load is the steadier figure.
"""
import argparse
import os
import tempfile
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

ap = argparse.ArgumentParser()
ap.add_argument("--processes", type=int, default=2)
ap.add_argument("--skip-generation", action="store_true")
args = ap.parse_args()

t0 = time.perf_counter()
import torch  # noqa: E402

from dualtalker_lite.data import sample_path  # noqa: E402
from dualtalker_lite.data.corpus import Corpus  # noqa: E402
from dualtalker_lite.data.dataset import TalkingFaceDataset  # noqa: E402
from dualtalker_lite.data.generate import CorpusSpec, generate_corpus  # noqa: E402

torch.set_num_threads(1)
t_import = time.perf_counter() - t0
t0, c0 = time.perf_counter(), time.process_time()
corpus = Corpus(sample_path())
sets = {s: TalkingFaceDataset(corpus, s) for s in corpus.metadata["splits"]}
t_load, c_load = time.perf_counter() - t0, time.process_time() - c0
meta = corpus.metadata
frames = sum(c["n_frames"] for c in meta["clips"].values())
size = sum(p.stat().st_size for p in sample_path().rglob("*") if p.is_file())
print(f"sample: {len(meta['clips'])} clips, {frames} frames ({frames / 30 / 60:.1f} min), {meta['n_vertices']} vertices, "
      f"{len(corpus.faces)} triangles, {size / 1e6:.2f} MB")
print("splits: " + ", ".join(f"{k} {len(v)}" for k, v in sets.items()))
by_emotion: dict[str, int] = {}
for c in meta["clips"].values():
    key = c["emotion"] if c["emotion"] == "neutral" else f"{c['emotion']}{c['level']}"
    by_emotion[key] = by_emotion.get(key, 0) + 1
print("clips per emotion and level: " + ", ".join(f"{k} {v}" for k, v in sorted(by_emotion.items())))
print(f"pseudo-pair groups (same speaker + sentence, neutral and emotional clips): {len(meta['pairs'])}")
long = [meta["clips"][n]["n_samples"] / meta["sample_rate"] for n in meta["splits"].get("long", [])]
print(f"long clips: {', '.join(f'{d:.1f} s' for d in long)}")
print(f"loading the whole sample (all {len(sets)} splits: rig reconstruction + log-mel features): "
      f"{t_load:.2f} s wall, {c_load:.2f} s CPU (+ {t_import:.1f} s of imports)")

if not args.skip_generation:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        gen = generate_corpus(CorpusSpec.sample(), tmp, processes=args.processes, progress=False)
        t_gen = time.perf_counter() - t0
    print(f"generating the sample ({len(gen['clips'])} clips, speech + faces, {args.processes} processes): {t_gen:.1f} s")
