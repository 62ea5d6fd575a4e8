"""The template head: a procedural, left/right-symmetric triangle mesh with a mouth slit, eyelids and brows.

Coordinates: metres, y up, the face looks towards +z, x points to the subject's left (FaceFormer/VOCASET).

Construction, in four steps (``build_template``):

1. **Rings.** The head is a stack of ``n_rows`` horizontal rings (plus a pole at the top and one under the
   neck). A ring at height ``y`` has half axes ``a(y) = a s(y) t(y)`` (x) and ``c(y) = c s(y)``
   (z), where ``s(y) = (1 - |y/b|^p)^(1/p)`` is a super-ellipse profile (``p = 2.6``, fuller than an ellipse)
   and ``t(y)`` narrows the lower face from the nose down to the jaw (``FaceShape.jaw_width``).
   Vertex ``(row r, column j)`` sits at ``(a(y_r) sin th_j, y_r, c(y_r) (1 - |sin th_j|^(2/q))^(q/2))`` (z signed
   like ``cos th_j``): the rings are super-ellipses ``|x/a|^(2/q) + |z/c|^(2/q) = 1`` with ``q = 0.75``, so the face
   is flatter than an egg.
2. **Anchored sampling.** Rows and columns are spaced densely on the face and sparsely on the scalp: some
   row indices are *anchors* pinned to facial landmarks (chin, mouth line, nose tip, lower lid, eye line,
   brow, hairline) and some column indices to angles (mouth corner, outer eye corner, ear). Heights/angles
   are interpolated between anchors. Because anchors are fixed *indices*, every speaker's head has the same
   topology (same faces, same regions): only the positions change.
3. **Mouth slit.** The row at the mouth line is duplicated between the two mouth corners: the original
   vertices form the *upper-lip* row, the copies the *lower-lip* row, and no triangle joins them. The lips
   can therefore part; at rest they are ``lip_gap`` (~2 mm) apart at the middle and meet at the corners.
   Behind the lips a small *mouth bag* (two loops and a centre vertex) closes the surface: the head is
   watertight, and an open mouth shows a pocket instead of the inside of the skull.
4. **Features.** Gaussian bumps and dents, pushed along +z and faded out towards the sides: nose (bridge,
   tip, wings), eye sockets with eyeballs, brow ridge, cheekbones, lips, the groove under the lower lip
   and the chin.

Named vertex regions (``TemplateMesh.regions``) are computed once on the *canonical* head (default
``FaceShape``), so they are the same index sets for every speaker; see ``REGION_NAMES``.

Summary: ``build_template(shape, n_vertices)`` -> ``TemplateMesh`` (vertices, faces, regions, lip midpoints,
landmarks, slit); ``lip_distance`` measures the mouth opening in metres.

Exercises: (1) plot ``vertices[regions["lips"]]`` over a front view; (2) raise ``n_vertices`` to 3000 and
check that the regions still sit in the same places; (3) make a long-nosed speaker with ``nose_depth``.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

__all__ = ["FaceShape", "TemplateMesh", "REGION_NAMES", "build_template", "grid_size", "lip_distance",
           "vertex_normals"]

# The default grid: 34 rings x 44 columns + 2 poles + 11 lower-lip copies + 49 mouth-bag vertices = 1558.
BASE_VERTICES, BASE_ROWS, BASE_HALF_COLS = 1500, 34, 22
# Anchor rows on the default 34-row grid (rescaled for other resolutions): index -> landmark.
_ROW_ANCHORS = (("bottom", 0), ("chin", 3), ("mouth", 12), ("nose", 17), ("lower_lid", 20), ("eye", 23),
                ("brow", 27), ("hair", 30), ("top", 33))
# Anchor columns on the default half ring of 22 columns (0 = front, 22 = back).
_COL_ANCHORS = (("front", 0), ("corner", 6), ("eye_out", 10), ("ear", 15), ("back", 22))
_PROFILE_P = 2.6  # super-ellipse exponent of the vertical head profile
_RING_Q = 0.75    # super-ellipse exponent of the rings (< 1: a flatter face than an ellipse)

REGION_NAMES = ("upper_lip", "lower_lip", "mouth_corners", "lips", "mouth", "mouth_interior", "jaw", "cheeks", "nose",
                "eyes", "brows", "forehead", "upper_face", "eyes_forehead", "face")


@dataclass(frozen=True)
class FaceShape:
    """Proportions of one head, metres (the defaults are an average adult). Heights are relative to the
    centre of the head ellipsoid; the derived landmark heights are the ``y_*`` properties."""

    head_width: float = 0.150     # 2a: ear to ear at eye level
    head_height: float = 0.230    # 2b: crown to the bottom of the (virtual) head ellipsoid
    head_depth: float = 0.190     # 2c: nose root to back of the head, without features
    eye_height: float = 0.010     # eye line above the head centre
    eye_spacing: float = 0.062    # between the pupils
    eye_width: float = 0.028      # corner to corner of one eye
    brow_height: float = 0.020    # brow above the eye line
    nose_length: float = 0.040    # eye line down to the nose tip
    nose_depth: float = 0.020     # how far the tip sticks out
    philtrum: float = 0.022       # nose tip down to the mouth line
    mouth_width: float = 0.050    # corner to corner
    lip_thickness: float = 0.009  # height of the upper lip (the lower lip is 1.15x)
    lip_fullness: float = 0.006   # how far the lips stick out
    lip_gap: float = 0.002        # rest gap between the middle lip vertices
    jaw_length: float = 0.040     # mouth line down to the chin
    jaw_width: float = 0.80       # width of the jaw relative to the upper head
    chin_depth: float = 0.012     # how far the chin sticks out

    @property
    def a(self) -> float:
        return self.head_width / 2

    @property
    def b(self) -> float:
        return self.head_height / 2

    @property
    def c(self) -> float:
        return self.head_depth / 2

    @property
    def y_eye(self) -> float:
        return self.eye_height

    @property
    def y_brow(self) -> float:
        return self.eye_height + self.brow_height

    @property
    def y_nose(self) -> float:
        return self.eye_height - self.nose_length

    @property
    def y_mouth(self) -> float:
        return self.y_nose - self.philtrum

    @property
    def y_chin(self) -> float:
        return self.y_mouth - self.jaw_length

    @property
    def y_bottom(self) -> float:
        return max(self.y_chin - 0.012, -0.95 * self.b)

    @property
    def y_hair(self) -> float:
        return self.y_brow + 0.035

    @property
    def x_eye(self) -> float:
        return self.eye_spacing / 2

    @property
    def x_corner(self) -> float:
        return self.mouth_width / 2

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class TemplateMesh:
    """A head: vertices (V, 3) float32 metres, faces (F, 3) int64, named regions and rig landmarks.

    ``slit`` (2, S): indices of the upper-lip row (``slit[0]``) and of the lower-lip row (``slit[1]``), pairwise
    facing each other across the mouth opening; ``lip_midpoints = (slit[0][S//2], slit[1][S//2])``.
    ``landmarks``: heights/offsets (floats, metres) the rig builds its deformations from.
    ``grid``: per-vertex ``row``, ``col`` (signed, 0 = front midline) and ``side`` (+1 upper lip row,
    -1 lower lip row, 2/3/4 outer loop/inner loop/centre of the mouth bag, 0 elsewhere) of the construction grid.
    """

    vertices: np.ndarray
    faces: np.ndarray
    regions: dict[str, np.ndarray]
    lip_midpoints: tuple[int, int]
    slit: np.ndarray
    landmarks: dict[str, float]
    grid: dict[str, np.ndarray]
    shape: FaceShape

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    def to_trimesh(self) -> "trimesh.Trimesh":  # noqa: F821
        """The mesh as ``trimesh.Trimesh`` (``process=False``: vertex order and duplicates are kept)."""
        import trimesh  # lazy: importing trimesh costs ~1 s, and loading a corpus does not need it

        return trimesh.Trimesh(self.vertices.astype(np.float64), self.faces, process=False)

    @property
    def vertex_neighbors(self) -> list[list[int]]:
        """1-ring neighbours of every vertex (for k-ring spirals, Laplacians ...)."""
        return self.to_trimesh().vertex_neighbors


# ------------------------------------------------------------------------------------------ helpers
def smoothstep(edge0: float, edge1: float, x):
    """0 at ``edge0``, 1 at ``edge1`` (either order), cubic in between; exactly 0/1 outside."""
    t = np.clip((np.asarray(x, dtype=np.float64) - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def cosine_falloff(d, radius: float):
    """Raised cosine: 1 at d = 0, 0 for d >= radius (smooth, compact support)."""
    d = np.abs(np.asarray(d, dtype=np.float64)) / radius
    return np.where(d < 1.0, 0.5 * (1.0 + np.cos(np.pi * np.minimum(d, 1.0))), 0.0)


def _gauss(x, y, x0, y0, sx, sy):
    return np.exp(-0.5 * (((x - x0) / sx) ** 2 + ((y - y0) / sy) ** 2))


def grid_size(n_vertices: int = BASE_VERTICES) -> tuple[int, int]:
    """(rings, columns per ring) for about ``n_vertices`` vertices; the count grows like the square. Never fewer
    than 24 rings of 32 columns (810 vertices in all, ``generate --vertices`` says so): the coarsest grid."""
    scale = float(np.sqrt(n_vertices / BASE_VERTICES))
    n_rows = max(24, int(round(BASE_ROWS * scale)))
    half = max(16, int(round(BASE_HALF_COLS * scale)))
    return n_rows, 2 * half


def _anchor_indices(anchors, base_last: int, last: int) -> dict[str, int]:
    idx = {name: int(round(i * last / base_last)) for name, i in anchors}
    values = list(idx.values())
    assert all(b > a for a, b in zip(values, values[1:])), f"grid too coarse for its anchors: {idx}"
    return idx


def _profile(y, shape: FaceShape):
    """Ring half axes (a(y), c(y)) of the head at height y."""
    s = (1.0 - np.abs(y / shape.b) ** _PROFILE_P) ** (1.0 / _PROFILE_P)
    taper = 1.0 - (1.0 - shape.jaw_width) * smoothstep(shape.y_nose, shape.y_chin, y)
    return shape.a * s * taper, shape.c * s


# ------------------------------------------------------------------------------------------ geometry
def _rows(shape: FaceShape, n_rows: int) -> tuple[np.ndarray, dict[str, int]]:
    """Ring heights (n_rows,), interpolated in elevation angle between the anchor rows."""
    rows = _anchor_indices(_ROW_ANCHORS, BASE_ROWS - 1, n_rows - 1)
    y_of = {"bottom": shape.y_bottom, "chin": shape.y_chin, "mouth": shape.y_mouth, "nose": shape.y_nose,
            "lower_lid": shape.y_eye - 0.012, "eye": shape.y_eye, "brow": shape.y_brow, "hair": shape.y_hair,
            "top": shape.b * np.sin(np.radians(80.0))}
    phi = np.arcsin(np.array([y_of[k] for k in rows]) / shape.b)
    y = shape.b * np.sin(np.interp(np.arange(n_rows), list(rows.values()), phi))
    y[rows["mouth"]] = shape.y_mouth  # exactly on the mouth line
    return y, rows


def _columns(shape: FaceShape, half: int) -> tuple[np.ndarray, dict[str, int]]:
    """Ring angles (half + 1,) from the front (0) to the back (pi) of one half ring; x = a(y) sin(angle)."""
    cols = _anchor_indices(_COL_ANCHORS, BASE_HALF_COLS, half)
    a_mouth, _ = _profile(shape.y_mouth, shape)
    a_eye, _ = _profile(shape.y_eye, shape)
    u_eye = min(0.95, (shape.x_eye + 0.6 * shape.eye_width) / a_eye)
    th_of = {"front": 0.0, "corner": np.arcsin(shape.x_corner / a_mouth), "eye_out": np.arcsin(u_eye),
             "ear": np.radians(95.0), "back": np.pi}
    th = np.interp(np.arange(half + 1), list(cols.values()), [th_of[k] for k in cols])
    return th, cols


def _features(x, y, front, shape: FaceShape):
    """Forward (+z) offsets of the facial features at base positions (x, y); ``front`` fades them out."""
    s = shape
    ax = np.abs(x)
    dz = np.zeros_like(x)
    # Nose: a ridge from the nose root down to the tip (rising like t^1.5), then a fast fall under the tip.
    y_root = s.y_brow - 0.006
    t = np.clip((y_root - y) / (y_root - s.y_nose), 0.0, 1.0)
    ridge = np.where(y >= s.y_nose, 0.25 + 0.75 * t ** 1.5, np.exp(-(((y - s.y_nose) / 0.006) ** 2)))
    ridge = np.where(y > y_root, 0.25 * np.exp(-(((y - y_root) / 0.008) ** 2)), ridge)
    width = 0.006 + 0.006 * t
    dz += s.nose_depth * ridge * np.exp(-0.5 * (x / width) ** 2)
    dz += 0.2 * s.nose_depth * _gauss(ax, y, 0.015, s.y_nose - 0.001, 0.005, 0.005)       # nose wings
    # Eyes: a socket and an eyeball in it.
    dz -= 0.010 * _gauss(ax, y, s.x_eye, s.y_eye + 0.003, 0.017, 0.013)
    dz += 0.011 * _gauss(ax, y, s.x_eye, s.y_eye, 0.36 * s.eye_width, 0.006)
    # Brow ridge, cheekbones.
    dz += 0.005 * np.exp(-(((y - s.y_brow) / 0.007) ** 2)) * smoothstep(0.065, 0.045, ax)
    dz += 0.006 * _gauss(ax, y, s.x_eye + 0.012, s.y_nose + 0.004, 0.016, 0.014)
    # Lips (upper and lower bumps, fading towards the corners), the groove under the lower lip, the chin.
    lip_x = smoothstep(1.15 * s.x_corner, 0.4 * s.x_corner, ax)
    t_up, t_lo = s.lip_thickness, 1.15 * s.lip_thickness
    dz += s.lip_fullness * lip_x * np.exp(-(((y - s.y_mouth - 0.45 * t_up) / (0.55 * t_up)) ** 2))
    dz += s.lip_fullness * lip_x * np.exp(-(((y - s.y_mouth + 0.45 * t_lo) / (0.55 * t_lo)) ** 2))
    dz += 0.004 * _gauss(x, y, 0.0, s.y_mouth + t_up + 0.004, 0.012, 0.006)                # philtrum area
    dz -= 0.003 * _gauss(x, y, 0.0, s.y_mouth - t_lo - 0.004, 0.015, 0.004)                 # labiomental groove
    dz += s.chin_depth * _gauss(x, y, 0.0, s.y_chin + 0.010, 0.018, 0.011)
    return dz * front


def _build(shape: FaceShape, n_rows: int, n_cols: int) -> dict:
    """Vertices, faces and grid bookkeeping of one head (no regions), in the steps of the module docstring.

    The points grow in a dict of parallel arrays (x, y, z, row, col, side): the rings, the lower-lip copies, the
    two poles, then (after the features) the mouth bag; the last step reorders them so the jaw's vertices lead.
    """
    ring = _ring_grid(shape, n_rows, n_cols)                                        # steps 1-2
    pts = ring["points"]
    upper, lower = _cut_mouth_slit(pts, ring, shape)                                # step 3
    top, bottom = _append_points(pts, x=[0.0, 0.0], y=[shape.b, shape.y_bottom - 0.01], z=[0.0, -0.2 * shape.c],
                                 row=[n_rows, -1], col=[0, 0], side=[0, 0])        # crown, under the neck
    faces = _ring_faces(ring, lower, top, bottom)
    # Step 4: features, faded out towards the sides and the back of the head.
    x, z = pts["x"], pts["z"]
    front = smoothstep(0.15, 0.55, z / np.maximum(np.hypot(x / shape.a, z / shape.c) * shape.c, 1e-9))
    pts["z"] = z + _features(x, pts["y"], front, shape)
    bag, bag_faces = _add_mouth_bag(pts, ring, upper, lower, shape)
    faces = np.concatenate([faces, bag_faces])
    # Store the vertices ring by ring from the neck up, the lower-lip copies and the mouth bag just before the
    # mouth ring: all the vertices the jaw moves then form one contiguous block at the start (rig.py relies on it).
    r_m, vid = ring["rows"]["mouth"], ring["vid"]
    order = np.concatenate([[bottom], vid[:r_m].ravel(), lower, *bag, vid[r_m:].ravel(), [top]])
    return _reordered(pts, faces, order, ring, upper, lower, shape)


def _append_points(pts: dict, **new) -> np.ndarray:
    """Append points (one sequence per array of ``pts``) in place; returns their indices."""
    start = len(pts["x"])
    for key, values in new.items():
        pts[key] = np.concatenate([pts[key], values])
    return np.arange(start, start + len(new["x"]))


def _ring_grid(shape: FaceShape, n_rows: int, n_cols: int) -> dict:
    """Steps 1-2: the (n_rows, n_cols) grid of ring points, with the bookkeeping the later steps read.

    Returns ``points`` (x, y, z, row, col, side: flat arrays of n_rows * n_cols), ``vid`` (n_rows, n_cols)
    indices, the signed column ``col`` of each ring position (0, 1, .., half, -(half-1), .., -1), the angles
    ``th`` (n_cols,) and ``th_half`` (half + 1,), the anchor indices ``rows`` and ``cols``, and ``slit_pos``: the
    ring positions strictly between the mouth corners, ordered -x .. +x.
    """
    half = n_cols // 2
    y_r, rows = _rows(shape, n_rows)
    th_half, cols = _columns(shape, half)
    # Signed column of every ring position, going round from the front towards +x: 0, 1, .., half, -(half-1), .., -1.
    col = np.concatenate([np.arange(half + 1), -np.arange(half - 1, 0, -1)])      # (n_cols,)
    th = th_half[np.abs(col)]
    sin_th = np.sin(th) * np.sign(col)                                             # exact mirror image
    cos_th = np.sign(np.cos(th)) * (1.0 - np.sin(th) ** (2.0 / _RING_Q)) ** (_RING_Q / 2.0)
    a_r, c_r = _profile(y_r, shape)
    X = a_r[:, None] * sin_th[None, :]                                              # (n_rows, n_cols)
    Y = np.repeat(y_r[:, None], n_cols, axis=1)
    Z = c_r[:, None] * cos_th[None, :]
    slit_pos = np.nonzero(np.abs(col) < cols["corner"])[0]                          # the mouth ring's slit part
    slit_pos = slit_pos[np.argsort(col[slit_pos])]                                  # ordered -x .. +x
    points = {"x": X.ravel(), "y": Y.ravel(), "z": Z.ravel(), "row": np.repeat(np.arange(n_rows), n_cols),
              "col": np.tile(col, n_rows), "side": np.zeros(n_rows * n_cols, dtype=np.int64)}
    return {"points": points, "vid": np.arange(n_rows * n_cols).reshape(n_rows, n_cols), "col": col, "th": th,
            "th_half": th_half, "rows": rows, "cols": cols, "slit_pos": slit_pos}


def _cut_mouth_slit(pts: dict, ring: dict, shape: FaceShape) -> tuple[np.ndarray, np.ndarray]:
    """Step 3: duplicate the mouth ring between the corners; originals = upper lip (side 1), copies = lower (-1).

    The two rows part by ``lip_gap`` at the middle, ``lip_gap (1 - (th / th_corner)^2)``, and meet at the corners.
    Returns the indices of the upper-lip row and of its lower-lip copies, both ordered -x .. +x.
    """
    slit_pos, r_m, k_c = ring["slit_pos"], ring["rows"]["mouth"], ring["cols"]["corner"]
    upper = ring["vid"][r_m, slit_pos]
    gap = 0.5 * shape.lip_gap * (1.0 - (ring["th"][slit_pos] / ring["th_half"][k_c]) ** 2)  # half gap, 0 at corners
    lower = _append_points(pts, x=pts["x"][upper], y=pts["y"][upper] - gap, z=pts["z"][upper],
                           row=np.full(len(upper), r_m), col=pts["col"][upper], side=np.full(len(upper), -1))
    pts["y"][upper] += gap
    pts["side"][upper] = 1
    return upper, lower


def _ring_faces(ring: dict, lower: np.ndarray, top, bottom) -> np.ndarray:
    """Triangles (F, 3) of the rings and the two pole fans; the mouth slit stays open.

    Quads join ring r (bottom) and ring r+1 (top). Seen from above the mouth ring is the upper lip (originals);
    seen from below it is the lower lip (copies). No quad joins the two: the slit.
    """
    vid, col = ring["vid"], ring["col"]
    n_cols = len(col)
    top_ring = vid.copy()
    top_ring[ring["rows"]["mouth"], ring["slit_pos"]] = lower
    j0, j1 = np.arange(n_cols), (np.arange(n_cols) + 1) % n_cols
    a, b = vid[:-1][:, j0], vid[:-1][:, j1]                                          # (n_rows-1, n_cols)
    d, c = top_ring[1:][:, j0], top_ring[1:][:, j1]
    # Diagonal a-c on the +x half, its mirror image b-d on the -x half: the triangulation is symmetric too.
    right = np.broadcast_to((col[j0] >= 0) & (col[j1] > col[j0]), a.shape)[..., None]
    t1 = np.where(right, np.stack([a, b, c], -1), np.stack([a, b, d], -1))
    t2 = np.where(right, np.stack([a, c, d], -1), np.stack([b, c, d], -1))
    faces = [t1.reshape(-1, 3), t2.reshape(-1, 3)]
    faces.append(np.stack([vid[-1, j0], vid[-1, j1], np.full(n_cols, top)], -1))
    faces.append(np.stack([vid[0, j1], vid[0, j0], np.full(n_cols, bottom)], -1))
    return np.concatenate(faces).astype(np.int64)


def _add_mouth_bag(pts: dict, ring: dict, upper: np.ndarray, lower: np.ndarray,
                   shape: FaceShape) -> tuple[list, np.ndarray]:
    """The pocket behind the lips: two smaller loops (side 2, 3) and a centre vertex (side 4), and their faces.

    The loop runs round the slit (corner, upper lip, corner, lower lip backwards); the bag's loops shrink it to
    90% and 60% in x and sink it 6 and 16 mm, so the mesh is watertight and an open jaw shows the pocket, not
    the inside of the skull. Returns ``[loop, bag loop 1, bag loop 2, [centre]]`` indices and the new faces.
    """
    r_m, k_c = ring["rows"]["mouth"], ring["cols"]["corner"]
    x, z = pts["x"], pts["z"]
    pos = {int(cc): j for j, cc in enumerate(ring["col"])}
    loop = np.concatenate([[ring["vid"][r_m, pos[-k_c]]], upper, [ring["vid"][r_m, pos[k_c]]], lower[::-1]])
    half_sign = np.concatenate([[0.0], np.ones(len(upper)), [0.0], -np.ones(len(lower))])
    prof = np.clip(1.0 - (x[loop] / shape.x_corner) ** 2, 0.0, 1.0)
    n = len(loop)
    new = _append_points(pts, x=np.concatenate([0.9 * x[loop], 0.6 * x[loop], [0.0]]),
                         y=np.concatenate([shape.y_mouth + 0.004 * half_sign * prof,
                                           shape.y_mouth + 0.008 * half_sign * prof, [shape.y_mouth]]),
                         z=np.concatenate([z[loop] - 0.006, z[loop] - 0.016, [z[loop].mean() - 0.026]]),
                         row=np.full(2 * n + 1, r_m), col=np.concatenate([pts["col"][loop], pts["col"][loop], [0]]),
                         side=np.concatenate([np.full(n, 2), np.full(n, 3), [4]]))
    bag, centre = [new[:n], new[n:2 * n]], new[2 * n]
    i0 = np.arange(n)
    i1 = (i0 + 1) % n
    faces = []
    for A, B in ((loop, bag[0]), (bag[0], bag[1])):                                  # winding: reversed loop edges
        faces += [np.stack([A[i1], A[i0], B[i0]], -1), np.stack([A[i1], B[i0], B[i1]], -1)]
    faces.append(np.stack([bag[1][i1], bag[1][i0], np.full(n, centre)], -1))
    return [*bag, [centre]], np.concatenate(faces)

def _reordered(pts: dict, faces: np.ndarray, order: np.ndarray, ring: dict, upper: np.ndarray, lower: np.ndarray,
               shape: FaceShape) -> dict:
    """The head with its points stored in ``order`` (faces and slit renumbered), its landmarks and grid."""
    new = np.empty_like(order)
    new[order] = np.arange(len(order))
    theta = np.arctan2(np.abs(pts["x"]), pts["z"])                                   # 0 front .. pi back
    vertices = np.stack([pts["x"], pts["y"], pts["z"]], -1)[order]
    corner = ring["vid"][ring["rows"]["mouth"], ring["cols"]["corner"]]
    landmarks = {"y_eye": shape.y_eye, "x_eye": shape.x_eye, "eye_width": shape.eye_width, "y_brow": shape.y_brow,
                 "y_nose": shape.y_nose, "y_mouth": shape.y_mouth, "x_corner": shape.x_corner,
                 "y_chin": shape.y_chin, "y_hair": shape.y_hair, "lip_thickness": shape.lip_thickness,
                 "hinge_y": shape.y_nose + 0.004, "hinge_z": -0.08 * shape.c,
                 "th_corner": float(theta[corner]), "head_a": shape.a, "head_c": shape.c}
    grid = {"row": pts["row"][order], "col": pts["col"][order], "side": pts["side"][order], "theta": theta[order],
            "rows": ring["rows"], "cols": ring["cols"]}
    return {"vertices": vertices, "faces": new[faces], "slit": np.stack([new[upper], new[lower]]),
            "landmarks": landmarks, "grid": grid}


# ------------------------------------------------------------------------------------------ regions
def _regions(g: dict) -> dict[str, np.ndarray]:
    """Named vertex sets, from the canonical head's geometry (see the module docstring)."""
    v, L, side = g["vertices"], g["landmarks"], g["grid"]["side"]
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    ax, theta = np.abs(x), g["grid"]["theta"]
    col = np.abs(g["grid"]["col"])
    k_c = g["grid"]["cols"]["corner"]
    inner = side >= 2                                                                # the mouth bag
    front = (theta < np.radians(75.0)) & ~inner
    ym, tl, xc = L["y_mouth"], L["lip_thickness"], L["x_corner"]
    upper_side = (side == 1) | ((side != -1) & (y > ym))
    lower_side = (side == -1) | ((side != 1) & (y < ym))
    inside = (col < k_c) & front
    reg = {}
    reg["upper_lip"] = inside & upper_side & (y <= ym + tl)
    reg["lower_lip"] = inside & lower_side & (y >= ym - 1.15 * tl)
    reg["mouth_corners"] = (col == k_c) & (g["grid"]["row"] == g["grid"]["rows"]["mouth"]) & ~inner
    reg["lips"] = reg["upper_lip"] | reg["lower_lip"] | reg["mouth_corners"]
    reg["mouth"] = front & (((x / (1.45 * xc)) ** 2 + ((y - ym) / 0.021) ** 2) <= 1.0)
    reg["mouth_interior"] = inner
    reg["jaw"] = (theta < np.radians(100.0)) & (lower_side | reg["mouth_corners"]) & (y < ym + 0.002)
    reg["cheeks"] = front & (((ax - (xc + 0.020)) / 0.026) ** 2 + ((y - (ym + 0.016)) / 0.026) ** 2 <= 1.0)
    reg["nose"] = front & (ax < 0.022) & (y > L["y_nose"] - 0.010) & (y < L["y_brow"] - 0.004)
    ex, ey, ew = L["x_eye"], L["y_eye"], L["eye_width"]
    reg["eyes"] = front & ((((ax - ex) / (0.8 * ew)) ** 2 + ((y - ey) / 0.0135) ** 2) <= 1.0)
    reg["brows"] = front & (ax < 0.062) & (np.abs(y - L["y_brow"]) <= 0.0075)
    reg["forehead"] = front & (ax < 0.062) & (y > L["y_brow"] + 0.0075) & (y <= L["y_hair"] + 0.012)
    reg["eyes_forehead"] = reg["eyes"] | reg["brows"] | reg["forehead"]
    reg["upper_face"] = reg["eyes_forehead"] | (reg["nose"] & (y > L["y_nose"] + 0.012))
    reg["face"] = front & (y > L["y_chin"] - 0.012) & (y <= L["y_hair"] + 0.012)
    return {k: np.nonzero(reg[k])[0].astype(np.int64) for k in REGION_NAMES}


@lru_cache(maxsize=8)
def _canonical(n_rows: int, n_cols: int) -> dict:
    g = _build(FaceShape(), n_rows, n_cols)
    g["regions"] = _regions(g)
    return g


def build_template(shape: FaceShape | None = None, n_vertices: int = BASE_VERTICES) -> TemplateMesh:
    """The template head of ``shape`` (default: the canonical head) with about ``n_vertices`` vertices.

    Every shape at the same ``n_vertices`` shares the faces, regions and lip midpoints (only positions differ).
    """
    shape = FaceShape() if shape is None else shape
    n_rows, n_cols = grid_size(n_vertices)
    canon = _canonical(n_rows, n_cols)
    g = canon if shape == FaceShape() else _build(shape, n_rows, n_cols)
    vertices = g["vertices"].astype(np.float32)
    slit = canon["slit"]
    mid = slit.shape[1] // 2
    return TemplateMesh(vertices=vertices, faces=canon["faces"].copy(),
                        regions={k: v.copy() for k, v in canon["regions"].items()},
                        lip_midpoints=(int(slit[0, mid]), int(slit[1, mid])), slit=slit.copy(),
                        landmarks=dict(g["landmarks"]), grid=g["grid"], shape=shape)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (V, 3), unit length: the sum of the adjacent triangles' cross products."""
    v = np.asarray(vertices, dtype=np.float64)
    cross = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])  # (F, 3), |.| = 2 x area
    acc = np.zeros_like(v)
    for corner in range(3):
        np.add.at(acc, faces[:, corner], cross)
    return acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-12)


def lip_distance(vertices: np.ndarray, mesh: TemplateMesh) -> np.ndarray:
    """Distance (metres) between the upper- and lower-lip mid vertices: (T, V, 3) -> (T,), (V, 3) -> ()."""
    v = np.asarray(vertices)
    if v.ndim == 2 and v.shape[-1] != 3:                                           # (T, V*3) FaceFormer rows
        v = v.reshape(v.shape[0], -1, 3)
    up, lo = mesh.lip_midpoints
    return np.linalg.norm(v[..., up, :].astype(np.float64) - v[..., lo, :], axis=-1)
