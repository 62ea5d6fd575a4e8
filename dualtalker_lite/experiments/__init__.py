"""Experiment runner: the analogues of DualTalker's Table I (main comparison), Table IV (ablations), a CCRL sweep,
CorrTalk's Table III and EmoFace's Tables 2/3 and ablations.

Every run follows one protocol ("same features, same data, same training budget"):

1. build the model with ``set_seed(seed)`` at the tiny sizes of the registry (``models.registry``);
2. train on the row's clips (``RunSpec.data``; default the ``train`` split of ``data_samples/``) for a FIXED
   number of epochs, the same for every model; no early stopping and no model selection (no test-set peeking);
3. generate the table's test split (``TABLE_SPLITS``: test-A, the emotional tables test_emo_a) autoregressively and
   measure the columns of ``specs.METRICS`` (LVE, FDD, EVE, over-smoothing ratios, bilabial closures, vowel opening,
   lip-distance correlation: the ``metrics`` module docstring has the formulas; the emotional tables add
   ``EMOTION_METRICS``), plus training seconds and the number of trainable parameters;
4. check for collapse: generate again with every clip's audio replaced by that of another sentence (same template
   and speaker) -> ``audio_sensitivity``; a run is flagged ``collapsed`` when its lip motion ratio < 0.1 or its audio
   sensitivity < 0.1 (:func:`collapse_reasons`); the tables leave flagged runs out of mean ± std (:func:`summarize`).

Runs are independent jobs ``(row, seed)``: ``--processes N`` spreads them over N worker processes (one torch thread
each), ``--executor dask[://HOST:PORT]`` over a dask cluster (docs/cluster.md); the numbers do not depend on either.
Identical configurations that appear in several requested tables run once.

Tables (``TABLES``): ``main``, ``ablation``, ``sweep`` (λ4, the CCRL bandwidth σ, the InfoNCE reading of eq. 9),
``corrtalk``, ``emotion`` and ``emoface``; their rows, the front end each trains on and what it is compared with are
:class:`RunSpec` s in :mod:`.specs`. The runner has no per-paper branch: a model with extra generation inputs names
them (the ``generation_conditions`` hook), a model with a classifier supplies ``emotion_logits``.

    python -m dualtalker_lite.experiments --table main --seeds 0 1 2 --epochs 15 --processes 2 --out results/
    python -m dualtalker_lite.experiments --table emotion emoface --seeds 0 1 2 3 4 --epochs 12 --processes 2 \
        --out results/
    python -m dualtalker_lite.experiments --table all --quick --out /tmp/smoke      # 1 epoch, 1 seed, few clips

Writes ``<out>/<table>.json`` (every run, every seed, the configs, the exact command) and ``<out>/<table>.md``
(mean ± sample std over seeds, with a note column comparing each row with the table's reference row); the epoch
budgets of the committed tables are in docs/design-notes.md ("The experiment runner").

The package: :mod:`.specs` (tables and rows), :mod:`.evaluation` (features, metrics, collapse check),
:mod:`.assembly` (a row's training set-up, shared with ``dualtalker-lite train``), :mod:`.runner` (data, ``run_one``,
``run_specs``), :mod:`.report` (summaries, ``<table>.json`` / ``.md``), :mod:`.command` (the command line, ``main``);
their public names are re-exported here. Private names once re-exported here are deprecated (``CHANGELOG.md``).
"""
from __future__ import annotations

from . import command as _command, evaluation as _evaluation, report as _report, runner as _runner, specs as _specs
from .. import provenance as _provenance
from ..deprecation import moved
from .command import main, parse_args, reusable_runs
from .assembly import Assembly, assemble_training
from .evaluation import (COLLAPSE_AUDIO_SENSITIVITY, COLLAPSE_MOTION_RATIO, AudioSwapped, PhonemeOneHot,
                         audio_sensitivity, collapse_reasons, emotion_split_metrics, is_collapsed,
                         over_smoothing_ratio, phoneme_onehot, predict_split, split_metrics, swap_partners,
                         typical_bandwidth)
from ..provenance import is_clean_commit, machine, machine_line, provenance
from .report import (DEFINITIONS, EMOTION_DEFINITIONS, load_table, summarize, table_markdown, verdict, write_table)
from .runner import (build_model, data_split, feature_view, load_data, run_one, run_specs, test_features,
                     training_set)
from .specs import (CORRTALK_NOTE, DATA, EMOFACE_NOTE, EMOTION_METRICS, EMOTIONAL_TRAIN, FEATURES, FRONT_END_NOTES,
                    LIP_SYNC_KEYS, METRICS, PRIMAL_ONLY, QUICK_CLIPS, TABLE_SPLITS, TABLES, TEST_SPLIT, TITLES, RunSpec,
                    table_metrics, table_specs, table_split)

__all__ = ["TABLES", "METRICS", "FEATURES", "RunSpec", "table_specs", "test_features", "feature_view", "phoneme_onehot",
           "PhonemeOneHot", "over_smoothing_ratio",
           "typical_bandwidth", "swap_partners", "AudioSwapped", "audio_sensitivity", "collapse_reasons",
           "is_collapsed",
           "load_data", "build_model", "predict_split", "split_metrics", "run_one", "run_specs", "summarize", "verdict",
           "write_table", "load_table", "table_markdown", "main", "provenance", "machine", "Assembly",
           "assemble_training"]

# old addresses, one release: private helpers once re-exported here, and the front-end notes' old name
_OLD = {name: (module, name) for module, names in (
    (_command, ("_display_path",)), (_evaluation, ("_unpad",)), (_provenance, ("_git",)),
    (_report, ("_collapse_note", "_compare", "_fmt")), (_runner, ("_DATA", "_job", "_trimmed", "_worker_init")))
    for name in names}
_OLD["FRONT_ENDS"] = (_specs, "FRONT_END_NOTES")  # name -> text; front_ends.FRONT_ENDS is name -> FrontEnd
__getattr__ = moved(__name__, {old: (f"{module.__name__}.{new}", getattr(module, new))
                               for old, (module, new) in _OLD.items()})
