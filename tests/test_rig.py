"""The rig: exact rest pose, localised controls, a nonlinear jaw, lip closure, determinism and speed."""
import json
import time

import numpy as np
import pytest

from dualtalker_lite.face import (CONTROL_NAMES, CONTROL_REGIONS, FaceRig, Speaker, control_vector, lip_distance,
                                  make_speakers)
from dualtalker_lite.face.rig import CONTROL_QUANTUM, JAW_MAX_ANGLE, snap_controls

C = len(CONTROL_NAMES)


@pytest.fixture(scope="module")
def rig():
    return FaceRig()


def _moved(rig, name, value=1.0):
    v = rig.animate(control_vector({name: value})).astype(np.float64)
    return v - rig.template


def test_control_names():
    assert len(CONTROL_NAMES) >= 12 and len(set(CONTROL_NAMES)) == C
    assert CONTROL_NAMES[:2] == ("jaw_open", "lip_press") and set(CONTROL_REGIONS) == set(CONTROL_NAMES)


def test_zero_controls_give_exactly_the_template(rig):
    for r in (rig, FaceRig(make_speakers(2, seed=3)[1])):
        out = r.animate(np.zeros((5, C), np.float32))
        assert out.shape == (5, len(r.template), 3) and out.dtype == np.float32
        assert all(np.array_equal(frame, r.template) for frame in out)
    assert np.array_equal(rig.animate(np.zeros(C)), rig.template)  # one frame (C,) -> (V, 3)


@pytest.mark.parametrize("name", CONTROL_NAMES)
def test_each_control_moves_its_own_region(rig, name):
    d = _moved(rig, name)
    energy = (d ** 2).sum(1)                                          # (V,) squared displacement
    region = np.unique(np.concatenate([rig.mesh.regions[k] for k in CONTROL_REGIONS[name]]))
    assert np.sqrt(energy.max()) > 0.0015                            # moves something by > 1.5 mm ...
    assert energy[region].sum() / energy.sum() > 0.9                 # ... mostly inside its region


def test_blink_closes_the_upper_lid(rig):
    d = _moved(rig, "blink")
    eyes = rig.mesh.regions["eyes"]
    energy = (d ** 2).sum(1)
    assert energy[eyes].sum() / energy.sum() > 0.9
    v, L = rig.template, rig.mesh.landmarks
    upper_lid = eyes[v[eyes, 1] > L["y_eye"] - 0.001]
    assert np.all(d[upper_lid, 1] <= 0)                               # the upper lid only moves down ...
    centre = upper_lid[(np.abs(np.abs(v[upper_lid, 0]) - L["x_eye"]) < 0.006) & (v[upper_lid, 1] < L["y_eye"] + 0.008)]
    assert len(centre) >= 4
    assert np.all(v[centre, 1] + d[centre, 1] < L["y_eye"] - 0.001)   # ... past the eye centre: the eye is shut


def test_jaw_rotates_the_chin_about_the_hinge(rig):
    v0 = rig.template.astype(np.float64)
    chin = np.nonzero((np.abs(v0[:, 0]) < 1e-6) & (np.abs(v0[:, 1] - rig.mesh.landmarks["y_chin"]) < 0.006))[0]
    chin = chin[np.argmax(v0[chin, 2])]
    assert rig.jaw_weights[chin] == 1.0
    hinge = rig.hinge.astype(np.float64)
    radius = lambda p: np.hypot(p[..., 1] - hinge[1], p[..., 2] - hinge[2])   # distance to the x-axis hinge
    values = np.linspace(0.0, 1.0, 6)
    out = rig.animate(control_vector({"jaw_open": 1.0})[None] * values[:, None]).astype(np.float64)
    path = out[:, chin]
    assert np.all(np.diff(path[:, 1]) < 0) and np.all(np.diff(path[:, 2]) < 0)   # down and back
    assert np.allclose(radius(path), radius(v0[chin]), atol=1e-6)                 # on a circle
    angle = np.arctan2(path[:, 1] - hinge[1], path[:, 2] - hinge[2])
    assert np.allclose(angle[0] - angle, snap_controls(values) * JAW_MAX_ANGLE, atol=1e-6)  # jaw_open * max
    half, full = path[3] - path[0], path[5] - path[0]                 # nonlinear: not twice the half motion
    assert np.linalg.norm(full - 2 * half) > 1e-4
    # The upper lip does not follow the jaw; the lips part.
    up, lo = rig.mesh.lip_midpoints
    assert rig.jaw_weights[up] == 0.0 and rig.jaw_weights[lo] == 1.0
    assert lip_distance(out[-1], rig.mesh) > 0.02


def test_lip_press_closes_the_lips(rig):
    assert lip_distance(rig.template, rig.mesh) > 0.001
    for jaw in (0.0, 0.1, 0.3):
        v = rig.animate(control_vector({"lip_press": 1.0, "jaw_open": jaw}))
        assert lip_distance(v, rig.mesh) < 0.001
    half = rig.animate(control_vector({"lip_press": 0.5}))
    assert lip_distance(half, rig.mesh) == pytest.approx(0.5 * lip_distance(rig.template, rig.mesh), rel=1e-3)


def _mirror_index(v):
    """For every vertex, the index of its mirror image x -> -x (the mesh is exactly symmetric)."""
    key = np.round(v.astype(np.float64), 7)
    order, mirrored = np.lexsort(key.T), np.lexsort((key * [-1, 1, 1]).T)
    out = np.empty(len(v), dtype=np.int64)
    out[mirrored] = order
    return out


def test_smiles_are_one_sided_and_mirror_images(rig):
    left, right = _moved(rig, "smile_left"), _moved(rig, "smile_right")
    x = rig.template[:, 0]
    assert left[x > 0, 1].sum() > 0 and np.all(left[x < 0, 1] == 0)   # +x is the subject's left
    m = _mirror_index(rig.template)
    assert np.allclose(right[m], left * [-1, 1, 1], atol=1e-7)


def test_animate_is_deterministic_and_snaps_to_the_grid(rig):
    ctrl = np.random.default_rng(0).uniform(-0.2, 1.0, (60, C)).astype(np.float32)
    a, b = rig.animate(ctrl), FaceRig().animate(ctrl.copy())
    assert np.array_equal(a, b)                                       # bit-identical, fresh rig too
    assert np.array_equal(a, rig.animate(snap_controls(ctrl)))        # controls live on a 1/4096 grid
    frames = np.stack([rig.animate(c) for c in ctrl[:5]])             # frame by frame = all at once
    assert np.array_equal(frames, a[:5])
    assert np.all(np.abs(snap_controls(ctrl) - ctrl) <= CONTROL_QUANTUM / 2)
    # The linear part is exact in float64, so any summation order (BLAS, einsum, a reversed loop) agrees bit for bit.
    q, D = snap_controls(ctrl)[:, 1:], rig._linear
    backwards = sum(np.outer(q[:, c], D[c]) for c in reversed(range(len(D))))
    assert np.array_equal(q @ D, np.einsum("tc,cv->tv", q, D)) and np.array_equal(q @ D, backwards)


def test_speakers_have_different_faces_and_motion():
    s1, s2 = make_speakers(2, seed=0)
    r1, r2 = FaceRig(s1), FaceRig(s2)
    assert not np.allclose(r1.template, r2.template, atol=1e-4)
    ctrl = control_vector({"jaw_open": 0.5, "smile_left": 0.5})
    assert not np.allclose(r1.animate(ctrl) - r1.template, r2.animate(ctrl) - r2.template, atol=1e-4)
    # The rig is rebuilt exactly from the speaker's JSON parameters (what the compact corpus stores).
    r3 = FaceRig(Speaker.from_dict(json.loads(json.dumps(s1.to_dict()))))
    assert np.array_equal(r3.animate(ctrl), r1.animate(ctrl))


def test_animate_is_fast(rig):
    clips = np.random.default_rng(1).uniform(0.0, 1.0, (300, 90, C)).astype(np.float32)
    rig.animate(clips[0])
    start = time.process_time()
    for c in clips:
        rig.animate(c)
    cpu = time.process_time() - start
    print(f"rig.animate: 300 clips x 90 frames in {cpu:.3f} s CPU")
    assert cpu < 2.0                                                  # ~0.3 s on an idle laptop core
