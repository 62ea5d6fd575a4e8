"""The template head: size, topology, mouth slit, and where the named regions are."""
import numpy as np
import pytest

from dualtalker_lite.face import REGION_NAMES, FaceShape, build_template, lip_distance, make_speakers


@pytest.fixture(scope="module")
def mesh():
    return build_template()


def test_size_units_and_axes(mesh):
    v = mesh.vertices
    assert v.dtype == np.float32 and v.ndim == 2 and v.shape[1] == 3
    assert 1400 <= len(v) <= 1700                                   # default ~1,500
    height, width = np.ptp(v[:, 1]), np.ptp(v[:, 0])
    assert 0.18 <= height <= 0.25 and 0.12 <= width <= 0.18         # metres, human scale
    nose_tip = v[np.argmax(v[:, 2])]                                # face looks towards +z
    assert abs(nose_tip[0]) < 1e-6
    assert mesh.faces.dtype == np.int64 and mesh.faces.shape[1] == 3
    assert mesh.faces.min() == 0 and mesh.faces.max() == len(v) - 1


@pytest.mark.parametrize("n", [1000, 2000, 3000])
def test_resolution_is_configurable(n):
    m = build_template(n_vertices=n)
    assert 1000 <= m.n_vertices <= 3100 and abs(m.n_vertices - n) / n < 0.1
    assert all(len(m.regions[k]) > 0 for k in REGION_NAMES)


def test_topology_watertight_with_a_mouth_slit(mesh):
    tm = mesh.to_trimesh()
    assert tm.is_winding_consistent and tm.is_watertight           # the mouth bag closes the surface
    assert len(mesh.vertex_neighbors) == mesh.n_vertices
    upper, lower = mesh.slit
    # No triangle joins an upper-lip row vertex to the lower-lip row: the lips can part.
    edges = {tuple(sorted(e)) for e in tm.edges_unique.tolist()}
    assert not any(tuple(sorted((u, l))) in edges for u in upper for l in lower)
    assert mesh.lip_midpoints == (upper[len(upper) // 2], lower[len(lower) // 2])


def test_rest_lip_gap(mesh):
    gap = lip_distance(mesh.vertices, mesh)
    assert 0.001 <= gap <= 0.003
    up, lo = mesh.lip_midpoints
    assert mesh.vertices[up, 1] > mesh.vertices[lo, 1]


def test_mesh_is_left_right_symmetric(mesh):
    v = np.round(mesh.vertices.astype(np.float64), 6)
    mirrored = v * [-1, 1, 1]
    key = lambda a: a[np.lexsort(a.T[::-1])]
    assert np.array_equal(key(v), key(mirrored))


def _mirror_closed(v, idx):
    pts = np.round(v[idx].astype(np.float64), 6)
    key = lambda a: a[np.lexsort(a.T[::-1])]
    return np.array_equal(key(pts), key(pts * [-1, 1, 1]))


def test_regions_are_where_they_should_be(mesh):
    v, r = mesh.vertices, mesh.regions
    mean_y = lambda k: v[r[k], 1].mean()
    nose_tip = v[np.argmax(v[:, 2])]
    lips = v[r["lips"]]
    # Lips: at the front, below the nose, centred and symmetric in x.
    assert lips[:, 2].mean() > np.percentile(v[:, 2], 90)
    band = np.abs(v[:, 1] - v[mesh.lip_midpoints[0], 1]) < 0.008      # at mouth height, the lips stick out most
    assert v[band, 2].max() == lips[:, 2].max()
    assert lips[:, 1].max() < nose_tip[1]
    assert abs(lips[:, 0].mean()) < 1e-6
    for k in ("lips", "eyes", "brows", "forehead", "cheeks", "jaw", "upper_face", "eyes_forehead"):
        assert _mirror_closed(v, r[k]), k
    # Vertical order: lower lip < upper lip < nose tip < eyes < brows < forehead.
    assert mean_y("lower_lip") < mean_y("upper_lip") < nose_tip[1] < mean_y("eyes") < mean_y("brows") < mean_y("forehead")
    up, lo = mesh.slit
    assert np.all(v[up, 1] >= v[lo, 1])
    # Mouth corners: the extreme x of the lips, one per side, on the mouth line.
    corners = v[r["mouth_corners"]]
    assert len(corners) == 2 and np.isclose(np.abs(corners[:, 0]).max(), np.abs(lips[:, 0]).max())
    assert np.isclose(corners[0, 0], -corners[1, 0])
    # Eyes: two clusters, left and right of the nose, above the lips.
    eyes = v[r["eyes"]]
    assert (eyes[:, 0] > 0.01).sum() == (eyes[:, 0] < -0.01).sum() and np.abs(eyes[:, 0]).min() > 0.005
    # Upper face (FDD) lies entirely above the mouth; eyes + forehead (EVE) are part of it.
    assert v[r["upper_face"], 1].min() > lips[:, 1].max()
    assert set(r["eyes_forehead"]) <= set(r["upper_face"])
    assert set(r["eyes"]) | set(r["brows"]) | set(r["forehead"]) == set(r["eyes_forehead"])
    # The jaw region is the chin/lower face: below the mouth line.
    assert v[r["jaw"], 1].max() <= v[r["mouth_corners"], 1].max() + 0.002
    assert set(r["lower_lip"]) <= set(r["jaw"])
    # Mouth interior is behind the lips.
    assert v[r["mouth_interior"], 2].max() < v[r["lips"], 2].max()


def test_every_speaker_shares_topology_and_regions(mesh):
    for spk in make_speakers(3, seed=1):
        m = build_template(spk.shape)
        assert np.array_equal(m.faces, mesh.faces) and m.lip_midpoints == mesh.lip_midpoints
        assert all(np.array_equal(m.regions[k], mesh.regions[k]) for k in REGION_NAMES)
        assert not np.allclose(m.vertices, mesh.vertices)
        assert m.to_trimesh().is_watertight


def test_shape_parameters_move_landmarks():
    wide = build_template(FaceShape(mouth_width=0.056))
    narrow = build_template(FaceShape(mouth_width=0.044))
    corner_x = lambda m: np.abs(m.vertices[m.regions["mouth_corners"], 0]).max()
    assert corner_x(wide) == pytest.approx(0.028, abs=1e-4) and corner_x(narrow) == pytest.approx(0.022, abs=1e-4)
    gap = lip_distance(build_template(FaceShape(lip_gap=0.0025)).vertices, wide)
    assert gap == pytest.approx(0.0025, abs=2e-4)


def test_vertex_normals_match_trimesh_closely():
    """Area-weighted normals (numpy, no trimesh import at load time) vs trimesh's angle-weighted ones."""
    from dualtalker_lite.face.mesh import build_template, vertex_normals

    mesh = build_template()
    ours = vertex_normals(mesh.vertices, mesh.faces)
    ref = np.asarray(mesh.to_trimesh().vertex_normals)
    np.testing.assert_allclose(np.linalg.norm(ours, axis=1), 1.0, atol=1e-9)
    angle = np.degrees(np.arccos(np.clip((ours * ref).sum(1), -1.0, 1.0)))
    assert np.median(angle) < 2.0 and angle[mesh.regions["cheeks"]].max() < 15.0
    # a single triangle: the normal of the plane, oriented by the winding
    tri = vertex_normals(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]]))
    np.testing.assert_allclose(tri, [[0, 0, 1]] * 3)
