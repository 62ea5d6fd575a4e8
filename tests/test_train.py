"""The training loop: it learns, it is reproducible, checkpoints round-trip with weights_only=True."""
import pytest
import torch
from torch.utils.data import Subset

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.dataset import TalkingFaceDataset, make_loader
from dualtalker_lite.losses import LossWeights
from dualtalker_lite.models.baselines import VocaConfig, VocaStyle
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.train import TrainConfig, load_checkpoint, predict, save_checkpoint, train, validation_lve


@pytest.fixture(scope="module")
def data():
    torch.set_num_threads(1)
    corpus = Corpus(sample_path())
    train_set = Subset(TalkingFaceDataset(corpus, "train"), range(16))
    val_set = Subset(TalkingFaceDataset(corpus, "val"), range(4))
    return corpus, train_set, val_set


def _model(corpus, seed=0):
    torch.manual_seed(seed)
    return DualTalker(DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=160, n_speakers=8))


def _run(corpus, train_set, val_set, seed=0, epochs=3, **kw):
    model = _model(corpus, seed)
    cfg = TrainConfig.tiny(epochs=epochs, seed=seed, progress=False, weights=LossWeights(), **kw)
    hist = train(model, make_loader(train_set, 8, shuffle=True, seed=seed), cfg,
                 val_loader=make_loader(val_set, 4, shuffle=False), lip_idx=corpus.regions["lips"])
    return model, hist


def _primal_on(model, train_set):
    from dualtalker_lite.losses import joint_loss

    batch = next(iter(make_loader(train_set, len(train_set), shuffle=False)))
    model.eval()
    with torch.no_grad():
        return float(joint_loss(model(batch), batch, LossWeights())[1]["primal"])


def test_every_term_is_logged_and_the_primal_loss_falls(data):
    corpus, train_set, val_set = data
    before = _primal_on(_model(corpus), train_set)  # untrained: the template, zero motion
    model, hist = _run(corpus, train_set, val_set, epochs=10, validate_every=1)
    assert set(hist.terms[0]) == {"primal", "dual", "dr", "ccrl", "total"}
    assert _primal_on(model, train_set) < 0.5 * before
    assert len(hist.val_lve) == 10 and all(v > 0 for v in hist.val_lve)
    assert hist.seconds == sorted(hist.seconds)


def test_same_seed_same_history(data):
    _, h1 = _run(*data, seed=3, epochs=2)
    _, h2 = _run(*data, seed=3, epochs=2)
    assert h1.terms == h2.terms and h1.val_lve == h2.val_lve
    _, h3 = _run(*data, seed=4, epochs=2)
    assert h3.terms != h1.terms


def test_checkpoint_round_trip_with_weights_only(data, tmp_path):
    corpus, train_set, val_set = data
    model, hist = _run(corpus, train_set, val_set, epochs=1)
    path = save_checkpoint(tmp_path / "dt.pt", model, model.cfg, TrainConfig.tiny(), hist)
    assert not list(tmp_path.glob("*.tmp"))  # atomic write leaves no temporary file
    raw = torch.load(path, weights_only=True)  # plain values and tensors only
    assert raw["model_class"] == "DualTalker" and raw["history"]["terms"] == hist.terms
    loaded, _ = load_checkpoint(path)
    batch = next(iter(make_loader(val_set, 2, shuffle=False)))
    torch.testing.assert_close(predict(loaded, batch), predict(model, batch), rtol=0, atol=0)


def test_checkpoint_errors_are_clear(tmp_path):
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        load_checkpoint(tmp_path / "missing.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="junk.pt"):
        load_checkpoint(tmp_path / "junk.pt")


def test_baselines_train_with_the_same_loop(data):
    corpus, train_set, val_set = data
    torch.manual_seed(0)
    model = VocaStyle(VocaConfig.tiny(n_vertices=corpus.metadata["n_vertices"], n_speakers=8))
    lips = corpus.regions["lips"]
    before = validation_lve(model, make_loader(val_set, 4, shuffle=False), lips)
    hist = train(model, make_loader(train_set, 8, shuffle=True), TrainConfig.tiny(epochs=6, progress=False))
    after = validation_lve(model, make_loader(val_set, 4, shuffle=False), lips)
    assert hist.terms[0]["dual"] == 0.0 and after < before
