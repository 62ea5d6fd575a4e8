"""Emotional metrics: brow raise, smile width, per-emotion "right emotion" errors, classification accuracy."""
import numpy as np
import pytest

from dualtalker_lite.metrics import emotion as em

# a 5-vertex toy face (metres): 0, 1 = mouth corners 40 mm apart along x; 2, 3 = brows; 4 = nose tip
TEMPLATE = np.array([[0.02, 0.0, 0.0], [-0.02, 0.0, 0.0], [0.01, 0.03, 0.0], [-0.01, 0.03, 0.0], [0.0, 0.01, 0.01]])
REGIONS = {"mouth_corners": [0, 1], "brows": [2, 3]}


def clip(brow_up_mm=(0.0, 0.0), corner_out_mm=(0.0, 0.0), jaw_down_mm=0.0):
    """Two frames: brows up by brow_up_mm[t], each corner pulled outward by corner_out_mm[t], both corners down."""
    x = np.repeat(TEMPLATE[None], 2, axis=0).copy()
    for t in range(2):
        x[t, 2:4, 1] += brow_up_mm[t] / 1000
        x[t, 0, 0] += corner_out_mm[t] / 1000
        x[t, 1, 0] -= corner_out_mm[t] / 1000
        x[t, 0:2, 1] -= jaw_down_mm / 1000
    return x


def test_brow_raise_and_smile_hand_computed():
    x = clip(brow_up_mm=(1.0, 3.0), corner_out_mm=(0.5, 1.5), jaw_down_mm=4.0)
    assert em.brow_raise(x, TEMPLATE, REGIONS["brows"]) == pytest.approx(2.0)  # mean of 1 and 3 mm
    # width 40 + 1 and 40 + 3 mm -> mean change 2 mm; the jaw's common downward pull changes nothing
    assert em.smile_width(x, TEMPLATE, REGIONS["mouth_corners"]) == pytest.approx(2.0)
    assert em.smile_width(x.reshape(2, -1), TEMPLATE.reshape(-1), REGIONS["mouth_corners"]) == pytest.approx(2.0)
    assert em.brow_raise(TEMPLATE[None], TEMPLATE, [2]) == 0.0
    frown = clip(brow_up_mm=(-2.0, -2.0))
    assert em.brow_raise(frown, TEMPLATE, REGIONS["brows"]) == pytest.approx(-2.0)


def test_expression_metrics_per_emotion_hand_computed():
    gts = [clip((2, 2), (1, 1)), clip((4, 4), (3, 3)), clip((-1, -1), (0, 0))]
    preds = [clip((1, 1), (1, 1)), clip((1, 1), (1, 1)), clip((0, 0), (0, 0))]
    out = em.emotion_expression_metrics(preds, gts, [TEMPLATE] * 3, ["happy", "happy", "angry"], REGIONS)
    happy, angry = out["per_emotion"]["happy"], out["per_emotion"]["angry"]
    assert list(out["per_emotion"]) == ["happy", "angry"] and happy["n_clips"] == 2 and angry["n_clips"] == 1
    assert happy["brow_raise_mm_gt"] == pytest.approx(3.0) and happy["brow_raise_mm"] == pytest.approx(1.0)
    assert happy["smile_mm_gt"] == pytest.approx(4.0) and happy["smile_mm"] == pytest.approx(2.0)  # 2 x outward
    assert angry["brow_raise_mm_gt"] == pytest.approx(-1.0) and angry["brow_raise_mm"] == pytest.approx(0.0)
    # brow errors |1-3| = 2 and |0-(-1)| = 1 -> 1.5; smile errors |2-4| = 2 and 0 -> 1.0
    assert out["brow_raise_error_mm"] == pytest.approx(1.5) and out["smile_error_mm"] == pytest.approx(1.0)
    perfect = em.emotion_expression_metrics(gts, gts, [TEMPLATE] * 3, ["happy", "happy", "angry"], REGIONS)
    assert perfect["brow_raise_error_mm"] == 0.0 and perfect["smile_error_mm"] == 0.0


def test_emotion_accuracy_hand_computed():
    assert em.emotion_accuracy([1, 2, 3, 0], [1, 2, 0, 0]) == 0.75
    assert em.emotion_accuracy(np.array([4]), np.array([4])) == 1.0


@pytest.mark.parametrize("call, message", [
    (lambda: em.emotion_accuracy([1, 2], [1]), "2 predictions for 1 labels"),
    (lambda: em.emotion_accuracy([], []), "no clips"),
    (lambda: em.smile_width(clip(), TEMPLATE, [0, 1, 2]), "expected the 2 mouth-corner vertices, got 3"),
    (lambda: em.brow_raise(clip(), TEMPLATE, []), "brow region is empty"),
    (lambda: em.brow_raise(clip(), TEMPLATE[:4], [2]), "template: 4 vertices, the sequence has 5"),
    (lambda: em.brow_raise(np.zeros((2, 5, 2)), TEMPLATE, [2]), r"expected \(T, V\*3\) or \(T, V, 3\)"),
    (lambda: em.emotion_expression_metrics([clip()], [clip()], [TEMPLATE], [], REGIONS), "must be as many"),
    (lambda: em.emotion_expression_metrics([], [], [], [], REGIONS), "no clips"),
])
def test_bad_inputs_fail_with_one_clear_line(call, message):
    with pytest.raises(ValueError, match=message):
        call()
