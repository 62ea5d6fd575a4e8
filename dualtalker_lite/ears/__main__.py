"""One command for the student's distillation, end to end (issue 47, item 2; docs/ears.md, "The command").

    python -m dualtalker_lite.ears build --out runs/ears/data [--copies 2] [--held-out-copies 1] [--seed 0]
                                         [--cache runs/ears/sources] [--sources NAME ...] [--threads 1]
    python -m dualtalker_lite.ears train --data runs/ears/data/train --val runs/ears/data/val \\
                                         --out runs/ears/student_la3.pt [--lookahead 3] [--cpu-budget-s 1200] ...
    python -m dualtalker_lite.ears all   --out runs/ears/data --weights runs/ears/student_la3.pt [both's options]
    python -m dualtalker_lite.ears evaluate --weights runs/ears/student_la3.pt [...] --audio FILE [FILE ...]
    python -m dualtalker_lite.ears calibrate --weights runs/ears/student_la3.pt --pp-bias 0.5 --out W

``build`` fetches the manifest's used sources from their packages (``ears.sources``: apt-get download, dpkg-deb,
TTS), verifies them against the manifest, and writes the held-out split (``ears.dataset.build_split``): the
training shards in ``<out>/train`` (``--copies`` per recording, copy 0 clean, the others augmented) and the
held-out shards in ``<out>/val`` (``--held-out-copies``, clean by default). ``train`` is the distillation loop
(``ears.distil``: the same options as ``python -m dualtalker_lite.ears.distil``). ``all`` runs both, the
training on ``<out>/train`` with ``<out>/val`` held out. ``evaluate`` runs the teacher and each student on
recordings (``ears.compare``: frame agreement, PP recall against the teacher, the student's CPU s per s whole and
streamed in 100 ms chunks) and prints one line per weights file. ``calibrate`` writes the same student with a
decision bias on PP (``model.calibrate_student``; ``benchmarks/student_gate.py`` chooses it on held-out faces).
Big outputs go under ``runs/`` (git ignores it).

Exit status: 0 done; 2 bad arguments (one ``error:`` line from the parser, before anything is fetched, read or
written); 1 a run that failed (a source that cannot be fetched or does not match the manifest, a damaged shard:
one ``error:`` line).
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import resource
import shlex
import sys
import time
from pathlib import Path

import torch

from ..audio import load_audio
from . import compare, dataset, distil, sources
from .model import StudentWeightsError, calibrate_student, load_student
from .teacher import Teacher

PROG = "python -m dualtalker_lite.ears"


def _add_build_arguments(p: argparse.ArgumentParser, out_help: str) -> None:
    p.add_argument("--out", required=True, help=out_help)
    p.add_argument("--copies", type=int, default=2, help="copies of each training recording (copy 0 clean)")
    p.add_argument("--held-out-copies", type=int, default=1, help="copies of each held-out recording (0: clean)")
    p.add_argument("--seed", type=int, default=0, help="seeds the augmentation")
    p.add_argument("--cache", default=None, help="fetched sources and teacher tracks (default: runs/ears/sources "
                                                 "or $DUALTALKER_EARS_CACHE)")
    p.add_argument("--sources", nargs="+", default=None, metavar="NAME", help="only these manifest sources")


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="Build the student's training set and distil it "
                                                       "(docs/ears.md).")
    sub = p.add_subparsers(dest="command", required=True)
    build = sub.add_parser("build", help="fetch, verify, augment, teacher tracks, shards (train + held out)")
    _add_build_arguments(build, "the data set's folder (<out>/train, <out>/val)")
    build.add_argument("--threads", type=int, default=None)
    distil.add_arguments(sub.add_parser("train", help="distil a student from shards"))
    both = sub.add_parser("all", help="build, then train on <out>/train with <out>/val held out")
    _add_build_arguments(both, "the data set's folder (<out>/train, <out>/val)")
    # the training options, without --data/--val/--out (they follow from --out) and with --weights for the file
    train_options = argparse.ArgumentParser(add_help=False)
    distil.add_arguments(train_options)
    for action in train_options._actions:
        if action.dest not in ("data", "val", "out", "help", "seed"):     # one --seed for both
            both._add_action(action)
    both.add_argument("--weights", required=True, help="the weights file to write")
    ev = sub.add_parser("evaluate", help="students against the teacher on recordings, and their cost")
    ev.add_argument("--weights", nargs="+", required=True, help="student weights files")
    ev.add_argument("--audio", nargs="+", required=True, help="recordings (wav/flac, resampled to 16 kHz)")
    ev.add_argument("--val", default=None, help="also: the held-out set build wrote (<out>/val), by part")
    ev.add_argument("--tolerance", type=int, default=distil.DistilConfig.tolerance, help="frames (20 ms)")
    ev.add_argument("--chunk-ms", type=float, default=100.0, help="the streamed cost's chunk")
    ev.add_argument("--cache", default=None, help="teacher tracks' cache (default: <sources cache>/teacher)")
    ev.add_argument("--threads", type=int, default=None)
    cal = sub.add_parser("calibrate", help="the same student with a PP decision bias (benchmarks/student_gate.py "
                                           "chooses it)")
    cal.add_argument("--weights", required=True, help="the trained student's weights file")
    cal.add_argument("--pp-bias", type=float, required=True, help="b: log-odds added to the PP logit")
    cal.add_argument("--out", required=True, help="the calibrated weights file to write")
    return p


def check_build_arguments(args: argparse.Namespace) -> str | None:
    """One line saying what is wrong with ``build``'s options, or None (nothing is fetched or written before)."""
    if args.copies < 1:
        return f"--copies must be >= 1, got {args.copies}"
    if args.held_out_copies < 1:
        return f"--held-out-copies must be >= 1, got {args.held_out_copies}"
    if getattr(args, "threads", None) is not None and args.threads < 1:
        return f"--threads must be >= 1, got {args.threads}"
    if Path(args.out).exists() and not Path(args.out).is_dir():
        return f"--out {args.out} is a file: give a folder"
    if args.sources:
        try:
            known = {s["name"]: s for s in sources.load_manifest()["sources"]}
        except ValueError as err:
            return str(err)
        unknown = [n for n in args.sources if n not in known]
        if unknown:
            return f"--sources: {unknown[0]} is not in the manifest (ears/manifest.json)"
        unused = [n for n in args.sources if not known[n]["use"]]
        if unused:
            return f"--sources: {unused[0]} is not used ({known[unused[0]].get('why', '')})"
    return None


def _cpu_seconds() -> float:
    """CPU seconds of this process and its finished children (espeak-ng, flite, apt-get, dpkg-deb)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def run_build(args: argparse.Namespace) -> tuple[Path, Path]:
    wall, cpu = time.monotonic(), _cpu_seconds()
    train_json, val_json = dataset.build_split(args.out, args.cache, names=args.sources, copies=args.copies,
                                               held_out_copies=args.held_out_copies, seed=args.seed)
    for path in (train_json, val_json):
        meta = json.loads(path.read_text())
        print(f"{path.parent}: {len(meta['items'])} copies, {meta['frames'] * dataset.HOP_S / 60:.1f} minutes, "
              f"{len(meta['shards'])} shards")
    print(f"build: {time.monotonic() - wall:.0f} s wall, {_cpu_seconds() - cpu:.0f} CPU s")
    return train_json, val_json


def check_evaluate_arguments(args: argparse.Namespace) -> str | None:
    """One line saying what is wrong with ``evaluate``'s options, or None."""
    for flag, paths in (("--weights", args.weights), ("--audio", args.audio)):
        missing = [p for p in paths if not Path(p).is_file()]
        if missing:
            return f"{flag} {missing[0]}: no such file"
    if args.val is not None and not (Path(args.val) / "dataset.json").is_file():
        return f"--val {args.val}: no dataset.json there (build one with `{PROG} build`)"
    if args.tolerance < 0 or args.chunk_ms <= 0:
        return "--tolerance must be >= 0 and --chunk-ms > 0"
    if args.threads is not None and args.threads < 1:
        return f"--threads must be >= 1, got {args.threads}"
    return None


def run_evaluate(args: argparse.Namespace) -> list[dict]:
    cache = Path(args.cache) if args.cache else sources.default_cache_dir() / "teacher"
    teacher = Teacher(cache_dir=cache)
    quiet = io.StringIO()
    with contextlib.redirect_stderr(quiet):              # one line for all the upsampled telephone recordings
        waves = [load_audio(p, mono="mean") for p in args.audio]
    upsampled = quiet.getvalue().count("upsampled")
    if upsampled:
        print(f"{upsampled} of {len(waves)} recordings sampled below 16 kHz, upsampled (as in training)",
              file=sys.stderr)
    longest = max(waves, key=len)
    rows = []
    for path in args.weights:
        student, info = load_student(path)
        student.eval()
        row = {"weights": path, "lookahead": student.cfg.lookahead,
               **compare.against_teacher(student, waves, teacher, args.tolerance),
               **{f"cost_{k}": v for k, v in compare.student_cost(student, longest, args.chunk_ms / 1000).items()
                  if k != "chunk_s"}}
        rows.append(row)
        print(f"{path}: look-ahead {row['lookahead']} ({row['lookahead'] * 20} ms), {len(waves)} recordings, "
              f"{row['seconds'] / 60:.1f} min: agreement {row['agreement']:.3f}, PP recall {row['pp_recall']:.3f} "
              f"({row['pp_runs']} teacher runs, +-{args.tolerance * 20} ms); CPU s per s: whole "
              f"{row['cost_whole']:.4f}, streamed in {args.chunk_ms:.0f} ms chunks {row['cost_streamed']:.4f} "
              f"(on {len(longest) / 16000:.1f} s)", flush=True)
        if args.val:
            for part, m in compare.by_held_out_part(student, args.val, args.tolerance).items():
                print(f"  {args.val} {part}: {m['minutes']:.1f} min, agreement {m['agreement']:.3f}, PP recall "
                      f"{m['pp_recall']:.3f} ({m['pp_runs']} runs)", flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    p = parser()
    args = p.parse_args(argv)
    sub = {a.dest: a for a in p._actions}["command"].choices[args.command]
    problem = None
    if args.command in ("build", "all"):
        problem = check_build_arguments(args)
    if args.command == "all" and problem is None:
        # the training options; --data and --val are the folders build is about to write
        problem = distil.check_arguments(argparse.Namespace(**{**vars(args), "out": args.weights, "data": None,
                                                               "val": None}))
    elif args.command == "train":
        problem = distil.check_arguments(args)
    elif args.command == "evaluate":
        problem = check_evaluate_arguments(args)
    if problem:
        sub.error(problem)                                              # exit 2, one line, nothing written
    if getattr(args, "threads", None) is not None:
        torch.set_num_threads(args.threads)
    command = f"{PROG} {shlex.join(argv)}"
    try:
        if args.command == "evaluate":
            run_evaluate(args)
        if args.command == "calibrate":
            print(f"wrote {calibrate_student(args.weights, args.pp_bias, args.out, command)} "
                  f"(pp_bias {args.pp_bias:g})")
        if args.command in ("build", "all"):
            run_build(args)
        if args.command in ("train", "all"):
            if args.command == "all":
                args.data, args.val = str(Path(args.out) / "train"), str(Path(args.out) / "val")
                args.out = args.weights
            distil.train(args, command)
    except (sources.SourceError, StudentWeightsError, ValueError, OSError) as err:
        print(f"{PROG} {args.command}: error: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
