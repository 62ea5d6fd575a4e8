"""Experiment runner: the analogues of DualTalker's Table I (main comparison), Table IV (ablations), a CCRL sweep,
CorrTalk's Table III and EmoFace's Tables 2/3 and ablations.

Every run follows one protocol ("same features, same data, same training budget"):

1. build the model with ``set_seed(seed)`` (tiny sizes: ``DualTalkerConfig.tiny``, ``VocaConfig.tiny``);
2. train on the row's clips (``RunSpec.data``; default the ``train`` split of ``data_samples/``) for a FIXED
   number of epochs, the same for every model; no early stopping and no model selection (no test-set peeking);
3. generate the test split (test-A; the emotional tables: test_emo_a) autoregressively (``train.predict``) and measure
   the columns of ``specs.METRICS`` (LVE and FDD in the published squared convention and the text's Euclidean one,
   EVE, over-smoothing ratios, bilabial closures < 2 / < 1 mm, vowel opening and lip-distance correlation; the
   ``metrics`` module docstring has the formulas), plus training seconds and the number of trainable parameters;
4. check for collapse: generate test-A again with every clip's audio replaced by that of a clip of another
   sentence (same template and speaker) -> ``audio_sensitivity``; a trained run is flagged ``collapsed`` when
   its lip motion ratio < 0.1 or its audio sensitivity < 0.1 (:func:`collapse_reasons`). The tables show the flag
   and leave flagged runs out of mean ± std, naming them in the note (:func:`summarize`).

Runs are independent jobs ``(row, seed)``; ``--processes N`` spreads them over N worker processes, each with one
torch thread, and the metrics do not depend on N (each run reseeds everything and builds its own loader).
``--executor dask`` runs the same jobs on a dask LocalCluster, ``--executor dask://HOST:PORT`` on the workers of a
running dask scheduler (several machines, Slurm via dask-jobqueue: docs/cluster.md); the numbers are the same bit
for bit, and a run whose worker dies fails alone (the finished ones are kept for ``--reuse``).
Identical configurations that appear in several requested tables (e.g. the full DualTalker in all three) run once.

Tables (``TABLES``): ``main`` (static template, VOCA-style, FaceFormer-style, DualTalker, CorrTalk), ``ablation``
(w/o CCRL, w/o dual training, phoneme one-hot features as the analogue of the paper's DeepSpeech row, shared
encoder/decoder weights), ``sweep`` (λ4, the CCRL kernel bandwidth σ, and the kernel-weighted vs InfoNCE reading of
eq. 9), ``corrtalk`` (CorrTalk's Table III: w/o hierarchical encoder, single branch, random mask, feature swap),
``emotion`` (EmoFace's Table 2/3: FaceFormer-style, DualTalker, CorrTalk, EmoFace) and ``emoface`` (EmoFace's
ablations: w/o Mesh Attention, w/o SpiralConv3D, w/o self-growing, w/o cross-reconstruction).

What a row trains on is part of its :class:`RunSpec` (``data``: the neutral ``train`` split, ``train`` +
``train_emo``, or the same as pseudo-pairs for cross-reconstruction); which split a table is evaluated on is the
table's (``TABLE_SPLITS``: the two emotional tables use ``test_emo_a`` and add the columns of ``EMOTION_METRICS``:
emotion classification accuracy for models with a classifier, brow-raise and smile errors per emotion). The runner
has no per-paper branch: a model with extra generation inputs names them (``generation_conditions``, EmoFace: the
level), a model with a classifier supplies ``emotion_logits``.

    python -m dualtalker_lite.experiments --table main --seeds 0 1 2 --epochs 15 --processes 2 --out results/
    python -m dualtalker_lite.experiments --table emotion emoface --seeds 0 1 2 3 4 --epochs 12 --processes 2 \
        --out results/    # 560 training clips: 12 epochs ~ the neutral tables' 814 steps
    python -m dualtalker_lite.experiments --table all --quick --out /tmp/smoke      # 1 epoch, 1 seed, few clips

Writes ``<out>/<table>.json`` (every run, every seed, the configs, the exact command) and ``<out>/<table>.md``
(mean ± sample std over seeds, with a note column comparing each row with the table's reference row).

The package: :mod:`.specs` (tables and their rows), :mod:`.evaluation` (features, metrics, collapse check),
:mod:`.assembly` (a row's training set-up, shared with ``dualtalker-lite train``), :mod:`.runner` (data, ``run_one``,
``run_specs``), :mod:`.report` (summaries, ``<table>.json`` / ``.md``), :mod:`.command` (the command line, ``main``),
:mod:`.provenance` (command, commit and machine of a results file); every name is re-exported here.
"""
from __future__ import annotations

from .command import _display_path, main, parse_args, reusable_runs
from .assembly import Assembly, assemble_training
from .evaluation import (COLLAPSE_AUDIO_SENSITIVITY, COLLAPSE_MOTION_RATIO, AudioSwapped, PhonemeOneHot,
                         _unpad, audio_sensitivity, collapse_reasons, emotion_split_metrics, is_collapsed,
                         over_smoothing_ratio, phoneme_onehot, predict_split, split_metrics, swap_partners,
                         typical_bandwidth)
from ..provenance import _git, is_clean_commit, machine, machine_line, provenance
from .report import (DEFINITIONS, EMOTION_DEFINITIONS, _collapse_note, _compare, _fmt, load_table, summarize,
                     table_markdown, verdict, write_table)
from .runner import (_DATA, feature_view, _job, _trimmed, _worker_init, build_model, data_split, load_data, run_one,
                     run_specs, test_features, training_set)
from .specs import (CORRTALK_NOTE, DATA, EMOFACE_NOTE, EMOTION_METRICS, EMOTIONAL_TRAIN, FEATURES, FRONT_ENDS,
                    LIP_SYNC_KEYS, METRICS, PRIMAL_ONLY, QUICK_CLIPS, TABLE_SPLITS, TABLES, TEST_SPLIT, TITLES, RunSpec,
                    table_metrics, table_specs, table_split)

__all__ = ["TABLES", "METRICS", "FEATURES", "RunSpec", "table_specs", "test_features", "feature_view", "phoneme_onehot",
           "PhonemeOneHot", "over_smoothing_ratio",
           "typical_bandwidth", "swap_partners", "AudioSwapped", "audio_sensitivity", "collapse_reasons",
           "is_collapsed",
           "load_data", "build_model", "predict_split", "split_metrics", "run_one", "run_specs", "summarize", "verdict",
           "write_table", "load_table", "table_markdown", "main", "provenance", "machine", "Assembly",
           "assemble_training"]
