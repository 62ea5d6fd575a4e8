"""The training loop: it learns, it is reproducible, checkpoints round-trip with weights_only=True."""
import resource
import sys

import pytest
import torch
from torch.utils.data import Subset

from dualtalker_lite.checkpoints import load_checkpoint, save_checkpoint
from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.dataset import TalkingFaceDataset, make_loader
from dualtalker_lite.losses import LossWeights
from dualtalker_lite.models.baselines import VocaConfig, VocaStyle
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.train import TrainConfig, motion_basis, predict, reuse_freed_memory, train, validation_lve

pytestmark = pytest.mark.usefixtures("one_thread")  # conftest.py


@pytest.fixture(scope="module")
def data():
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


def test_checkpoint_is_plain_data_written_atomically(data, tmp_path):
    """What a checkpoint holds and how it is written. That a loaded model computes what the saved one did is
    checked against files written by older code (tests/test_legacy_checkpoints.py), not against itself."""
    corpus, train_set, val_set = data
    model, hist = _run(corpus, train_set, val_set, epochs=1)
    path = save_checkpoint(tmp_path / "dt.pt", model, model.cfg, TrainConfig.tiny(), hist)
    assert not list(tmp_path.glob("*.tmp"))  # atomic write leaves no temporary file
    raw = torch.load(path, weights_only=True)  # plain values and tensors only
    assert raw["model_class"] == "DualTalker" and raw["history"]["terms"] == hist.terms
    loaded, info = load_checkpoint(path)
    assert loaded.cfg == model.cfg and info["history"]["terms"] == hist.terms


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
    assert set(hist.terms[0]) == {"primal", "total"} and after < before  # the baselines' own loss


def test_lr_factor_warmup_and_cosine_by_hand():
    from dualtalker_lite.train import lr_factor

    # warm-up: (step + 1) / warmup_steps, whatever the decay
    assert lr_factor(0, 4, "cosine", 0.0) == 0.25 and lr_factor(3, 4, "none", 0.9) == 1.0
    # cosine from 1 to min_lr_ratio over the budget: 0.5 (1 + cos(pi p)) -> p = 0, 1/3, 1/2, 1
    assert lr_factor(10, 4, "cosine", 0.0) == 1.0
    assert abs(lr_factor(10, 4, "cosine", 1 / 3) - 0.75) < 1e-12  # cos(pi/3) = 1/2
    assert abs(lr_factor(10, 4, "cosine", 0.5, min_lr_ratio=0.1) - 0.55) < 1e-12  # 0.1 + 0.9 * 0.5
    assert abs(lr_factor(10, 0, "cosine", 1.0, min_lr_ratio=0.1) - 0.1) < 1e-12
    assert lr_factor(10, 0, "none", 0.7) == 1.0


def test_config_errors_are_clear():
    with pytest.raises(ValueError, match="decay must be 'none' or 'cosine'"):
        TrainConfig(decay="linear")
    with pytest.raises(ValueError, match="lr must be > 0"):
        TrainConfig(lr=0.0)


class _Line(torch.nn.Module):
    """y = a * x fitted by SGD-free Adam; records the learning rate of every step."""

    def __init__(self):
        super().__init__()
        self.a = torch.nn.Parameter(torch.zeros(()))

    def forward(self, batch):
        return {"y": self.a * batch["audio"]}

    def loss(self, out, batch, weights):
        total = (out["y"] - 2 * batch["audio"]).square().mean()
        return total, {"total": total.detach()}


def _line_loader(n_batches=5):
    x = torch.linspace(-1, 1, 8)
    return [{"audio": x[None, :, None] * (i + 1), "mask": torch.ones(1, 8, dtype=torch.bool)} for i in range(n_batches)]


def test_step_budget_stops_mid_epoch_and_the_schedule_follows_it(monkeypatch):
    lrs = []
    real_step = torch.optim.Adam.step

    def spy(self, *a, **k):
        lrs.append(self.param_groups[0]["lr"])
        return real_step(self, *a, **k)

    monkeypatch.setattr(torch.optim.Adam, "step", spy)
    cfg = TrainConfig(epochs=10, lr=0.1, max_steps=7, warmup_steps=2, decay="cosine", grad_clip=0, max_frames=None,
                      progress=False)
    hist = train(_Line(), _line_loader(), cfg)
    assert hist.steps == [5, 7] and len(hist.terms) == 2  # 5 steps per epoch, stopped after 7
    # warm-up 0.05, 0.1; then cosine over the 7-step budget at progress 2/7 .. 6/7
    import math
    expect = [0.05, 0.1] + [0.1 * 0.5 * (1 + math.cos(math.pi * s / 7)) for s in range(2, 7)]
    assert lrs == pytest.approx(expect, rel=1e-12)


def test_cpu_budget_stops_training():
    hist = train(_Line(), _line_loader(), TrainConfig(epochs=10_000, cpu_budget_s=0.3, max_frames=None, progress=False))
    assert 0.3 <= hist.cpu_seconds[-1] < 5 and len(hist.terms) < 10_000


def test_on_epoch_time_is_not_training_time():
    import time as _time

    calls = []
    hist = train(_Line(), _line_loader(), TrainConfig(epochs=3, max_frames=None, progress=False),
                 on_epoch=lambda m, h: (calls.append(len(h.terms)), _time.sleep(0.2)))
    assert calls == [1, 2, 3] and hist.seconds[-1] < 0.2 * 3


def test_a_model_without_a_loss_method_is_a_clear_error():
    class NoLoss(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.a = torch.nn.Parameter(torch.zeros(()))

        def forward(self, batch):
            return {"y": self.a * batch["audio"]}

    with pytest.raises(TypeError, match="NoLoss has no loss"):
        train(NoLoss(), _line_loader(), TrainConfig(epochs=1, max_frames=None, progress=False))


def test_mean_motion_by_hand_and_mean_init_sets_the_output_bias(data):
    from dualtalker_lite.train import mean_motion

    corpus, train_set, _ = data
    two = Subset(train_set, [0, 1])
    items = [two[0], two[1]]
    frames = torch.cat([it["vertices"] - it["template"][None] for it in items])  # every frame of both clips
    torch.testing.assert_close(mean_motion(two), frames.double().mean(0).float())
    model = _model(corpus)
    batch = next(iter(make_loader(two, 2, shuffle=False)))
    model.init_output_bias(mean_motion(two))
    # the untrained model (zero decoder weights) now predicts template + mean motion in every frame
    pred = predict(model, batch)
    torch.testing.assert_close(pred[0, 0], batch["template"][0] + mean_motion(two), atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="mean_motion: expected shape"):
        model.init_output_bias(torch.zeros(5))


def test_weights_of_another_model_kind_are_refused_with_one_line():
    """TrainConfig.weights must be the model's own loss-weight dataclass; None means that class's defaults."""
    from dataclasses import dataclass

    from dualtalker_lite.train import loss_weights

    @dataclass
    class OtherWeights:
        alpha: float = 1.0

    class Weighted(_Line):
        loss_weights_cls = OtherWeights

    cfg = TrainConfig(epochs=1, lr=0.1, max_frames=None, progress=False, weights=LossWeights())
    with pytest.raises(TypeError, match=r"TrainConfig.weights is a LossWeights, but Weighted is trained with "
                                        r"OtherWeights"):
        train(Weighted(), _line_loader(), cfg)
    assert loss_weights(Weighted(), {"alpha": 2.0}) == OtherWeights(alpha=2.0)
    with pytest.raises(TypeError, match="_Line has no loss_weights_cls"):
        loss_weights(_Line(), {"alpha": 2.0})


@pytest.mark.parametrize("extra", [{}, {"pca_init": 8, "lr": 6e-3, "basis_space": True}], ids=["tiny", "basis"])
def test_resumed_training_ends_with_the_same_weights_bit_for_bit(data, tmp_path, extra):
    """4 epochs straight == 2 epochs, the state saved (weights_only round trip), a fresh model resumed to 4:
    crops (max_frames 20, so the crop generator matters), dropout, shuffle order, Adam and the schedule; with
    basis_space also the basis and the head bias's rest (buffers of the state, not recomputed)."""
    corpus, train_set, val_set = data
    kw = dict(epochs=4, seed=5, progress=False, weights=LossWeights(), max_frames=20, **extra)
    straight = _model(corpus, 5)
    h1 = train(straight, make_loader(train_set, 8, shuffle=True, seed=5), TrainConfig.tiny(**kw))
    saved = []
    first = _model(corpus, 5)
    train(first, make_loader(train_set, 8, shuffle=True, seed=5), TrainConfig.tiny(**kw), checkpoint_every=2,
          on_checkpoint=lambda state: saved.append(torch.save(state, tmp_path / f"s{len(saved)}.pt")))
    assert len(saved) == 1  # after epoch 2; never after the last epoch
    state = torch.load(tmp_path / "s0.pt", weights_only=True)
    assert state["epoch"] == 2 and state["step"] == 4
    resumed = _model(corpus, 99)  # another initialisation: the state replaces it
    h2 = train(resumed, make_loader(train_set, 8, shuffle=True, seed=5), TrainConfig.tiny(**kw), resume=state)
    assert h1.terms == h2.terms and h1.steps == h2.steps
    for (k, a), b in zip(straight.state_dict().items(), resumed.state_dict().values()):
        assert torch.equal(a, b), k


def test_resume_state_finds_the_generator_under_viseme_labels():
    """The phonetic route wraps the training set (VisemeLabels(...).base): its own generator (pseudo-pair partners,
    crops) must still be saved and restored by --resume."""
    from torch.utils.data import DataLoader, Dataset

    from dualtalker_lite.data.dataset import VisemeLabels
    from dualtalker_lite.train import _generators

    class Pairs(Dataset):
        generator = torch.Generator().manual_seed(3)

        def __len__(self):
            return 1

        def __getitem__(self, i):
            raise AssertionError("not read")

    base = Pairs()
    gens = _generators(DataLoader(VisemeLabels(base, n_visemes=15), generator=torch.Generator()))
    assert set(gens) == {"loader", "dataset1"} and gens["dataset1"] is base.generator


# ---- the PCA-initialised motion head (issue 31) ----------------------------------------------------------------
def _clips(motions, template):
    """Items as a dataset gives them: vertices = template + motion (T, V*3), template (V*3,)."""
    return [{"vertices": template + m, "template": template} for m in motions]


def test_motion_basis_matches_an_exact_pca_written_in_numpy():
    """train.motion_basis against an independent reference: the covariance's eigenvectors (numpy), each scaled by
    the square root of its eigenvalue (the standard deviation along it). Directions carry an arbitrary sign, so rows
    are compared up to sign; the variances must come out in decreasing order."""
    import numpy as np

    from dualtalker_lite.train import motion_basis

    rng = np.random.default_rng(0)
    v3, k = 12, 3
    mix = rng.normal(size=(k, v3))                                  # 3 latent modes with stds 5, 2, 0.5 mm
    frames = (rng.normal(size=(300, k)) * [5e-3, 2e-3, 5e-4]) @ mix + 1e-6 * rng.normal(size=(300, v3))
    template = rng.normal(size=v3)
    clips = _clips([torch.tensor(frames[i:i + 100], dtype=torch.float64) for i in (0, 100, 200)],
                   torch.tensor(template, dtype=torch.float64))
    basis = motion_basis(clips, k).double().numpy()                 # (k, V*3)
    centred = frames - frames.mean(0)
    eigval, eigvec = np.linalg.eigh(centred.T @ centred / (len(frames) - 1))
    order = np.argsort(eigval)[::-1][:k]
    expected = (eigvec[:, order] * np.sqrt(eigval[order])).T       # (k, V*3)
    for got, want in zip(basis, expected):
        sign = np.sign(got @ want)
        assert np.allclose(sign * got, want, rtol=1e-3, atol=1e-7)
    assert np.all(np.diff(np.linalg.norm(basis, axis=1)) < 0)


def test_motion_basis_leaves_the_global_rng_alone_and_refuses_bad_input():
    from dualtalker_lite.checks import NonFiniteError
    from dualtalker_lite.train import motion_basis

    clips = _clips([torch.randn(20, 6)], torch.zeros(6))
    state = torch.get_rng_state()
    first = motion_basis(clips, 2, seed=3)
    assert torch.equal(torch.get_rng_state(), state)                # training's random stream is not consumed
    assert torch.equal(first, motion_basis(clips, 2, seed=3))       # same seed, same basis
    with pytest.raises(ValueError, match="k must be at least 1"):
        motion_basis(clips, 0)
    bad = _clips([torch.full((4, 6), float("nan"))], torch.zeros(6))
    with pytest.raises(NonFiniteError, match="non-finite"):
        motion_basis(bad, 2)


def test_init_output_basis_maps_feature_j_to_the_j_th_direction():
    """MotionDecoder.init_output_basis: with the head's input a one-hot e_j the decoded motion is the bias plus row j
    of the basis (metres), and inputs beyond the basis's k rows contribute nothing."""
    from dualtalker_lite.blocks.decoder import MotionDecoder

    dec = MotionDecoder(n_vertices=4, d_model=8, n_heads=2, d_ff=16, n_speakers=2)
    basis = torch.arange(1, 37, dtype=torch.float32).reshape(3, 12) * 1e-4   # k=3 rows of V*3=12 values, metres
    dec.init_output_basis(basis)
    bias = dec.decode_motion(torch.zeros(1, 8))
    for j in range(8):
        got = dec.decode_motion(torch.eye(8)[j][None]) - bias
        want = basis[j] if j < 3 else torch.zeros(12)
        assert torch.allclose(got[0], want, atol=1e-9)
    with pytest.raises(ValueError, match=r"basis: expected shape \(k, 12\), got \(3, 11\)"):
        dec.init_output_basis(basis[:, :11])
    tied = MotionDecoder(n_vertices=4, d_model=8, n_heads=2, d_ff=16, n_speakers=2, tie_output=True)
    with pytest.raises(ValueError, match="tied to the motion encoder"):
        tied.init_output_basis(basis)


def test_train_with_pca_init_starts_from_the_training_motion_basis(data):
    """TrainConfig.pca_init = k: before the first step the motion head holds motion_basis(training set, k) (checked
    with epochs=0: the weights are the initialisation itself); a model without init_output_basis is refused."""
    from dualtalker_lite.train import motion_basis

    corpus, train_set, _ = data
    model = _model(corpus)
    train(model, make_loader(train_set, 8, shuffle=True, seed=0), TrainConfig.tiny(epochs=0, pca_init=8,
                                                                                  progress=False))
    head = model.decoder.motion_decoder.weight / model.decoder.motion_scale      # (V*3, d), metres per unit
    assert torch.allclose(head[:, :8].T, motion_basis(train_set, 8), atol=1e-7)
    assert not head[:, 8:].any()

    class NoBasis(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.w = torch.nn.Parameter(torch.zeros(1))

    with pytest.raises(TypeError, match="NoBasis has no init_output_basis"):
        train(NoBasis(), make_loader(train_set, 8, shuffle=True, seed=0),
              TrainConfig.tiny(epochs=0, pca_init=4, progress=False, mean_init=False))


def test_motion_basis_subsamples_a_large_set_evenly_in_bounded_memory():
    """More frames than ``max_frames``: the basis comes from an evenly spaced subset gathered in one pass (at most
    2 x max_frames rows held). On low-rank motion (3 modes, tiny noise) the subset spans the same directions as the
    exact PCA of every frame: each row of the subsampled basis lies in the exact 3-d principal subspace."""
    import numpy as np

    from dualtalker_lite.train import motion_basis

    rng = np.random.default_rng(1)
    v3, k = 15, 3
    mix = np.linalg.qr(rng.normal(size=(v3, k)))[0].T                  # orthonormal modes (3, V*3)
    frames = (rng.normal(size=(2000, k)) * [4e-3, 2e-3, 1e-3]) @ mix + 1e-8 * rng.normal(size=(2000, v3))
    clips = _clips([torch.tensor(frames[i:i + 50]) for i in range(0, 2000, 50)], torch.zeros(v3, dtype=torch.float64))
    basis = motion_basis(clips, k, max_frames=64).double().numpy()
    residual = basis - (basis @ mix.T) @ mix                          # the part outside the true subspace
    assert np.abs(residual).max() < 1e-6
    stds = np.linalg.norm(basis, axis=1)
    assert np.allclose(stds, [4e-3, 2e-3, 1e-3], rtol=0.25)          # 64 frames estimate each std to ~10-20%


def test_twenty_steps_match_a_reference_loss_written_out_bit_for_bit(data):
    """The step's cheaper loss (losses.common.masked_mse for the primal term, no unused motion tensor for CCRL) trains
    exactly as the joint loss written out with plain autograd operations: the same loss at each of 20 steps and the
    same weights at the end (issue 31: the step's cost went down, not what it computes)."""
    from dualtalker_lite.losses import ccrl_loss, dual_loss, duality_loss

    corpus, train_set, _ = data

    def reference(model, out, batch, w):  # joint_loss as it was written before issue 31
        mask, s = batch["mask"], w.vertex_scale
        d = (out["vertices"] * s - batch["vertices"] * s).masked_fill(~mask[..., None], 0.0).square()
        primal = torch.where(mask[..., None], d, d.new_zeros(())).sum() / (mask.sum() * d.shape[-1]).clamp(min=1)
        dual = dual_loss(out["audio"], batch["audio"], mask)
        dr = duality_loss(out["x"], out["x_fused"], out["y"], out["y_fused"], mask)
        motion = batch["vertices"] - batch["template"][:, None, :]
        ccrl = ccrl_loss(out["x"], out["y"], motion, mask, w.bandwidth, kernel_weights=model.kernel_weights(batch, w))
        total = batch["vertices"].new_zeros(()) + w.lambda1 * primal + w.lambda2 * dual + w.lambda3 * dr \
            + w.lambda4 * ccrl
        return total, {"total": total.detach()}

    runs = []
    for loss in ("model", "reference"):
        model, seen = _model(corpus), []
        own = model.loss

        def logged(out, batch, w=None, model=model, own=own, loss=loss):
            total, terms = own(out, batch, w) if loss == "model" else reference(model, out, batch, w)
            seen.append(float(total.detach()))
            return total, terms

        model.loss = logged
        train(model, make_loader(train_set, 8, shuffle=True, seed=0),
              TrainConfig.tiny(epochs=10, lr=6e-3, pca_init=16, progress=False, weights=LossWeights()))
        runs.append((seen, model.state_dict()))
    (new, w_new), (ref, w_ref) = runs
    assert len(new) == 20 and new == ref
    assert all(torch.equal(w_new[k], w_ref[k]) for k in w_ref)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_reuse_freed_memory_stops_the_page_faults_of_large_tensors():
    """A (8, 90, 4674) float32 tensor is 13.5 MB = 3290 pages of 4 kB. Two live at once, allocated, filled and freed
    10 times: glibc's defaults fault ~60,000 pages in (measured: 62,212); after reuse_freed_memory() the freed
    blocks are reused from the second round on (measured: 0; the bound leaves room for one round's pages)."""
    def rounds():
        for _ in range(10):
            x = torch.empty(8, 90, 4674).fill_(1.0)
            y = x * 2.0  # a second live block, as in a step
            del x, y

    assert reuse_freed_memory() is True
    rounds()  # the first round may fault the blocks' pages in once
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    rounds()
    assert resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before < 2 * 3290  # 10% of the 10 x 2 x 3290


def test_fast_recipe_is_the_tiny_recipe_with_the_pca_head_at_twice_the_rate():
    """TrainConfig.fast (issue 31): what results/time_to_quality_2core.md measured (recipes C20, FC30), written out;
    the tiny recipe (the tables') keeps the models' own losses (no contact term)."""
    from dataclasses import asdict

    tiny, fast, ff = asdict(TrainConfig.tiny()), asdict(TrainConfig.fast()), asdict(TrainConfig.fast("faceformer"))
    assert {k for k in tiny if tiny[k] != fast[k]} == {"epochs", "lr", "pca_init", "basis_space", "lip_contact"}
    assert (fast["epochs"], fast["lr"], fast["pca_init"], fast["basis_space"], fast["lip_contact"]) == \
        (20, 6e-3, 64, True, 1e-3)
    assert (ff["epochs"], ff["lr"], ff["pca_init"], ff["basis_space"], ff["lip_contact"]) == (30, 6e-3, 64, True, 1e-3)
    assert tiny["lip_contact"] == 0.0
    assert TrainConfig.fast(seed=3).seed == 3
    ct = asdict(TrainConfig.fast("corrtalk"))  # no basis step: its two decoders are combined per vertex
    assert (ct["epochs"], ct["lr"], ct["pca_init"], ct["basis_space"], ct["lip_contact"]) == (10, 6e-3, 64, False, 1e-3)
    emo = asdict(TrainConfig.fast("emoface"))  # 4 epochs (results/emoface_recipe.md); Mesh Attention mixes two
    assert (emo["epochs"], emo["lr"], emo["pca_init"], emo["basis_space"], emo["lip_contact"]) == \
        (4, 6e-3, 64, False, 1e-3)  # decoders per vertex: no basis step
    assert TrainConfig.fast("emoface", epochs=10).epochs == 10  # the emotional tables' one budget
    with pytest.raises(ValueError, match=r"no short recipe measured for model 'voca'.*give epochs="):
        TrainConfig.fast("voca")  # no measured budget: the tables give their one budget
    voca = asdict(TrainConfig.fast("voca", epochs=30))  # a sliding window: no basis step
    assert (voca["epochs"], voca["lr"], voca["pca_init"], voca["basis_space"], voca["lip_contact"]) == \
        (30, 6e-3, 64, False, 1e-3)


# ---- basis_space: the step in k basis coordinates (issue 31) ------------------------------------------------------
def test_set_motion_basis_projects_the_head_and_the_encoder_by_hand():
    """V = 2 (6 coordinates), basis rows e_0 and (e_1 + e_2)/sqrt(2) (given unnormalised: x3): the projector keeps
    coordinate 0 and the mean of coordinates 1 and 2, drops 3-5. Head weight/bias and encoder weight by hand."""
    from dualtalker_lite.blocks.decoder import MotionDecoder

    dec = MotionDecoder(2, 4, 2, 8, motion_scale=1.0)
    with torch.no_grad():
        dec.motion_decoder.weight.copy_(torch.arange(24.0).reshape(6, 4))  # row i = coordinate i
        dec.motion_decoder.bias.copy_(torch.tensor([1.0, 2.0, 4.0, 5.0, 6.0, 7.0]))
        dec.motion_encoder.weight.copy_(torch.arange(24.0).reshape(4, 6))  # column j = coordinate j
    basis = torch.tensor([[3.0, 0, 0, 0, 0, 0], [0, 3.0, 3.0, 0, 0, 0]])
    dec.set_motion_basis(basis)
    w = torch.arange(24.0).reshape(6, 4)
    want_w = torch.stack([w[0], (w[1] + w[2]) / 2, (w[1] + w[2]) / 2, 0 * w[0], 0 * w[0], 0 * w[0]])
    torch.testing.assert_close(dec.motion_decoder.weight, want_w)
    # the bias: its part in the span (1; 3, 3) plus its rest when the basis was set (0; -1, 1; 5, 6, 7) = itself
    torch.testing.assert_close(dec.motion_decoder.bias, torch.tensor([1.0, 2.0, 4.0, 5.0, 6.0, 7.0]))
    e = torch.arange(24.0).reshape(4, 6)
    want_e = torch.stack([e[:, 0], (e[:, 1] + e[:, 2]) / 2, (e[:, 1] + e[:, 2]) / 2] + [0 * e[:, 0]] * 3, dim=1)
    torch.testing.assert_close(dec.motion_encoder.weight, want_e)
    # after a step moves the bias everywhere, projecting keeps its rest as it was set: (1+9; 3+9, 3+9) + rest
    with torch.no_grad():
        dec.motion_decoder.bias.add_(9.0)
    dec.project_motion_basis()
    torch.testing.assert_close(dec.motion_decoder.bias, torch.tensor([10.0, 11.0, 13.0, 5.0, 6.0, 7.0]))
    # train mode speaks k coordinates, a = sqrt(2 / 6): z = a P (W h + b) / s, with P's rows normalised
    dec.train()
    h = torch.tensor([[1.0, 0.0, 0.0, 0.0]])
    out = dec.decode_motion(h)  # W h = column 0 of W: (0, 6, 6, 0, 0, 0) after projection (rows 1, 2: (4+8)/2)
    a = (2 / 6) ** 0.5
    torch.testing.assert_close(out, a * torch.tensor([[0.0 + 10.0, (6 + 6 + 11 + 13) / 2 ** 0.5]]))
    z = torch.tensor([[2.0, 1.0]])  # motion a^-1 (2 e_0 + (e_1 + e_2)/sqrt 2)
    m = (2 * torch.eye(6)[0] + (torch.eye(6)[1] + torch.eye(6)[2]) / 2 ** 0.5) / a
    torch.testing.assert_close(dec.encode_motion(z), (dec.motion_encoder.weight @ m + dec.motion_encoder.bias)[None])
    dec.eval()  # eval mode: vertex coordinates, the plain (projected) weights
    torch.testing.assert_close(dec.decode_motion(h), (dec.motion_decoder.weight @ h[0] + dec.motion_decoder.bias)[None])
    with pytest.raises(ValueError, match="rows must be orthogonal"):
        dec.set_motion_basis(torch.tensor([[1.0, 0, 0, 0, 0, 0], [1.0, 1.0, 0, 0, 0, 0]]))
    with pytest.raises(ValueError, match=r"expected shape \(k, 6\)"):
        dec.set_motion_basis(torch.ones(2, 5))
    dec.set_motion_basis(None)
    dec.train()
    assert dec.decode_motion(h).shape == (1, 6)  # no basis: vertex coordinates in train mode too


@pytest.mark.parametrize("kind", ["dualtalker", "faceformer"])
def test_the_basis_step_is_the_vertex_loss_less_a_constant_with_the_same_gradients(kind):
    """For a model whose head and encoder lie in the span (set_motion_basis projects them): the loss on basis_batch's
    k coordinates = the vertex loss - (s^2 / (N 3V)) sum ||(I - P^T P)(b_rest - m)||^2 over valid frames (written
    here from the printed identity), and every gradient = the vertex loss's gradient of the projected model
    (head and encoder gradients projected; the others equal)."""
    from dualtalker_lite.models.faceformer import FaceFormer, FaceFormerConfig
    from dualtalker_lite.train import basis_batch

    nv, b, t, k = 40, 3, 16, 6
    g = torch.Generator().manual_seed(0)
    p = torch.linalg.qr(torch.randn(3 * nv, k, generator=g, dtype=torch.float64))[0].T.float()  # (k, 3V)
    template = torch.randn(b, 3 * nv, generator=g) * 0.01
    verts = template[:, None] + (torch.randn(b, t, k, generator=g) * 1e-3) @ p \
        + torch.randn(b, t, 3 * nv, generator=g) * 2e-5  # motion mostly in the span, some rest
    mask = torch.ones(b, t, dtype=torch.bool)
    mask[1, 11:] = False
    verts[1, 11:] = float("nan")  # padding may hold anything
    batch = {"audio": torch.randn(b, t, 15, generator=g), "vertices": verts, "template": template,
             "speaker": torch.tensor([0, 1, 2]), "mask": mask, "name": ["a", "b", "c"]}
    torch.manual_seed(1)
    if kind == "dualtalker":
        model = DualTalker(DualTalkerConfig.tiny(n_vertices=nv, audio_dim=15, n_speakers=4, motion_dropout=0.0))
        weights = LossWeights()
    else:
        model = FaceFormer(FaceFormerConfig.tiny(n_vertices=nv, audio_dim=15, n_speakers=4, motion_dropout=0.0))
        weights = None
    model.init_output_bias(torch.randn(3 * nv, generator=g) * 1e-3)
    model.init_output_basis(p * 1e-3)
    model.set_motion_basis(p)  # projects the encoder (the head and the bias's span part are already in it)
    model.set_motion_basis(None)
    model.train()

    def loss_and_grads(bt):
        torch.manual_seed(5)  # the same dropout draws
        total, terms = model.loss(model(bt), bt, weights)
        model.zero_grad()
        total.backward()
        return terms, {n: q.grad.clone() for n, q in model.named_parameters() if q.grad is not None}

    terms_v, grads_v = loss_and_grads(batch)
    rest = model.decoder.motion_decoder.bias.detach() / 1000.0  # metres: the bias is (its span part + its rest)
    model.set_motion_basis(p)
    terms_k, grads_k = loss_and_grads(basis_batch(batch, p))
    proj = torch.eye(3 * nv) - p.T @ p
    m = (verts - template[:, None])[mask]  # (N, 3V) valid frames
    constant = ((m - rest) @ proj).square().sum() * 1000.0 ** 2 / (m.shape[0] * 3 * nv)
    torch.testing.assert_close(terms_v["primal"] - terms_k["primal"], constant, rtol=2e-4, atol=1e-6)
    for name in set(terms_v) - {"primal", "total"}:
        torch.testing.assert_close(terms_v[name], terms_k[name], rtol=1e-4, atol=1e-6)
    for name, gv in grads_v.items():
        if name.endswith("motion_decoder.weight") or name.endswith("motion_decoder.bias"):
            gv = p.T @ (p @ gv)
        elif name.endswith("motion_encoder.weight"):
            gv = (gv @ p.T) @ p
        elif name.endswith("k_proj.bias"):  # softmax ignores a key bias: both ~0, rounding only
            continue
        err = float((grads_k[name] - gv).norm() / gv.norm().clamp(min=1e-12))  # float32 rounding: ~1e-5 here
        assert err < 1e-3, (name, err)


def test_train_in_the_basis_learns_leaves_a_plain_projected_model_and_is_reproducible(data):
    corpus, train_set, val_set = data
    before = _primal_on(_model(corpus), train_set)
    model, hist = _run(corpus, train_set, val_set, epochs=10, pca_init=16, lr=6e-3, basis_space=True,
                       validate_every=5)
    assert model.decoder._basis is None and not model.training  # a plain model again, in eval mode
    assert _primal_on(model, train_set) < 0.5 * before  # in vertex coordinates, on the clips it trained on
    p = motion_basis(train_set, 16, seed=0)
    p = p / p.norm(dim=1, keepdim=True)
    w = model.decoder.motion_decoder.weight.detach()
    torch.testing.assert_close(p.T @ (p @ w), w, atol=1e-5, rtol=1e-4)  # the head stays in the span
    again, hist2 = _run(corpus, train_set, val_set, epochs=10, pca_init=16, lr=6e-3, basis_space=True,
                        validate_every=5)
    assert hist.terms == hist2.terms and hist.val_lve == hist2.val_lve


def test_basis_space_needs_pca_init_and_a_model_with_one_motion_decoder(data):
    corpus, train_set, _ = data
    with pytest.raises(ValueError, match="basis_space trains in the span of the pca_init basis: set pca_init"):
        TrainConfig.tiny(basis_space=True)
    from dualtalker_lite.models.corrtalk import CorrTalk, CorrTalkConfig

    model = CorrTalk(CorrTalkConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=160, n_speakers=8))
    before = {n: q.clone() for n, q in model.state_dict().items()}
    with pytest.raises(TypeError, match="TrainConfig.basis_space: CorrTalk has no set_motion_basis"):
        train(model, make_loader(train_set, 8, shuffle=True, seed=0),
              TrainConfig.tiny(epochs=1, pca_init=8, basis_space=True, progress=False))
    assert all(torch.equal(before[n], q) for n, q in model.state_dict().items())  # nothing was trained


@pytest.mark.parametrize("name", ["save_checkpoint", "load_checkpoint"])
def test_the_old_address_of_the_checkpoint_functions_warns_and_still_works(name):
    """``dualtalker_lite.train.save_checkpoint``/``load_checkpoint`` moved to ``checkpoints``: kept one release."""
    from dualtalker_lite import checkpoints
    from dualtalker_lite import train as train_module

    with pytest.warns(DeprecationWarning, match=rf"dualtalker_lite\.train\.{name} is deprecated.*"
                                                rf"dualtalker_lite\.checkpoints"):
        moved = getattr(train_module, name)
    assert moved is getattr(checkpoints, name)
    with pytest.raises(AttributeError):
        train_module.no_such_name  # noqa: B018
