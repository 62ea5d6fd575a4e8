"""The spiral figure: one marker per real spiral entry, coloured by ring, and clear errors."""
import numpy as np
import pytest
from matplotlib.figure import Figure

from dualtalker_lite.blocks.spiral import spiral_indices, spiral_mask
from dualtalker_lite.face.mesh import build_template
from dualtalker_lite.viz import plot_spirals


def test_plot_spirals_draws_every_real_entry_with_its_ring_colour():
    mesh = build_template()
    spirals = spiral_indices(mesh.faces, mesh.n_vertices, length=12, vertices=mesh.vertices)
    centres = [int(mesh.lip_midpoints[0]), int(mesh.regions["brows"][0])]
    fig = plot_spirals(mesh.vertices, mesh.faces, spirals, centres, zoom=0.012)
    assert isinstance(fig, Figure) and len(fig.axes) == 2
    overview, close = fig.axes
    points = overview.collections[1:]  # collection 0 is the mesh
    assert [len(c.get_offsets()) for c in points] == [int(spiral_mask(spirals)[c].sum()) for c in centres]
    assert len(close.texts) == 12  # slot numbers 0..11
    assert close.get_xlabel() == "x (mm)" and fig._suptitle.get_text() == "Spirals on the template"
    # the centre's marker sits at the centre's front-view position (x, y in mm)
    np.testing.assert_allclose(points[0].get_offsets()[0], mesh.vertices[centres[0], :2] * 1e3, rtol=1e-6)
    colours = points[0].get_facecolors()
    assert not np.allclose(colours[0], colours[1])  # centre and ring 1 differ


def test_plot_spirals_rejects_bad_centres_and_shapes():
    mesh = build_template()
    spirals = spiral_indices(mesh.faces, mesh.n_vertices, length=4)
    with pytest.raises(ValueError, match=r"centres: need 1\+ vertex ids in \[0, 1558\), got \[5000\]"):
        plot_spirals(mesh.vertices, mesh.faces, spirals, [5000])
    with pytest.raises(ValueError, match=r"spirals: expected shape \(1558, L\), got \(10, 4\)"):
        plot_spirals(mesh.vertices, mesh.faces, spirals[:10], [0])
