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


# ---------------------------------------------------------------- lip sync (closures at /p b m/, opening on vowels)
FPS = 30.0
MID = (0, 1)  # upper-lip midpoint = vertex 0, lower = vertex 1; vertices 0-3 are the "lips"


def _track(dist_mm, move_mm=None):
    """A (T, 4, 3) track in metres whose lip distance is exactly ``dist_mm`` per frame: the upper midpoint at
    y = d, the lower one at the origin; vertices 2-3 move by ``move_mm`` along x (for the motion ratio)."""
    d = np.asarray(dist_mm, dtype=float)
    v = np.zeros((len(d), 4, 3))
    v[:, 0, 1] = d / 1000
    if move_mm is not None:
        v[:, 2:, 0] = np.asarray(move_mm, dtype=float)[:, None] / 1000
    return v


# frame f is at f/30 s: 0, .033, .067, .1, .133, .167, .2, .233, .267, .3
PRED = [5.0, 3.0, 1.5, 0.5, 4.0, 10.0, 12.0, 9.0, 2.5, 2.5]
SEGMENTS = [["b", 0.0, 0.07],     # frames 0, 1, 2              -> min(5, 3, 1.5) = 1.5
            ["'p", 0.1, 0.2],     # frames 3, 4, 5 (0.2 is out) -> min(.5, 4, 10) = 0.5 (stress mark ignored)
            ["V", 0.16, 0.17],    # frame 5 (0.1667)            -> max 10
            ["a", 0.2, 0.27],     # frames 6, 7, 8              -> max(12, 9, 2.5) = 12
            ["t", 0.27, 0.28],    # not counted
            ["m", 0.28, 0.295]]   # no frame time inside: nearest to the middle 0.2875 s = frame 8.6 -> 9: 2.5


def test_segment_frames_hand_checked():
    assert M.segment_frames(0.1, 0.2, 10, FPS).tolist() == [3, 4, 5]          # [0.1, 0.2): 0.2 excluded
    assert M.segment_frames(0.052, 0.086313, 10, FPS).tolist() == [2]         # 0.0667 only (a real /p/)
    assert M.segment_frames(0.07, 0.09, 10, FPS).tolist() == [2]              # none inside; mid 0.08 s = 2.4 -> 2
    assert M.segment_frames(0.1, 0.2, 10, FPS, tolerance_frames=1).tolist() == [2, 3, 4, 5, 6]
    assert M.segment_frames(0.0, 0.04, 10, FPS, tolerance_frames=2).tolist() == [0, 1, 2, 3]  # clipped at 0
    assert M.segment_frames(0.29, 0.5, 10, FPS).tolist() == [9]              # clipped at the last frame


def test_segment_frames_bad_input():
    with pytest.raises(ValueError, match="starts after the end of a 10-frame track"):
        M.segment_frames(0.5, 0.6, 10, FPS)                                   # 15 frames > 10
    with pytest.raises(ValueError, match="start <= end"):
        M.segment_frames(0.2, 0.1, 10, FPS)
    with pytest.raises(ValueError, match="start <= end"):
        M.segment_frames(float("nan"), 0.1, 10, FPS)


def test_segment_extrema_and_closure_rate_hand_checked():
    mins = M.segment_extrema(PRED, SEGMENTS, M.BILABIALS, reduce="min")
    assert mins.tolist() == [1.5, 0.5, 2.5]
    assert M.segment_extrema(PRED, SEGMENTS, M.OPEN_VOWELS, reduce="max").tolist() == [10.0, 12.0]
    assert M.closure_rate(mins, 2.0) == pytest.approx(2 / 3)                  # 1.5 and 0.5 are under 2 mm
    assert M.closure_rate(mins, 1.0) == pytest.approx(1 / 3)                  # only 0.5
    assert M.closure_rate(mins, 0.5) == 0.0                                   # strictly under
    assert np.isnan(M.closure_rate([], 2.0))


def test_curve_correlation_hand_checked():
    g1, g2 = np.array([1.0, 4.0, 2.0, 8.0]), np.array([0.0, 1.0, 2.0])
    # clip 1: an affine copy -> r = 1; clip 2: pred (0, 2, 1) vs (0, 1, 2): centred (-1, 1, 0)·(-1, 0, 1) = 1,
    # both centred norms^2 = 2 -> r = 1 / 2 = 0.5; mean over clips (1 + 0.5) / 2 = 0.75
    assert M.curve_correlation([2 * g1 + 1, [0.0, 2.0, 1.0]], [g1, g2]) == pytest.approx(0.75)
    assert M.curve_correlation([np.full(4, 3.0)], [g1]) == 0.0                # flat (collapsed) prediction: 0
    assert np.isnan(M.curve_correlation([g1], [np.ones(4)]))                   # flat truth: skipped


def test_motion_ratio_hand_checked():
    g = _track(np.ones(4), move_mm=[0.0, 2.0, 0.0, 2.0])  # vertices 2, 3 move: std 1 mm each; 0, 1 still
    p = _track(np.ones(4), move_mm=[5.0, 6.0, 5.0, 6.0])  # std 0.5 mm each (an offset does not count)
    assert M.motion_ratio([p], [g], [0, 1, 2, 3]) == pytest.approx(0.5)       # (0.5 + 0.5) / (1 + 1)
    assert M.motion_ratio([g], [g], [2, 3]) == pytest.approx(1.0)


def test_lip_sync_metrics_hand_checked():
    gt = [0.0, 0.0, 0.0, 0.0, 6.0, 8.0, 14.0, 14.0, 6.0, 0.5]
    # second clip: 3 frames, one /m/ at frame 1 (pred 0.8, gt 0.2) and no open vowel
    pred2, gt2 = [3.0, 0.8, 3.0], [2.0, 0.2, 2.0]
    segs2 = [["_", 0.0, 0.02], ["m", 0.02, 0.05], ["i:", 0.05, 0.1]]        # m: frame 1 (0.033); i: not open
    out = M.lip_sync_metrics([_track(PRED), _track(pred2)], [_track(gt), _track(gt2)], [SEGMENTS, segs2],
                             {"lip_midpoints": list(MID), "lips": [0, 1, 2, 3]})
    # predicted bilabial minima: clip 1 (1.5, 0.5, 2.5), clip 2 (0.8)
    assert out["n_bilabials"] == 4 and out["n_open_vowels"] == 2
    assert out["bilabial_closure_2mm"] == pytest.approx(3 / 4)                # 1.5, 0.5, 0.8
    assert out["bilabial_closure_1mm"] == pytest.approx(2 / 4)                # 0.5, 0.8
    assert out["bilabial_min_mm"] == pytest.approx((1.5 + 0.5 + 2.5 + 0.8) / 4)  # 1.325
    assert out["open_vowel_max_mm"] == pytest.approx((10 + 12) / 2)          # 11
    # ground truth: bilabial minima (0, 0, 0.5, 0.2); open-vowel maxima (8, 14)
    assert out["bilabial_closure_2mm_gt"] == 1.0 and out["bilabial_closure_1mm_gt"] == 1.0
    assert out["bilabial_min_mm_gt"] == pytest.approx(0.7 / 4)
    assert out["open_vowel_max_mm_gt"] == pytest.approx(11.0)
    # correlation: clip 2 pred (3, .8, 3) is an affine function of gt (2, .2, 2) with a positive slope -> r = 1;
    # clip 1 by the textbook formula written out here (independent of metrics.curve_correlation)
    a, b = np.array(PRED) - np.mean(PRED), np.array(gt) - np.mean(gt)
    r1 = (a @ b) / np.sqrt((a @ a) * (b @ b))
    assert out["lip_distance_corr"] == pytest.approx((r1 + 1.0) / 2)
    assert 0.5 < r1 < 1.0
    # lip motion ratio on vertices 0-3: only vertex 0 moves, by the lip distance itself: std(pred) / std(gt)
    assert out["lip_motion_ratio"] == pytest.approx((np.std(PRED) / np.std(gt) + np.std(pred2) / np.std(gt2)) / 2)


def test_lip_sync_metrics_perfect_and_flat_predictions():
    gts = [_track([0.0, 5.0, 12.0, 5.0, 0.0, 0.0])]
    segs = [["p", 0.0, 0.03], ["A:", 0.03, 0.1], ["b", 0.12, 0.2]]
    perfect = M.lip_sync_metrics(gts, gts, segs, lip_mid=MID, lips=[0, 1])
    assert perfect["bilabial_closure_2mm"] == perfect["bilabial_closure_2mm_gt"] == 1.0
    assert perfect["lip_distance_corr"] == pytest.approx(1.0) and perfect["lip_motion_ratio"] == pytest.approx(1.0)
    flat = M.lip_sync_metrics([_track(np.full(6, 3.7))], gts, segs, lip_mid=MID, lips=[0, 1])  # mumbling
    assert flat["bilabial_closure_2mm"] == 0.0 and flat["bilabial_min_mm"] == pytest.approx(3.7)
    assert flat["open_vowel_max_mm"] == pytest.approx(3.7) and flat["open_vowel_max_mm_gt"] == pytest.approx(12.0)
    assert flat["lip_distance_corr"] == 0.0 and flat["lip_motion_ratio"] == pytest.approx(0.0, abs=1e-12)


def test_lip_sync_metrics_bad_input():
    gts = [_track([0.0, 5.0, 1.0]), _track([0.0, 5.0, 1.0])]
    segs = [["p", 0.0, 0.03]]
    with pytest.raises(ValueError, match="one clip's phoneme list for 2 sequences"):
        M.lip_sync_metrics(gts, gts, segs, lip_mid=MID, lips=[0])
    with pytest.raises(ValueError, match=r"one list of \[phoneme, start_s, end_s\] per sequence \(2\), got 3"):
        M.lip_sync_metrics(gts, gts, [segs] * 3, lip_mid=MID, lips=[0])
    with pytest.raises(ValueError, match="phoneme segment 0: expected"):
        M.lip_sync_metrics(gts, gts, [[["p", 0.0]], segs], lip_mid=MID, lips=[0])
    with pytest.raises(KeyError, match="lip_midpoints"):
        M.lip_sync_metrics(gts, gts, [segs, segs], {"lips": [0]})
    with pytest.raises(ValueError, match="starts after the end"):
        M.lip_sync_metrics(gts, gts, [segs, [["m", 1.0, 1.1]]], lip_mid=MID, lips=[0])
    with pytest.raises(ValueError, match="lengths must match"):
        M.lip_sync_metrics([gts[0][:2]], [gts[0]], [segs], lip_mid=MID, lips=[0])


def test_phoneme_sets_match_the_rig():
    from dualtalker_lite.face.visemes import PHONEME_TO_VISEME

    assert set(M.BILABIALS) == {p for p, v in PHONEME_TO_VISEME.items() if v == "PP"}
    assert set(M.OPEN_VOWELS) == {p for p, v in PHONEME_TO_VISEME.items() if v == "aa"}


def test_lip_sync_on_the_shipped_sample():
    """The ground truth closes the lips at every bilabial of test-A; its per-clip mean face never does."""
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus

    corpus = Corpus(sample_path())
    names = corpus.metadata["splits"]["test_a"][:4]
    gts = [np.asarray(corpus.vertices(n), dtype=np.float64) for n in names]
    segs = [corpus.meta(n)["phonemes"] for n in names]
    out = M.lip_sync_metrics(gts, gts, segs, corpus.regions)
    assert out["n_bilabials"] > 0 and out["n_open_vowels"] > 0
    assert out["bilabial_closure_2mm"] == 1.0 and out["bilabial_min_mm"] < 1.0
    assert out["open_vowel_max_mm"] > 8.0
    mean = [np.repeat(g.mean(0, keepdims=True), len(g), 0) for g in gts]
    flat = M.lip_sync_metrics(mean, gts, segs, corpus.regions)
    assert flat["bilabial_closure_2mm"] == 0.0 and flat["lip_distance_corr"] == 0.0
