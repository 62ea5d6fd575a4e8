"""viz.heatmap: several per-vertex maps side by side (shared or own colour scales), vertex spectrograms, the
branch error maps; minimal checks (a figure comes back, its colour ranges, bad lengths refused)."""
import numpy as np
import pytest
import trimesh
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

from dualtalker_lite.viz import (branch_mean_errors, plot_branch_error_maps, plot_vertex_maps,
                                 plot_vertex_spectrograms)


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    return mesh.vertices * 0.1, np.asarray(mesh.faces)  # (162, 3) metres


def _mesh_norms(fig):
    return [(c.norm.vmin, c.norm.vmax) for ax in fig.axes for c in ax.collections if isinstance(c, PolyCollection)]


def test_shared_scale_one_colour_bar_and_one_range(sphere):
    v, f = sphere
    a, b = v[:, 1] * 1e3, 2.0 + v[:, 0] * 1e3                             # ranges [-100, 100] and [-98, 102]
    fig = plot_vertex_maps(v, f, {"a": a, "b": b}, label="FAI", units="mm")
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 2 * 2 + 1                                     # 2 maps x 2 views + one colour bar
    lo, hi = min(a.min(), b.min()), max(a.max(), b.max())
    assert _mesh_norms(fig) == [(pytest.approx(lo), pytest.approx(hi))] * 4
    assert fig.axes[-1].get_ylabel() == "FAI (mm)"
    assert [ax.get_title() for ax in fig.axes[:4]] == ["a (front)", "b (front)", "a (side)", "b (side)"]


def test_own_scales_one_colour_bar_per_map(sphere):
    v, f = sphere
    maps = [v[:, 1], 10 * v[:, 1], 100 * v[:, 1]]
    fig = plot_vertex_maps(v, f, maps, titles=["x1", "x10", "x100"], shared_scale=False, views="front", units="")
    assert len(fig.axes) == 3 + 3
    norms = _mesh_norms(fig)
    np.testing.assert_allclose([hi for _, hi in norms], [m.max() for m in maps])
    assert fig.axes[-1].get_ylabel() == "value"


def test_maps_of_the_wrong_length_or_nan_are_refused(sphere):
    v, f = sphere
    with pytest.raises(ValueError, match=r"^map 'short': expected shape \(162,\) \(one value per mesh vertex\), "
                                         r"got \(161,\)$"):
        plot_vertex_maps(v, f, {"ok": np.zeros(162), "short": np.zeros(161)})
    with pytest.raises(ValueError, match=r"^map 'map 0': 1 NaN/infinite value\(s\)$"):
        plot_vertex_maps(v, f, np.r_[np.nan, np.zeros(161)])
    with pytest.raises(ValueError, match=r"^titles: 1 given for 2 maps$"):
        plot_vertex_maps(v, f, [np.zeros(162), np.zeros(162)], titles=["one"])
    with pytest.raises(ValueError, match=r"^map 'weak branch': expected shape \(162,\)"):
        plot_branch_error_maps(v, f, np.zeros(162), np.zeros(3), np.zeros(162))


def test_branch_error_maps_share_a_scale_from_zero(sphere):
    v, f = sphere
    strong, weak = np.abs(v[:, 0]) * 1e3, np.abs(v[:, 1]) * 2e3
    fig = plot_branch_error_maps(v, f, strong, weak, strong + weak)
    assert len(fig.axes) == 3 * 2 + 1
    assert _mesh_norms(fig) == [(0.0, pytest.approx((strong + weak).max()))] * 6


def test_vertex_spectrograms_figure_and_bad_index():
    t = np.arange(120) / 30.0
    disp = np.stack([0.004 + 0.003 * np.sin(2 * np.pi * 4 * t), np.full(120, 1e-4)], axis=1)   # (T, 2) metres
    fig = plot_vertex_spectrograms(disp, 30.0, {"mouth": 0, "forehead": 1})
    assert isinstance(fig, Figure)
    assert [ax.get_ylabel() for ax in fig.axes[:4]] == ["displacement (mm)", "frequency (Hz)"] * 2
    with pytest.raises(ValueError, match=r"^vertex index out of range 0\.\.1: \{'x': 5\}$"):
        plot_vertex_spectrograms(disp, 30.0, {"x": 5})


def test_branch_mean_errors_hand_case():
    # Two vertices, 4 frames. Ground truth: vertex 0 moves 4 mm along x in every frame, vertex 1 stays.
    # mask (0.75, 0.25); both branches predict the ground truth exactly, so the sum is exact:
    # strong part = 0.75 * 4 mm at vertex 0 -> error 1 mm; weak part = 0.25 * 4 mm -> error 3 mm; sum -> 0.
    gt = np.zeros((1, 4, 6))
    gt[..., 0] = 0.004                                                    # (B, T, V*3) metres
    mask_xyz = np.repeat([0.75, 0.25], 3)
    strong, weak = mask_xyz * gt, (1 - mask_xyz) * gt
    errors = branch_mean_errors(strong, weak, strong + weak, gt)
    np.testing.assert_allclose(errors["strong branch"], [1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(errors["weak branch"], [3.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(errors["sum (output)"], [0.0, 0.0], atol=1e-12)
    valid = np.array([[True, True, False, False]])                        # padding frames are ignored
    strong_padded = strong.copy()
    strong_padded[:, 2:] = 1.0
    np.testing.assert_allclose(branch_mean_errors(strong_padded, weak, strong + weak, gt, mask=valid)
                               ["strong branch"], [1.0, 0.0], atol=1e-12)
