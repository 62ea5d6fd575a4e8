"""The bilabial contact term (losses.contact, eq. C1; TrainConfig.lip_contact): by hand, in basis coordinates, in
train(), and its refusals."""
import pytest
import torch
from torch.utils.data import ConcatDataset, Dataset, Subset

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.dataset import TalkingFaceDataset, VisemeLabels, make_loader
from dualtalker_lite.losses.contact import bilabial_contact
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.models.faceformer import FaceFormer, FaceFormerConfig
from dualtalker_lite.train import TrainConfig, _LipContact, basis_batch, train

pytestmark = pytest.mark.usefixtures("one_thread")


def test_bilabial_contact_by_hand():
    """Eq. C1 on 2 clips x 3 frames: the mean over the bilabial frames of the squared midpoint distance in mm²."""
    upper = torch.zeros(2, 3, 3)
    lower = torch.zeros(2, 3, 3)
    upper[0, 0] = torch.tensor([0.0, 0.001, 0.0])      # 1 mm apart: 1 mm²
    upper[0, 1] = torch.tensor([0.0003, 0.0004, 0.0])  # 0.5 mm apart: 0.25 mm²
    upper[1, 2] = torch.tensor([0.0, 0.0, 0.002])      # 2 mm apart, not a bilabial frame: left out
    lower[1, 0] = torch.tensor([0.0, 0.0, 0.0])        # touching: 0 mm²
    bilabial = torch.tensor([[True, True, False], [True, False, False]])
    assert float(bilabial_contact(upper, lower, bilabial)) == pytest.approx((1.0 + 0.25 + 0.0) / 3, rel=1e-6)
    up = upper.clone().requires_grad_(True)
    none = bilabial_contact(up, lower, torch.zeros(2, 3, dtype=torch.bool))
    none.backward()  # still in the graph
    assert float(none.detach()) == 0.0 and float(up.grad.abs().sum()) == 0.0
    with pytest.raises(ValueError, match=r"bilabial_contact: upper, lower \(B, T, 3\) and bilabial \(B, T\)"):
        bilabial_contact(upper, lower, bilabial[:, :2])


@pytest.mark.parametrize("kind", ["dualtalker", "faceformer"])
def test_the_term_in_basis_coordinates_is_the_vertex_one(kind):
    """In basis_space the midpoints come from z (z @ P[:, cols] / a + template + the head bias's rest outside the
    span, the mean motion's): the same value as the projected model's vertex-coordinate output gives."""
    nv, b, t, k = 30, 2, 12, 8
    g = torch.Generator().manual_seed(0)
    p = torch.linalg.qr(torch.randn(3 * nv, k, generator=g, dtype=torch.float64))[0].T.float()  # (k, 3V)
    template = torch.randn(b, 3 * nv, generator=g) * 0.01
    batch = {"audio": torch.randn(b, t, 15, generator=g), "template": template,
             "vertices": template[:, None] + torch.randn(b, t, 3 * nv, generator=g) * 1e-3,
             "speaker": torch.tensor([0, 1]), "mask": torch.ones(b, t, dtype=torch.bool),
             "visemes": torch.randint(0, 3, (b, t), generator=g)}
    batch["mask"][1, 9:] = False
    torch.manual_seed(1)
    cls, cfg = (DualTalker, DualTalkerConfig) if kind == "dualtalker" else (FaceFormer, FaceFormerConfig)
    model = cls(cfg.tiny(n_vertices=nv, audio_dim=15, n_speakers=2, motion_dropout=0.0))
    mean = torch.randn(3 * nv, generator=g) * 1e-3  # has a part outside the span
    model.init_output_bias(mean)
    model.init_output_basis(p * 1e-3)
    model.set_motion_basis(p)
    model.train()
    in_basis = _LipContact((3, 7), p, mean)(model(basis_batch(batch, p))["vertices"], batch, template)
    model.set_motion_basis(None)  # the same (projected) weights, vertex coordinates
    plain = _LipContact((3, 7), None, None)(model(batch)["vertices"], batch, template)
    assert plain.item() > 0.1
    torch.testing.assert_close(in_basis, plain, rtol=1e-4, atol=1e-6)


@pytest.fixture(scope="module")
def phonetic():
    corpus = Corpus(sample_path())
    return corpus, VisemeLabels(Subset(TalkingFaceDataset(corpus, "train"), range(16)))


def _model(corpus, seed=0):
    torch.manual_seed(seed)
    return DualTalker(DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=15, n_speakers=8))


def _contact_of(model, corpus, clips) -> float:
    """Eq. C1 of a trained model on its clips, teacher forced in eval mode, written out from the corpus's midpoints."""
    up, lo = (int(i) for i in corpus.regions["lip_midpoints"])
    batch = next(iter(make_loader(clips, len(clips), shuffle=False)))
    model.eval()
    with torch.no_grad():
        v = model(batch)["vertices"]
    v = v.reshape(*v.shape[:2], -1, 3)
    gap = (v[:, :, up] - v[:, :, lo]) * 1000.0  # (B, T, 3) mm
    on = (batch["visemes"] == 1) & batch["mask"]
    return float(gap[on].square().sum(-1).mean())


def test_train_with_the_term_logs_it_and_closes_the_lips_on_bilabials(phonetic):
    corpus, clips = phonetic
    runs = {}
    for weight in (0.0, 0.05):
        model = _model(corpus)
        cfg = TrainConfig.tiny(epochs=6, progress=False, lip_contact=weight, pca_init=16, basis_space=True,
                               lr=6e-3)
        hist = train(model, make_loader(clips, 8, shuffle=True, seed=0), cfg)
        runs[weight] = (hist, _contact_of(model, corpus, clips))
    off, on = runs[0.0], runs[0.05]
    assert "contact" not in off[0].terms[-1] and "contact" in on[0].terms[-1]
    assert on[0].terms[-1]["contact"] < on[0].terms[0]["contact"]  # the term falls while training
    assert on[1] < 0.25 * off[1], (on[1], off[1])  # closer lips on /p b m/ (measured: 1.2 against 24.8 mm²)


class _NoVisemes(Dataset):
    def __init__(self, base):
        self.base = base

    def __len__(self):
        return len(self.base)

    def __getitem__(self, i):
        return {k: v for k, v in self.base[i].items() if k != "visemes"}


def test_the_term_is_refused_without_labels_and_off_without_midpoints(phonetic, capsys):
    corpus, clips = phonetic
    with pytest.raises(ValueError, match="lip_contact must be a finite weight >= 0, got -1"):
        TrainConfig.tiny(lip_contact=-1.0)
    model = _model(corpus)
    before = {n: q.clone() for n, q in model.state_dict().items()}
    with pytest.raises(ValueError, match="the training clips carry no 'visemes' labels"):
        train(model, make_loader(_NoVisemes(clips), 8, shuffle=True, seed=0),
              TrainConfig.tiny(epochs=1, progress=False, lip_contact=1e-3))
    assert all(torch.equal(before[n], q) for n, q in model.state_dict().items())  # refused before any change
    batches = list(make_loader(clips, 8, shuffle=False))[:1]  # padded batches: no corpus, so no lip midpoints
    hist = train(model, batches, TrainConfig.tiny(epochs=1, progress=False, lip_contact=1e-3))
    assert "contact" not in hist.terms[-1]
    assert capsys.readouterr().err.splitlines() == [
        "train: lip_contact is set but the training data name no lip midpoints (the corpus's regions); the "
        "bilabial contact term is off"]


def test_the_term_finds_the_midpoints_through_a_concatenation(capsys):
    """The emotional tables train on ConcatDataset([train, train_emo]) under the viseme wrapper: the term must find
    the corpus's lip midpoints through it (it was silently off there before, with lip_contact recorded as set)."""
    corpus = Corpus(sample_path())
    parts = [Subset(TalkingFaceDataset(corpus, split), range(8)) for split in ("train", "train_emo")]
    clips = VisemeLabels(ConcatDataset(parts))
    hist = train(_model(corpus), make_loader(clips, 8, shuffle=True, seed=0),
                 TrainConfig.tiny(epochs=1, progress=False, lip_contact=1e-3))
    assert "contact" in hist.terms[-1] and hist.terms[-1]["contact"] > 0
    assert capsys.readouterr().err == ""
