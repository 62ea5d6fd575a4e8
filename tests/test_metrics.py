"""Metrics on tiny hand-computed cases: every expected value is a literal with its arithmetic in a comment.

Displacements are written in mm below and divided by 1000 because inputs are metres (docs/design.md).
"""
import numpy as np
import pytest
import torch

from dualtalker_lite import metrics as M

LIPS = [0, 1, 2]  # vertex 3 is not a lip vertex (it carries a 100 mm error that must be ignored)


def _lip_case():
    """Two sequences, T = 2 and 3, V = 4; returns (preds, gts) as lists of (T, 4, 3) arrays in metres."""
    rng = np.random.default_rng(0)
    err_a = np.zeros((2, 4, 3))
    err_a[0, 0] = [1, 0, 0]  # |e|^2 = 1
    err_a[0, 1] = [0, 2, 0]  # |e|^2 = 4   -> frame max 4  (euclid 2)
    err_a[1, 0] = [3, 4, 0]  # |e|^2 = 25  -> frame max 25 (euclid 5)
    err_b = np.zeros((3, 4, 3))  # frame 0: all zero -> max 0
    err_b[1, 1] = [0, 0, 1]  # |e|^2 = 1 -> frame max 1 (euclid 1)
    err_b[2, 2] = [2, 2, 1]  # |e|^2 = 9 -> frame max 9 (euclid 3)
    err_a[:, 3] = err_b[:, 3] = [100, 0, 0]  # non-lip vertex
    gts = [rng.normal(size=(2, 4, 3)) * 0.01, rng.normal(size=(3, 4, 3)) * 0.01]
    preds = [gts[0] + err_a / 1000, gts[1] + err_b / 1000]
    return preds, gts


def test_lve_published_pools_frames_and_squares():
    preds, gts = _lip_case()
    # pooled: (4 + 25 + 0 + 1 + 9) / 5 = 39 / 5 = 7.8 mm^2
    assert M.lve_published(preds, gts, LIPS) == pytest.approx(7.8)
    # mean of per-sequence means would be ((4 + 25)/2 + (0 + 1 + 9)/3) / 2 = (14.5 + 3.3333) / 2 = 8.9167: not that
    assert M.lve_published(preds, gts, LIPS) != pytest.approx((14.5 + 10 / 3) / 2)
    # in m^2 (the unit the published VOCASET numbers are in): 7.8 mm^2 = 7.8e-6 m^2
    assert M.lve_published(preds, gts, LIPS, unit="m") == pytest.approx(7.8e-6)


def test_lve_euclidean_is_the_paper_text_reading():
    preds, gts = _lip_case()
    # (2 + 5 + 0 + 1 + 3) / 5 = 11 / 5 = 2.2 mm
    assert M.lve_euclidean(preds, gts, LIPS) == pytest.approx(2.2)
    assert M.lve_euclidean(preds, gts, LIPS, unit="m") == pytest.approx(2.2e-3)


def test_eve_is_the_lip_computation_on_another_region():
    preds, gts = _lip_case()
    # region {2, 3}: seq A frames: max(0, 100^2) twice; seq B: 100^2 each of 3 frames -> 10000 mm^2 / 100 mm
    assert M.eve(preds, gts, [2, 3]) == pytest.approx(10000.0)
    assert M.eve(preds, gts, [2, 3], convention="euclidean") == pytest.approx(100.0)
    assert M.eve(preds, gts, LIPS) == M.lve_published(preds, gts, LIPS)
    with pytest.raises(ValueError, match="convention"):
        M.eve(preds, gts, LIPS, convention="l2")


def test_mean_vertex_error_map():
    preds, gts = _lip_case()
    # over the 5 pooled frames: v0 (1 + 5 + 0 + 0 + 0)/5 = 1.2; v1 (2 + 0 + 0 + 1 + 0)/5 = 0.6;
    # v2 (0 + 0 + 0 + 0 + 3)/5 = 0.6; v3 100 everywhere
    np.testing.assert_allclose(M.mean_vertex_error(preds, gts), [1.2, 0.6, 0.6, 100.0])


def _fdd_case():
    """Two sequences, V = 3, upper face = {0, 1}; vertex 2 (lower face) moves a lot and must be ignored."""
    rng = np.random.default_rng(1)
    h = rng.normal(size=(3, 3)) * 0.05  # template (V, 3), metres
    # seq 1 (T=2): GT |disp| of v0 = [0, 2] -> squared [0, 4]: std 2 (sq), std 1 (norm); v1 constant 1 -> std 0
    g1 = np.zeros((2, 3, 3)); g1[1, 0] = [0, 0, 2]; g1[:, 1] = [1, 0, 0]; g1[:, 2] = [[0, 0, 0], [50, 0, 0]]
    p1 = np.zeros((2, 3, 3))  # prediction does not move: dyn 0
    # seq 2 (T=4): GT v0 |disp| = [0, 3, 0, 3] -> sq [0, 9, 0, 9]: std 4.5 (sq), 1.5 (norm)
    #              pred v0 |disp| = [0, 1, 0, 1] -> sq [0, 1, 0, 1]: std 0.5 (sq), 0.5 (norm); v1 still
    g2 = np.zeros((4, 3, 3)); g2[[1, 3], 0] = [0, 3, 0]; g2[[0, 2], 2] = [0, 40, 0]
    p2 = np.zeros((4, 3, 3)); p2[[1, 3], 0] = [0.6, 0.8, 0]
    gts = [h + g1 / 1000, h + g2 / 1000]
    preds = [h + p1 / 1000, h + p2 / 1000]
    return preds, gts, h


def test_fdd_published_and_paper_by_hand():
    preds, gts, h = _fdd_case()
    # published, seq 1: mean_v(2, 0) - 0 = 1;  seq 2: mean_v(4.5, 0) - mean_v(0.5, 0) = 2.25 - 0.25 = 2
    # -> (1 + 2) / 2 = 1.5 mm^2
    assert M.fdd_published(preds, gts, h, [0, 1]) == pytest.approx(1.5)
    # paper text, seq 1: mean_v(1, 0) - 0 = 0.5;  seq 2: mean_v(1.5, 0) - mean_v(0.5, 0) = 0.75 - 0.25 = 0.5
    # -> (0.5 + 0.5) / 2 = 0.5 mm
    assert M.fdd_paper(preds, gts, h, [0, 1]) == pytest.approx(0.5)
    assert M.fdd_published(preds, gts, h, [0, 1], unit="m") == pytest.approx(1.5e-6)


def test_fdd_sign_ground_truth_more_dynamic_is_positive():
    preds, gts, h = _fdd_case()
    assert M.fdd_published(preds, gts, h, [0, 1]) > 0
    assert M.fdd_published(gts, preds, h, [0, 1]) == pytest.approx(-1.5)
    assert M.fdd_paper(gts, preds, h, [0, 1]) == pytest.approx(-0.5)
    assert M.fdd_published(gts, gts, h, [0, 1]) == 0.0


def test_templates_shared_list_or_batched_agree():
    preds, gts, h = _fdd_case()
    want = M.fdd_published(preds, gts, h, [0, 1])
    for templates in (h.reshape(-1), [h, h], np.stack([h, h]), np.stack([h, h]).reshape(2, -1), torch.tensor(h)):
        assert M.fdd_published(preds, gts, templates, [0, 1]) == pytest.approx(want)


def test_invariant_to_the_same_offset_on_template_and_both_sequences():
    rng = np.random.default_rng(2)
    gts = [rng.normal(size=(5, 6, 3)) * 0.01, rng.normal(size=(3, 6, 3)) * 0.01]
    preds = [g + rng.normal(size=g.shape) * 0.002 for g in gts]
    h = rng.normal(size=(6, 3)) * 0.01
    off = rng.normal(size=(6, 3))  # per-vertex offset, the same in every frame
    shift = lambda seqs: [s + off for s in seqs]  # noqa: E731
    for fn in (M.fdd_published, M.fdd_paper):
        assert fn(shift(preds), shift(gts), h + off, [0, 2, 4]) == pytest.approx(fn(preds, gts, h, [0, 2, 4]))
    for fn in (M.lve_published, M.lve_euclidean):
        assert fn(shift(preds), shift(gts), [1, 3]) == pytest.approx(fn(preds, gts, [1, 3]))


def test_numpy_and_torch_inputs_agree():
    preds, gts, h = _fdd_case()
    t = lambda seqs: [torch.tensor(s) for s in seqs]  # noqa: E731
    assert M.fdd_published(t(preds), t(gts), torch.tensor(h), torch.tensor([0, 1])) == \
        M.fdd_published(preds, gts, h, [0, 1])
    preds, gts = _lip_case()
    assert M.lve_published(t(preds), t(gts), LIPS) == M.lve_published(preds, gts, LIPS)
    f32 = [torch.tensor(s, dtype=torch.float32) for s in preds]
    assert M.lve_euclidean(f32, t(gts), LIPS) == pytest.approx(2.2, rel=1e-4)


def test_flat_vertex_layout_agrees():
    preds, gts = _lip_case()
    flat = lambda seqs: [s.reshape(len(s), -1) for s in seqs]  # noqa: E731  (T, V*3)
    assert M.lve_published(flat(preds), flat(gts), LIPS) == pytest.approx(7.8)


def _pad(seqs, T, fill):
    out = np.full((len(seqs), T, seqs[0].shape[1] * 3), fill)
    mask = np.zeros((len(seqs), T), dtype=bool)
    for b, s in enumerate(seqs):
        out[b, : len(s)] = s.reshape(len(s), -1)
        mask[b, : len(s)] = True
    return out, mask


def test_padded_with_mask_agrees_with_lists():
    preds, gts = _lip_case()
    P, mask = _pad(preds, 4, fill=7.0)  # garbage in padded frames must not count
    G, _ = _pad(gts, 4, fill=-3.0)
    assert M.lve_published(P, G, LIPS, mask=mask) == pytest.approx(7.8)
    assert M.lve_euclidean(torch.tensor(P), torch.tensor(G), LIPS, mask=torch.tensor(mask)) == pytest.approx(2.2)
    np.testing.assert_allclose(M.mean_vertex_error(P, G, mask=mask), M.mean_vertex_error(preds, gts))
    preds, gts, h = _fdd_case()
    P, mask = _pad(preds, 5, fill=1.0)
    G, _ = _pad(gts, 5, fill=2.0)
    assert M.fdd_published(P, G, h, [0, 1], mask=mask) == pytest.approx(1.5)
    assert M.fdd_paper(P.reshape(2, 5, 3, 3), G, h, [0, 1], mask=mask) == pytest.approx(0.5)


def test_lip_distance_by_hand():
    v = np.zeros((2, 4, 3))
    v[:, 0] = [0, 5, 0]; v[:, 1] = [2, 5, 0]          # upper-lip midpoint = mean of v0, v1 = (1, 5, 0)
    v[0, 2] = [1, -5, 0]; v[1, 2] = [1, -15, 0]       # lower-lip midpoint
    # frame 0: |(1, 5) - (1, -5)| = 10 mm; frame 1: |(1, 5) - (1, -15)| = 20 mm
    np.testing.assert_allclose(M.lip_distance(v / 1000, [0, 1], 2), [10.0, 20.0])
    np.testing.assert_allclose(M.lip_distance(torch.tensor(v / 1000).reshape(2, -1), [0, 1], 2, unit="m"),
                               [0.01, 0.02])


def test_evaluate_collects_everything_with_units():
    preds, gts, h = _fdd_case()
    regions = {"lips": [2], "upper_face": [0, 1], "eyes": [0], "forehead": [1]}
    out = M.evaluate(preds, gts, h, regions, lip_mid=(0, 2))
    assert out["fdd_published"] == pytest.approx(1.5) and out["fdd_paper"] == pytest.approx(0.5)
    assert out["lve_published"] == M.lve_published(preds, gts, [2])
    assert out["eve_euclidean"] == M.eve(preds, gts, [0, 1], convention="euclidean")
    assert out["n_sequences"] == 2 and out["n_frames"] == 6 and out["vertex_error_map"].shape == (3,)
    assert out["units"]["lve_published"] == "mm^2" and out["units"]["lve_euclidean"] == "mm"
    assert [len(d) for d in out["lip_distance_gt"]] == [2, 4]
    out_m = M.evaluate(preds, gts, h, regions, unit="m", eye_forehead=None)
    assert "eve_published" not in out_m and out_m["units"]["fdd_published"] == "m^2"
    by_name = M.evaluate(preds, gts, h, {**regions, "lip_midpoints": [0, 2]}, lip_mid="lip_midpoints")
    # "auto" prefers the corpus's combined eyes_forehead region when it exists
    only_eye = M.evaluate(preds, gts, h, {**regions, "eyes_forehead": [0]})
    assert only_eye["eve_published"] == M.eve(preds, gts, [0]) != M.eve(preds, gts, [0, 1])
    assert out["eve_published"] == M.eve(preds, gts, [0, 1])
    np.testing.assert_allclose(by_name["lip_distance_pred"][1], out["lip_distance_pred"][1])
    with pytest.raises(KeyError, match="available"):
        M.evaluate(preds, gts, h, {"lips": [0]})
    with pytest.raises(ValueError, match="lip_mid"):
        M.evaluate(preds, gts, h, regions, lip_mid=(0, 1, 2))


def test_clear_errors_for_bad_input():
    preds, gts = _lip_case()
    with pytest.raises(ValueError, match="lengths must match"):
        M.lve_published([preds[0][:1], preds[1]], gts, LIPS)
    with pytest.raises(ValueError, match="1 predicted sequences but 2"):
        M.lve_published(preds[:1], gts, LIPS)
    with pytest.raises(ValueError, match="vertex counts"):
        M.lve_published([preds[0], preds[1][:, :3]], gts, LIPS)
    with pytest.raises(ValueError, match=r"\[0, 4\)"):
        M.lve_published(preds, gts, [0, 4])
    with pytest.raises(ValueError, match="empty"):
        M.lve_published(preds, gts, [])
    with pytest.raises(ValueError, match="ambiguous"):
        M.lve_published(np.zeros((2, 5, 3)), np.zeros((2, 5, 3)), [0])
    with pytest.raises(ValueError, match="mask shape"):
        M.lve_published(np.zeros((2, 5, 12)), np.zeros((2, 5, 12)), [0], mask=np.ones((2, 4), bool))
    with pytest.raises(ValueError, match="only for padded"):
        M.lve_published(preds, gts, LIPS, mask=np.ones((2, 3), bool))
    with pytest.raises(ValueError, match="unit"):
        M.lve_published(preds, gts, LIPS, unit="cm")
    with pytest.raises(ValueError, match="templates"):
        M.fdd_published(preds, gts, np.zeros(11), [0])
    with pytest.raises(ValueError, match="templates"):
        M.fdd_published(preds, gts, [np.zeros(12)] * 3, [0])
    with pytest.raises(ValueError, match=r"\(T, V, 3\) or \(T, V\*3\)"):
        M.lve_published([np.zeros((2, 5))], [np.zeros((2, 5))], [0])


def test_parity_with_a_loop_reference_of_the_published_evaluation():
    """Independent, deliberately naive re-statement of the published evaluation loop (frame by frame)."""
    rng = np.random.default_rng(3)
    gts = [rng.normal(size=(T, 8, 3)) * 0.01 for T in (4, 7, 2)]
    preds = [g + rng.normal(size=g.shape) * 0.003 for g in gts]
    hs = [rng.normal(size=(8, 3)) * 0.01 for _ in gts]
    lips, upper = [1, 4, 5], [0, 2, 3, 7]
    worst = [max(sum((p[t, v, k] - g[t, v, k]) ** 2 for k in range(3)) for v in lips)
             for p, g in zip(preds, gts) for t in range(len(g))]
    fdd = []
    for p, g, h in zip(preds, gts, hs):
        dyn = lambda x: np.mean([np.std([np.sum((x[t, v] - h[v]) ** 2) for t in range(len(x))]) for v in upper])  # noqa
        fdd.append(dyn(g) - dyn(p))
    assert M.lve_published(preds, gts, lips, unit="m") == pytest.approx(np.mean(worst), rel=1e-12)
    assert M.fdd_published(preds, gts, hs, upper, unit="m") == pytest.approx(np.mean(fdd), rel=1e-12)
