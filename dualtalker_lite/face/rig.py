"""The face rig: 14 named controls -> vertex positions, vectorised over frames.

``vertices_t = closure(jaw(template + sum_c q_tc D_c, q_t,jaw_open), q_t,lip_press)``, where

* ``D_c`` (V, 3) are *blendshape deltas* in metres: a smooth, compactly supported weight map (raised-cosine
  or smoothstep falloff around a landmark) times a direction, e.g. ``blink`` pulls the upper lid down to
  the lower-lid line, ``smile_left`` moves the left mouth corner up and out. Weights are computed once on the
  canonical head (so they are the same for every speaker), directions and sizes on the speaker's own head.
* ``jaw`` is **nonlinear**: the lower face rotates about a horizontal hinge axis (x direction, near the
  ears) by ``angle = jaw_open * JAW_MAX_ANGLE``, blended per vertex (linear blend skinning with one bone):
  ``p' = p + w_jaw (R(angle) (p - hinge) - (p - hinge))``. Vertices with ``w_jaw = 1`` (lower lip, chin)
  move on circles about the hinge; the weight falls to 0 at the upper lip, smoothly towards the ears.
* ``closure`` is **nonlinear** too: ``lip_press = p`` moves every upper-lip slit vertex and its lower-lip
  partner a fraction p of the way to their common midpoint (the skin above/below follows with a falloff).
  At p = 1 the lips touch wherever the jaw is, so bilabials (/p b m/) close the mouth even in fast speech.

Exactness and speed. The data loader rebuilds vertices from stored control tracks and must get
*bit-identical* arrays on any machine. Controls are snapped to a 1/4096 grid and deltas to a 2^-24 m grid
(60 nm), so every product ``q_tc D_c`` and every partial sum of the linear part is exactly representable in
float64: the sum gives the same bits whatever its order, SIMD width or CPU. (It is an ``einsum``, not a
BLAS matmul: for these thin matrices BLAS threads cost more than they save on a busy machine.) All
that follows is elementwise float32 +, -, * (cos/sin of the jaw angle by a fixed polynomial, not libm),
which IEEE 754 rounds identically everywhere. Only the ~400 vertices some blendshape moves enter the
sum, and the jaw works on one contiguous block of vertices (the mesh stores them from the neck up):
about 1-2 ms of CPU per 90-frame clip.

Summary: ``FaceRig(speaker).animate(controls (T, C)) -> (T, V, 3)`` float32; ``CONTROL_NAMES`` fixes the order;
``CONTROL_REGIONS`` says where each control acts; ``CONTROL_RANGES`` are the ranges speech/emotion use.

Exercises: (1) animate ``jaw_open`` from 0 to 1 and plot the chin's path; (2) find the vertex each control
moves most; (3) add a ``nose_wrinkle`` control (a new delta in ``_deltas``).
"""
from __future__ import annotations

import numpy as np

from .mesh import BASE_VERTICES, FaceShape, TemplateMesh, build_template, cosine_falloff, smoothstep, vertex_normals

__all__ = ["CONTROL_NAMES", "CONTROL_INDEX", "CONTROL_RANGES", "CONTROL_REGIONS", "JAW_MAX_ANGLE",
           "CONTROL_QUANTUM", "FaceRig", "control_vector", "snap_controls"]

CONTROL_NAMES = ("jaw_open", "lip_press", "lip_pucker", "lip_stretch", "smile_left", "smile_right",
                 "upper_lip_raise", "lower_lip_depress", "mouth_frown", "brow_raise", "brow_furrow",
                 "blink", "eye_wide", "cheek_puff")
CONTROL_INDEX = {name: i for i, name in enumerate(CONTROL_NAMES)}
# Range of every control as produced by clip_controls (the rig itself extrapolates linearly).
_RANGES = {"jaw_open": (-0.1, 1.2), "lip_press": (0.0, 1.0), "blink": (0.0, 1.0)}
CONTROL_RANGES = {n: _RANGES.get(n, (-1.0, 1.5)) for n in CONTROL_NAMES}
# Where each control acts (>= 90 % of its displacement energy lies in these regions; tests check it).
_MOUTH = ("mouth", "mouth_interior")
CONTROL_REGIONS = {"jaw_open": ("jaw",), "lip_press": ("lips", "mouth_interior"), "lip_pucker": _MOUTH,
                   "lip_stretch": _MOUTH, "smile_left": _MOUTH + ("cheeks",), "smile_right": _MOUTH + ("cheeks",),
                   "upper_lip_raise": _MOUTH, "lower_lip_depress": _MOUTH, "mouth_frown": _MOUTH + ("jaw",),
                   "brow_raise": ("brows", "forehead"), "brow_furrow": ("brows",), "blink": ("eyes",),
                   "eye_wide": ("eyes",), "cheek_puff": ("cheeks",)}
JAW_MAX_ANGLE = 0.30       # radians (~17 degrees) at jaw_open = 1
CONTROL_QUANTUM = 2.0 ** -12  # animate() snaps controls to this grid (clip_controls already emits it)
_DELTA_QUANTUM = 2.0 ** -24   # metres
_MAX_CONTROL = 8.0            # |control| bound that keeps the linear part exact


def control_vector(values: dict[str, float] | None = None) -> np.ndarray:
    """A (C,) float64 control vector from ``{name: value}`` (missing controls are 0; unknown names raise)."""
    out = np.zeros(len(CONTROL_NAMES))
    for name, value in (values or {}).items():
        out[CONTROL_INDEX[name]] = value
    return out


def snap_controls(controls: np.ndarray) -> np.ndarray:
    """Controls clipped to +-8 and rounded to the 1/4096 grid (float64), as ``animate`` uses them."""
    q = np.clip(np.asarray(controls, dtype=np.float64), -_MAX_CONTROL, _MAX_CONTROL)
    return np.round(q * (1.0 / CONTROL_QUANTUM)) * CONTROL_QUANTUM


def _cos_sin(angle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin by their Taylor series to degree 17 (|angle| <= 0.6: error < 1e-19), so no libm is involved."""
    a2 = angle * angle
    cos, sin = np.ones_like(angle), np.ones_like(angle)
    for k in range(8, 0, -1):                       # Horner: 1 - a2/(2k-1)(2k) (1 - ...)
        cos = 1.0 - a2 / ((2 * k - 1) * (2 * k)) * cos
        sin = 1.0 - a2 / ((2 * k) * (2 * k + 1)) * sin
    return cos, angle * sin


class FaceRig:
    """The rig of one speaker: precomputes the template, the blendshape deltas, the jaw and lip-closure maps."""

    def __init__(self, speaker=None):
        shape = getattr(speaker, "shape", None) or FaceShape()
        n_vertices = int(getattr(speaker, "n_vertices", BASE_VERTICES))
        self.speaker = speaker
        self.mesh: TemplateMesh = build_template(shape, n_vertices)
        self.canonical: TemplateMesh = build_template(None, n_vertices)
        self.template = self.mesh.vertices                                            # (V, 3) float32
        self.faces = self.mesh.faces
        deltas = self._deltas()                                                       # (C, V, 3) metres
        self.deltas = np.round(deltas * (1.0 / _DELTA_QUANTUM)) * _DELTA_QUANTUM       # exact grid, see docstring
        assert np.abs(self.deltas).max() < 2.0 ** -4, "deltas too large for exact products"
        moved = np.any(self.deltas[1:] != 0.0, axis=(0, 2))
        self._moved = np.nonzero(moved)[0]                                            # vertices some delta moves
        self._moved_xyz = (3 * self._moved[:, None] + np.arange(3)).ravel()          # their x, y, z columns
        self._linear = self.deltas[1:, moved].reshape(len(CONTROL_NAMES) - 1, -1)     # (C-1, |moved|*3), no jaw
        self._template_moved = self.template[moved].astype(np.float64).reshape(-1)
        self.jaw_weights = self._jaw_weights()                                        # (V,)
        self._jaw_end = int(np.nonzero(self.jaw_weights > 0)[0].max()) + 1           # jaw block = [0, end)
        self._jaw_w = self.jaw_weights[: self._jaw_end].astype(np.float32)
        L = self.mesh.landmarks
        self.hinge = np.array([0.0, L["hinge_y"], L["hinge_z"]], dtype=np.float32)    # a point on the hinge axis
        self._closure = self._closure_maps()

    # ---------------------------------------------------------------- weights, on the canonical head
    def _canon(self):
        c, L = self.canonical.vertices.astype(np.float64), self.canonical.landmarks
        g = self.canonical.grid
        upper = (g["side"] == 1) | ((g["side"] != -1) & (c[:, 1] > L["y_mouth"]))
        return c[:, 0], c[:, 1], c[:, 2], L, g["theta"], upper

    def _jaw_weights(self) -> np.ndarray:
        """1 on the lower lip and chin, 0 on the upper lip and above; smooth from the mouth corners to the ears."""
        x, y, z, L, theta, _ = self._canon()
        th_c = L["th_corner"]
        y_t = L["y_mouth"] + (L["hinge_y"] - L["y_mouth"]) * smoothstep(th_c, np.radians(86.0), theta)
        h = 0.0008 + 0.012 * smoothstep(0.6 * th_c, 1.5 * th_c, theta)               # sharp at the slit only
        w = smoothstep(y_t + h, y_t - h, y) * smoothstep(np.radians(115.0), np.radians(80.0), theta)
        return w

    def _deltas(self) -> np.ndarray:
        """Blendshape deltas D (C, V, 3), metres; weights from the canonical head, sizes from this speaker."""
        x, y, z, L, theta, upper = self._canon()
        v, S = self.template.astype(np.float64), self.mesh.landmarks
        ax, sx = np.abs(x), np.sign(x)
        front = smoothstep(np.radians(80.0), np.radians(60.0), theta)
        ym, xc = L["y_mouth"], L["x_corner"]
        mouth_scale = S["x_corner"] / xc
        D = np.zeros((len(CONTROL_NAMES), len(x), 3))

        def ellipse(x0, y0, rx, ry, xx=x):
            return cosine_falloff(np.hypot((xx - x0) / rx, (y - y0) / ry), 1.0) * front

        def put(name, w, dx=0.0, dy=0.0, dz=0.0):
            D[CONTROL_INDEX[name]] += w[:, None] * np.stack(np.broadcast_arrays(dx, dy, dz), -1)

        vx, vy = v[:, 0], v[:, 1] - S["y_mouth"]                                       # speaker, mouth-centred
        w_mouth = ellipse(0.0, ym, 1.3 * xc, 0.018)
        put("lip_press", ellipse(0.0, ym, 1.05 * xc, 0.008), dz=-0.0015)              # + the closure, see animate
        put("lip_pucker", w_mouth, dx=-0.35 * vx, dy=-0.1 * vy, dz=0.010 * mouth_scale)
        put("lip_stretch", w_mouth, dx=0.22 * vx, dy=-0.08 * vy, dz=-0.002)
        for name, sign in (("smile_left", 1.0), ("smile_right", -1.0)):               # +x is the subject's left
            w = ellipse(sign * xc, ym + 0.003, 0.020, 0.017)
            put(name, w, dx=sign * 0.005 * mouth_scale, dy=0.008, dz=-0.002)
        put("upper_lip_raise", ellipse(0.0, ym + 0.004, 1.1 * xc, 0.013) * upper, dy=0.0045, dz=0.001)
        put("lower_lip_depress", ellipse(0.0, ym - 0.005, 1.1 * xc, 0.014) * ~upper, dy=-0.0045, dz=0.0015)
        put("mouth_frown", ellipse(xc, ym - 0.003, 0.018, 0.016, xx=ax), dx=0.0015 * sx, dy=-0.006, dz=-0.001)
        # Brows and forehead.
        yb, yh = L["y_brow"], L["y_hair"]
        band = np.where(y < yb, cosine_falloff(yb - y, 0.008),
                        np.where(y < yh, 1.0 - 0.65 * smoothstep(yb, yh, y), 0.35 * cosine_falloff(y - yh, 0.012)))
        put("brow_raise", band * smoothstep(0.064, 0.05, ax) * front, dy=0.008)
        put("brow_furrow", ellipse(0.014, yb - 0.001, 0.024, 0.0075, xx=ax),
            dx=-0.0035 * np.tanh(vx / 0.01), dy=-0.003, dz=0.0015)
        # Eyes: blink pulls the upper lid down onto the lower-lid line, eye_wide lifts it.
        ew, ye = L["eye_width"], L["y_eye"]
        w_eye = ellipse(L["x_eye"], ye + 0.002, 0.75 * ew, 0.011, xx=ax)
        above = smoothstep(ye - 0.004, ye + 0.001, y)
        y_close = S["y_eye"] - 0.004
        put("blink", w_eye * above, dy=-(v[:, 1] - y_close), dz=0.002)
        put("blink", w_eye * (1.0 - above), dy=0.2 * (y_close - v[:, 1]))
        put("eye_wide", w_eye * above, dy=0.004)
        put("eye_wide", w_eye * (1.0 - above), dy=-0.0015)
        # Cheeks puff out along the surface normal.
        normals = vertex_normals(self.mesh.vertices, self.mesh.faces)  # (V, 3)
        put("cheek_puff", ellipse(xc + 0.018, ym + 0.012, 0.022, 0.022, xx=ax),
            dx=0.006 * normals[:, 0], dy=0.006 * normals[:, 1], dz=0.006 * normals[:, 2])
        return D

    def _closure_maps(self) -> dict[str, np.ndarray]:
        """For lip_press: which vertices follow which slit column, with which weight (upper and lower side)."""
        g, c = self.canonical.grid, self.canonical.vertices.astype(np.float64)
        upper, lower = self.mesh.slit
        r_m = g["rows"]["mouth"]
        out = {"upper": upper, "lower": lower}
        for side, slit, step in (("up", upper, 1), ("lo", lower, -1)):
            idx, src, wts = [slit], [np.arange(len(slit))], [np.ones(len(slit))]
            cols = g["col"][slit]
            for k in range(1, 4):                                                     # rings above / below
                ring = np.nonzero((g["row"] == r_m + step * k) & (g["side"] == 0))[0]
                by_col = dict(zip(g["col"][ring].tolist(), ring.tolist()))
                vids = np.array([by_col[cc] for cc in cols.tolist()])
                w = cosine_falloff(c[vids, 1] - c[slit, 1], 0.010)
                keep = w > 0
                idx.append(vids[keep]), src.append(np.arange(len(slit))[keep]), wts.append(w[keep])
            for code, w in ((2, 0.8), (3, 0.4)):                                      # the mouth bag follows
                half = (g["side"] == code) & (step * (c[:, 1] - self.canonical.landmarks["y_mouth"]) > 0)
                by_col = dict(zip(g["col"][half].tolist(), np.nonzero(half)[0].tolist()))
                idx.append(np.array([by_col[cc] for cc in cols.tolist()]))
                src.append(np.arange(len(slit))), wts.append(np.full(len(slit), w))
            out[f"{side}_idx"], out[f"{side}_src"] = np.concatenate(idx), np.concatenate(src)
            out[f"{side}_w"] = np.concatenate(wts).astype(np.float32)[None, :, None]  # (1, N, 1)
        return out

    # ---------------------------------------------------------------- animation
    def animate(self, controls: np.ndarray) -> np.ndarray:
        """Controls (T, C) -> vertices (T, V, 3) float32, metres; a single (C,) frame gives (V, 3)."""
        q = np.asarray(controls)
        single = q.ndim == 1
        q = np.atleast_2d(q)
        if q.ndim != 2 or q.shape[1] != len(CONTROL_NAMES):
            raise ValueError(f"controls: expected shape (T, {len(CONTROL_NAMES)}), got {np.shape(controls)}")
        q = snap_controls(q)                                                           # (T, C) on the 1/4096 grid
        T = q.shape[0]
        P = np.repeat(self.template[None], T, axis=0)                                  # (T, V, 3) float32
        qT = np.ascontiguousarray(q[:, 1:].T)                                          # (C-1, T)
        linear = np.einsum("ct,cv->tv", qT, self._linear)                              # exact: see the docstring
        linear += self._template_moved
        P.reshape(T, -1)[:, self._moved_xyz] = linear                                  # one rounding to float32
        # Jaw: rotate about the hinge axis (x direction) by w_v * R(angle), angle = jaw_open * JAW_MAX_ANGLE.
        # Mesh vertices are stored from the neck up, so every vertex with w_v > 0 is in the block [0, end).
        cos, sin = _cos_sin(np.clip(q[:, 0], -1.0, 2.0) * JAW_MAX_ANGLE)
        cos, sin = cos.astype(np.float32)[:, None], sin.astype(np.float32)[:, None]   # (T, 1)
        Py, Pz = P[:, : self._jaw_end, 1], P[:, : self._jaw_end, 2]                    # views into P
        rel_y, rel_z = Py - self.hinge[1], Pz - self.hinge[2]                          # (T, end)
        # dy = w ((cos rel_y - sin rel_z) - rel_y), dz = w ((sin rel_y + cos rel_z) - rel_z), written in place
        # (fewer temporaries; the same float32 operations in the same order, so the same bits).
        dy, tmp = np.multiply(cos, rel_y), np.multiply(sin, rel_z)
        dy -= tmp
        dy -= rel_y
        dy *= self._jaw_w
        dz = np.multiply(sin, rel_y, out=tmp)
        dz += np.multiply(cos, rel_z, out=rel_y)
        dz -= rel_z
        dz *= self._jaw_w
        Py += dy                                                                       # chin goes down ...
        Pz += dz                                                                       # ... and back
        # Lip closure: slit pairs move a fraction lip_press of the way to their midpoint.
        press = q[:, 1]
        if np.any(press != 0.0):
            m = self._closure
            half = 0.5 * (P[:, m["lower"]] - P[:, m["upper"]])                         # (T, S, 3)
            p = press.astype(np.float32)[:, None, None]
            P[:, m["up_idx"]] += p * m["up_w"] * half[:, m["up_src"]]
            P[:, m["lo_idx"]] -= p * m["lo_w"] * half[:, m["lo_src"]]
        return P[0] if single else P
