"""Experiment runner and demo: smoke runs (--quick), independent metric checks, determinism, feature option."""
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from dualtalker_lite import experiments as ex
from dualtalker_lite.experiments import command, report
from dualtalker_lite.losses import rbf_kernel_weights


pytestmark = pytest.mark.usefixtures("one_thread")  # conftest.py


@pytest.fixture(scope="module")
def quick_tables(tmp_path_factory):
    """All three tables in --quick mode (1 epoch, 1 seed, few clips), in this process."""
    out = tmp_path_factory.mktemp("tables")
    ex.main(["--table", "all", "--quick", "--out", str(out), "--no-progress"])
    return out


# ------------------------------------------------------------------------------ features and small helpers
def test_phoneme_onehot_hand_checked():
    ids = torch.tensor([0, 2, 1, 2])
    expected = torch.tensor([[1, 0, 0], [0, 0, 1], [0, 1, 0], [0, 0, 1]], dtype=torch.float32)
    got = ex.phoneme_onehot(ids, 3)
    assert got.dtype == torch.float32 and torch.equal(got, expected)
    with pytest.raises(ValueError, match="phoneme ids"):
        ex.phoneme_onehot(torch.tensor([0, 3]), 3)


def test_phoneme_dataset_replaces_audio_only():
    base = [{"name": "a", "audio": torch.randn(4, 160), "phonemes": torch.tensor([0, 2, 2, 1]),
             "vertices": torch.zeros(4, 6)}]
    ds = ex.PhonemeOneHot(base, n_phonemes=3)
    item = ds[0]
    assert len(ds) == 1 and item["audio"].shape == (4, 3)
    assert torch.equal(item["audio"].argmax(-1), base[0]["phonemes"])
    assert torch.equal(item["audio"].sum(-1), torch.ones(4))
    assert item["vertices"] is base[0]["vertices"] and base[0]["audio"].shape == (4, 160)  # base untouched


def test_over_smoothing_ratio_hand_checked():
    g = np.random.default_rng(0).normal(size=(20, 4, 3))
    idx = [0, 2]
    assert ex.over_smoothing_ratio([g], [g], idx) == pytest.approx(1.0)
    assert ex.over_smoothing_ratio([0.5 * g + 3.0], [g], idx) == pytest.approx(0.5)  # offsets do not count
    assert ex.over_smoothing_ratio([np.repeat(g[:1], 20, 0)], [g], idx) == pytest.approx(0.0, abs=1e-12)  # static


def test_typical_bandwidth_hand_computed():
    """Three clips, one vertex (3 coordinates), motions in mm; per pair the RMS coordinate difference
    sqrt(|Δ|² / 3), per clip the lower median over ordered pairs t ≠ k, then the median over clips.

    clip A: (0,0,0), (3,0,0), (3,4,0): |Δ| = 3, 5, 4 -> sqrt(9/3), sqrt(25/3), sqrt(16/3) = 1.732, 2.887, 2.309,
            each twice; the lower median of the 6 sorted values is the 3rd: 4/sqrt(3) = 2.309 mm
    clip B: (0,0,0), (0,0,6): sqrt(36/3) = 3.464 mm;   clip C: (1,1,1), (2.5,1,1): sqrt(2.25/3) = 0.866 mm
    median over clips: 2.309 mm = 4/sqrt(3) mm. A template offset changes nothing (only differences count).
    """
    mm = 1e-3
    template = torch.tensor([0.1, -0.2, 0.3], dtype=torch.float64)
    clips = [[(0, 0, 0), (3, 0, 0), (3, 4, 0)], [(0, 0, 0), (0, 0, 6)], [(1, 1, 1), (2.5, 1, 1)]]
    data = [{"vertices": template + torch.tensor(c, dtype=torch.float64) * mm, "template": template} for c in clips]
    assert ex.typical_bandwidth(data) == pytest.approx(4 / math.sqrt(3) * mm, rel=1e-9)
    # the per-clip value is what rbf_kernel_weights(bandwidth=None) uses: there w = exp(-1/2) at that distance
    motion = (data[0]["vertices"] - template)[None]
    w = rbf_kernel_weights(motion, None, torch.ones(1, 3, dtype=torch.bool))
    assert w[0, 0, 2].item() == pytest.approx(math.exp(-0.5 * (25 / 3) / (16 / 3)), rel=1e-9)  # |Δ| = 5 pair


def test_compare_note():
    row = {"lve_euclidean": {"mean": 5.0, "std": 0.1, "n": 3}}
    ref = {"lve_euclidean": {"mean": 4.0, "std": 0.1, "n": 3}}
    assert report._compare(row, ref, "ref", "worse").endswith("worse")
    assert "not reproduced" in report._compare(ref, row, "ref", "worse")
    assert "within seed noise" in report._compare(row, {"lve_euclidean": {"mean": 5.05, "std": 0.1, "n": 3}}, "ref")


def test_compare_note_judges_bilabial_closure_too():
    # LVE: 5.0 vs 4.0, se = sqrt(0.01/3 + 0.01/3) = 0.0816 -> worse. Closure: 0.30 vs 0.50 with std 0.05 and 0.10
    # over 3 seeds: se = sqrt(0.0025/3 + 0.01/3) = 0.0645, |diff| 0.20 > 0.129 -> worse (higher is better).
    row = {"lve_euclidean": {"mean": 5.0, "std": 0.1, "n": 3},
           "bilabial_closure_1mm": {"mean": 0.30, "std": 0.05, "n": 3}}
    ref = {"lve_euclidean": {"mean": 4.0, "std": 0.1, "n": 3},
           "bilabial_closure_1mm": {"mean": 0.50, "std": 0.10, "n": 3}}
    assert report._compare(row, ref, "ref") == "LVE +1.000 mm vs ref: worse; closed <1 mm -0.200: worse"
    # the reverse: LVE better, closure better; the paper's claim is judged on LVE only
    assert report._compare(ref, row, "ref", "better") == "LVE -1.000 mm vs ref: better; closed <1 mm +0.200: better"
    # 0.40 vs 0.50: |diff| 0.10 <= 2 se = 0.129 -> within seed noise
    near = {**row, "bilabial_closure_1mm": {"mean": 0.40, "std": 0.05, "n": 3}}
    assert report._compare(near, ref, "ref").endswith("closed <1 mm -0.100: within seed noise")
    # a table without the lip-sync metric keeps the LVE-only note
    assert report._compare({"lve_euclidean": row["lve_euclidean"]}, ref, "ref") == "LVE +1.000 mm vs ref: worse"


# ------------------------------------------------------------------------------ the runner
def test_tables_written_with_every_row(quick_tables):
    for table in ex.TABLES:
        data = json.loads((quick_tables / f"{table}.json").read_text())
        md = (quick_tables / f"{table}.md").read_text()
        assert data["quick"] and data["seeds"] == [0] and data["epochs"] == 1
        assert "--quick" in data["command"] and data["command"] in md
        rows = [s.row for s in ex.table_specs(table, data["typical_bandwidth_m"])]
        assert [r["row"] for r in data["rows"]] == rows
        assert [r["row"] for r in data["runs"]] == rows  # one seed: one run per row
        for row in rows:
            assert f"| {row} |" in md
        for run in data["runs"]:
            assert all(math.isfinite(v) for v in run["metrics"].values()), run["row"]
            assert isinstance(run["collapsed"], bool) and run["collapsed"] == bool(run["collapse_reasons"])
            assert math.isfinite(run["train_seconds"]) and run["n_parameters"] >= 0
        assert "| collapsed |" in md
    assert "| n/a |" in (quick_tables / "main.md").read_text()  # the static template is not checked


def test_template_lve_matches_an_independent_computation(quick_tables):
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus

    data = json.loads((quick_tables / "main.json").read_text())
    run = next(r for r in data["runs"] if r["row"] == "Static template")
    corpus = Corpus(sample_path())
    lips = corpus.regions["lips"]
    worst = []
    for name in run["test_clips"]:
        gt = corpus.vertices(name).astype(np.float64).reshape(-1, corpus.metadata["n_vertices"], 3)
        tpl = corpus.template(corpus.meta(name)["subject"]).astype(np.float64).reshape(-1, 3)
        sq = (((gt[:, lips] - tpl[lips]) * 1000.0) ** 2).sum(-1)  # (T, |lips|) mm^2
        worst.append(sq.max(1))
    worst = np.concatenate(worst)
    assert len(run["test_clips"]) == ex.QUICK_CLIPS[ex.TEST_SPLIT]
    assert run["metrics"]["lve_published"] == pytest.approx(worst.mean(), rel=1e-9)
    assert run["metrics"]["lve_euclidean"] == pytest.approx(np.sqrt(worst).mean(), rel=1e-9)
    assert run["metrics"]["smoothing_lips"] == pytest.approx(0.0, abs=1e-12)
    # lip sync: the ground truth closes at every bilabial; the static face has a flat lip-distance curve
    m = run["metrics"]
    assert m["bilabial_closure_2mm_gt"] == 1.0 and m["lip_distance_corr"] == 0.0
    assert m["bilabial_closure_1mm"] == 0.0 and m["open_vowel_max_mm"] < 0.25 * m["open_vowel_max_mm_gt"]


def test_same_seed_same_metrics(quick_tables, tmp_path):
    """A second quick run of the main table: identical metrics and loss histories.

    (``--processes 2`` gives the same numbers too; not run here: spawning workers costs ~10 s of CPU.)"""
    ex.main(["--table", "main", "--quick", "--out", str(tmp_path), "--no-progress"])
    first = json.loads((quick_tables / "main.json").read_text())["runs"]
    second = json.loads((tmp_path / "main.json").read_text())["runs"]
    assert [r["row"] for r in first] == [r["row"] for r in second]
    for a, b in zip(first, second):
        assert a["metrics"] == b["metrics"], a["row"]
        assert a["loss_history"] == b["loss_history"], a["row"]


def test_reuse_takes_over_matching_runs_and_computes_none(quick_tables, tmp_path, monkeypatch, capsys):
    """--reuse: every (row, seed) of the earlier table is taken over, nothing is trained, provenance recorded."""
    def no_training(*a, **k):
        raise AssertionError("a reused run was recomputed")

    monkeypatch.setattr(ex.runner, "run_one", no_training)  # looked up by runner._job
    ex.main(["--table", "main", "--quick", "--out", str(tmp_path), "--no-progress",
             "--reuse", str(quick_tables / "main.json")])
    n = len(ex.table_specs("main"))  # one seed: one run per row
    assert f"0 distinct runs to compute, {n} reused" in capsys.readouterr().out
    first = json.loads((quick_tables / "main.json").read_text())
    second = json.loads((tmp_path / "main.json").read_text())
    assert [r["metrics"] for r in second["runs"]] == [r["metrics"] for r in first["runs"]]
    assert second["n_runs_reused"] == n
    assert second["reused_from"] == [{"table": "main.json", "run_commits": [first["git"]], "n_runs": n,
                                      "n_runs_not_clean": 0}]
    assert {r["git"] for r in second["runs"]} == {first["git"]}  # each run keeps the commit it was computed at


def test_reuse_recomputes_runs_of_a_dirty_tree(quick_tables, tmp_path):
    """A stored run stamped with a dirty tree (or with no commit, in a table that itself reused runs) is not taken
    over; a clean one is; a run of this invocation's own dirty tree is (the new table is dirty too)."""
    payload = json.loads((quick_tables / "main.json").read_text())
    a, b, c = payload["runs"][:3]
    payload["runs"] = [{**a, "git": "abc1234"}, {**b, "git": "abc1234+dirty"}, {**c, "git": "fff0000+dirty"}]
    path = tmp_path / "main.json"
    path.write_text(json.dumps(payload))
    found, sources = ex.reusable_runs([path], 1, payload["corpus"], quick=True, commit="fff0000+dirty")
    assert sorted(found) == sorted([(a["key"], a["seed"]), (c["key"], c["seed"])])
    assert sources == [{"table": "main.json", "run_commits": ["abc1234", "fff0000+dirty"], "n_runs": 2,
                        "n_runs_not_clean": 1}]
    found, _ = ex.reusable_runs([path], 1, payload["corpus"], quick=True)
    assert sorted(found) == [(a["key"], a["seed"])]
    payload["runs"] = [{k: v for k, v in r.items() if k != "git"} for r in payload["runs"]]
    payload.update(git="abc1234", reused_from=[{"table": "other.json", "git": "abc1234", "n_runs": 3}])
    path.write_text(json.dumps(payload))
    found, sources = ex.reusable_runs([path], 1, payload["corpus"], quick=True)
    assert found == {} and sources[0]["n_runs_not_clean"] == 3  # which table computed them is unknown
    payload["reused_from"] = []
    path.write_text(json.dumps(payload))
    assert len(ex.reusable_runs([path], 1, payload["corpus"], quick=True)[0]) == 3  # its own runs: its commit


def test_reuse_recomputes_a_run_whose_contact_term_never_ran(quick_tables, tmp_path):
    """A run whose recipe sets lip_contact but whose loss history has no "contact" term (the term was off: the
    emotional tables' concatenated clips before the fix) is not taken over; one that logged it is, and so is a
    run without the term in its recipe."""
    payload = json.loads((quick_tables / "main.json").read_text())
    a, b, c = payload["runs"][:3]
    on = {**a["train_config"], "lip_contact": 1e-3}
    payload["runs"] = [{**a, "git": "abc1234", "train_config": on, "loss_history": [{"total": 1.0}]},
                       {**b, "git": "abc1234", "train_config": on, "loss_history": [{"total": 1.0, "contact": 0.5}]},
                       {**c, "git": "abc1234", "train_config": {**c["train_config"], "lip_contact": 0.0},
                        "loss_history": [{"total": 1.0}]}]
    path = tmp_path / "main.json"
    path.write_text(json.dumps(payload))
    found, sources = ex.reusable_runs([path], 1, payload["corpus"], quick=True)
    assert sorted(found) == sorted([(b["key"], b["seed"]), (c["key"], c["seed"])])
    assert sources[0]["n_runs"] == 2 and sources[0]["n_runs_not_clean"] == 1


def test_reuse_refuses_a_table_with_another_budget(quick_tables, tmp_path):
    """A table trained for another number of epochs (or on another corpus) is refused, naming the file."""
    path = quick_tables / "main.json"
    with pytest.raises(ValueError, match=r"main\.json: cannot reuse its runs: epochs is 1, this invocation has 37"):
        ex.reusable_runs([path], 37, json.loads(path.read_text())["corpus"], quick=True)
    with pytest.raises(ValueError, match=r"main\.json: cannot reuse its runs: quick is True, this invocation has False"):
        ex.reusable_runs([path], 1, json.loads(path.read_text())["corpus"], quick=False)
    old = json.loads(path.read_text())
    del old["recipe"]  # a table written before --recipe: the tiny recipe
    (tmp_path / "old.json").write_text(json.dumps(old))
    with pytest.raises(ValueError, match=r"old\.json: cannot reuse its runs: recipe is 'tiny', this invocation has "
                                         r"'fast'"):
        ex.reusable_runs([tmp_path / "old.json"], 1, old["corpus"], quick=True, recipe="fast")
    assert len(ex.reusable_runs([tmp_path / "old.json"], 1, old["corpus"], quick=True, commit=old["git"])[0]) > 0
    bad = tmp_path / "junk.json"
    bad.write_text("[1, 2]")
    with pytest.raises(ValueError, match=r"junk\.json: not a table written by this runner"):
        ex.reusable_runs([bad], 1, "data_samples")


def test_save_models_writes_one_loadable_checkpoint_per_trained_run(tmp_path):
    """--save-models DIR: each trained run's model as <row>_seed<seed>.pt, loadable; the static template has none."""
    from dualtalker_lite.checkpoints import load_checkpoint

    out, models = tmp_path / "t", tmp_path / "models"
    ex.main(["--table", "main", "--quick", "--out", str(out), "--no-progress", "--save-models", str(models)])
    assert sorted(p.name for p in models.iterdir()) == ["CorrTalk_seed0.pt", "DualTalker_seed0.pt",
                                                       "FaceFormer-style_seed0.pt", "VOCA-style_seed0.pt"]
    model, ckpt = load_checkpoint(models / "DualTalker_seed0.pt")
    assert type(model).__name__ == "DualTalker" and ckpt["train_config"]["epochs"] == 1
    assert ex.command._slug("w/o Mesh Attention") == "w-o_Mesh_Attention"


def test_fast_recipe_tables_record_it_and_train_each_row_with_it(tmp_path):
    """--recipe fast (issue 31 item 6): every trained row is assembled with TrainConfig.fast at the one budget,
    the shared-weights row without the PCA head and basis step its tied head cannot have; the table says so."""
    from dualtalker_lite.checkpoints import load_checkpoint

    out, models = tmp_path / "t", tmp_path / "models"
    ex.main(["--table", "ablation", "--quick", "--recipe", "fast", "--out", str(out), "--no-progress",
             "--save-models", str(models)])
    payload = json.loads((out / "ablation.json").read_text())
    assert payload["recipe"] == "fast"
    full = load_checkpoint(models / "DualTalker_full_seed0.pt")[1]["train_config"]
    tied = load_checkpoint(models / "shared_enc-dec_weights_seed0.pt")[1]["train_config"]
    assert (full["lr"], full["pca_init"], full["basis_space"], full["lip_contact"]) == (6e-3, 64, True, 1e-3)
    assert (tied["lr"], tied["pca_init"], tied["basis_space"], tied["lip_contact"]) == (6e-3, 0, False, 1e-3)
    md = (out / "ablation.md").read_text()
    assert "the short recipe (`TrainConfig.fast`" in md and "short recipe with pca_init=0, basis_space=False" in md


# ------------------------------------------------------------------------------ the demo
def test_demo_quick_writes_every_file(tmp_path):
    from dualtalker_lite import demo
    from dualtalker_lite.checkpoints import load_checkpoint
    from dualtalker_lite.export.video import stream_info

    res = demo.main(["--out", str(tmp_path), "--quick", "--no-progress"])
    for name in ("metrics.md", "metrics.json", "lip_distance.png", "error_map.png", "side_by_side.mp4",
                 "dualtalker.pt", "faceformer.pt"):
        assert (tmp_path / name).stat().st_size > 0, name
    info = stream_info(tmp_path / "side_by_side.mp4")
    assert "Video:" in info and "Audio:" in info
    payload = json.loads((tmp_path / "metrics.json").read_text())
    assert set(payload["models"]) == set(demo.MODELS)
    assert all(math.isfinite(v) for m in payload["models"].values() for v in m["metrics"].values())
    model, _ = load_checkpoint(tmp_path / "dualtalker.pt")
    assert type(model).__name__ == "DualTalker" and model.cfg.dual
    assert res["metrics"]["DualTalker"] == payload["models"]["DualTalker"]["metrics"]
    # the real-voice closures of evaluate --real, for both trained models: 44 /p b m/ in the 24 shipped recordings
    assert set(payload["real_voices"]) == {"DualTalker", "FaceFormer-style"}
    assert all(m["n_bilabials"] == 44 and 0 <= m["closure_1mm"] <= m["closure_2mm"] <= 1
               for m in payload["real_voices"].values())


# ------------------------------------------------------------------------------ collapse detection
def test_swap_partners_pick_another_sentence():
    assert ex.swap_partners([1, 1, 2, 3, 2]) == [2, 2, 3, 4, 0]  # clip 0 skips clip 1 (same sentence 1)
    assert ex.swap_partners(["a", "a", "a"]) == [1, 2, 0]  # no other sentence: simply the next clip


def test_audio_swapped_tiles_the_partner_audio():
    base = [{"name": "a", "audio": torch.arange(5.0)[:, None], "vertices": torch.zeros(5, 3)},
            {"name": "b", "audio": torch.tensor([[7.0], [8.0]]), "vertices": torch.ones(2, 3)}]
    ds = ex.AudioSwapped(base, [1, 0])
    assert ds[0]["audio"].flatten().tolist() == [7, 8, 7, 8, 7] and ds[0]["name"] == "a"
    assert ds[1]["audio"].flatten().tolist() == [0, 1] and torch.equal(ds[1]["vertices"], base[1]["vertices"])
    with pytest.raises(ValueError, match="1 partners for 2 clips"):
        ex.AudioSwapped(base, [1])


def test_audio_sensitivity_hand_checked():
    mm = 1e-3
    g = np.zeros((2, 2, 3))
    g[:, 0, 0] = [0.0, 2 * mm]  # lip vertex 0 moves 0 -> 2 mm: squared deviations from its mean 1 + 1 = 2 mm²
    p = np.zeros((2, 2, 3))
    q = p.copy()
    q[:, 0, 0] = mm  # the swapped-audio output differs by 1 mm on both frames: 1 + 1 = 2 mm²
    q[:, 1, 0] = 5 * mm  # vertex 1 is not a lip vertex: ignored
    assert ex.audio_sensitivity([p], [q], [g], [0]) == pytest.approx(1.0)  # sqrt(2 / 2)
    assert ex.audio_sensitivity([p], [p], [g], [0]) == 0.0
    q[:, 0, 0] = [mm, -mm]  # still 1 + 1 mm²
    assert ex.audio_sensitivity([p], [q], [g], [0]) == pytest.approx(1.0)


def test_collapse_rules():
    assert ex.collapse_reasons({"smoothing_lips": 0.8, "audio_sensitivity": 1.1}) == []
    assert ex.collapse_reasons({"smoothing_lips": 0.001, "audio_sensitivity": 0.002}) == [
        "lip motion ratio 0.001 < 0.1", "audio sensitivity 0.002 < 0.1"]
    assert ex.collapse_reasons({"smoothing_lips": 0.7, "audio_sensitivity": 0.05}) == ["audio sensitivity 0.050 < 0.1"]
    assert ex.collapse_reasons({"smoothing_lips": 0.05}) == ["lip motion ratio 0.050 < 0.1"]  # older results
    template = {"key": ex.table_specs("main")[0].key(), "metrics": {"smoothing_lips": 0.0}}
    assert not ex.is_collapsed(template)  # the floor, not a failed run


class _FakeModel(torch.nn.Module):
    """generate() = template + a lip motion that follows the audio (follow=True) or a fixed sine (False)."""

    def __init__(self, follow: bool, lips):
        super().__init__()
        self.follow, self.lips = follow, torch.as_tensor(lips)

    def generate(self, audio, template, speaker=None, use_cache=True, mask=None):
        B, T = audio.shape[:2]
        drive = audio.mean(-1) if self.follow else torch.sin(torch.arange(T) / 3.0).expand(B, T)  # (B, T)
        out = template[:, None].repeat(1, T, 1).view(B, T, -1, 3).clone()  # (B, T, V, 3)
        out[:, :, self.lips, 1] += 1e-3 * drive[..., None]
        return out.view(B, T, -1)


def test_audio_independent_output_is_flagged_and_audio_driven_is_not():
    data = ex.load_data(quick=True)
    corpus, test = data["corpus"], data["test"]
    lips = corpus.regions["lips"]
    partners = ex.swap_partners([corpus.meta(test[i]["name"])["sentence_id"] for i in range(len(test))])
    sens = {}
    for follow in (True, False):
        model = _FakeModel(follow, lips)
        out = ex.predict_split(model, test)
        swapped = ex.predict_split(model, ex.AudioSwapped(test, partners))
        sens[follow] = ex.audio_sensitivity(out["preds"], swapped["preds"], out["gts"], lips)
        ratio = ex.over_smoothing_ratio(out["preds"], out["gts"], lips)
        assert ratio > 0.1  # both move: the motion ratio alone cannot tell them apart
        reasons = ex.collapse_reasons({"smoothing_lips": ratio, "audio_sensitivity": sens[follow]})
        assert bool(reasons) == (not follow), reasons
    assert sens[False] == 0.0 and sens[True] > 0.1


def _fake_run(row, seed, lve, collapsed=False):
    metrics = {k: 1.0 for k, _, _ in ex.METRICS}
    metrics.update(lve_euclidean=lve, eve_euclidean=1.0, smoothing_lips=0.001 if collapsed else 0.8,
                   audio_sensitivity=0.0 if collapsed else 1.0)
    return {"row": row, "key": json.dumps({"model": "faceformer", "seed_row": row}), "seed": seed,
            "metrics": metrics, "collapsed": collapsed,
            "collapse_reasons": ex.collapse_reasons(metrics), "train_seconds": 10.0, "n_parameters": 5}


def test_tables_exclude_and_name_collapsed_runs(tmp_path):
    specs = [ex.RunSpec("A", "faceformer", note="a"), ex.RunSpec("B", "dualtalker", reference=True)]
    runs = [_fake_run("A", 0, 9.0, collapsed=True), _fake_run("A", 1, 4.0), _fake_run("A", 2, 5.0),
            _fake_run("B", 0, 4.0), _fake_run("B", 1, 4.2), _fake_run("B", 2, 4.4)]
    meta = {"command": "python -m dualtalker_lite.experiments (test)", "seeds": [0, 1, 2], "epochs": 1, "quick": False,
            "n_train_clips": 1, "n_test_clips": 1, "corpus": "data_samples", "git": "x", "created": "now"}
    json_path, md_path = ex.write_table("main", specs, runs, meta, tmp_path)
    summary = {r["row"]: r["summary"] for r in json.loads(json_path.read_text())["rows"]}
    # row A: seed 0 (9.0 mm, collapsed) left out: mean (4 + 5) / 2 = 4.5, sample std sqrt(0.5) = 0.707
    assert summary["A"]["lve_euclidean"]["mean"] == pytest.approx(4.5)
    assert summary["A"]["lve_euclidean"]["std"] == pytest.approx(math.sqrt(0.5))
    assert summary["A"]["collapsed"] == [0] and summary["B"]["collapsed"] == []
    md = md_path.read_text()
    row_a = next(line for line in md.splitlines() if line.startswith("| A |"))
    assert "4.500 ± 0.707" in row_a and "**1/3**" in row_a
    assert "**1 of 3 runs collapsed** (seed 0: lip motion ratio 0.001 < 0.1, audio sensitivity 0.000 < 0.1)" in row_a
    assert "excluded from mean ± std" in row_a
    assert "| 0/3 |" in next(line for line in md.splitlines() if line.startswith("| B |"))
    specs_back, runs_back, payload = ex.load_table(json_path)  # the notebook's path: JSON -> the same Markdown
    assert specs_back == specs and ex.table_markdown("main", specs_back, runs_back, payload) == md
    runs_old = [{**r, "metrics": {k: v for k, v in r["metrics"].items() if not k.startswith("bilabial")}}
                for r in runs]  # results written before the lip-sync metrics: "—", not nan
    for r in runs_old:
        r.pop("collapsed")  # ... and before the flag: the rule is applied to their metrics
    old_md = ex.table_markdown("main", specs, runs_old, meta)
    row_a = next(line for line in old_md.splitlines() if line.startswith("| A |"))
    assert "| — |" in row_a and "nan" not in old_md and "**1/3**" in row_a
    # every run collapsed: the numbers are theirs, and the note says so
    runs_all = [_fake_run("A", s, 9.0 + s, collapsed=True) for s in range(3)] + runs[3:]
    _, md_path = ex.write_table("main", specs, runs_all, meta, tmp_path)
    row_a = next(line for line in md_path.read_text().splitlines() if line.startswith("| A |"))
    assert "10.000 ± 1.000" in row_a and "ALL runs collapsed" in row_a


def test_results_carry_no_machine_paths(quick_tables, tmp_path):
    from dualtalker_lite.files import repo_root

    data = json.loads((quick_tables / "main.json").read_text())
    assert data["corpus"] == "data_samples"
    assert command._display_path(tmp_path / "my_corpus") == "my_corpus"  # outside the repository: the name only
    assert command._display_path(Path(repo_root()) / "data_samples") == "data_samples"


def test_markdown_names_the_stored_corpus_whatever_the_working_directory(quick_tables, monkeypatch):
    """The table text quotes the corpus path stored in the JSON; rendering from notebooks/ must not re-resolve it."""
    specs, runs, payload = ex.load_table(quick_tables / "main.json")
    assert payload["corpus"] == "data_samples"
    monkeypatch.chdir(Path(ex.__file__).resolve().parents[2] / "notebooks")
    md = ex.table_markdown("main", specs, runs, payload)
    assert "Corpus `data_samples`" in md and "notebooks/data_samples" not in md


def test_emotional_tables_columns(quick_tables):
    """The emotional tables are evaluated on test_emo_a and add the emotion columns; only EmoFace has a classifier."""
    data = json.loads((quick_tables / "emotion.json").read_text())
    md = (quick_tables / "emotion.md").read_text()
    assert data["test_split"] == "test_emo_a" and "test_emo_a clips: 4" in md
    assert "| emotion acc. ↑ | brow-raise error (mm) ↓ | smile error (mm) ↓ |" in md
    runs = {r["row"]: r for r in data["runs"]}
    assert set(runs["EmoFace"]["metrics"]) >= {"emotion_accuracy", "brow_raise_error_mm", "smile_error_mm"}
    dualtalker = runs["DualTalker"]["metrics"]
    assert "emotion_accuracy" not in dualtalker and "brow_raise_error_mm" in dualtalker
    assert all(r["test_split"] == "test_emo_a" and r["n_train_clips"] == 32 for r in data["runs"])  # 16 + 16 (quick)
    assert all(c.startswith("SPK01_s02-") for r in data["runs"] for c in r["test_clips"])
    assert "emotion acc." not in (quick_tables / "main.md").read_text()


def test_markdown_with_a_few_metrics_fits_and_says_where_the_rest_is():
    """Notebooks show a few columns of the committed tables (the full ones are too wide for the page)."""
    from dualtalker_lite.files import repo_root

    specs, runs, payload = ex.load_table(repo_root() / "results" / "corrtalk.json")
    full = ex.table_markdown("corrtalk", specs, runs, payload)
    md = ex.table_markdown("corrtalk", specs, runs, payload, metrics=["lve_euclidean", "bilabial_closure_1mm"])
    header = next(line for line in md.splitlines() if line.startswith("| model |"))
    assert header == "| model | LVE (mm) ↓ | closed <1 mm at /p b m/ ↑ | collapsed | train (s) | params | note |"
    assert "Columns: 2 of the 12 metrics; all of them in `results/corrtalk.md`." in md
    row = next(line for line in md.splitlines() if line.startswith("| CorrTalk |"))
    assert row.split(" | ")[1] == next(ln for ln in full.splitlines() if ln.startswith("| CorrTalk |")).split(" | ")[2]
    with pytest.raises(ValueError, match="no metric"):
        ex.table_markdown("corrtalk", specs, runs, payload, metrics=["emotion_accuracy"])


def test_refresh_rewrites_descriptions_not_numbers(tmp_path):
    """--refresh: a stored table gets the current notes, claims and definitions back; its runs stay as they were."""
    stored = json.loads((Path(__file__).parents[1] / "results" / "corrtalk.json").read_text())
    stale = json.loads(json.dumps(stored))
    stale["rows"][-1]["expect"], stale["rows"][-1]["note"] = "worse", "an old note"
    stale["caveat"] = "a warning kept under the title"
    path = tmp_path / "corrtalk.json"
    path.write_text(json.dumps(stale))
    ex.main(["--refresh", str(path)])
    fresh = json.loads(path.read_text())
    specs = ex.table_specs("corrtalk")
    assert [(r["row"], r["note"], r["expect"]) for r in fresh["rows"]] == [(s.row, s.note, s.expect) for s in specs]
    assert fresh["runs"] == stored["runs"] and fresh["command"] == stored["command"]
    md = path.with_suffix(".md").read_text()
    assert "an old note" not in md and "> a warning kept under the title" in md
    row = md.split("| phoneme one-hot features |")[1].split("\n")[0]
    assert "not reproduced" not in row and "not a paper row" in row  # the paper never tested phoneme ids
    stale["rows"][0]["row"] = "renamed"
    path.write_text(json.dumps(stale))
    with pytest.raises(ValueError, match="not the current"):
        ex.main(["--refresh", str(path)])


def test_trimmed_view_keeps_named_clips_or_the_first_n():
    """run_one/load_data(clips=...): a benchmark's reduced training set, by count or by clip names."""
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus
    from dualtalker_lite.experiments.runner import _trimmed

    corpus = Corpus(sample_path())
    train = list(corpus.metadata["splits"]["train"])
    view = _trimmed(corpus, {"train": [train[5], train[2]], "test_a": 3})
    assert view.metadata["splits"]["train"] == [train[2], train[5]]  # the split's order
    assert view.metadata["splits"]["test_a"] == list(corpus.metadata["splits"]["test_a"])[:3]
    assert list(corpus.metadata["splits"]["train"]) == train  # the corpus itself is untouched
    with pytest.raises(ValueError, match="not in split"):
        _trimmed(corpus, {"train": ["no_such_clip"]})


def test_swapped_in_rows_name_the_front_end_they_replace():
    """On the phonetic default the one-hot phoneme rows replace the recogniser's classes, not log-mel."""
    for table in ("ablation", "corrtalk"):
        logmel = {s.row: s for s in ex.table_specs(table, features="logmel")}["phoneme one-hot features"]
        phon = {s.row: s for s in ex.table_specs(table, features="visemes")}["phoneme one-hot features"]
        assert phon.features == logmel.features == "phonemes"
        assert "log-mel" in logmel.note and "log-mel" not in phon.note
        assert phon.note == logmel.note.replace("log-mel", "the recogniser's viseme classes")
