"""Command line of the experiment runner (``python -m dualtalker_lite.experiments``): arguments, reuse of runs of
earlier tables (clean commits only), the corpus as a repository-relative path and :func:`main`; the command,
commit and machine stamp comes from :mod:`.provenance`.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import re
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Sequence

import torch

from ..files import repo_root
from .evaluation import typical_bandwidth
from ..provenance import is_clean_commit, provenance
from .report import refresh_table, write_table
from .runner import data_split, executor_kind, load_data, run_specs
from .specs import FEATURES, TABLES, RunSpec, table_specs, table_split

RECIPES = ("tiny", "fast")  # assembly.assemble_training's recipes

# ------------------------------------------------------------------------------------------- command line
def _display_path(path: str | Path) -> str:
    """The corpus folder as written into results: relative to the repository (or the working directory) when
    inside it, else its name only, so committed tables carry no machine-specific paths."""
    path = Path(path).resolve()
    for base in (repo_root(), Path.cwd()):
        try:
            return path.relative_to(Path(base).resolve()).as_posix() or "."
        except ValueError:
            continue
    return path.name


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The runner's arguments (tables, seeds, recipe, budget, front end, executor, output, reuse); an executor it
    cannot read is a usage error."""
    p = argparse.ArgumentParser(prog="python -m dualtalker_lite.experiments",
                                description=sys.modules[__package__].__doc__.split("\n")[0])
    p.add_argument("--table", nargs="+", default=["main"], choices=[*TABLES, "all"],
                   help="one or more tables (identical runs shared between them), or 'all'")
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--recipe", choices=RECIPES, default="tiny",
                   help="training recipe of every trained row: tiny (default; TrainConfig.tiny, the models' own "
                        "losses) or fast (TrainConfig.fast, train's default: the PCA-initialised head at lr 6e-3, "
                        "the basis step where the model has one, and the bilabial contact term)")
    p.add_argument("--epochs", type=int, default=None,
                   help="fixed training budget of every trained model (default: the recipe's: tiny 37; fast the "
                        "longest of its per-model budgets, 30, so that every model has converged)")
    p.add_argument("--features", choices=FEATURES, default=FEATURES[0],
                   help="front end of every row that does not name its own: visemes (default: the phonetic route, "
                        "trained on the corpus's viseme labels and tested on the phoneme recogniser's tracks; "
                        "EmoFace keeps log-mel) or logmel (the papers' kind of input; the tables made before "
                        "issue 19)")
    p.add_argument("--processes", type=int, default=1,
                   help="worker processes, one torch thread each (--executor local: the pool; dask: the "
                        "LocalCluster's workers; ignored for dask://, whose workers are the scheduler's)")
    p.add_argument("--executor", default="local", metavar="{local,dask,dask://HOST:PORT}",
                   help="where the runs execute: local (default; this process or a pool of --processes), dask (a "
                        "dask LocalCluster on this machine) or dask://HOST:PORT (a running dask scheduler, e.g. on a "
                        "Slurm cluster: docs/cluster.md); the numbers are the same bit for bit (needs the [cluster] "
                        "extra for dask)")
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--corpus", default=None, help="corpus folder (default: the shipped data_samples/)")
    p.add_argument("--quick", action="store_true", help="smoke test: 1 epoch, first seed only, few clips")
    p.add_argument("--reuse", nargs="+", type=Path, default=[], metavar="TABLE_JSON",
                   help="tables written earlier (e.g. results/main.json): their runs with the same row computation, "
                        "seed, epochs and corpus are taken over instead of recomputed (their git commit is recorded)")
    p.add_argument("--save-models", type=Path, default=None, metavar="DIR",
                   help="also save each computed run's trained model there as a checkpoint, <row>_seed<seed>.pt "
                        "(for `dualtalker-lite animate --checkpoint ...`; reused runs and the static template "
                        "have none)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--refresh", nargs="+", type=Path, default=[], metavar="TABLE_JSON",
                   help="compute nothing: rewrite these stored tables (JSON and Markdown) with the current row notes, "
                        "paper claims and definitions, their numbers untouched")
    args = p.parse_args(argv)
    try:
        executor_kind(args.executor)
    except ValueError as e:
        p.error(str(e))
    return args


def reusable_runs(paths: Sequence[str | Path], epochs: int, corpus: str, quick: bool = False,
                  commit: str | None = None, recipe: str = "tiny") -> tuple[dict, list[dict]]:
    """Runs of earlier tables that a new invocation may take over: {(key, seed): run}, plus one provenance entry
    per table (file name, the commits of the runs taken, runs taken, runs left to recompute). Only tables with the
    same epoch budget, the same corpus, the same ``--quick`` setting and the same recipe (a table written before
    ``--recipe`` existed: "tiny") qualify; a table that does not is refused with one line naming it and the
    mismatch.

    Each run keeps the commit it was computed at (its ``git``; a run without one takes its table's, unless that
    table itself reused runs: then its origin is unknown). A run from a dirty tree or of unknown origin is not
    taken over: it is recomputed, so a table re-made from a clean commit holds no number of a dirty one. The one
    exception: a run stamped with this invocation's own ``commit`` (the same dirty tree, e.g. while developing;
    the new table is then stamped dirty as well). Nor is a run whose recipe sets the bilabial contact term
    (``lip_contact``) but whose loss history never logged it: the term was off in that run (until 2026-11-28 the
    emotional tables' concatenated clips hid the lip midpoints from it), so its numbers are not those of its
    recorded recipe; it is recomputed and counted in ``n_runs_not_clean``."""
    found: dict = {}
    sources = []
    for path in paths:
        path = Path(path)
        try:
            payload = json.loads(path.read_text())
            runs = payload["runs"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise ValueError(f"{path}: not a table written by this runner ({type(e).__name__}: {e})") from None
        for field_, want in (("epochs", epochs), ("corpus", corpus), ("quick", quick), ("recipe", recipe)):
            have = payload.get(field_, "tiny" if field_ == "recipe" else None)  # before --recipe: the tiny one
            if have != want:
                raise ValueError(f"{path}: cannot reuse its runs: {field_} is {have!r}, this invocation has {want!r}")
        table_git = payload.get("git", "") if not payload.get("reused_from") else "unknown"
        kept = [{**run, "git": run.get("git") or table_git} for run in runs]
        kept = [run for run in kept if (is_clean_commit(run["git"]) or run["git"] == commit)
                and not _contact_missing(run)]
        for run in kept:
            found.setdefault((run["key"], run["seed"]), run)
        sources.append({"table": path.name, "run_commits": sorted({run["git"] for run in kept}),
                        "n_runs": len(kept), "n_runs_not_clean": len(runs) - len(kept)})
    return found, sources


def _contact_missing(run: dict) -> bool:
    """A stored run whose recipe sets ``lip_contact`` but whose per-epoch loss terms never name "contact"."""
    history = run.get("loss_history") or []
    return bool((run.get("train_config") or {}).get("lip_contact")) and bool(history) and \
        not any("contact" in epoch for epoch in history)


def _executor_text(args: argparse.Namespace) -> str:
    """How the runs were executed, as each results file records it."""
    kind = executor_kind(args.executor)
    if kind == "local":
        return f"local ({args.processes} process{'es' if args.processes > 1 else ''})"
    if kind == "dask":
        return f"dask LocalCluster ({max(1, args.processes)} worker process{'es' if args.processes > 1 else ''})"
    return f"dask scheduler {args.executor}"


def _stop_with_partial_runs(args, failures: list[str], by_key: dict, epochs: int, data: dict, stamp: dict,
                            n_runs: int) -> None:
    """Some runs failed (dask): keep the finished ones in ``<out>/partial_runs.json`` (a file ``--reuse`` takes),
    print one line per failed run and exit 1; no table is written from an incomplete set of runs."""
    from ..files import atomic_write_text

    path = Path(args.out) / "partial_runs.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"command": stamp["command"], "git": stamp["commit"], "created": stamp["created"],
               "epochs": epochs, "corpus": _display_path(data["path"]), "quick": args.quick, "recipe": args.recipe,
               "executor": _executor_text(args), "failed": failures, "runs": list(by_key.values())}
    atomic_write_text(path, json.dumps(payload, indent=1) + "\n")
    for line in failures:
        print(f"error: {line}", file=sys.stderr)
    print(f"error: {len(failures)} of {n_runs} runs failed; the {len(by_key)} that finished are kept in {path}: run "
          f"the same command with --reuse {path} to compute only the failed ones", file=sys.stderr)
    raise SystemExit(1)


def _slug(row: str) -> str:
    """A row label as a file name: 'w/o Mesh Attention' -> 'w-o_Mesh_Attention'."""
    return re.sub(r"[^A-Za-z0-9.-]+", "_", row.replace("/", "-")).strip("_")


def main(argv: Sequence[str] | None = None) -> dict:
    """Run the requested tables and write them; returns {table: (json path, md path)}.

    The distinct runs of every table (a row shared by two tables runs once), minus those ``--reuse`` takes over,
    run longest first; the tables are then written from the runs (``report.write_table``) and printed.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parse_args(argv)
    if args.refresh:
        return {Path(p).stem: refresh_table(p) for p in args.refresh}
    tables = list(TABLES) if "all" in args.table else list(dict.fromkeys(args.table))
    if args.epochs is None:
        from ..train import FAST_EPOCHS, TrainConfig

        args.epochs = max(FAST_EPOCHS.values()) if args.recipe == "fast" else TrainConfig.tiny().epochs
    epochs, seeds = (1, args.seeds[:1]) if args.quick else (args.epochs, args.seeds)
    torch.set_num_threads(1)
    data = load_data(args.corpus, args.quick)
    bandwidth = typical_bandwidth(data["train"]) if "sweep" in tables else None
    specs = {t: table_specs(t, bandwidth, args.features) for t in tables}
    unique = _distinct_runs(tables, specs, seeds)
    stamp = provenance("python -m dualtalker_lite.experiments " + shlex.join(argv))
    old, reused = (reusable_runs(args.reuse, epochs, _display_path(data["path"]), args.quick, stamp["commit"],
                                 args.recipe)
                   if args.reuse else ({}, []))
    taken = {k: old[k] for k in unique if k in old}
    jobs = _longest_first([job for k, job in unique.items() if k not in taken])
    not_clean = sum(r["n_runs_not_clean"] for r in reused)
    print(f"{len(jobs)} distinct runs to compute, {len(taken)} reused"
          f"{f' ({not_clean} stored runs not from a clean commit are recomputed)' if not_clean else ''} "
          f"({', '.join(tables)}; seeds {seeds}; "
          f"{epochs} epochs, recipe {args.recipe}; {_executor_text(args)})", flush=True)
    checkpoints = None
    if args.save_models is not None:
        args.save_models.mkdir(parents=True, exist_ok=True)
        checkpoints = [args.save_models / f"{_slug(spec.row)}_seed{seed}.pt" for spec, seed, _ in jobs]
    failures: list[str] = []
    results = run_specs(jobs, epochs, args.processes, args.corpus, args.quick, checkpoints=checkpoints,
                        progress=not args.no_progress, recipe=args.recipe, executor=args.executor,
                        failures=failures)
    by_key = {**taken, **{(r["key"], r["seed"]): {**r, "git": stamp["commit"]} for r in results if r is not None}}
    if failures:
        _stop_with_partial_runs(args, failures, by_key, epochs, data, stamp, len(unique))
    meta = {"command": stamp["command"], "argv": argv,
            "seeds": seeds, "epochs": epochs, "recipe": args.recipe, "processes": args.processes,
            "executor": _executor_text(args), "quick": args.quick,
            "features": args.features,
            "corpus": _display_path(data["path"]), "typical_bandwidth_m": bandwidth, "git": stamp["commit"],
            "created": stamp["created"], "torch": torch.__version__, "machine": stamp["machine"],
            "torch_threads_per_process": 1, "reused_from": reused, "n_runs_reused": len(taken)}
    return {t: _write_one_table(t, specs[t], seeds, by_key, meta, data, Path(args.out)) for t in tables}


def _distinct_runs(tables: list[str], specs: dict, seeds: list[int]) -> dict[tuple, tuple[RunSpec, int, str]]:
    """``{(run key, seed): (spec, seed, test split)}`` over every table's rows and seeds, in table order; a row
    that two tables share with the same test split (equal keys) is one run."""
    unique: dict[tuple, tuple[RunSpec, int, str]] = {}
    for t in tables:
        for s in specs[t]:
            for seed in seeds:
                unique.setdefault((s.key(table_split(t)), seed), (s, seed, table_split(t)))
    return unique


def _longest_first(jobs: list[tuple[RunSpec, int, str]]) -> list[tuple[RunSpec, int, str]]:
    """The jobs with the longest models first, so a pool of workers finishes together (a stable sort: ties keep
    their order)."""
    cost = {"template": 0, "voca": 1, "corrtalk": 4, "emoface": 5}  # every other model: 3
    return sorted(jobs, key=lambda job: -cost.get(job[0].model, 3))


def _write_one_table(table: str, specs: list[RunSpec], seeds: list[int], by_key: dict, meta: dict, data: dict,
                     out: Path) -> tuple:
    """Write ``table`` from the runs (``report.write_table``: the JSON and the Markdown), print the Markdown, and
    return the two paths. Its metadata adds the test split and the clip counts to the invocation's ``meta``."""
    split = table_split(table)
    runs = [{**by_key[(s.key(split), seed)], "row": s.row} for s in specs for seed in seeds]
    n_train = sorted({r.get("n_train_clips", 0) for r in runs})
    table_meta = {**meta, "test_split": split, "n_test_clips": len(data_split(data, split)),
                  "n_train_clips": n_train[0] if len(n_train) == 1 else n_train}
    written = write_table(table, specs, runs, table_meta, Path(out))
    print(Path(written[1]).read_text(), flush=True)
    return written
