"""Spirals (EmoFace eq. 1), the temporal neighbourhood (eq. 2) and SpiralConv3D (eq. 3) on hand-built meshes."""
import numpy as np
import pytest
import torch

from dualtalker_lite.blocks.spiral import (SpiralConv3D, k_rings, one_ring_order, spiral_indices, spiral_mask,
                                           spiral_ring_index, temporal_neighbourhood)
from dualtalker_lite.face.mesh import build_template

# A 4 x 4 grid in the z = 0 plane, seen from +z (y up), every quad split along its rising diagonal:
#   12 13 14 15
#    8  9 10 11
#    4  5  6  7
#    0  1  2  3
GRID_VERTICES = np.array([[x, y, 0.0] for y in range(4) for x in range(4)])
GRID_FACES = np.array([
    [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6],
    [4, 5, 9], [4, 9, 8], [5, 6, 10], [5, 10, 9], [6, 7, 11], [6, 11, 10],
    [8, 9, 13], [8, 13, 12], [9, 10, 14], [9, 14, 13], [10, 11, 15], [10, 15, 14]])  # counter-clockwise from +z
# A hexagon fan: centre 0, rim 1..6 counter-clockwise starting on the +x axis.
HEX_VERTICES = np.array([[0.0, 0.0, 0.0]] + [[np.cos(a), np.sin(a), 0.0] for a in np.arange(6) * np.pi / 3])
HEX_FACES = np.array([[0, i, i % 6 + 1] for i in range(1, 7)])


def test_k_rings_of_the_grid_match_hand_drawn_rings():
    assert k_rings(GRID_FACES, 16, 5, 3) == [[5], [0, 1, 4, 6, 9, 10], [2, 7, 8, 11, 13, 14, 15], [3, 12]]
    assert k_rings(GRID_FACES, 16, 0, 3) == [[0], [1, 4, 5], [2, 6, 8, 9, 10], [3, 7, 11, 12, 13, 14, 15]]
    assert k_rings(HEX_FACES, 7, 3, 2) == [[3], [0, 2, 4], [1, 5, 6]]
    assert k_rings(GRID_FACES, 16, 5, 5)[4:] == [[], []]  # past the mesh: empty rings


def test_one_ring_is_cyclic_and_starts_at_the_highest_neighbour():
    rings, boundary = one_ring_order(GRID_FACES, 16, GRID_VERTICES)
    # Around 5 at (1, 1), counter-clockwise from the highest neighbour (10 and 9 tie on y; larger x first: 10).
    assert rings[5] == [10, 9, 4, 0, 1, 6]
    assert rings[0] == [1, 5, 4]  # a boundary vertex: its open fan, from the neighbour nothing precedes
    assert np.nonzero(~boundary)[0].tolist() == [5, 6, 9, 10]
    hex_rings, hex_boundary = one_ring_order(HEX_FACES, 7, HEX_VERTICES)
    assert hex_rings[0] == [2, 3, 4, 5, 6, 1]  # 2 and 3 tie on y (sin 60 deg); 2 has the larger x
    assert not hex_boundary[0] and hex_boundary[1:].all()
    rings_no_pos, _ = one_ring_order(HEX_FACES, 7)
    assert rings_no_pos[0] == [1, 2, 3, 4, 5, 6]  # without positions: from the lowest index


def test_spiral_of_the_grid_matches_the_hand_traced_order():
    s = spiral_indices(GRID_FACES, 16, length=16, vertices=GRID_VERTICES)
    # Traced by hand: ring 1 from 10 counter-clockwise; ring 2 starts at 11, next to where ring 1 ended (6), and
    # each ring-1 vertex adds its new neighbours walking on from the neighbour that entered the spiral last.
    assert s[5].tolist() == [5, 10, 9, 4, 0, 1, 6, 11, 15, 14, 13, 8, 2, 7, 12, 3]
    assert s.dtype == torch.int64 and s.shape == (16, 16)
    assert spiral_mask(s).all()  # every vertex reaches all 16 vertices: no padding
    # Fixed length and dilation (eq. 1's k-disk read as SpiralNet++'s truncated spiral), from the hand trace above,
    # not from the package's length-16 spiral: the first 5 entries, then every second of the first 6.
    short = spiral_indices(GRID_FACES, 16, length=5, vertices=GRID_VERTICES)
    assert short[5].tolist() == [5, 10, 9, 4, 0]
    assert short[0].tolist() == [0, 1, 5, 4, 2]  # corner: its one-ring (1, 5, 4), then ring 2 from 1's side
    dilated = spiral_indices(GRID_FACES, 16, length=3, dilation=2, vertices=GRID_VERTICES)
    assert dilated[5].tolist() == [5, 9, 0]  # entries 0, 2, 4 of (5, 10, 9, 4, 0, 1)


def test_fallback_pads_with_the_centre_and_masks_it():
    s = spiral_indices(HEX_FACES, 7, length=10, vertices=HEX_VERTICES)  # only 7 vertices exist
    assert s[0].tolist() == [0, 2, 3, 4, 5, 6, 1, 0, 0, 0]
    mask = spiral_mask(s)
    assert mask.sum(1).tolist() == [7] * 7
    assert mask[:, :7].all() and not mask[:, 7:].any()
    # rings mode: the whole k-disk, padded to the largest one.
    r1 = spiral_indices(GRID_FACES, 16, rings=1, vertices=GRID_VERTICES)
    assert r1.shape == (16, 7)
    assert r1[5].tolist() == [5, 10, 9, 4, 0, 1, 6]
    assert r1[0].tolist() == [0, 1, 5, 4, 0, 0, 0]
    assert spiral_mask(r1)[0].tolist() == [True] * 4 + [False] * 3
    assert spiral_indices(GRID_FACES, 16, rings=0).tolist() == [[v] for v in range(16)]


def _bfs_distances(faces, n, centre):
    """Graph distance from ``centre`` to every vertex (independent of the package: its own adjacency and queue)."""
    nbrs = [set() for _ in range(n)]
    for f in faces:
        for i in range(3):
            nbrs[f[i]].add(f[(i + 1) % 3])
            nbrs[f[(i + 1) % 3]].add(f[i])
    dist = np.full(n, -1)
    dist[centre], frontier = 0, [centre]
    while frontier:
        nxt = []
        for v in frontier:
            for u in nbrs[v]:
                if dist[u] < 0:
                    dist[u] = dist[v] + 1
                    nxt.append(u)
        frontier = nxt
    return dist


def test_template_spirals_stay_inside_the_k_disk():
    mesh = build_template()
    faces, n = mesh.faces, mesh.n_vertices
    by_rings = spiral_indices(faces, n, rings=2, vertices=mesh.vertices)
    by_length = spiral_indices(faces, n, length=18, vertices=mesh.vertices)
    mask = spiral_mask(by_rings)
    for v in range(0, n, 37):
        dist = _bfs_distances(faces, n, v)
        row = by_rings[v][mask[v]].numpy()
        assert len(set(row.tolist())) == len(row)  # no vertex twice
        assert sorted(row.tolist()) == sorted(np.nonzero((dist >= 0) & (dist <= 2))[0].tolist())  # = 2-disk
        d = dist[by_length[v].numpy()]
        assert (np.diff(d) >= 0).all()  # rings in order: never back to an inner ring
        assert spiral_ring_index(by_length, faces, n, v).tolist() == d.tolist()
        full = max(k for k in range(6) if (dist <= k).sum() <= 18 and (dist >= 0).any())
        assert set(np.nonzero((dist >= 0) & (dist <= full))[0]) <= set(by_length[v].tolist())  # whole inner disks


def test_spirals_are_equivariant_to_a_relabelling_of_the_vertices():
    mesh = build_template()
    n = mesh.n_vertices
    perm = np.random.default_rng(0).permutation(n)  # old vertex i becomes perm[i]
    new_vertices = np.empty_like(mesh.vertices)
    new_vertices[perm] = mesh.vertices
    new_faces = perm[mesh.faces]
    old = spiral_indices(mesh.faces, n, length=18, dilation=2, vertices=mesh.vertices)
    new = spiral_indices(new_faces, n, length=18, dilation=2, vertices=new_vertices)
    torch.testing.assert_close(new[torch.from_numpy(perm)], torch.from_numpy(perm)[old])  # exactly, order included
    # Without positions the start depends on the labels, but the rings (as sets) do not.
    old_r = spiral_indices(mesh.faces, n, rings=2)
    new_r = spiral_indices(new_faces, n, rings=2)
    for v in range(0, n, 97):
        a, b = perm[old_r[v].numpy()], new_r[perm[v]].numpy()
        assert sorted(a.tolist()) == sorted(b.tolist())


def test_temporal_neighbourhood_hand_case():
    x = torch.tensor([[1.0, 2.0, 3.0, 4.0]])[..., None]  # (B=1, T=4, 1)
    z = temporal_neighbourhood(x, 3)[0, :, :, 0]  # (T, delta): oldest first
    assert z.tolist() == [[0, 0, 1], [0, 1, 2], [1, 2, 3], [2, 3, 4]]
    r = temporal_neighbourhood(x, 3, pad="replicate")[0, :, :, 0]
    assert r.tolist() == [[1, 1, 1], [1, 1, 2], [1, 2, 3], [2, 3, 4]]
    assert temporal_neighbourhood(x, 1)[0, :, 0, 0].tolist() == [1, 2, 3, 4]


def _dense_reference(conv: SpiralConv3D, x: torch.Tensor) -> torch.Tensor:
    """Eq. 3 written out: build every vertex's (delta x L x C) neighbourhood with loops, one matmul, add b."""
    B, T, V, C = x.shape
    spirals, delta = conv.spirals.tolist(), conv.delta
    out = torch.zeros(B, T, V, conv.out_channels, dtype=x.dtype)
    for t in range(T):
        for v in range(V):
            parts = []
            for j in range(delta):  # frame t - (delta - 1) + j
                tt = t - (delta - 1) + j
                if tt < 0:
                    tt = 0 if conv.time_pad == "replicate" else None
                for slot, u in enumerate(spirals[v]):
                    padded = slot > 0 and u == v
                    parts.append(torch.zeros(B, C, dtype=x.dtype) if tt is None or padded else x[:, tt, u])
            nb = torch.cat(parts, dim=-1)  # (B, delta*L*C)
            out[:, t, v] = nb @ conv.weight.reshape(conv.out_channels, -1).t() + conv.bias
    return out


@pytest.mark.parametrize("time_pad", ["zeros", "replicate"])
def test_spiral_conv_equals_dense_reference_and_gradients_match(time_pad):
    torch.manual_seed(0)
    spirals = spiral_indices(HEX_FACES, 7, length=9, vertices=HEX_VERTICES)  # 2 padded slots per vertex
    conv = SpiralConv3D(2, 3, spirals, delta=3, time_pad=time_pad).double()
    x = torch.randn(2, 5, 7, 2, dtype=torch.float64, requires_grad=True)
    out = conv(x)
    assert out.shape == (2, 5, 7, 3)
    ref = _dense_reference(conv, x)
    torch.testing.assert_close(out, ref)
    g = torch.randn_like(out)
    grads = torch.autograd.grad((out * g).sum(), [x, conv.weight, conv.bias])
    grads_ref = torch.autograd.grad((ref * g).sum(), [x, conv.weight, conv.bias])
    for a, b in zip(grads, grads_ref):
        torch.testing.assert_close(a, b)
    assert conv.weight.shape == (3, 3, 9, 2)


def test_spiral_conv_is_causal_in_time():
    torch.manual_seed(0)
    spirals = spiral_indices(GRID_FACES, 16, length=7, vertices=GRID_VERTICES)
    conv = SpiralConv3D(3, 4, spirals, delta=3)
    x = torch.randn(1, 8, 16, 3)
    for t in range(7):
        y = x.clone()
        y[:, t + 1] += torch.randn(16, 3)
        a, b = conv(x), conv(y)
        torch.testing.assert_close(a[:, :t + 1], b[:, :t + 1], rtol=0, atol=0)  # the past is untouched
        assert (a[:, t + 1] - b[:, t + 1]).abs().max() > 1e-3  # the changed frame itself is seen
    # delta = 3: frame t + 3 no longer sees frame t
    y = x.clone()
    y[:, 2] += 1.0
    torch.testing.assert_close(conv(x)[:, 5:], conv(y)[:, 5:], rtol=0, atol=0)


def test_spiral_conv_sees_exactly_its_spiral():
    torch.manual_seed(0)
    spirals = spiral_indices(GRID_FACES, 16, length=4, vertices=GRID_VERTICES)
    conv = SpiralConv3D(1, 1, spirals, delta=1)
    x = torch.zeros(1, 1, 16, 1, requires_grad=True)
    conv(x)[0, 0, 5, 0].backward()
    assert torch.nonzero(x.grad[0, 0, :, 0]).flatten().tolist() == sorted(spirals[5].tolist())  # [5, 10, 9, 4]


def test_same_seed_same_result():
    spirals = spiral_indices(HEX_FACES, 7, length=7)
    x = torch.randn(1, 3, 7, 2, generator=torch.Generator().manual_seed(1))
    torch.manual_seed(3)
    a = SpiralConv3D(2, 2, spirals)(x)
    torch.manual_seed(3)
    b = SpiralConv3D(2, 2, spirals)(x)
    torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_bad_inputs_are_refused_with_one_clear_line():
    with pytest.raises(ValueError, match=r"faces: expected integer triangles \(F, 3\)"):
        spiral_indices(GRID_FACES[:, :2], 16, length=4)
    with pytest.raises(ValueError, match=r"faces: indices span \[0, 15\], outside \[0, 10\)"):
        spiral_indices(GRID_FACES, 10, length=4)
    with pytest.raises(ValueError, match=r"faces: triangle 1 \[0, 0, 4\] repeats a vertex"):
        spiral_indices(np.array([[0, 1, 5], [0, 0, 4]]), 16, length=4)
    flipped = GRID_FACES.copy()
    flipped[1] = flipped[1, ::-1]  # one triangle wound the other way
    with pytest.raises(ValueError, match=r"directed edge \(\d+, \d+\) appears in two triangles"):
        spiral_indices(flipped, 16, length=4)
    with pytest.raises(ValueError, match="give exactly one of length= or rings="):
        spiral_indices(GRID_FACES, 16)
    with pytest.raises(ValueError, match="give exactly one of length= or rings="):
        spiral_indices(GRID_FACES, 16, length=3, rings=1)
    with pytest.raises(ValueError, match="dilation must be >= 1, got 0"):
        spiral_indices(GRID_FACES, 16, length=3, dilation=0)
    with pytest.raises(ValueError, match=r"vertices: expected shape \(16, 3\), got \(15, 3\)"):
        spiral_indices(GRID_FACES, 16, length=3, vertices=GRID_VERTICES[:15])
    with pytest.raises(ValueError, match=r"spirals: indices span \[0, 9\], outside \[0, 7\) vertices"):
        SpiralConv3D(1, 1, torch.tensor([[0, 9]] * 7))
    with pytest.raises(ValueError, match=r"spirals: expected a \(V, L\) LongTensor"):
        SpiralConv3D(1, 1, torch.zeros(7, 2))
    conv = SpiralConv3D(2, 1, spiral_indices(HEX_FACES, 7, length=3))
    with pytest.raises(ValueError, match=r"SpiralConv3D: expected input \(B, T, 7, 2\), got \(1, 3, 6, 2\)"):
        conv(torch.zeros(1, 3, 6, 2))
    with pytest.raises(ValueError, match="time pad must be 'zeros' or 'replicate', got 'reflect'"):
        temporal_neighbourhood(torch.zeros(1, 2, 1), 2, pad="reflect")


def test_spiral_linear_gradcheck_and_chunking(monkeypatch):
    import dualtalker_lite.blocks.spiral as spiral_module
    from dualtalker_lite.blocks.spiral import SpiralLinear

    torch.manual_seed(0)
    spirals = spiral_indices(HEX_FACES, 7, length=9, vertices=HEX_VERTICES)
    index = torch.where(spiral_mask(spirals), spirals, 7)  # padded slots -> the zero row 7
    rows = torch.randn(8, 2, 5, dtype=torch.float64)
    rows[7] = 0.0
    rows.requires_grad_(True)
    w = torch.randn(4, 9 * 2, dtype=torch.float64, requires_grad=True)
    monkeypatch.setattr(spiral_module, "CHUNK_NUMBERS", 40)
    assert len(spiral_module._chunks(7, 9 * 2 * 5)) == 7  # 90 numbers per vertex > 40: one vertex per chunk
    assert torch.autograd.gradcheck(SpiralLinear.apply, (rows, index, w))
    # Against a gather written with plain indexing: h[v, :, n] = W @ stack_l rows[index[v, l], :, n]
    expect = torch.stack([w @ rows[index[v]].reshape(-1, 5) for v in range(7)])
    torch.testing.assert_close(SpiralLinear.apply(rows, index, w), expect)
    conv = SpiralConv3D(2, 3, spirals, delta=2).double()
    x = torch.randn(1, 4, 7, 2, dtype=torch.float64)
    torch.testing.assert_close(conv(x), _dense_reference(conv, x))  # many chunks, same result


def test_spiral_conv_output_follows_a_relabelling():
    """Eq. 3 on relabelled vertices (reading: label-free spiral starts): the relabelled layer's output, mapped back,
    equals eq. 3 written out with loops (``_dense_reference``) on the original labels."""
    torch.manual_seed(0)
    perm = np.random.default_rng(1).permutation(16)  # old vertex i becomes perm[i]
    new_vertices = np.empty_like(GRID_VERTICES)
    new_vertices[perm] = GRID_VERTICES
    old = SpiralConv3D(2, 3, spiral_indices(GRID_FACES, 16, length=9, vertices=GRID_VERTICES))
    new = SpiralConv3D(2, 3, spiral_indices(perm[GRID_FACES], 16, length=9, vertices=new_vertices))
    with torch.no_grad():
        new.weight.copy_(old.weight)
        new.bias.copy_(old.bias)
    x = torch.randn(2, 4, 16, 2)
    x_new = torch.empty_like(x)
    x_new[:, :, perm] = x  # the same features under the new ids
    want = _dense_reference(old, x).detach()  # eq. 3's loops, not the package's layer
    torch.testing.assert_close(old(x), want, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(new(x_new)[:, :, perm], want, atol=1e-5, rtol=1e-5)
