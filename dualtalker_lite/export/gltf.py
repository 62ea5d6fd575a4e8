"""A predicted animation as one glTF 2.0 binary (.glb) with morph targets and a weights animation (issue 22).

What the file holds (the carrier every DCC tool, engine and web viewer reads, like ARKit blend shapes):

- the **template** (neutral face, V vertices) as one mesh, with its triangles;
- **morph targets** from a PCA of the predicted offsets ``D = X - template`` (T frames x 3V values):
  ``X_t ~= template + sum_k c_tk B_k`` with K orthonormal components ``B_k`` (3V,). K is the smallest number
  whose reconstruction error is below ``tol`` (default 0.1 mm) **at every vertex of every frame**, measured
  against the raw prediction on exactly the float32 arrays written to the file;
- one **animation** ("speech") whose LINEAR sampler drives the morph weights, one keyframe per mesh frame
  (30 fps), from t = 0 (the first audio sample);
- the **audio** beside it, same base name (``animation.glb`` -> ``animation.wav``), referenced from the scene's
  and the animation's ``extras.audio`` (uri, mimeType, sampleRate, startTime). Blender puts scene extras in the
  scene's custom properties, three.js in ``gltf.scene.userData``. No audio *extension* is declared:
  ``KHR_audio_emitter`` is still a draft that neither the Khronos validator nor the common importers know.

**Non-negative weights in [0, 1].** A PCA coefficient ``c_tk`` takes both signs, but Blender clamps a shape
key's value to its slider range (default [0, 1]; its glTF importer widens it from the first keyframe only) and
Unity clamps blend shapes to [0, 100]. So each component k becomes up to two targets, ``+max(c_k) B_k`` driven by
``max(c_tk, 0) / max(c_k)`` and ``min(c_k) B_k`` driven by ``min(c_tk, 0) / min(c_k)``: identical at every
keyframe, weights always in [0, 1], the basis shape is the neutral template. Cost: up to 2K weights per frame
(what that weighs for the rig's motion: ``docs/exports.md``).

**PCA in bounded memory** (:func:`morph_basis`). The covariance ``D^T D`` is 3V x 3V: 175 MB in float64 for the
sample's 1,558 vertices but 1.8 GB for VOCASET's 5,023, and the frames' Gram matrix ``D D^T`` is T x T: 93 GB
for an hour. Neither is formed. The prediction is read from its memory map in blocks of frames, a few times:

1. sketch: ``Y = D^T Omega`` (3V x l, Omega Gaussian T x l, generated block by block from a seed) or, when
   T <= l, ``Y = D^T`` itself (the row space exactly: the "Gram of frames" case of short clips);
2. ``power_iters`` subspace iterations ``Y = D^T (D Q)`` with ``Q = orth(Y)``, which sharpen the basis when
   the spectrum decays slowly (Halko, Martinsson & Tropp 2011, algorithm 4.4);
3. ``M = D Q`` (T x l) and ``H = M^T M`` (l x l): the eigenvectors R of H rotate Q into the principal
   directions ``B = (Q R)^T`` and give every frame's coefficients ``C = M R`` with no further pass;
4. selection of K (smallest K whose blocks all meet ``tol``), then 5. the exact check of the written arrays.

Memory: Q and Y (3V x l), M and C (T x l, float32) and a few copies of one block of frames (at most 64 MB
each; an hour's figures in ``docs/exports.md``). If K = l is not enough, l doubles (up to min(T, 3V), where the
basis is exact). The randomized sketch can only cost a larger K (a bigger file), never a wrong one: the reported
error is measured on the written arrays against the raw frames.
"""
from __future__ import annotations

import mmap
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["MorphBasis", "GltfReport", "morph_basis", "split_signed", "write_gltf", "read_gltf_animation",
           "write_wav", "AUDIO_SUFFIX"]

AUDIO_SUFFIX = ".wav"
_FLOAT, _USHORT, _UINT = 5126, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


def _as_frames(clip) -> np.ndarray:
    """(T, V*3) or (T, V, 3) array, memory map or ``.npy`` path -> (T, V*3) view (never loaded whole)."""
    if isinstance(clip, (str, os.PathLike)):
        clip = np.load(clip, mmap_mode="r", allow_pickle=False)
    clip = clip if isinstance(clip, np.ndarray) else np.asarray(clip, np.float32)
    if clip.ndim not in (2, 3) or len(clip) == 0:
        raise ValueError(f"expected frames of shape (T, V*3) or (T, V, 3) with T >= 1, got {clip.shape}")
    return clip.reshape(len(clip), -1)


def _release(clip: np.ndarray) -> None:
    """Drop the pages a read-only memory map has mapped so far from this process (``MADV_DONTNEED``).

    Pages read through a memory map stay mapped, and count in the resident size, until the map is closed: reading
    an hour (2 GB) block by block would look like a 2 GB process (reclaimable page cache, but a real figure to
    ``ru_maxrss`` and to container limits). Read-only file pages are re-read from the page cache if needed again.
    """
    mm = getattr(clip, "_mmap", None)
    if mm is not None and hasattr(mm, "madvise") and hasattr(mmap, "MADV_DONTNEED"):
        mm.madvise(mmap.MADV_DONTNEED)


def _offsets(clip: np.ndarray, base: np.ndarray, block: int):
    """Yield (start, D_b) with D_b = frames - base, float32 (n, 3V), one block of the memory map at a time.

    Blocks hold at most ``block`` frames and 64 MB (VOCASET's 5,023 vertices: 1,113 frames), so the few
    temporaries of a block stay small whatever the mesh.
    """
    block = max(1, min(block, (64 << 20) // (4 * clip.shape[1])))
    for s in range(0, len(clip), block):
        frames = np.array(clip[s:s + block], np.float32)
        _release(clip)
        if not np.isfinite(frames).all():
            bad = s + int(np.flatnonzero(~np.isfinite(frames).all(1))[0])
            raise ValueError(f"non-finite vertices at frame {bad}: nothing to export")
        yield s, frames - base


def _vertex_error(diff: np.ndarray) -> np.ndarray:
    """(n, 3V) coordinate differences -> (n, V) Euclidean error per vertex."""
    d = diff.reshape(len(diff), -1, 3)
    return np.sqrt(np.einsum("nvc,nvc->nv", d, d))


@dataclass
class MorphBasis:
    """PCA of the offsets: ``frames ~= base + coeffs[:, :K] @ components[:K]`` within ``tol`` at every vertex.

    ``base`` (3V,) float32, ``components`` (K, 3V) float32 orthonormal rows, ``coeffs`` (T, K) float32,
    ``singular_values`` (K,), ``sketch_size`` l (the subspace size that was searched), ``exact`` (T <= l: the
    basis spans the frames' row space exactly).
    """
    base: np.ndarray
    components: np.ndarray
    coeffs: np.ndarray
    singular_values: np.ndarray
    tol: float
    sketch_size: int
    exact: bool


def _subspace(clip, base, l: int, block: int, power_iters: int, seed: int):
    """Orthonormal Q (3V, l') spanning (approximately) the frames' offsets; l' = min(l, T) columns."""
    T, N = clip.shape
    if T <= l:  # short clip: the offsets' row space itself (exact)
        Y = np.empty((N, T), np.float32)
        for s, D in _offsets(clip, base, block):
            Y[:, s:s + len(D)] = D.T
        power_iters = 0
    else:
        Y = np.zeros((N, l), np.float32)
        for s, D in _offsets(clip, base, block):
            omega = np.random.default_rng([seed, s]).standard_normal((len(D), l), dtype=np.float32)
            Y += D.T @ omega
    Q = np.linalg.qr(Y)[0].astype(np.float32)
    for _ in range(power_iters):
        Y = np.zeros_like(Q)
        for _, D in _offsets(clip, base, block):
            Y += D.T @ (D @ Q)
        Q = np.linalg.qr(Y)[0].astype(np.float32)
    return Q, T <= l


def morph_basis(clip, base: np.ndarray, tol: float = 1e-4, block: int = 2048, sketch: int = 64,
                max_sketch: int = 1024, power_iters: int = 1, seed: int = 0) -> MorphBasis:
    """Streaming PCA of ``clip - base`` -> the smallest basis meeting ``tol`` (metres, per vertex, every frame).

    ``clip``: (T, V*3) / (T, V, 3) array, memory map or ``.npy`` path, read in blocks of ``block`` frames;
    ``base``: (V*3,) the rest shape (the template). ``sketch``: the first subspace size l, doubled while K = l
    does not meet ``tol`` (up to ``max_sketch``; beyond it a ValueError says so). See the module docstring for
    the passes and why no covariance or Gram matrix is formed.
    """
    clip = _as_frames(clip)
    base = np.asarray(base, np.float32).reshape(-1)
    T, N = clip.shape
    if base.size != N:
        raise ValueError(f"template has {base.size // 3} vertices, the frames {N // 3}")
    l = max(1, min(sketch, T, N))
    while True:
        Q, exact = _subspace(clip, base, l, block, power_iters, seed)
        n = Q.shape[1]
        H = np.zeros((n, n))  # Q^T D^T D Q, summed block by block: nothing of length T (issue 23)
        for s, D in _offsets(clip, base, block):
            M = (D @ Q).astype(np.float64)  # (n_b, n)
            H += M.T @ M
        lam, R = np.linalg.eigh(H)
        order = np.argsort(lam)[::-1]
        lam, R = np.clip(lam[order], 0, None), R[:, order].astype(np.float32)
        B = (Q @ R).T.copy()  # (n, 3V) principal directions, orthonormal rows
        del Q
        K = _select_k(clip, base, B, tol, block)
        if K is not None:
            C = np.empty((T, K), np.float32)  # (T, K) coefficients, the only array of length T
            for s, D in _offsets(clip, base, block):
                C[s:s + len(D)] = D @ B[:K].T
            return MorphBasis(base, B[:K].copy(), C, np.sqrt(lam[:K]), tol, n, exact)
        if exact or n >= min(T, N) or l >= max_sketch:
            raise ValueError(f"{n} principal components do not reach {tol * 1e3:.3g} mm at every vertex "
                             f"(subspace limit {max_sketch}); raise the tolerance or max_sketch")
        l = min(2 * l, max_sketch, T, N)


def _select_k(clip, base, B, tol, block) -> int | None:
    """Smallest K (>= 1) such that every block's max vertex error with K components is < tol; None if K = l fails.

    Blocks are visited in order; K only grows: a block is first tried at the K found so far (one product per
    block in the usual case) and otherwise binary-searched above it (the error decreases with K for the frame's
    total, and almost always per vertex; the exact check of the written file catches the rare exception).
    """
    n = B.shape[0]

    def block_max(D, Cb, k):
        return float(_vertex_error(D - Cb[:, :k] @ B[:k]).max()) if k else float(_vertex_error(D).max())

    K = 1
    for s, D in _offsets(clip, base, block):
        Cb = D @ B.T  # (n_b, n) the block's coefficients
        if block_max(D, Cb, K) < tol:
            continue
        if block_max(D, Cb, n) >= tol:
            return None
        lo, hi = K, n  # error(lo) >= tol, error(hi) < tol
        while hi - lo > 1:
            mid = (lo + hi) // 2
            lo, hi = (lo, mid) if block_max(D, Cb, mid) < tol else (mid, hi)
        K = hi
    return K


def split_signed(components: np.ndarray, coeffs: np.ndarray):
    """Signed PCA -> non-negative morph targets: (targets (J, 3V), weights (T, J) float32 in [0, 1], names).

    Component k yields ``+max(c_k) B_k`` (weight ``max(c, 0) / max(c_k)``) if any coefficient is positive and
    ``min(c_k) B_k`` (weight ``min(c, 0) / min(c_k)``) if any is negative; ``targets.T @ weights`` equals
    ``components.T @ coeffs`` at every frame. J <= 2K. (:func:`signed_targets` then :func:`signed_weights`, which
    :func:`write_gltf` runs block by block.)
    """
    targets, kept, names = signed_targets(components, coeffs.max(0), coeffs.min(0))
    return targets, signed_weights(coeffs, kept), names


def signed_targets(components: np.ndarray, his: np.ndarray, los: np.ndarray):
    """The targets of :func:`split_signed` from each coefficient's largest and smallest value over the clip
    (``his``, ``los``: (K,)) -> (targets (J, 3V) float32, kept [(k, extreme)] per target, names)."""
    kept = []  # (k, the extreme coefficient that scales its target): +max first, then min, per component
    for k in range(components.shape[0]):
        kept += [(k, float(his[k]))] if his[k] > 0 else []
        kept += [(k, float(los[k]))] if los[k] < 0 else []
    if not kept:  # a motionless clip: one zero target (weight 0) keeps the animation valid
        return np.zeros((1, components.shape[1]), np.float32), [(0, 0.0)], ["pc00+"]
    targets = np.empty((len(kept), components.shape[1]), np.float32)  # (J, 3V)
    for j, (k, ext) in enumerate(kept):
        targets[j] = components[k] * ext
    return targets, kept, [f"pc{k:02d}{'+' if ext > 0 else '-'}" for k, ext in kept]


def signed_weights(coeffs: np.ndarray, kept) -> np.ndarray:
    """Coefficients (n, K) of some frames -> their morph weights (n, J) float32 in [0, 1] (``kept`` from
    :func:`signed_targets`; an extreme of 0 is the motionless clip's zero target)."""
    weights = np.zeros((len(coeffs), len(kept)), np.float32)
    for j, (k, ext) in enumerate(kept):
        if ext:
            np.clip(coeffs[:, k] / ext, 0.0, 1.0, out=weights[:, j], casting="unsafe")
    return weights


def _check_written(clip, base, targets, weights, block) -> tuple[float, float]:
    """Max and mean vertex error (metres) of ``base + weights @ targets`` (float32, as players compute it);
    ``weights``: (T, J) or a function of (first frame, n) -> the (n, J) weights of those frames."""
    worst, total, count = 0.0, 0.0, 0
    for s, D in _offsets(clip, base, block):
        w = weights(s, len(D)) if callable(weights) else weights[s:s + len(D)]  # (n_b, J)
        err = _vertex_error(D - w @ targets)
        worst, total, count = max(worst, float(err.max())), total + float(err.sum()), count + err.size
    return worst, total / count


@dataclass
class GltfReport:
    """What :func:`write_gltf` wrote: ``components`` K, ``targets`` J (<= 2K morph targets), errors in metres."""
    path: Path
    audio: Path | None
    frames: int
    components: int
    targets: int
    max_error: float
    mean_error: float
    bytes: int
    extras: dict = field(default_factory=dict)

    def line(self) -> str:
        return (f"{self.path.name}: {self.targets} morph targets ({self.components} principal components) "
                f"x {self.frames} frames, max vertex error {self.max_error * 1e3:.4f} mm (mean "
                f"{self.mean_error * 1e3:.4f} mm), {self.bytes / 1e6:.2f} MB"
                + (f"; audio: {self.audio.name}" if self.audio else ""))


def write_wav(path, wave: np.ndarray, sample_rate: int):
    """Mono float speech (N,) -> 16-bit PCM WAV (what every DCC tool, engine and browser reads).

    Written in blocks of 2**20 samples, so an hour (230 MB of float32) is not copied whole on the way."""
    import soundfile as sf

    path = path if hasattr(path, "write") else Path(path)  # a path or a binary file object (io.BytesIO)
    if hasattr(wave, "blocks"):  # an audio.AudioStream: copied block by block, never whole
        pieces = wave.blocks()
    else:
        wave = np.asarray(wave).reshape(-1)
        pieces = (wave[s:s + (1 << 20)] for s in range(0, len(wave), 1 << 20))
    with sf.SoundFile(path, "w", int(sample_rate), 1, subtype="PCM_16", format="WAV") as f:
        for piece in pieces:
            f.write(np.clip(np.asarray(piece, np.float32), -1.0, 1.0))
    return path


def write_gltf(path: str | os.PathLike, clip, faces: np.ndarray, template: np.ndarray | None = None,
               wave: np.ndarray | None = None, sample_rate: int = 16000, fps: float = 30.0, tol: float = 1e-4,
               block: int = 2048, name: str = "face") -> GltfReport:
    """Predicted frames -> ``path`` (.glb: template mesh, morph targets, weights animation) [+ ``<stem>.wav``].

    ``clip``: (T, V*3) or (T, V, 3) float32 metres (array, memory map or ``.npy`` path; read in blocks);
    ``faces``: (F, 3) triangle indices; ``template``: the rest shape (V*3,) (default: the clip's mean frame,
    one extra pass); ``wave``: mono speech at ``sample_rate``, written beside as ``<stem>.wav`` and referenced in
    ``extras.audio``; ``tol``: max vertex error in metres (0.1 mm). Each file appears only when complete.
    Returns a :class:`GltfReport` (its ``line()`` is what ``animate`` prints).
    """
    path = Path(path)
    clip = _as_frames(clip)
    T, N = clip.shape
    faces = _checked_faces(faces, N // 3)
    if template is None:
        template = sum(D.sum(0, dtype=np.float64) for _, D in _offsets(clip, np.float32(0), block)) / T
    base = np.asarray(template, np.float32).reshape(-1)
    if not np.isfinite(base).all():
        raise ValueError("template has non-finite vertices")
    basis, targets, names, weights, max_err, mean_err = _fit_morph_targets(clip, base, tol, block)
    K, J = basis.components.shape[0], len(targets)

    buffer = _BinaryBuffer()
    a_idx, a_pos = buffer.add_mesh(faces, base, targets)
    a_time, a_w = buffer.add_weights_animation(T, J, fps, weights, block)
    audio = path.with_suffix(AUDIO_SUFFIX) if wave is not None else None
    extras = {"fps": fps, "frames": T, "morph_max_error_m": max_err, "morph_mean_error_m": mean_err,
              "principal_components": K}
    if audio is not None:
        extras["audio"] = {"uri": audio.name, "mimeType": "audio/wav", "sampleRate": int(sample_rate),
                           "startTime": 0.0, "duration": (len(wave) if hasattr(wave, "blocks") else
                                                         np.asarray(wave).size) / sample_rate}
    gltf = _document(name, extras, names, a_pos, a_idx, a_time, a_w, buffer.accessors, buffer.views, buffer.nbytes)
    _write_files(path, gltf, buffer.pieces, buffer.nbytes, audio, wave, sample_rate)
    return GltfReport(path, audio, T, K, J, max_err, mean_err, path.stat().st_size, extras)


def _checked_faces(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """``faces`` as an (F, 3) array of indices into ``n_vertices`` vertices, or a ValueError saying what is wrong."""
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ValueError(f"faces must be (F, 3) triangles, got shape {faces.shape}")
    if faces.min() < 0 or faces.max() >= n_vertices:
        raise ValueError(f"faces index vertices outside 0..{n_vertices - 1}")
    return faces


class _BinaryBuffer:
    """The .glb's one binary buffer as it is laid out: indices | base | targets | times | weights.

    Each array becomes a buffer view (``views``), starting 4-byte aligned, typed by an accessor (``accessors``);
    the arrays themselves (``pieces``) are written to the file by :func:`_write_glb`, block by block, never joined
    in memory. ``nbytes``: the buffer's length, padding included."""

    def __init__(self):
        self.pieces, self.views, self.accessors = [], [], []

    @property
    def nbytes(self) -> int:
        return sum(p.nbytes + (-p.nbytes % 4) for p in self.pieces)

    def add_view(self, data, target: int | None) -> int:
        import pygltflib as g

        offset = self.nbytes  # each view starts 4-byte aligned
        self.pieces.append(data)
        self.views.append(g.BufferView(buffer=0, byteOffset=offset, byteLength=data.nbytes, target=target))
        return len(self.views) - 1

    def add_accessor(self, view: int, ctype: int, count: int, kind: str, lo=None, hi=None) -> int:
        import pygltflib as g

        self.accessors.append(g.Accessor(bufferView=view, byteOffset=0, componentType=ctype, count=int(count),
                                         type=kind, min=lo, max=hi))
        return len(self.accessors) - 1

    def add_mesh(self, faces: np.ndarray, base: np.ndarray, targets: np.ndarray) -> tuple[int, list[int]]:
        """The triangles (F, 3) and the positions of the rest shape (3V,) and its J targets (J, 3V) -> (the
        indices' accessor, [the POSITION accessor of the base, then of each target])."""
        import pygltflib as g

        V = base.size // 3
        index_type = np.uint16 if V <= 65535 else np.uint32
        v_idx = self.add_view(faces.astype(index_type).reshape(-1), _ELEMENT_ARRAY_BUFFER)
        a_idx = self.add_accessor(v_idx, _USHORT if index_type is np.uint16 else _UINT, faces.size, g.SCALAR)
        per = np.concatenate([base[None], targets]).astype("<f4").reshape(1 + len(targets), V, 3)
        lo, hi = per.min(1), per.max(1)  # (1 + J, 3): required min/max of POSITION accessors
        # one buffer view per vertex accessor (views shared by vertex accessors would need a byteStride)
        return a_idx, [self.add_accessor(self.add_view(p, _ARRAY_BUFFER), _FLOAT, V, g.VEC3, lo[j].tolist(),
                                         hi[j].tolist()) for j, p in enumerate(per)]

    def add_weights_animation(self, T: int, J: int, fps: float, weights, block: int) -> tuple[int, int]:
        """Key times (T,) at ``fps`` from 0 and the (T, J) float32 weights, computed and written block by block by
        ``weights(first, n)`` -> (the times' accessor, the weights' accessor)."""
        import pygltflib as g

        times = (np.arange(T, dtype=np.float64) / fps).astype("<f4")
        a_time = self.add_accessor(self.add_view(times, None), _FLOAT, T, g.SCALAR,
                                   [float(times[0])], [float(times[-1])])
        v_w = self.add_view(_Blocks(T * J * 4, lambda: (weights(a, min(block, T - a)) for a in range(0, T, block))),
                            None)
        return a_time, self.add_accessor(v_w, _FLOAT, T * J, g.SCALAR)


def _fit_morph_targets(clip: np.ndarray, base: np.ndarray, tol: float, block: int):
    """The morph targets of ``clip`` (T, N) around ``base`` (N,) within ``tol`` metres, checked on what the file will
    hold -> (basis, targets (J, N), target names, weights(start, n) -> (n, J), max error, mean error). The PCA basis
    is searched at ``tol`` and, in the rare non-monotone case, at ``tol / 2`` and ``tol / 4``; one line otherwise."""
    for search_tol in (tol, tol / 2, tol / 4):  # a tighter search only in the rare non-monotone case
        basis = morph_basis(clip, base, tol=search_tol, block=block)
        C = basis.coeffs  # (T, K) float32: what stays of length T (K floats per frame)
        targets, kept, names = signed_targets(basis.components, C.max(0), C.min(0))
        weights = lambda s, n, C=C, kept=kept: signed_weights(C[s:s + n], kept)  # noqa: E731 (n, J) on demand
        max_err, mean_err = _check_written(clip, base, targets, weights, block)
        if max_err < tol:
            return basis, targets, names, weights, max_err, mean_err
    raise ValueError(f"the morph targets miss the tolerance: max vertex error {max_err * 1e3:.3f} mm >= "
                     f"{tol * 1e3:.3g} mm")


def _document(name: str, extras: dict, names: list, a_pos: list, a_idx: int, a_time: int, a_w: int, accessors: list,
              views: list, n_bin: int):
    """The glTF JSON part: one node with one mesh (the template, ``J`` morph targets named ``names``, a skin
    material) and one ``speech`` animation of its weights over the times accessor, sampled linearly."""
    import pygltflib as g

    J = len(a_pos) - 1
    return g.GLTF2(
        asset=g.Asset(version="2.0", generator="dualtalker-lite (pygltflib)"),
        scene=0, scenes=[g.Scene(name="speech", nodes=[0], extras=extras)],
        nodes=[g.Node(name=name, mesh=0)],
        materials=[g.Material(name="skin", doubleSided=True, pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorFactor=[0.80, 0.62, 0.52, 1.0], metallicFactor=0.0, roughnessFactor=0.6))],
        meshes=[g.Mesh(name=name, weights=[0.0] * J, extras={"targetNames": names}, primitives=[g.Primitive(
            attributes=g.Attributes(POSITION=a_pos[0]), indices=a_idx, material=0, mode=g.TRIANGLES,
            targets=[{"POSITION": a} for a in a_pos[1:]])])],
        animations=[g.Animation(name="speech", extras=extras,
                                samplers=[g.AnimationSampler(input=a_time, output=a_w, interpolation="LINEAR")],
                                channels=[g.AnimationChannel(sampler=0, target=g.AnimationChannelTarget(
                                    node=0, path="weights"))])],
        accessors=accessors, bufferViews=views, buffers=[g.Buffer(byteLength=n_bin)])


def _write_files(path: Path, gltf, pieces: list, n_bin: int, audio: Path | None, wave, sample_rate: int) -> None:
    """The .glb (and the speech beside it as ``audio``), each written to a temporary name and renamed into place only
    when complete; the temporary files are removed however this ends."""
    partial = path.with_name(path.name + ".partial")
    try:
        if audio is not None:
            write_wav(audio.with_name(audio.name + ".partial.wav"), wave, sample_rate)
        _write_glb(partial, gltf.gltf_to_json(separators=(",", ":"), indent=None).encode("utf-8"), pieces, n_bin)
        os.replace(partial, path)
        if audio is not None:
            os.replace(audio.with_name(audio.name + ".partial.wav"), audio)
    finally:
        for p in (partial, audio.with_name(audio.name + ".partial.wav") if audio is not None else None):
            if p is not None and p.exists():
                p.unlink()


@dataclass
class _Blocks:
    """A buffer view whose data comes as consecutive arrays (``blocks()``), ``nbytes`` in all: never whole."""
    nbytes: int
    blocks: object


def _write_glb(path: Path, json_blob: bytes, pieces: list, n_bin: int, block: int = 1 << 22) -> None:
    """A binary glTF (GLB 2.0) file: the 12-byte header, the JSON chunk (padded with spaces so that the binary
    data starts 4-byte aligned in the file), then the BIN chunk: ``pieces`` in order, each padded with zeros to
    4 bytes, ``n_bin`` bytes in all, written ``block`` bytes at a time (the same bytes as pygltflib's
    ``save_binary``, without its copies of the whole buffer: for hours of animation the weights are most of it)."""
    json_blob += b" " * (-(12 + len(json_blob)) % 4)
    with open(path, "wb") as f:
        f.write(b"glTF" + struct.pack("<II", 2, 12 + 8 + len(json_blob) + 8 + n_bin))
        f.write(struct.pack("<I", len(json_blob)) + b"JSON" + json_blob)
        f.write(struct.pack("<I", n_bin) + b"BIN\0")
        for piece in pieces:
            for part in (piece.blocks() if isinstance(piece, _Blocks) else [piece]):
                flat = np.ascontiguousarray(part, "<f4" if part.dtype.kind == "f" else None).reshape(-1).view(np.uint8)
                for a in range(0, flat.size, block):
                    f.write(flat[a:a + block].data)
            f.write(b"\0" * (-piece.nbytes % 4))
        if f.tell() != 12 + 8 + len(json_blob) + 8 + n_bin:
            raise RuntimeError(f"{path}: wrote {f.tell()} bytes, announced {12 + 16 + len(json_blob) + n_bin}")


def read_gltf_animation(path: str | os.PathLike) -> dict:
    """Read back a file of :func:`write_gltf` (with pygltflib) -> arrays to check or replay it.

    Returns ``base`` (V, 3), ``targets`` (J, V, 3), ``times`` (T,), ``weights`` (T, J), ``faces`` (F, 3),
    ``names`` (J,) and the scene's ``extras``; frame t is ``base + tensordot(weights[t], targets, 1)``.
    """
    import pygltflib as g

    gltf = g.GLTF2().load_binary(str(path))
    blob = gltf.binary_blob()
    dtypes = {_FLOAT: "<f4", _USHORT: "<u2", _UINT: "<u4"}
    widths = {g.SCALAR: 1, g.VEC3: 3}

    def array(i):
        acc = gltf.accessors[i]
        view = gltf.bufferViews[acc.bufferView]
        n = acc.count * widths[acc.type]
        return np.frombuffer(blob, dtypes[acc.componentType], n, view.byteOffset + (acc.byteOffset or 0))

    prim = gltf.meshes[0].primitives[0]
    sampler = gltf.animations[0].samplers[0]
    times = array(sampler.input)
    targets = np.stack([array(t["POSITION"]).reshape(-1, 3) for t in prim.targets])
    return {"base": array(prim.attributes.POSITION).reshape(-1, 3), "targets": targets, "times": times,
            "weights": array(sampler.output).reshape(len(times), len(targets)),
            "faces": array(prim.indices).reshape(-1, 3).astype(np.int64),
            "names": gltf.meshes[0].extras.get("targetNames"), "extras": gltf.scenes[0].extras}
