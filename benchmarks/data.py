"""Data figures of the foundation issue: template size, time to generate 300 clips, time to load the sample.

    .venv/bin/python benchmarks/data.py [--clips 300] [--processes 2]
"""
import argparse
import tempfile
import time

from dualtalker_lite.data.generate import CorpusSpec, generate_corpus

ap = argparse.ArgumentParser()
ap.add_argument("--processes", type=int, default=2)
args = ap.parse_args()

t0 = time.perf_counter()
from dualtalker_lite.data import sample_path  # noqa: E402
from dualtalker_lite.data.corpus import Corpus  # noqa: E402
from dualtalker_lite.data.dataset import TalkingFaceDataset  # noqa: E402

t_import = time.perf_counter() - t0
t0 = time.perf_counter()
corpus = Corpus(sample_path())
sets = {s: TalkingFaceDataset(corpus, s) for s in ("train", "val", "test_a", "test_b")}
t_load = time.perf_counter() - t0
meta = corpus.metadata
frames = sum(c["n_frames"] for c in meta["clips"].values())
size = sum(p.stat().st_size for p in sample_path().rglob("*") if p.is_file())
print(f"sample: {len(meta['clips'])} clips, {frames} frames ({frames / 30 / 60:.1f} min), {meta['n_vertices']} vertices, "
      f"{len(corpus.faces)} triangles, {size / 1e6:.1f} MB; splits {{{', '.join(f'{k}: {len(v)}' for k, v in sets.items())}}}")
print(f"loading the whole sample (rig reconstruction + log-mel features of every split): {t_load:.2f} s "
      f"(+ {t_import:.1f} s of imports)")

with tempfile.TemporaryDirectory() as tmp:
    spec = CorpusSpec.sample()  # exactly 300 clips
    t0 = time.perf_counter()
    meta = generate_corpus(spec, tmp, processes=args.processes, progress=False)
    t_gen = time.perf_counter() - t0
print(f"generating {len(meta['clips'])} clips (speech + faces, {args.processes} processes): {t_gen:.1f} s")
