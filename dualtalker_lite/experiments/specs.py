"""Table specifications of the experiment runner: the tables, their test splits and columns, and their rows
(:class:`RunSpec`, one per model configuration; a run is a (RunSpec, seed) pair, identified by ``RunSpec.key``).

Committed results are reused by key: ``RunSpec.key`` must stay stable (fields at their defaults are left out).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace

from .. import front_ends
from ..deprecation import moved

TABLES = ("main", "ablation", "sweep", "corrtalk", "emotion", "emoface")
TEST_SPLIT = "test_a"  # the default test split (neutral speech, seen speakers)
TABLE_SPLITS = {"emotion": "test_emo_a", "emoface": "test_emo_a"}  # tables evaluated on another split
EMOTIONAL_TRAIN = ("train", "train_emo")  # what RunSpec.data "emotional" and "pairs" train on
DATA = ("neutral", "emotional", "pairs")
QUICK_CLIPS = {"train": 16, TEST_SPLIT: 4, "train_emo": 16, "test_emo_a": 4}  # --quick: the first clips of each split
# (key, column header, digits) of the Markdown tables, in order.
METRICS = (
    ("lve_published", "LVE_pub (mm²) ↓", 2),
    ("lve_euclidean", "LVE (mm) ↓", 3),
    ("fdd_published", "FDD_pub (mm², →0)", 3),
    ("fdd_paper", "FDD (mm, →0)", 4),
    ("eve_published", "EVE_pub (mm²) ↓", 3),
    ("smoothing_lips", "lip motion ratio (→1)", 3),
    ("smoothing_upper", "upper-face motion ratio (→1)", 3),
    ("bilabial_closure_2mm", "closed <2 mm at /p b m/ ↑", 3),
    ("bilabial_closure_1mm", "closed <1 mm at /p b m/ ↑", 3),
    ("bilabial_min_mm", "min lip dist. at /p b m/ (mm) ↓", 2),
    ("open_vowel_max_mm", "max lip dist. at open vowels (mm, →GT)", 2),
    ("lip_distance_corr", "lip-distance corr. ↑", 3),
)
# the emotional tables' extra columns (``metrics.emotion`` module docstring has the definitions)
EMOTION_METRICS = (
    ("emotion_accuracy", "emotion acc. ↑", 3),
    ("brow_raise_error_mm", "brow-raise error (mm) ↓", 2),
    ("smile_error_mm", "smile error (mm) ↓", 2),
)
LIP_SYNC_KEYS = ("bilabial_closure_2mm", "bilabial_closure_1mm", "bilabial_min_mm", "open_vowel_max_mm",
                 "lip_distance_corr", "lip_motion_ratio", "bilabial_closure_2mm_gt", "bilabial_closure_1mm_gt",
                 "bilabial_min_mm_gt", "open_vowel_max_mm_gt")
TITLES = {
    "main": "Table I analogue: comparison with the baselines on test-A",
    "ablation": "Table IV analogue: ablations of DualTalker on test-A",
    "sweep": "CCRL sweep: weight λ4 and kernel bandwidth σ on test-A",
    "corrtalk": "Table III analogue (CorrTalk): ablations of CorrTalk on test-A",
    "emotion": "Table 2/3 analogue (EmoFace): comparison on the emotional test split test_emo_a",
    "emoface": "EmoFace ablations (Mesh Attention, SpiralConv3D, self-growing, cross-reconstruction) on test_emo_a",
}


def table_split(table: str) -> str:
    """The test split a table is evaluated on (``TABLE_SPLITS``, else ``TEST_SPLIT``)."""
    return TABLE_SPLITS.get(table, TEST_SPLIT)


def table_metrics(table: str) -> tuple:
    """The (key, header, digits) columns of ``table``: ``METRICS``, plus ``EMOTION_METRICS`` on emotional splits."""
    return METRICS + EMOTION_METRICS if table in TABLE_SPLITS else METRICS


# ------------------------------------------------------------------------------------------- configurations
@dataclass
class RunSpec:
    """One row of a table: which model, which overrides, which features. A run is a (RunSpec, seed) pair."""

    row: str                                            # label in the table
    model: str                                          # a name of models.registry: "template" | "voca" |
                                                        # "faceformer" | "dualtalker" | "corrtalk" | "emoface"
    model_overrides: dict = field(default_factory=dict)  # passed to DualTalkerConfig.tiny / VocaConfig.tiny
    loss: dict = field(default_factory=dict)            # LossWeights overrides (λ1..λ4, bandwidth, ...)
    features: str = front_ends.DEFAULT                  # the front end, a name of front_ends.FRONT_ENDS: "visemes"
                                                        # (the default, the phonetic route) | "logmel" | "phonemes"
                                                        # | "visemes+logmel" (pairs rows; table_specs sets these)
    data: str = "neutral"                               # training clips: "neutral" (train) | "emotional" (train +
                                                        # train_emo) | "pairs" (the same, each with its pseudo-pair
                                                        # partner: data.pairs.PairDataset, for cross-reconstruction)
    note: str = ""                                      # fixed part of the Markdown note column
    reference: bool = False                             # the row every other row of the table is compared with
    expect: str = ""                                    # the paper's claim vs the reference: "worse" | "better" |
                                                        # "" (the paper has no such row: no claim)
    fast_changes: dict = field(default_factory=dict)    # what this row changes in the short recipe (--recipe fast;
                                                        # TrainConfig fields); not in key(): the recipe is the
                                                        # table's (checked on reuse), this follows from the row

    def __post_init__(self):
        if self.data not in DATA:
            raise ValueError(f"RunSpec {self.row!r}: data must be one of {DATA}, got {self.data!r}")
        if self.data == "pairs" and self.features not in ("logmel", "visemes+logmel", "visemes+prosody"):
            raise ValueError(f"RunSpec {self.row!r}: data 'pairs' needs features 'logmel', 'visemes+logmel' or "
                             f"'visemes+prosody' (the emotion branch reads the partner's sound), got {self.features!r}")

    def key(self, test_split: str = TEST_SPLIT) -> str:
        """Identity of the computation (everything but the label and the notes): equal keys = equal runs.
        Fields at their defaults (``data`` "neutral", the test split ``TEST_SPLIT``) are left out, so the keys of
        rows written before those fields existed are unchanged and their committed results stay reusable."""
        ident = {"model": self.model, "model_overrides": self.model_overrides, "loss": self.loss,
                 "features": self.features}
        if self.data != "neutral":
            ident["data"] = self.data
        if test_split != TEST_SPLIT:
            ident["test_split"] = test_split
        return json.dumps(ident, sort_keys=True)


PRIMAL_ONLY = {"lambda2": 0.0, "lambda3": 0.0, "lambda4": 0.0}  # baselines: the reconstruction loss alone
CORRTALK_NOTE = "rec. + velocity loss (eqs. 9-11, λ=1, 1), FAI-initialised mask, 4 levels"
EMOFACE_NOTE = ("eq. 11 (λ 1/1/0.5 on mm L1s, λ_cls 0.01), Mesh Attention (L=9, δ=3), self-growing (θ=0.2 N), "
                "cross-reconstruction on pseudo-pairs; emotion type recognised from the speech, level given; "
                "the type is also an input of the emotion branch (the true label in training): a project addition")


FEATURES = front_ends.CHOICES  # the tables' front ends (--features); the first, the phonetic route, is the default
FRONT_END_NOTES = {name: f.description for name, f in front_ends.FRONT_ENDS.items()}  # name -> what the notes say
# the old name of FRONT_END_NOTES, one release (front_ends.FRONT_ENDS is the table of front ends: name -> FrontEnd)
__getattr__ = moved(__name__, {"FRONT_ENDS": (f"{__name__}.FRONT_END_NOTES", FRONT_END_NOTES)})


AS_WRITTEN = "logmel"  # the front end the rows below are written for; table_specs swaps in the table's


def table_specs(table: str, bandwidth: float | None = None, features: str = AS_WRITTEN) -> list[RunSpec]:
    """The rows of ``table``. ``bandwidth`` (metres, the typical median-heuristic σ) sets the sweep's fixed σ's.

    ``features``: the front end of every row written for :data:`AS_WRITTEN` ("logmel"; the other rows name their
    own, e.g. the one-hot phoneme ablations). With
    "visemes" (the phonetic route, the runner's default since issue 19) EmoFace's pair rows get "visemes+logmel"
    (its content branch reads the visemes, its emotion branch the log-mel: emotion is in the sound, not in the
    phones), and rows that swap in one-hot phonemes as an ablation keep theirs."""
    if features not in FEATURES:
        raise ValueError(f"unknown features {features!r}; choose from {FEATURES}")
    rows = _rows(table, bandwidth)
    if features == AS_WRITTEN:
        return rows
    # the swapped-in rows' notes name the front end they replace
    return [replace(s, features=front_ends.paired(features) if s.data == "pairs" else features)
            if s.features == AS_WRITTEN
            else replace(s, note=s.note.replace("log-mel", "the recogniser's viseme classes")) for s in rows]


def _rows(table: str, bandwidth: float | None) -> list[RunSpec]:
    """The rows of ``table`` as written (the log-mel front end; :func:`table_specs` swaps it): one function each."""
    if table == "sweep":
        return _sweep_rows(bandwidth)
    builders = {"main": _main_rows, "corrtalk": _corrtalk_rows, "ablation": _ablation_rows,
                "emotion": _emotion_rows, "emoface": _emoface_rows}
    if table not in builders:
        raise ValueError(f"unknown table {table!r}; choose from {TABLES}")
    return builders[table]()


def _row(*args, features: str = AS_WRITTEN, **kwargs) -> RunSpec:
    """A table row: a :class:`RunSpec` whose front end is :data:`AS_WRITTEN` unless the row names another."""
    return RunSpec(*args, features=features, **kwargs)


_FULL = dict(model="dualtalker")  # DualTalker rows: _row(label, **_FULL, ...)


def _main_rows() -> list[RunSpec]:
    """Table I analogue: the baselines (static template, VOCA-style, FaceFormer-style), DualTalker (the
    reference) and CorrTalk, each on the neutral clips."""
    return [
        _row("Static template", "template", note="zero motion: the floor to beat"),
        _row("VOCA-style", "voca", loss=PRIMAL_ONLY, note="sliding window, no autoregression", expect="worse"),
        _row("FaceFormer-style", "faceformer", loss=PRIMAL_ONLY, note="primal task only, no gate, no CCRL",
                expect="worse"),
        _row("DualTalker", **_FULL, note="λ2=λ3=0.1, λ4=0.01", reference=True),
        _row("CorrTalk", "corrtalk", note=CORRTALK_NOTE),
    ]


def _corrtalk_rows() -> list[RunSpec]:
    """Table III analogue: CorrTalk (the reference) without the hierarchical encoder, with one branch, with a
    random mask, with phoneme features."""
    ct = dict(model="corrtalk")
    return [
        _row("CorrTalk", **ct, note=CORRTALK_NOTE, reference=True),
        _row("w/o hierarchical encoder", **ct, model_overrides={"hierarchical": False},
                note="frame level only (softmax over one level = 1)", expect="worse"),
        _row("single branch", **ct, model_overrides={"dual_branch": False},
                note="one FaceFormer-style branch decodes the whole face, no mask", expect="worse"),
        _row("mask initialised at random", **ct, model_overrides={"mask_init": "random"},
                note="mask ~ U(0, 1) instead of the normalised FAI", expect="worse"),
        _row("phoneme one-hot features", **ct, features="phonemes",
                note="the project's front-end swap, not a paper row (the paper swaps wavLM -> wav2vec 2.0, never "
                     "phoneme ids): log-mel -> one-hot phoneme ids, the rig's own driving signal (an easier input)"),
    ]


def _ablation_rows() -> list[RunSpec]:
    """Table IV analogue: DualTalker (the reference) without CCRL, without the dual task, with phoneme
    features, with tied encoder/decoder weights."""
    return [
        _row("DualTalker (full)", **_FULL, note="λ2=λ3=0.1, λ4=0.01", reference=True),
        _row("w/o CCRL", **_FULL, loss={"lambda4": 0.0}, note="λ4=0", expect="worse"),
        _row("w/o dual training", **_FULL, model_overrides={"dual": False},
                loss={"lambda2": 0.0, "lambda3": 0.0},
                note="no lip reading, λ2=λ3=0; CCRL kept (λ4=0.01 on X, Y)", expect="worse"),
        _row("phoneme one-hot features", **_FULL, features="phonemes",
                note="DeepSpeech analogue: one-hot phoneme ids instead of log-mel (here the rig's own "
                     "driving signal, so an easier input than in the paper)", expect="worse"),
        _row("shared enc/dec weights", **_FULL, model_overrides={"share_enc_dec": True},
                note="decoders = transposed encoders", expect="worse",
                # the tied head has no weights of its own to start from the PCA basis, nor a basis step
                fast_changes={"pca_init": 0, "basis_space": False}),
    ]


def _sweep_rows(bandwidth: float | None) -> list[RunSpec]:
    """CCRL sweep: λ4 in {0, 0.01, 0.1}, the InfoNCE reading, and fixed σ's of 0.5 and 2 times ``bandwidth`` (the
    typical median-heuristic σ, metres: required)."""
    if bandwidth is None:
        raise ValueError("the sweep needs the typical bandwidth (see typical_bandwidth)")
    rows = [
        _row("λ4=0", **_FULL, loss={"lambda4": 0.0}, note="no CCRL", expect="worse"),
        _row("λ4=0.01, σ=median", **_FULL, note="the default", reference=True),
        _row("λ4=0.1, σ=median", **_FULL, loss={"lambda4": 0.1}),
        _row("λ4=0.1, σ=median, InfoNCE reading", **_FULL, loss={"lambda4": 0.1, "ccrl_reading": "infonce"},
                note="CCRL with one positive in the denominator (the reading before issue 8)"),
    ]
    for factor in (0.5, 2.0):
        sigma = factor * bandwidth
        rows.append(_row(f"λ4=0.1, σ={factor:g}×typ = {sigma * 1e3:.3g} mm", **_FULL,
                            loss={"lambda4": 0.1, "bandwidth": sigma},
                            note=f"fixed σ for every clip ({factor:g}× the median of the per-clip medians)"))
    return rows


def _emotion_rows() -> list[RunSpec]:
    """EmoFace's Table 2/3 analogue: FaceFormer-style, DualTalker and CorrTalk trained on the emotional clips
    against EmoFace (the reference) on its pseudo-pairs."""
    emo = dict(data="emotional")  # every row trains on the same clips: train + train_emo
    return [
        _row("FaceFormer-style", "faceformer", loss=PRIMAL_ONLY, **emo, note="primal task only, no emotion "
                "input (the emotion must come from the audio)", expect="worse"),
        _row("DualTalker", **_FULL, **emo, note="λ2=λ3=0.1, λ4=0.01; no emotion input (not in EmoFace's "
                "Table 2: no paper claim)"),
        _row("CorrTalk", "corrtalk", **emo, note=CORRTALK_NOTE + "; no emotion input (not in EmoFace's "
                "Table 2: no paper claim)"),
        _row("EmoFace", "emoface", data="pairs", note=EMOFACE_NOTE, reference=True),
    ]


def _emoface_rows() -> list[RunSpec]:
    """EmoFace ablations: EmoFace (the reference) without Mesh Attention, SpiralConv3D, self-growing or
    cross-reconstruction, all on the pseudo-pairs."""
    ef = dict(model="emoface", data="pairs")
    return [
        _row("EmoFace (full)", **ef, note=EMOFACE_NOTE, reference=True),
        _row("w/o Mesh Attention", **ef, model_overrides={"fusion": "sum"},
                note="the mean of the two branches (the map held at 0.5); the paper's 'Add' adds them",
                expect="worse"),
        _row("w/o SpiralConv3D", **ef, model_overrides={"spiral_length": 1, "spiral_delta": 1},
                note="MLP in its place: spirals of length 1, δ=1 (one linear map per vertex and frame); not a "
                     "row of the paper's Table 3 (its Table 4 varies SpiralConv3D's settings instead)"),
        _row("w/o self-growing", **ef, model_overrides={"past_motion": "teacher_forcing"},
                note="plain teacher forcing (ground-truth past motion at every epoch)", expect="worse"),
        _row("w/o cross-reconstruction", **ef, model_overrides={"cross_reconstruction": False},
                note="same pair loader, no cross pass (λ_cross term 0); not a row of the paper's Table 3"),
    ]
