"""SpiralConv3D of EmoFace (Liu et al., section 3.2, eqs. 1-3): spiral sequences on a triangle mesh and a
spatio-temporal convolution over (spiral x past frames).

**Space (eq. 1).** The rings around a vertex v, and its k-disk::

    0-ring(v) = {v},   (k+1)-ring(v) = N(k-ring(v)) \\ k-disk(v),   k-disk(v) = U_{i=0..k} i-ring(v)      (eq. 1)

where N(S) is every vertex joined by an edge to a vertex of S. A *spiral* lists the k-disk in a fixed order
(SpiralNet++, Gong et al. 2019): the centre, its one-ring in cyclic order, then each next ring continuing from
where the previous one ended. ``spiral_indices`` builds one per vertex, of one length L for all:

- **Cyclic order** follows the faces' orientation: around v, face (v, a, b) means "after a comes b".
- **Starting point** of the one-ring (reading taken; SpiralNet++ starts wherever its mesh library's circulator
  starts, which depends on the vertex labels). Interior vertex with ``vertices`` given: the highest neighbour
  (largest y, ties by z, then x, compared to 1e-9 of the mesh size; y is up in this package), so slot 1 means
  "the neighbour above" everywhere and the spirals do not depend on how the vertices are numbered. Boundary
  vertex: the first neighbour of its open fan (also label-free). Without ``vertices``: the lowest-index
  neighbour (label-dependent; only the rings' *sets* are then independent of the labels).
- **Next rings.** For each vertex u of the last ring, in spiral order, walk u's cyclic one-ring starting just
  after its neighbour that entered the spiral last, and append every neighbour not yet in the spiral. On a
  regular patch this is SpiralNet++'s order; it is defined the same way at irregular and boundary vertices.
- **Fixed length** (``length``, SpiralNet++'s truncated spiral, the paper's "kernel size" 5/9/18 of Table 4):
  the first ``length x dilation`` entries, every ``dilation``-th kept. Or ``rings=k``: the whole k-disk of the
  paper's text, padded to the largest disk. **Fallback where rings run out** (a mesh component smaller than
  the spiral, or a small disk in ``rings`` mode): the remaining slots repeat the centre index, and
  ``spiral_mask`` marks them so ``SpiralConv3D`` reads zeros there (zero padding, as a CNN at an image
  border). SpiralNet++ fills them with the nearest vertices in space instead; we keep the graph neighbourhood.
  Boundaries (FLAME's open mouth and eye holes) need no fallback: their rings are shorter, so the spiral simply
  reaches one ring further. The package's template head is closed (the mouth bag seals the lip slit); remove
  the bag faces to see an open slit (notebook 13).

**Time (eq. 2).** Vertex i at frame t sees the same vertex over the last delta frames, {V_{t-delta+1,i}, ...,
V_{t,i}}, causal; before the first frame ``Pad(delta - t)`` is zeros (``time_pad="zeros"``) or the first frame.

**Eq. 3.** SpiralConv3D(v) = W f(cnt_delta(k-disk(v))) + b: the features of the delta x L neighbours concatenated
(oldest frame first, then spiral order, then channels), W of shape (C_out, delta L C_in), computed as a gather, one
matmul and a shifted sum over frames (never the whole neighbourhood tensor; docs/design-notes.md, "SpiralConv3D").
Layout (B, T, V, C); the paper's defaults (Table 4): spiral length 18, dilation 2, delta = 3 frames.
"""
from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn as nn
from torch import Tensor

__all__ = ["PAPER_SPIRAL_LENGTH", "PAPER_DILATION", "PAPER_DELTA", "one_ring_order", "k_rings", "spiral_indices",
           "spiral_mask", "spiral_ring_index", "temporal_neighbourhood", "SpiralLinear", "SpiralConv3D"]

PAPER_SPIRAL_LENGTH, PAPER_DILATION, PAPER_DELTA = 18, 2, 3  # Table 4, adopted row: kernel 18, dilation 2, 3 frames


def _check_faces(faces, n_vertices: int) -> np.ndarray:
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or f.dtype.kind not in "iu":
        raise ValueError(f"faces: expected integer triangles (F, 3), got {f.dtype} {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= n_vertices):
        raise ValueError(f"faces: indices span [{f.min()}, {f.max()}], outside [0, {n_vertices}) vertices")
    bad = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    if bad.any():
        raise ValueError(f"faces: triangle {int(np.nonzero(bad)[0][0])} {f[bad][0].tolist()} repeats a vertex")
    return f.astype(np.int64)


def one_ring_order(faces, n_vertices: int, vertices=None) -> tuple[list[list[int]], np.ndarray]:
    """Every vertex's one-ring in the faces' cyclic order, rotated to its starting point (module docstring).

    Returns (rings, boundary): ``rings[v]`` lists v's neighbours; ``boundary[v]`` is True where the fan is open.
    Raises ValueError for a directed edge used twice (inconsistent orientation or an edge in > 2 triangles).
    """
    f = _check_faces(faces, n_vertices)
    succ: list[dict[int, int]] = [dict() for _ in range(n_vertices)]  # around v: neighbour a -> next neighbour b
    for a, b, c in f.tolist():
        for v, x, y in ((a, b, c), (b, c, a), (c, a, b)):
            if x in succ[v]:
                raise ValueError(f"faces: directed edge ({v}, {x}) appears in two triangles (inconsistent "
                                 "orientation or an edge shared by more than two triangles)")
            succ[v][x] = y
    pos = None if vertices is None else np.asarray(vertices, dtype=np.float64)
    if pos is not None and pos.shape != (n_vertices, 3):
        raise ValueError(f"vertices: expected shape ({n_vertices}, 3), got {pos.shape}")
    if pos is not None:  # compare positions to 1e-9 of the mesh size: mirror-image neighbours tie exactly
        pos = np.round(pos / max(float(np.abs(pos).max(initial=0.0)), 1e-30), 9)
    rings, boundary = [], np.zeros(n_vertices, dtype=bool)
    for v in range(n_vertices):
        nxt = succ[v]
        has_pred = set(nxt.values())
        starts = [x for x in nxt if x not in has_pred]  # open fans start at a neighbour nothing precedes
        boundary[v] = bool(starts)
        fans, seen = [], set()
        for s in sorted(starts, key=lambda x: _key(x, pos)) + sorted(nxt, key=lambda x: _key(x, pos)):
            if s in seen:
                continue
            fan, x = [], s
            while x is not None and x not in seen:  # follow the fan until it closes or ends
                seen.add(x)
                fan.append(x)
                x = nxt.get(x)
            fans.append(fan)
        ring = [x for fan in fans for x in fan]
        if not boundary[v] and len(fans) == 1 and ring:  # closed fan: rotate to the starting neighbour
            i = ring.index(min(ring, key=lambda x: _key(x, pos)))
            ring = ring[i:] + ring[:i]
        rings.append(ring)
    return rings, boundary


def _key(x: int, pos: np.ndarray | None):
    """Sort key of a starting neighbour: highest first (then front-most, then +x), else the lowest index."""
    if pos is None:
        return (x,)
    return (-pos[x, 1], -pos[x, 2], -pos[x, 0], x)


def k_rings(faces, n_vertices: int, centre: int, k: int) -> list[list[int]]:
    """Eq. 1 literally: the rings 0..k of ``centre`` as sorted vertex lists (breadth-first over the edges)."""
    f = _check_faces(faces, n_vertices)
    if not 0 <= centre < n_vertices:
        raise ValueError(f"centre {centre} outside [0, {n_vertices})")
    adj: list[set[int]] = [set() for _ in range(n_vertices)]
    for a, b, c in f.tolist():
        adj[a] |= {b, c}
        adj[b] |= {a, c}
        adj[c] |= {a, b}
    rings, disk = [[centre]], {centre}
    for _ in range(k):
        nxt = {u for v in rings[-1] for u in adj[v]} - disk  # N(k-ring) \ k-disk
        disk |= nxt
        rings.append(sorted(nxt))
    return rings


def _spiral(v: int, rings: list[list[int]], need: int | None, max_ring: int | None) -> list[int]:
    """One spiral: centre, one-ring from its start, then each next ring continuing from the previous one."""
    if max_ring == 0:
        return [v]
    order = {v: 0}
    spiral, ring = [v], []
    for u in rings[v]:
        order[u] = len(spiral)
        spiral.append(u)
        ring.append(u)
    k = 1
    while ring and (need is None or len(spiral) < need) and (max_ring is None or k < max_ring):
        new = []
        for u in ring:
            nb = rings[u]
            if not nb:
                continue
            last = max(range(len(nb)), key=lambda i: order.get(nb[i], -1))  # the neighbour that entered last
            for w in nb[last + 1:] + nb[:last + 1]:
                if w not in order:
                    order[w] = len(spiral)
                    spiral.append(w)
                    new.append(w)
        ring, k = new, k + 1
    return spiral


def spiral_indices(faces, n_vertices: int, length: int | None = None, rings: int | None = None,
                   dilation: int = 1, vertices=None) -> Tensor:
    """Spiral sequences (V, L) LongTensor: row v = centre v, its one-ring in cyclic order, the next rings, ...

    Exactly one of ``length`` (L entries, SpiralNet++'s truncated spiral) or ``rings`` (the whole k-disk of eq. 1,
    L = the largest disk) is given. ``dilation`` keeps every d-th of the first L x d entries (SpiralNet++'s
    dilated spiral). Slots past the end of a too-small neighbourhood repeat the centre (see ``spiral_mask``).
    ``vertices`` (V, 3) makes the starting point geometric and the result independent of the vertex labels.
    """
    if (length is None) == (rings is None):
        raise ValueError("spiral_indices: give exactly one of length= or rings=")
    if length is not None and length < 1:
        raise ValueError(f"spiral_indices: length must be >= 1, got {length}")
    if rings is not None and rings < 0:
        raise ValueError(f"spiral_indices: rings must be >= 0, got {rings}")
    if dilation < 1:
        raise ValueError(f"spiral_indices: dilation must be >= 1, got {dilation}")
    order, _ = one_ring_order(faces, n_vertices, vertices)
    need = None if length is None else length * dilation
    seqs = []
    for v in range(n_vertices):
        s = _spiral(v, order, need, rings)
        seqs.append((s if need is None else s[:need])[::dilation])
    width = length if length is not None else max(len(s) for s in seqs)
    out = np.empty((n_vertices, width), dtype=np.int64)
    for v, s in enumerate(seqs):
        out[v, :len(s)] = s
        out[v, len(s):] = v  # fallback: repeat the centre; spiral_mask marks these slots
    return torch.from_numpy(out)


def spiral_mask(spirals: Tensor) -> Tensor:
    """(V, L) bool: True at real spiral entries, False at padded slots (a repeat of the centre after slot 0)."""
    centre = torch.arange(spirals.shape[0], device=spirals.device)[:, None]
    mask = spirals != centre
    mask[:, 0] = True
    return mask


def spiral_ring_index(spirals: Tensor, faces, n_vertices: int, centre: int) -> np.ndarray:
    """Ring number (graph distance from the centre) of each entry of ``spirals[centre]``; -1 at padded slots."""
    row = spirals[centre].tolist()
    rings = k_rings(faces, n_vertices, centre, len(row))
    dist = {u: k for k, ring in enumerate(rings) for u in ring}
    mask = [True] + [u != centre for u in row[1:]]  # as spiral_mask
    return np.array([dist[u] if m else -1 for u, m in zip(row, mask)], dtype=np.int64)


def temporal_neighbourhood(x: Tensor, delta: int, pad: str = "zeros") -> Tensor:
    """Eq. 2: (B, T, ...) -> (B, T, delta, ...), slot j = frame t - (delta - 1) + j (oldest first), causal."""
    if delta < 1:
        raise ValueError(f"delta must be >= 1, got {delta}")
    if pad not in ("zeros", "replicate"):
        raise ValueError(f"time pad must be 'zeros' or 'replicate', got {pad!r}")
    T = x.shape[1]
    first = x[:, :1] if pad == "replicate" else torch.zeros_like(x[:, :1])
    xp = torch.cat([first.expand(-1, delta - 1, *x.shape[2:]), x], dim=1)  # (B, T + delta - 1, ...) Pad(delta - t)
    return torch.stack([xp[:, j:j + T] for j in range(delta)], dim=2)


class SpiralLinear(torch.autograd.Function):
    """h[v, :, n] = W g_v[:, n], g_v = the features of spiral(v) stacked (L C_in): the spatial half of eq. 3.

    x_rows (V + 1, C_in, N): the vertices' features, channels before the N = B T frames, plus a zero row (index
    V) that padded spiral slots point to; index (V, L); w (D, L C_in) -> (V, D, N). Vertices are processed in
    chunks and the gathered (chunk, L C_in, N) block is recomputed in backward instead of stored: memory stays
    O(V D N + chunk L C_in N), not O(V L C_in N) (the gathered tensor is 18x the input at L = 18).
    """

    @staticmethod
    def forward(ctx, x_rows: Tensor, index: Tensor, w: Tensor) -> Tensor:
        V, L = index.shape
        N = x_rows.shape[-1]
        out = x_rows.new_empty(V, w.shape[0], N)  # (V, D, N)
        for v0, v1 in _chunks(V, L * x_rows.shape[1] * N):
            g = x_rows.index_select(0, index[v0:v1].reshape(-1)).view(v1 - v0, -1, N)  # (v, L*C, N)
            torch.matmul(w, g, out=out[v0:v1])
        ctx.save_for_backward(x_rows, index, w)
        return out

    @staticmethod
    def backward(ctx, grad_out: Tensor):
        x_rows, index, w = ctx.saved_tensors
        V, L = index.shape
        C, N = x_rows.shape[1], x_rows.shape[2]
        grad_x = torch.zeros_like(x_rows) if ctx.needs_input_grad[0] else None
        grad_w = torch.zeros_like(w) if ctx.needs_input_grad[2] else None
        for v0, v1 in _chunks(V, L * C * N):
            go = grad_out[v0:v1]  # (v, D, N)
            if grad_w is not None:
                g = x_rows.index_select(0, index[v0:v1].reshape(-1)).view(v1 - v0, -1, N)  # recomputed
                grad_w += torch.matmul(go, g.transpose(1, 2)).sum(0)  # (D, L*C)
            if grad_x is not None:
                gg = torch.matmul(w.t(), go)  # (v, L*C, N)
                grad_x.index_add_(0, index[v0:v1].reshape(-1), gg.view(-1, C, N))
        return grad_x, None, grad_w


CHUNK_NUMBERS = 1 << 18  # numbers in one gathered block (1 MB in float32: cache-sized; measured best on 1 core)


def _chunks(n_vertices: int, per_vertex: int):
    """Vertex ranges whose gathered block holds about ``CHUNK_NUMBERS`` numbers."""
    step = max(1, CHUNK_NUMBERS // max(per_vertex, 1))
    return [(v0, min(v0 + step, n_vertices)) for v0 in range(0, n_vertices, step)]


class SpiralConv3D(nn.Module):
    """Eq. 3: out[b, t, v] = W [f(frame t-delta+1 .. t, vertices spirals[v])] + b; (B, T, V, C_in) -> (B, T, V, C_out).

    ``weight`` has shape (C_out, delta, L, C_in): slot j of the delta axis is frame t - (delta - 1) + j.
    Causal in time; padded spiral slots (``spiral_mask``) read zeros.
    """

    def __init__(self, in_channels: int, out_channels: int, spirals: Tensor, delta: int = PAPER_DELTA,
                 time_pad: str = "zeros"):
        super().__init__()
        spirals = torch.as_tensor(spirals, device=spirals.device if torch.is_tensor(spirals) else "cpu")
        if spirals.ndim != 2 or spirals.dtype != torch.int64:
            raise ValueError(f"spirals: expected a (V, L) LongTensor, got {spirals.dtype} {tuple(spirals.shape)}")
        if spirals.numel() and (spirals.min() < 0 or spirals.max() >= spirals.shape[0]):
            raise ValueError(f"spirals: indices span [{int(spirals.min())}, {int(spirals.max())}], outside "
                             f"[0, {spirals.shape[0]}) vertices")
        if delta < 1 or time_pad not in ("zeros", "replicate"):
            raise ValueError(f"SpiralConv3D: need delta >= 1 and time_pad 'zeros'/'replicate', got {delta}, "
                             f"{time_pad!r}")
        self.in_channels, self.out_channels, self.delta, self.time_pad = in_channels, out_channels, delta, time_pad
        self.register_buffer("spirals", spirals.clone())
        length = spirals.shape[1]
        self.weight = nn.Parameter(torch.empty(out_channels, delta, length, in_channels))  # W
        self.bias = nn.Parameter(torch.empty(out_channels))  # b
        bound = 1.0 / math.sqrt(delta * length * in_channels)  # nn.Linear's init for fan_in = delta L C_in
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.uniform_(self.bias, -bound, bound)

    @property
    def n_vertices(self) -> int:
        return self.spirals.shape[0]

    def extra_repr(self) -> str:
        return (f"{self.in_channels}, {self.out_channels}, vertices={self.n_vertices}, "
                f"spiral_length={self.spirals.shape[1]}, delta={self.delta}, time_pad={self.time_pad!r}")

    def gather(self, x: Tensor) -> Tensor:
        """f(k-disk(v)) for every vertex: (B, T, V, C) -> (B, T, V, L, C), padded slots zeroed."""
        B, T, V, C = x.shape
        g = x.index_select(2, self.spirals.reshape(-1)).view(B, T, V, -1, C)  # (B, T, V, L, C)
        return g * spiral_mask(self.spirals)[:, :, None].to(x.dtype)

    def forward(self, x: Tensor) -> Tensor:
        if x.ndim != 4 or x.shape[2] != self.n_vertices or x.shape[3] != self.in_channels:
            raise ValueError(f"SpiralConv3D: expected input (B, T, {self.n_vertices}, {self.in_channels}), "
                             f"got {tuple(x.shape)}")
        B, T, V, C = x.shape
        rows = x.permute(2, 3, 0, 1).reshape(V, C, B * T)  # (V, C_in, N): one row per vertex
        rows = torch.cat([rows, rows.new_zeros(1, C, B * T)])  # (V + 1, C_in, N): row V = zeros for padding
        index = torch.where(spiral_mask(self.spirals), self.spirals, V)  # (V, L): padded slots -> zero row
        w = self.weight.permute(1, 0, 2, 3).reshape(self.delta * self.out_channels, -1)  # (delta*C_out, L*C_in)
        h = SpiralLinear.apply(rows, index, w)  # (V, delta*C_out, N): W_j f(k-disk(v)) for every frame
        h = h.view(V, self.delta, self.out_channels, B, T)  # (V, delta, C_out, B, T)
        first = h[..., :1] if self.time_pad == "replicate" else torch.zeros_like(h[..., :1])
        hp = torch.cat([first.expand(-1, -1, -1, -1, self.delta - 1), h], dim=-1)  # Pad(delta - t): T+delta-1 frames
        out = sum(hp[:, j, :, :, j:j + T] for j in range(self.delta))  # (V, C_out, B, T): frame t-(delta-1)+j via W_j
        return out.permute(2, 3, 0, 1) + self.bias  # (B, T, V, C_out)
