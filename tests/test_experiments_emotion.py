"""The runner's emotional tables: RunSpec.data, per-table test splits, keys of existing rows, EmoFace's rows."""
import json
from pathlib import Path

import pytest
import torch

from dualtalker_lite import experiments as ex

ROOT = Path(__file__).resolve().parents[1]


def test_committed_main_table_keys_unchanged():
    """Committed results are reused by key: every row of results/main.json still has the key its spec computes."""
    payload = json.loads((ROOT / "results" / "main.json").read_text())
    specs = {s.row: s for s in ex.table_specs("main")}
    stored = {r["row"]: r["key"] for r in payload["runs"]}
    assert stored and set(stored) <= set(specs)
    for row, key in stored.items():
        assert specs[row].key() == key == specs[row].key(ex.table_split("main")), row


def test_key_adds_new_fields_only_when_not_default():
    plain = ex.RunSpec("x", "dualtalker")  # the default front end is the project's, the phonetic route (issue 46)
    assert plain.key() == '{"features": "visemes", "loss": {}, "model": "dualtalker", "model_overrides": {}}'
    assert json.loads(ex.RunSpec("x", "dualtalker", features="logmel", data="emotional").key()) == {
        "data": "emotional", "features": "logmel", "loss": {}, "model": "dualtalker", "model_overrides": {}}
    assert json.loads(plain.key("test_emo_a"))["test_split"] == "test_emo_a"  # same row, other split: another run
    assert plain.key("test_emo_a") != plain.key()


@pytest.mark.parametrize("kwargs, message", [
    (dict(data="both"), r"RunSpec 'r': data must be one of \('neutral', 'emotional', 'pairs'\), got 'both'"),
    (dict(data="pairs", features="phonemes"), r"RunSpec 'r': data 'pairs' needs features 'logmel'"),
])
def test_runspec_refuses_bad_data(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ex.RunSpec("r", "emoface", **kwargs)


def test_table_splits_and_columns():
    for table in ("main", "ablation", "sweep", "corrtalk"):
        assert ex.table_split(table) == "test_a" and ex.table_metrics(table) == ex.METRICS
    for table in ("emotion", "emoface"):
        assert ex.table_split(table) == "test_emo_a"
        assert [k for k, _, _ in ex.table_metrics(table)][-3:] == ["emotion_accuracy", "brow_raise_error_mm",
                                                                  "smile_error_mm"]


def test_emotion_tables_rows():
    emo = ex.table_specs("emotion")
    assert [s.row for s in emo] == ["FaceFormer-style", "DualTalker", "CorrTalk", "EmoFace"]
    assert [s.model for s in emo] == ["faceformer", "dualtalker", "corrtalk", "emoface"]
    assert [s.data for s in emo] == ["emotional", "emotional", "emotional", "pairs"]  # the same clips for all
    assert [s.reference for s in emo] == [False, False, False, True]
    abl = ex.table_specs("emoface")
    assert all(s.model == "emoface" and s.data == "pairs" for s in abl)
    assert [s.model_overrides for s in abl] == [{}, {"fusion": "sum"}, {"spiral_length": 1, "spiral_delta": 1},
                                                {"past_motion": "teacher_forcing"}, {"cross_reconstruction": False}]
    assert abl[0].key() == emo[-1].key()  # the full EmoFace is one computation in both tables
    assert len({s.key() for s in abl}) == len(abl)


def test_emoface_ablation_models_build_and_run():
    """Every ablation row builds (the length-1 spirals of "w/o SpiralConv3D" are not mistaken for the placeholder)."""
    import numpy as np

    rows, cols = 3, 4  # a flat grid, two triangles per square: V = 12
    corners = [(i * cols + j, i * cols + j + 1, (i + 1) * cols + j, (i + 1) * cols + j + 1)
               for i in range(rows - 1) for j in range(cols - 1)]
    faces = np.array([f for a, b, c, d in corners for f in ((a, b, d), (a, d, c))])
    n = rows * cols
    for spec in ex.table_specs("emoface"):
        torch.manual_seed(0)
        model, cfg = ex.build_model(spec, n, 8, 2, faces=faces)
        audio, tpl = torch.randn(1, 3, 8), torch.zeros(1, 3 * n)
        out = model.generate(audio, tpl, torch.zeros(1, dtype=torch.long), level=torch.tensor([2]))
        assert out.shape == (1, 3, 3 * n) and torch.isfinite(out).all(), spec.row
        if spec.row == "w/o SpiralConv3D":
            assert model.mesh_attention.convs[0].spirals.shape == (n, 1) and model.mesh_attention.receptive_field == 1


def test_swap_partners_from_another_source_hand_checked():
    # every target reads "a": partners are the first source clips (from index i, cyclically) reading another sentence
    assert ex.swap_partners(["a", "a", "a"], ["a", "b", "c"]) == [1, 1, 2]
    assert ex.swap_partners(["a", "b"], ["b", "b", "a"]) == [0, 2]
    assert ex.swap_partners(["a"], ["a", "a"]) == [0]  # no other sentence: the clip at the same index
    with pytest.raises(ValueError, match="source set is empty"):
        ex.swap_partners(["a"], [])


def test_audio_swapped_takes_audio_from_the_source():
    base = [{"name": "e", "audio": torch.zeros(5, 2), "vertices": torch.ones(5, 3)}]
    source = [{"name": "n0", "audio": torch.arange(6.0).reshape(3, 2)}]
    item = ex.AudioSwapped(base, [0], source)[0]
    assert torch.equal(item["audio"], torch.tensor([[0, 1], [2, 3], [4, 5], [0, 1], [2, 3.0]]))  # tiled to T=5
    assert item["name"] == "e" and torch.equal(item["vertices"], base[0]["vertices"])


def test_predict_passes_the_conditions_the_model_names():
    from dualtalker_lite.train import predict

    class Stub(torch.nn.Module):
        generation_conditions = ("level", "missing_key")

        def __init__(self):
            super().__init__()
            self.w = torch.nn.Parameter(torch.zeros(()))
            self.seen = None

        def generate(self, audio, template, speaker, use_cache=True, mask=None, **kw):
            self.seen = kw
            return template[:, None].expand(-1, audio.shape[1], -1)

    batch = {"audio": torch.zeros(2, 4, 3), "template": torch.zeros(2, 6), "speaker": torch.tensor([0, -1]),
             "mask": torch.ones(2, 4, dtype=torch.bool), "level": torch.tensor([1, 2])}
    model = Stub()
    predict(model, batch)
    assert list(model.seen) == ["level"] and torch.equal(model.seen["level"], torch.tensor([1, 2]))
    plain = Stub()
    plain.generation_conditions = ()
    predict(plain, batch)
    assert plain.seen == {}


def _toy_clip(name, emotion, brow_mm, template):
    """A 3-frame clip of a 5-vertex face (vertex 2, 3 = brows, 0, 1 = mouth corners) with brows up by brow_mm."""
    v = template.reshape(1, 5, 3).repeat(3, 1, 1).clone()
    v[:, 2:4, 1] += brow_mm / 1000
    return {"name": name, "audio": torch.full((3, 2), float(emotion)), "vertices": v.reshape(3, 15),
            "template": template, "phonemes": torch.zeros(3, dtype=torch.long),
            "visemes": torch.zeros(3, dtype=torch.long), "speaker": 0, "emotion": emotion, "level": 1}


def test_emotion_split_metrics_hand_computed():
    """Accuracy through the model's emotion_logits hook; brow/smile errors from the predictions (hand values)."""
    template = torch.tensor([[0.02, 0, 0], [-0.02, 0, 0], [0.01, 0.03, 0], [-0.01, 0.03, 0], [0, 0.01, 0.01]])
    template = template.reshape(-1)  # (V*3,)
    data = [_toy_clip("a", 1, 2.0, template), _toy_clip("b", 1, 4.0, template), _toy_clip("c", 3, -1.0, template)]

    class Classifier(torch.nn.Module):  # names emotion 1 for every clip: right for a and b, wrong for c
        def emotion_logits(self, audio, mask):
            return torch.nn.functional.one_hot(torch.ones(audio.shape[0], dtype=torch.long), 5).float()

    flat = [template.reshape(1, -1).repeat(3, 1).numpy()] * 3  # predictions: the still template
    out = {"preds": flat, "gts": [d["vertices"].numpy() for d in data], "templates": [template.numpy()] * 3}
    regions = {"brows": [2, 3], "mouth_corners": [0, 1]}
    emotions = ["neutral", "happy", "sad", "angry", "surprised"]
    res, per = ex.emotion_split_metrics(Classifier(), data, out, emotions, regions)
    assert res["emotion_accuracy"] == pytest.approx(2 / 3)
    # brow raise GT: happy mean 3 mm, angry -1 mm; prediction 0 -> errors 3 and 1 -> 2 mm; no smile anywhere
    assert res["brow_raise_error_mm"] == pytest.approx(2.0, abs=1e-5) and res["smile_error_mm"] == pytest.approx(0.0)
    assert list(per) == ["happy", "angry"] and per["happy"]["n_clips"] == 2
    res_plain, _ = ex.emotion_split_metrics(torch.nn.Module(), data, out, emotions, regions)
    assert "emotion_accuracy" not in res_plain  # no classifier: no accuracy (the table shows "—")


def test_paper_claims_only_where_the_paper_has_the_row():
    """EmoFace's Table 3 has two ablations, its Table 2 compares with FaceFormer; CorrTalk never tested phoneme ids."""
    assert {s.row: s.expect for s in ex.table_specs("emoface")} == {
        "EmoFace (full)": "", "w/o Mesh Attention": "worse", "w/o SpiralConv3D": "", "w/o self-growing": "worse",
        "w/o cross-reconstruction": ""}
    assert {s.row: s.expect for s in ex.table_specs("emotion")} == {
        "FaceFormer-style": "worse", "DualTalker": "", "CorrTalk": "", "EmoFace": ""}
    corrtalk = {s.row: s.expect for s in ex.table_specs("corrtalk")}
    assert corrtalk["phoneme one-hot features"] == "" and corrtalk["single branch"] == "worse"
