"""Run machinery of the experiment runner: data (cached per process), training sets, features and models of a row,
:func:`run_one` (train one row with one seed, evaluate, check for collapse) and :func:`run_specs` (jobs in this
process or in a spawn pool of workers with one torch thread each; ``_job``/``_worker_init`` live here so that
spawned workers import them by this module's path).
"""
from __future__ import annotations

import copy
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict
from multiprocessing import get_context
from pathlib import Path

import torch
from torch.utils.data import Dataset

from .assembly import PHONETIC, feature_view, assemble_training, build_model  # noqa: F401 - re-exported
from .evaluation import (AudioSwapped, audio_sensitivity, collapse_reasons, emotion_split_metrics,
                         predict_split, split_metrics, swap_partners)
from .. import front_ends
from ..console import ProgressLines
from .specs import EMOTIONAL_TRAIN, QUICK_CLIPS, TEST_SPLIT, RunSpec

# ------------------------------------------------------------------------------------------- data and models
_DATA: dict = {}  # per process: (corpus path, quick) -> data dict (features are computed once per process)


def _trimmed(corpus, counts: dict):
    """A shallow view of ``corpus`` whose splits keep only their first ``counts[split]`` clips (--quick), or, where
    ``counts[split]`` is a list of clip names, those clips of the split (in the split's order)."""
    view = copy.copy(corpus)
    splits = dict(corpus.metadata["splits"])
    for split, n in counts.items():
        if isinstance(n, int):
            splits[split] = list(splits[split])[:n]
        else:
            missing = sorted(set(n) - set(splits[split]))
            if missing:
                raise ValueError(f"clips {missing[:3]} are not in split {split!r}")
            splits[split] = [c for c in splits[split] if c in set(n)]
    view.metadata = {**corpus.metadata, "splits": splits}
    return view


def load_data(corpus_path: str | Path | None = None, quick: bool = False, clips: dict | None = None) -> dict:
    """Corpus, train and test-A datasets (log-mel), regions, sizes; cached per process. Other splits:
    :func:`data_split` (loaded on first use, cached in the same dict). ``clips`` ({split: n}, e.g. a benchmark's
    reduced training set): keep only the first n clips of those splits, or the named clips where n is a list of names
    (applied after ``quick``'s trim)."""
    from ..data import sample_path
    from ..data.corpus import Corpus
    from ..data.dataset import TalkingFaceDataset

    path = str(Path(corpus_path or sample_path()).resolve())
    key = (path, quick, repr(sorted((clips or {}).items())))
    if key not in _DATA:
        corpus = Corpus(path)
        view = _trimmed(corpus, QUICK_CLIPS) if quick else corpus
        view = _trimmed(view, clips) if clips else view
        train_set, test_set = TalkingFaceDataset(view, "train"), TalkingFaceDataset(view, TEST_SPLIT)
        _DATA[key] = {"corpus": corpus, "view": view, "path": path, "train": train_set, "test": test_set,
                      "splits": {"train": train_set, TEST_SPLIT: test_set},
                      "n_vertices": int(train_set[0]["template"].numel() // 3),
                      "n_speakers": len(corpus.train_speakers), "n_phonemes": len(corpus.phoneme_inventory)}
    return _DATA[key]


def data_split(data: dict, split: str) -> Dataset:
    """The log-mel dataset of ``split`` (of the --quick view when ``data`` is quick), cached in ``data``."""
    from ..data.dataset import TalkingFaceDataset

    if split not in data["splits"]:
        data["splits"][split] = TalkingFaceDataset(data["view"], split, data["train"].front_end)
    return data["splits"][split]


def test_features(data: dict, split: str, features: str) -> Dataset:
    """What a row is evaluated on: for the phonetic features the recogniser's per-frame viseme classes of the
    split's audio (``RecogniserExtractor``, hama; computed once, cached under the user cache dir; "visemes+logmel"
    appends the log-mel), never the corpus's labels; for the other features :func:`feature_view` of the log-mel split."""
    if features not in PHONETIC:
        return feature_view(data_split(data, split), features, data["n_phonemes"])[0]
    from ..data.dataset import TalkingFaceDataset

    cache = data.setdefault("recognised", {})
    if (split, features) not in cache:
        cache[split, features] = TalkingFaceDataset(data["view"], split, front_ends.build(features,
                                                                                          data["corpus"].fps))
    return cache[split, features]


def training_set(data: dict, spec: RunSpec, seed: int) -> tuple[Dataset, bool]:
    """The clips a row trains on (``spec.data``) -> (dataset, whether it needs the pair loader)."""
    from torch.utils.data import ConcatDataset

    if spec.data == "neutral":
        return data["train"], False
    if spec.data == "emotional":
        return ConcatDataset([data_split(data, s) for s in EMOTIONAL_TRAIN]), False
    from ..data.pairs import PairDataset

    return PairDataset(data["view"], EMOTIONAL_TRAIN, front_end=data["train"].front_end, seed=seed), True


def run_one(spec: RunSpec | dict, seed: int, epochs: int | None, corpus_path: str | None = None, quick: bool = False,
            checkpoint: str | Path | None = None, time_budget_s: float | None = None,
            test_split: str = TEST_SPLIT, clips: dict | None = None, recipe: str = "tiny",
            cpu_budget_s: float | None = None, epoch_lines_s: float | None = None) -> dict:
    """Train one row with one seed for ``epochs`` epochs (1 torch thread), evaluate on ``test_split`` -> a result.

    ``recipe``: "tiny" (``TrainConfig.tiny``, the tables') or "fast" (``TrainConfig.fast``, the demo's); ``epochs``
    None: the recipe's own budget for the row's model.

    The training clips come from ``spec.data`` (:func:`training_set`; "pairs" uses ``data.pairs.make_pair_loader``,
    so EmoFace's cross-reconstruction happens). On a split with more than one emotion the emotional metrics are
    added (:func:`emotion_split_metrics`). The collapse check swaps in the audio of another sentence; on a split
    whose clips all read one sentence (``test_emo_a``) that audio comes from ``TEST_SPLIT``.

    ``checkpoint``: also save the trained model there. ``time_budget_s`` (the demo only; the tables never use it):
    stop after the epoch in which that many seconds have passed, so the epoch count depends on the machine;
    ``cpu_budget_s`` (the demo's default): the same in CPU seconds of this process, which another job on the machine
    barely changes.
    ``clips`` ({split: n}; benchmarks only): train and test on the first n clips of those splits (:func:`load_data`).
    ``epoch_lines_s`` (the demo): progress lines on stderr, per epoch at most that often (:func:`_epoch_lines`)."""
    from ..train import train

    spec = RunSpec(**spec) if isinstance(spec, dict) else spec
    threads = torch.get_num_threads()
    try:
        data = load_data(corpus_path, quick, clips)
        base_train, paired = training_set(data, spec, seed)
        test_set = test_features(data, test_split, spec.features)
        run = assemble_training(spec, base_train, data["view"], paired=paired, seed=seed, epochs=epochs, threads=1,
                                time_budget_s=time_budget_s, cpu_budget_s=cpu_budget_s,
                                logmel=data["train"].front_end, recipe=recipe)
        model, model_cfg, train_cfg = run.model, run.model_config, run.train_config
        t0 = time.perf_counter()
        lines = _epoch_lines(spec, seed, train_cfg.epochs, epoch_lines_s if run.loader is not None else None)
        history = None if run.loader is None else train(model, run.loader, train_cfg, on_epoch=lines)
        train_seconds = time.perf_counter() - t0
        if checkpoint is not None and model_cfg is not None:
            _save_row_checkpoint(checkpoint, run, history, data["corpus"])
        t1 = time.perf_counter()
        out = predict_split(model, test_set)
        metrics, per_emotion = _test_metrics(model, test_set, out, data["corpus"])
        reasons = _collapse_check(model, spec, data, test_set, out, test_split, metrics)
        result = {"row": spec.row, "key": spec.key(test_split), "seed": seed,
                  "epochs": len(history.terms) if history else 0,
                  "metrics": metrics, "collapsed": bool(reasons), "collapse_reasons": reasons,
                  "train_seconds": train_seconds, "eval_seconds": time.perf_counter() - t1,
                  "train_cpu_seconds": history.cpu_seconds[-1] if history and history.cpu_seconds else 0.0,
                  "steps": history.steps[-1] if history and history.steps else 0,
                  "n_parameters": sum(p.numel() for p in model.parameters() if p.requires_grad),
                  "model_config": asdict(model_cfg) if model_cfg is not None else None,
                  "train_config": {k: v for k, v in asdict(train_cfg).items()},
                  "loss_history": history.terms if history else [],
                  "test_clips": out["names"], "n_train_clips": len(run.train_set), "pid": os.getpid()}
        if test_split != TEST_SPLIT:
            result["test_split"] = test_split
        if per_emotion is not None:
            result["emotion_expression"] = per_emotion
        return result
    finally:
        torch.set_num_threads(threads)


def _epoch_lines(spec: RunSpec, seed: int, epochs: int, every_s: float | None):
    """``run_one``'s ``on_epoch`` for ``epoch_lines_s``: a :class:`~dualtalker_lite.console.ProgressLines` line on
    stderr after the first and the last epoch and after any epoch that ends ``every_s`` seconds or more after the
    previous line (``DualTalker, seed 0: epoch 7/20, loss 0.0123, 0:14 elapsed, about 0:26 left``), after one line
    saying the training starts (the data are ready; the first epoch also sets up); None: none."""
    if every_s is None:
        return None
    print(f"{spec.row}, seed {seed}: data ready, training {epochs} epochs (the first also sets up)", file=sys.stderr,
          flush=True)
    lines = ProgressLines(f"{spec.row}, seed {seed}: epoch", epochs, every_s=every_s)
    return lambda model, history: lines.update(len(history.terms),
                                               loss=f"{history.terms[-1].get('total', math.nan):.4g}")


def _save_row_checkpoint(path: str | Path, run, history, corpus) -> None:
    """Save a trained row's model with its recipe, history, training speakers, faces and front end (a phonetic
    row records the recogniser, so the checkpoint animates any voice)."""
    from ..checkpoints import save_checkpoint

    save_checkpoint(path, run.model, run.model_config, run.train_config, history, speakers=corpus.train_speakers,
                    faces=corpus.faces, features=run.features)


def _test_metrics(model, test_set: Dataset, out: dict, corpus) -> tuple[dict, dict | None]:
    """The row's metrics on its test split (:func:`split_metrics`) -> ``(metrics, per-emotion expression or None)``;
    on a split with more than one emotion, the emotional metrics join them (:func:`emotion_split_metrics`)."""
    metrics = split_metrics(out, corpus.regions, [corpus.meta(n)["phonemes"] for n in out["names"]])
    per_emotion = None
    if len({corpus.meta(n).get("emotion", "neutral") for n in out["names"]}) > 1:
        extra, per_emotion = emotion_split_metrics(model, test_set, out, corpus.emotions, corpus.regions)
        metrics.update(extra)
    return metrics, per_emotion


def _collapse_check(model, spec: RunSpec, data: dict, test_set: Dataset, out: dict, test_split: str,
                    metrics: dict) -> list[str]:
    """The collapse check: the same faces driven by another sentence's audio -> the reasons a row collapsed.

    Sets ``metrics["audio_sensitivity"]`` (:func:`audio_sensitivity` on the lips; 0 for the static template, which
    ignores the audio by design). On a split whose clips all read one sentence (``test_emo_a``) the swapped-in
    audio comes from ``TEST_SPLIT``."""
    metrics["audio_sensitivity"] = 0.0
    if spec.model == "template":
        return []
    corpus = data["corpus"]
    sentences = [corpus.meta(n).get("sentence_id", n) for n in out["names"]]
    source = None
    if len(set(sentences)) == 1 and test_split != TEST_SPLIT:  # one sentence: borrow test-A's audio
        source = test_features(data, TEST_SPLIT, spec.features)
    ids = None if source is None else [corpus.meta(source[i]["name"]).get("sentence_id") for i in range(len(source))]
    partners = swap_partners(sentences, ids)
    swapped = predict_split(model, AudioSwapped(test_set, partners, source))
    metrics["audio_sensitivity"] = audio_sensitivity(out["preds"], swapped["preds"], out["gts"],
                                                     corpus.regions["lips"])
    return collapse_reasons(metrics)


def _worker_init(parent_pid: int | None = None) -> None:
    """Set up a spawned pool worker: one torch thread, Ctrl-C left to the parent, exit when the parent dies."""
    import signal

    from ..processes import watch_parent

    torch.set_num_threads(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is handled once, by the parent (run_specs)
    watch_parent(parent=parent_pid)  # exit when the parent dies instead of training on and hanging on the pipe


def _job(args: tuple) -> tuple[int, dict]:
    """One job of :func:`run_specs` (a plain tuple, so it pickles to a worker) -> (its index, :func:`run_one`'s
    result)."""
    index, spec, seed, epochs, corpus_path, quick, checkpoint, budget, split, recipe, cpu_budget, lines_s = args
    return index, run_one(spec, seed, epochs, corpus_path, quick, checkpoint, budget, split, recipe=recipe,
                          cpu_budget_s=cpu_budget, epoch_lines_s=lines_s)


def executor_kind(executor: str) -> str:
    """``--executor`` -> "local", "dask" (a LocalCluster here) or the scheduler address of ``dask://HOST:PORT``
    (given as ``tcp://HOST:PORT``, what dask's clients take); one ValueError line for anything else."""
    if executor in ("local", "dask"):
        return executor
    for prefix in ("dask://", "tcp://"):
        if executor.startswith(prefix):
            host, _, port = executor[len(prefix):].rpartition(":")
            if host and port.isdigit():
                return f"tcp://{host}:{port}"
    raise ValueError(f"--executor {executor!r}: expected local, dask or dask://HOST:PORT (a running dask scheduler)")


def _dask_job(args: tuple) -> tuple[int, dict]:
    """One job on a dask worker: one torch thread, as in the local pool (a worker may hold several jobs over its
    life; each reseeds everything, so the thread count is all that must match)."""
    torch.set_num_threads(1)
    return _job(args)


def run_specs(jobs: list[tuple], epochs: int | None, processes: int = 1, corpus_path: str | None = None,
              quick: bool = False, checkpoints: list | None = None, progress: bool = True,
              time_budget_s: float | None = None, recipe: str = "tiny", executor: str = "local",
              failures: list | None = None, cpu_budget_s: float | None = None,
              epoch_lines_s: float | None = None) -> list[dict]:
    """Run (spec, seed) or (spec, seed, test split) jobs -> results in job order.

    ``executor`` "local": in this process (``processes=1``) or in a spawn pool of ``processes`` workers; a failed
    run stops them all and raises. "dask": the same jobs on a dask ``LocalCluster`` of ``processes`` worker
    processes (one thread each) on this machine; ``dask://HOST:PORT``: on a running dask scheduler's workers (a
    cluster started by dask-jobqueue, or ``dask scheduler`` / ``dask worker`` by hand: docs/cluster.md). On dask a run
    whose worker dies or whose job raises fails alone: its result is None, one line naming the row, the seed and the
    cause goes to ``failures`` (a list; required with dask) and the other runs finish. The runs are the same
    :func:`run_one` calls whatever the executor, so their numbers are the same bit for bit (each run reseeds
    everything, one torch thread; tested).

    ``checkpoints``: one path (or None) per job; see :func:`run_one` for ``time_budget_s``, ``cpu_budget_s``,
    ``recipe``, ``epoch_lines_s`` and ``epochs`` None."""
    from tqdm.auto import tqdm

    kind = executor_kind(executor)
    checkpoints = checkpoints or [None] * len(jobs)
    args = [(i, asdict(job[0]), job[1], epochs, corpus_path, quick, ckpt, time_budget_s,
             job[2] if len(job) > 2 else TEST_SPLIT, recipe, cpu_budget_s, epoch_lines_s)
            for i, (job, ckpt) in enumerate(zip(jobs, checkpoints))]
    results: list = [None] * len(jobs)
    bar = tqdm(total=len(jobs), desc="runs", unit="run", disable=not progress)
    if kind != "local":
        if failures is None:
            raise ValueError("run_specs(executor='dask...') needs a failures list for the runs that fail")
        _run_on_dask(args, kind, processes, results, failures, bar)
    elif processes <= 1:
        for a in args:
            i, res = _job(a)
            results[i] = res
            bar.set_postfix_str(f"{res['row']} seed {res['seed']}")
            bar.update()
    else:
        pool = ProcessPoolExecutor(max_workers=processes, mp_context=get_context("spawn"), initializer=_worker_init,
                                   initargs=(os.getpid(),))
        try:
            futures = [pool.submit(_job, a) for a in args]
            for fut in as_completed(futures):
                i, res = fut.result()
                results[i] = res
                bar.set_postfix_str(f"{res['row']} seed {res['seed']}")
                bar.update()
        except BaseException:  # Ctrl-C, SIGTERM or a failed run: stop every worker now, not after its run
            for proc in list(getattr(pool, "_processes", {}).values()):
                proc.terminate()
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        pool.shutdown(wait=True)
    bar.close()
    return results


def _run_on_dask(args: list[tuple], kind: str, processes: int, results: list, failures: list, bar) -> None:
    """The jobs on dask (``kind``: "dask" for a LocalCluster of ``processes`` workers, else a scheduler address):
    fills ``results`` in place; a failed job leaves None and appends one line to ``failures``.

    A worker that dies fails the job it held at once (the scheduler's ``allowed-failures`` 0 on the LocalCluster;
    a scheduler started elsewhere keeps its own setting, dask's default 3: the job is retried on other workers
    first). Ctrl-C cancels what is left and closes the cluster."""
    try:
        import dask
        from distributed import Client, LocalCluster, as_completed as dask_completed
    except ImportError:
        raise ValueError("--executor dask needs the dask.distributed package: pip install -e '.[cluster]'") from None
    # worker.daemon False: a worker process may start processes of its own, as a run in the local pool may
    with dask.config.set({"distributed.scheduler.allowed-failures": 0, "distributed.worker.daemon": False,
                          "logging.distributed": "error"}):
        cluster = None
        if kind == "dask":
            cluster = LocalCluster(n_workers=max(1, processes), threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=50)
        client = Client(cluster if cluster is not None else kind, timeout="30s")
        try:
            futures = {client.submit(_dask_job, a, key=f"run-{a[0]}-{a[1]['row']}-seed{a[2]}", pure=False): a
                       for a in args}
            for fut in dask_completed(futures):
                a = futures[fut]
                if fut.status == "finished":
                    i, res = fut.result()
                    results[i] = res
                    bar.set_postfix_str(f"{res['row']} seed {res['seed']}")
                else:
                    error = fut.exception()
                    cause = (f"its worker died ({type(error).__name__})" if type(error).__name__ == "KilledWorker"
                             else f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}")
                    failures.append(f"run {a[1]['row']!r} seed {a[2]} failed: {cause}")
                bar.update()
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
