"""The demo's outputs a reader opens first: metrics.md explains every column, the lip-distance figure its phones.
(The whole demo runs in tests/test_experiments.py; these check the two writers without training anything.)"""
import matplotlib
import numpy as np

from dualtalker_lite import demo
from dualtalker_lite.data.speech import ENGLISH_PHONEMES, ESPEAK_IPA, to_ipa
from dualtalker_lite.experiments import METRICS

matplotlib.use("Agg")


def fake_results():
    metrics = {key: 0.5 + i for i, (key, _, _) in enumerate(METRICS)}
    return {"Static template": {"metrics": metrics, "train_seconds": 0.0, "n_parameters": 0},
            "DualTalker": {"metrics": {**metrics, "lve_euclidean": 2.9437}, "train_seconds": 131.2,
                           "n_parameters": 812194}}


def test_metrics_md_has_a_legend_line_for_every_column():
    text = demo.metrics_markdown(fake_results(), "python -m dualtalker_lite.demo", {"Static template": 0,
                                                                                   "DualTalker": 37}, 48)
    lines = text.splitlines()
    header = next(ln for ln in lines if ln.startswith("| model |"))
    columns = [c.strip() for c in header.strip("|").split("|")]
    assert len(columns) == len(METRICS) + 4 and columns[1] == "LVE_pub (mm²) ↓" and columns[-1] == "params"
    legend = [ln for ln in lines if ln.startswith("- `")]
    assert [ln[3:].split("`: ")[0] for ln in legend] == columns   # one line per column, in the table's order
    by_column = dict(ln[3:].split("`: ", 1) for ln in legend)
    assert "mm²; lower is better" in by_column["LVE_pub (mm²) ↓"]
    assert "mm; signed, closer to 0 is better" in by_column["FDD (mm, →0)"]
    assert "0 to 1; higher is better" in by_column["closed <1 mm at /p b m/ ↑"]
    assert "closer to 1 is better" in by_column["lip motion ratio (→1)"]
    row = next(ln for ln in lines if ln.startswith("| DualTalker |")).strip("|").split("|")
    assert [c.strip() for c in row][2] == "2.944" and [c.strip() for c in row][-3:] == ["37", "131", "812,194"]


def test_every_metric_of_the_tables_has_a_legend():
    assert {key for key, _, _ in METRICS} <= set(demo.COLUMN_LEGEND)


def test_espeak_symbols_become_ipa():
    assert set(ESPEAK_IPA) == set(ENGLISH_PHONEMES) - {"_"}
    assert [to_ipa(s) for s in (";", "O2", "N", "T", "D", "S", "tS", "@", "3:", "_", "qq")] == [
        "j", "ɔ", "ŋ", "θ", "ð", "ʃ", "tʃ", "ə", "ɜː", "_", "qq"]


def test_lip_distance_figure_shows_ipa_and_explains_it():
    meta = {"text": "Sing on.", "phonemes": [["_", 0.0, 0.1], ["s", 0.1, 0.2], ["I", 0.2, 0.3], ["N", 0.3, 0.4],
                                             ["O2", 0.4, 0.5], ["n", 0.5, 0.6], ["_", 0.6, 0.7]]}
    times = np.arange(21) / 30
    fig = demo.lip_distance_figure(times, {"ground truth": np.linspace(2, 10, 21)}, "SPK01_s00", meta)
    labels = [t.get_text() for t in fig.axes[0].texts]
    assert labels == ["s", "ɪ", "ŋ", "ɔ", "n"]
    assert fig.get_supxlabel() == demo.PHONE_CAPTION and "IPA" in demo.PHONE_CAPTION


def test_budget_notes_name_every_model_a_budget_cut_short():
    """A model that a demo budget stopped before the recipe's last epoch is named in one line (stderr and
    metrics.json's "truncated") with the budget(s) in force; a model trained to the end, and the static template (no
    training), are not."""
    from dualtalker_lite.demo import budget_notes

    results = {"Static template": {"epochs": 0, "model_config": None, "train_config": {"epochs": 12}},
               "FaceFormer-style": {"epochs": 20, "model_config": {}, "train_config": {"epochs": 20}},
               "DualTalker": {"epochs": 7, "model_config": {}, "train_config": {"epochs": 12}}}
    notes = budget_notes(results, cpu_budget=150.0)   # each model against its own recipe's epochs (here 20 and 12)
    assert list(notes) == ["DualTalker"]
    assert notes["DualTalker"] == ("DualTalker stopped after 7 of 12 epochs: the --cpu-budget of 150 CPU seconds ran "
                                   "out; its checkpoint is under-trained. Re-run with --cpu-budget 0 --time-budget 0, "
                                   "or train it with dualtalker-lite train")
    both = budget_notes(results, cpu_budget=150.0, time_budget=60.0)["DualTalker"]
    assert "the --cpu-budget of 150 CPU seconds or the --time-budget of 60 wall seconds ran out" in both
    assert budget_notes({"DualTalker": {"epochs": 12, "model_config": {}, "train_config": {"epochs": 12}}},
                        cpu_budget=150.0) == {}
    results["FaceFormer-style"]["epochs"] = 12   # 12 epochs is DualTalker's whole recipe, not FaceFormer-style's
    assert list(budget_notes(results, cpu_budget=150.0)) == ["FaceFormer-style", "DualTalker"]


def test_the_demo_budget_is_cpu_seconds_by_default():
    """A busy machine must not cut the demo's models short (a 180 s wall budget stopped DualTalker at 17 of 20
    epochs): the default budget is 150 CPU seconds per model, no wall-clock one, and it reaches train()."""
    from dualtalker_lite.demo import parse_args
    from dualtalker_lite.experiments import runner
    from dualtalker_lite.experiments.specs import RunSpec

    args = parse_args([])
    assert (args.cpu_budget, args.time_budget) == (150.0, 0.0)
    # a CPU budget spent at the first step: training stops in the first of 3 epochs (the step budget's rule)
    run = runner.run_one(RunSpec(row="VOCA-style", model="voca", features="logmel"), 0, 3, quick=True, cpu_budget_s=1e-6)
    assert run["epochs"] == 1 and run["train_config"]["cpu_budget_s"] == 1e-6 and run["train_config"]["epochs"] == 3
    assert runner.run_one(RunSpec(row="VOCA-style", model="voca", features="logmel"), 0, 2, quick=True)["epochs"] == 2


def test_demo_trains_each_model_with_the_short_recipe_by_default():
    """The demo's default recipe is TrainConfig.fast (issue 31): the runner assembles DualTalker with 20 epochs and
    FaceFormer-style with 30 (FAST_EPOCHS, written out here), both at lr 6e-3 with 64 PCA components, in the basis's
    coordinates; the static template trains nothing and takes the tiny recipe's settings; --recipe tiny gives 37
    (TrainConfig.tiny) for both, in vertex coordinates."""
    from dualtalker_lite import demo
    from dualtalker_lite.experiments import load_data, table_specs
    from dualtalker_lite.experiments.assembly import assemble_training

    assert demo.parse_args([]).recipe == "fast" and demo.parse_args([]).epochs is None
    data = load_data(None, quick=True)
    rows = {s.row: s for s in table_specs("main", features="visemes")}
    got = {}
    for label, (row, _) in demo.MODELS.items():
        for recipe in ("fast", "tiny"):
            run = assemble_training(rows[row], data["train"], data["view"], epochs=None, recipe=recipe)
            tc = run.train_config
            got[label, recipe] = (tc.epochs, tc.lr, tc.pca_init, tc.basis_space)
    assert got["DualTalker", "fast"] == (20, 6e-3, 64, True) and got["FaceFormer-style", "fast"] == (30, 6e-3, 64, True)
    assert got["DualTalker", "tiny"] == got["FaceFormer-style", "tiny"] == (37, 3e-3, 0, False)
    assert got["Static template", "fast"] == got["Static template", "tiny"]


def test_each_run_reports_its_epochs_and_the_demo_its_steps(capsys):
    """``make demo``'s progress is per epoch, not per run (a bar counting runs sat at 0/3 for minutes on a busy
    machine): ``run_one(epoch_lines_s=0)`` prints a line after every epoch, naming the row, seed and epoch, from the
    process that trains (a worker's stderr is the demo's); ``demo.step`` says which step begins."""
    from dualtalker_lite.demo import PROGRESS_EVERY_S, parse_args, step
    from dualtalker_lite.experiments import runner
    from dualtalker_lite.experiments.specs import RunSpec

    runner.run_one(RunSpec(row="VOCA-style", model="voca", features="logmel"), 0, 3, quick=True, epoch_lines_s=0)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "VOCA-style, seed 0: data ready, training 3 epochs (the first also sets up)"
    assert [line.split(", loss")[0] for line in lines[1:]] == [f"VOCA-style, seed 0: epoch {k}/3" for k in (1, 2, 3)]
    assert PROGRESS_EVERY_S < 10  # with epochs of at most 5 s on a busy machine: a line at least every ~10 s
    step("figures", parse_args([]))
    step("figures", parse_args(["--no-progress"]))
    assert capsys.readouterr().err == "demo: figures\n"
