"""Real datasets in FaceFormer's folder layout (VOCASET, BIWI): a safe ``templates.pkl`` reader and presets.

FaceFormer (Fan et al., CVPR 2022) and its successors (CodeTalker, SelfTalk, DualTalker) ship each dataset as

    <root>/wav/<subject>_<sentence>.wav          speech (any rate; resampled to 16 kHz on load)
    <root>/vertices_npy/<subject>_<sentence>.npy  (T, V*3) float vertex positions
    <root>/templates.pkl                          {subject: (V, 3) neutral face}, a Python pickle
    <root>/templates/<mesh>.ply                   the topology used for rendering

and FaceFormer's ``data_loader.py`` derives the subject from the file name (everything before the last ``_``)
and the sentence number from its last two characters. The splits are subject lists and sentence ranges:

=========  =====================================================  =======================================
preset     rates and sizes                                        splits (subjects x sentences)
=========  =====================================================  =======================================
vocaset    meshes at 60 fps, kept every 2nd -> 30 fps             train: 8 subjects x 1-40; val: 2 others
           (FaceFormer's ``[::2]``); FLAME, 5023 vertices;        x 21-40; test: 2 others x 21-40
           regions: ``FLAME_masks.pkl`` (lips, eye_region,        (FaceFormer's defaults, ``main.py``)
           forehead) or ``regions/lips.txt``/``regions/eyes.txt``
biwi       25 fps, 23370 vertices; regions ``regions/lve.txt``    train: F2 F3 F4 M3 M4 M5 x 1-32; val:
           (lips, for LVE) and ``regions/fdd.txt`` (upper face,   same x 33-36; test_a: same x 37-40;
           for FDD), CodeTalker's comma-separated index lists     test_b: F1 F5 F6 F7 F8 M1 M2 M6 x 37-40
=========  =====================================================  =======================================

``templates.pkl`` is read with :func:`safe_load_pickle`, a restricted unpickler that admits only numpy
arrays, dicts, lists, tuples, strings and numbers: any other global (``os.system``, ``builtins.eval``, ...)
raises :class:`UnsafePickleError` before anything runs. Forged plain data is bounded too: each object is
visited once (shared references and cycles cannot make the check hang), at most ``MAX_OBJECTS`` objects and
``MAX_DEPTH`` levels, and no array may declare more bytes than the file holds, checked before anything is
allocated. :func:`prepare_dataset` (``dualtalker-lite prepare-dataset ROOT --preset vocaset``) converts it
to ``templates.npz`` and writes ``metadata.json``, ``regions.json`` and ``faces.npy`` beside the data, so
:class:`~dualtalker_lite.data.corpus.Corpus` and the whole package read the folder like the shipped sample. Nothing is downloaded: the real datasets need
their own licences. Assumptions where FaceFormer's code is the only specification are stated above; the
region file names follow CodeTalker (BIWI) and the FLAME masks file (VOCASET).
"""
from __future__ import annotations

import importlib
import io
import json
import math
import os
import pickle
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["UnsafePickleError", "safe_load_pickle", "convert_templates", "DatasetPreset", "PRESETS",
           "parse_clip_name", "faceformer_splits", "read_index_file", "prepare_dataset", "convert_templates_command",
           "prepare_command"]


# ------------------------------------------------------------------------------- restricted unpickler
class UnsafePickleError(pickle.UnpicklingError, ValueError):
    """A pickle asked for something other than plain data (numpy arrays, dicts, lists, strings, numbers), or is
    forged to exhaust time or memory (too deep, too many objects, arrays larger than the file's data).

    A ``ValueError`` too, so every command shows it as one ``error: <file>: <problem>`` line with exit status 2."""


MAX_PICKLE_BYTES = 256 * 2 ** 20  # a templates.pkl / FLAME_masks.pkl is a few MB (BIWI's 14 templates: 8 MB)
MAX_OBJECTS = 2_000_000           # objects in the loaded data, each shared reference counted where it is used
MAX_DEPTH = 20                    # nesting levels


def _latin1_encode(text: str, encoding: str = "utf-8", errors: str = "strict") -> bytes:
    # Python 3 pickles bytes at protocol <= 2 as _codecs.encode(str, "latin1"); only plain text codecs are allowed.
    if encoding.lower().replace("_", "-") not in ("latin1", "latin-1", "iso-8859-1", "utf-8", "utf8", "ascii"):
        raise UnsafePickleError(f"refused codec {encoding!r} in _codecs.encode")
    return text.encode(encoding, errors)


_ALLOWED = {
    ("numpy", "ndarray"), ("numpy", "dtype"),
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy.core.numeric", "_frombuffer"), ("numpy._core.numeric", "_frombuffer"),  # pickle protocol 5
    ("collections", "OrderedDict"),
}


def _numpy_attr(module: str, name: str):
    try:
        return getattr(importlib.import_module(module.replace("numpy.core", "numpy._core")), name)
    except ImportError:  # numpy 1.x
        return getattr(importlib.import_module(module.replace("numpy._core", "numpy.core")), name)


def _declared_bytes(shape, dtype) -> int:
    """Bytes an array of ``shape`` and ``dtype`` would take, computed without allocating anything."""
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    if not all(isinstance(n, (int, np.integer)) and n >= 0 for n in shape):
        raise ValueError(f"invalid array shape {shape!r}")
    return math.prod(int(n) for n in shape) * np.dtype(dtype).itemsize


class _RestrictedUnpickler(pickle.Unpickler):
    """Plain data only, and no allocation beyond the data the file holds.

    Every array's bytes must come from the file: numpy's reconstructor (``_reconstruct(ndarray, shape, dtype)``)
    and ``ndarray.__setstate__`` are guarded so that the declared sizes of all arrays together never exceed the
    file's size *before* anything is allocated (a 97-byte pickle cannot declare a 1.2 GB array, and one buffer
    referenced many times cannot be copied into many arrays or numpy scalars)."""

    def __init__(self, file, source: str, budget: int):
        super().__init__(file, encoding="latin1")  # Python 2 pickles (VOCASET's) need latin1 for numpy buffers
        self.source = source
        self.budget = budget  # bytes of array data still allowed
        unpickler = self

        class _Array(np.ndarray):  # stands for numpy.ndarray inside the pickle; unwrapped after the load
            def __new__(cls, *args, **kwargs):
                raise UnsafePickleError(f"{source}: refused a direct call of numpy.ndarray (it allocates "
                                        f"uninitialised memory of any size); numpy never pickles arrays that way")

            def __setstate__(self, state):
                if isinstance(state, tuple) and len(state) in (4, 5):
                    shape, dtype = state[-4], state[-3]
                    unpickler._spend(_declared_bytes(shape, dtype))
                super().__setstate__(state)

        self._array_cls = _Array
        reconstruct = _numpy_attr("numpy._core.multiarray", "_reconstruct")
        frombuffer = _numpy_attr("numpy._core.numeric", "_frombuffer")
        scalar = _numpy_attr("numpy._core.multiarray", "scalar")

        def _reconstruct(subtype, shape, dtype):
            if subtype is not _Array:
                raise UnsafePickleError(f"{source}: refused numpy _reconstruct of {subtype!r}; only plain arrays")
            unpickler._spend(_declared_bytes(shape, dtype))
            return reconstruct(_Array, shape, dtype)

        def _frombuffer(buf, dtype, shape, order):
            arr = frombuffer(buf, dtype, shape, order)  # a view on the file's bytes: nothing allocated yet
            unpickler._spend(arr.nbytes)
            return arr

        def _scalar(dtype, *args):
            unpickler._spend(np.dtype(dtype).itemsize)  # copies its bytes: one buffer must not feed many
            return scalar(dtype, *args)

        self._guarded = {"_reconstruct": _reconstruct, "_frombuffer": _frombuffer, "scalar": _scalar}

    def _spend(self, nbytes: int) -> None:
        self.budget -= nbytes
        if self.budget < 0:
            raise UnsafePickleError(f"{self.source}: its arrays declare more data than the file holds "
                                    f"(a forged pickle; every array's bytes must be in the file)")

    def find_class(self, module: str, name: str):
        if (module, name) == ("_codecs", "encode"):
            return _latin1_encode
        if (module, name) not in _ALLOWED:
            raise UnsafePickleError(f"{self.source}: refused to load {module}.{name}; only numpy arrays, dicts, "
                                    f"lists, strings and numbers are allowed (the pickle may be malicious)")
        if (module, name) == ("numpy", "ndarray"):
            return self._array_cls
        if name in self._guarded:
            return self._guarded[name]
        if module.startswith("numpy.core") or module.startswith("numpy._core"):
            return _numpy_attr(module, name)
        return getattr(importlib.import_module(module), name)

    def persistent_load(self, pid):
        raise UnsafePickleError(f"{self.source}: refused a persistent id in the pickle")


_SCALARS = (str, bytes, int, float, complex, bool, type(None), np.generic, np.dtype)


def _check_plain(obj, source: str, array_cls: type = np.ndarray):
    """Check that ``obj`` is plain data and return it with the loader's guarded arrays as plain ndarrays.

    Visits each object once (shared references cost nothing; a list referenced ten times at each of 18 levels is
    checked in microseconds), refuses cycles, more than ``MAX_DEPTH`` levels and data that expands to more than
    ``MAX_OBJECTS`` objects when shared references are counted where they are used (what ``np.asarray`` or a
    loop over it would visit). The walk is depth-first with an explicit stack (no recursion limit): a container
    is met twice, first to push its children, then, once they are done, to rebuild it from their plain forms."""
    done: dict[int, tuple] = {}     # id -> (plain object, depth, expanded size)
    active: set[int] = set()        # on the current path (a cycle if met again)
    keep = []                       # keep the originals alive, so no id is reused during the walk
    stack = [(obj, False)]
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        if key in done and not children_done:
            continue
        leaf = _plain_leaf(node, source, array_cls)
        if leaf is not _CONTAINER:
            done[key] = (leaf, 1, 1)
            keep.append(node)
            continue
        kids = _children(node, source)
        if not children_done:                          # first visit: the children first, then this node again
            _enter(key, kids, active, source)
            stack.append((node, True))
            stack.extend((k, False) for k in reversed(kids) if id(k) not in done)
            continue
        active.discard(key)
        done[key] = _plain_container(node, [done[id(k)] for k in kids], source)
        keep.append(node)
    return done[id(obj)][0]


_CONTAINER = object()  # what _plain_leaf returns for a dict, list or tuple


def _plain_leaf(node, source: str, array_cls: type):
    """A leaf's plain form (a numeric ndarray, a scalar), or ``_CONTAINER`` for anything else.

    An array the guarded loader built (``array_cls``) becomes a plain ndarray view; arrays of Python objects and
    ndarray subclasses are refused."""
    if isinstance(node, np.ndarray):
        if node.dtype.hasobject:
            raise UnsafePickleError(f"{source}: holds a numpy array of Python objects; only numeric arrays "
                                    f"allowed")
        plain = node.view(np.ndarray) if type(node) is array_cls else node
        if type(plain) is not np.ndarray:
            raise UnsafePickleError(f"{source}: holds a {type(node).__name__}; only plain arrays allowed")
        return plain
    if isinstance(node, _SCALARS):
        return node
    return _CONTAINER


def _children(node, source: str) -> list:
    """The objects a container holds, in order (a dict's keys and values interleaved); any other type is refused."""
    if isinstance(node, dict):
        return [x for kv in node.items() for x in kv]
    if isinstance(node, (list, tuple)):
        return list(node)
    raise UnsafePickleError(f"{source}: holds a {type(node).__name__}; only plain data is allowed")


def _enter(key: int, kids: list, active: set[int], source: str) -> None:
    """Put the container ``key`` on the current path, refusing a cycle: it, or one of its children, already on it."""
    if key in active:
        raise UnsafePickleError(f"{source}: refers to itself (a cycle); plain data never does")
    active.add(key)
    for k in kids:
        if id(k) in active:
            raise UnsafePickleError(f"{source}: refers to itself (a cycle); plain data never does")


def _plain_container(node, parts: list[tuple], source: str) -> tuple:
    """(plain copy, depth, expanded size) of a container from its children's; refuses too deep or too big.

    depth = 1 + the deepest child's, size = 1 + the sum of the children's sizes (a shared child counts each time
    it is used). A dict subclass the loader admitted is rebuilt as its own type; a list or tuple subclass becomes
    a list."""
    depth = 1 + max((p[1] for p in parts), default=0)
    size = 1 + sum(p[2] for p in parts)
    if depth > MAX_DEPTH:
        raise UnsafePickleError(f"{source}: nested more than {MAX_DEPTH} levels deep")
    if size > MAX_OBJECTS:
        raise UnsafePickleError(f"{source}: too big: its shared references expand to more than {MAX_OBJECTS:,} "
                                f"objects (a forged pickle?)")
    values = [p[0] for p in parts]
    if isinstance(node, dict):
        plain = type(node)(zip(values[0::2], values[1::2])) if type(node) is not dict else \
            dict(zip(values[0::2], values[1::2]))
    else:
        plain = type(node)(values) if type(node) in (list, tuple) else list(values)
    return plain, depth, size


def safe_load_pickle(path: str | os.PathLike):
    """Load a pickle of plain data (numpy arrays, dicts, lists, strings, numbers) without running any code,
    in time and memory bounded by the file's size.

    Raises :class:`UnsafePickleError` (a ``ValueError``) naming the file and the problem for anything else (a
    refused global, a cycle, more than ``MAX_DEPTH`` levels, more than ``MAX_OBJECTS`` objects, arrays declaring
    more bytes than the file holds, a file over ``MAX_PICKLE_BYTES``), and ``ValueError`` for a file that is not a
    pickle at all.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, not a pickle file")
    if not path.is_file():
        raise FileNotFoundError(f"pickle file not found: {path}")
    size = path.stat().st_size
    if size > MAX_PICKLE_BYTES:
        raise UnsafePickleError(f"{path}: {size / 2 ** 20:.0f} MiB, larger than any plausible templates or masks "
                                f"pickle ({MAX_PICKLE_BYTES // 2 ** 20} MiB)")
    data = path.read_bytes()
    unpickler = _RestrictedUnpickler(io.BytesIO(data), str(path), budget=len(data))
    try:
        obj = unpickler.load()
    except UnsafePickleError:
        raise
    except Exception as e:  # truncated, not a pickle, ...
        raise ValueError(f"{path}: not a readable pickle ({type(e).__name__}: {str(e)[:120]})") from e
    return _check_plain(obj, str(path), unpickler._array_cls)


def _is_npz_of_arrays(path: Path) -> bool:
    """Whether ``path`` is a zip archive of ``.npy`` members only (what ``np.savez`` writes): the one kind of file
    ``convert-templates --overwrite`` may replace."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
    except (zipfile.BadZipFile, OSError, ValueError):
        return False
    return bool(names) and all(n.endswith(".npy") for n in names)


def convert_templates(pkl: str | os.PathLike, out: str | os.PathLike | None = None, overwrite: bool = False) -> Path:
    """FaceFormer's ``templates.pkl`` ({subject: (V, 3)}) -> ``templates.npz`` (float32 (V*3,) per subject)."""
    from ..checks import check_finite, check_name
    from ..files import default_file_mode

    from ..files import refuse_inputs, temporary_prefix

    pkl = Path(pkl)
    out = Path(out) if out is not None else pkl.with_suffix(".npz")
    if out.is_dir() or out.name in ("", ".", ".."):
        raise IsADirectoryError(f"--out {out}: is a folder; name the .npz file to write")
    refuse_inputs(out, [("source file", pkl)])  # never the pickle being converted, even with --overwrite
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} already exists; pass --overwrite to replace it")
    if out.exists() and not _is_npz_of_arrays(out):
        raise FileExistsError(f"--out {out}: is not a .npz archive of arrays (as convert-templates writes); "
                              f"--overwrite replaces only that; remove it yourself or choose another --out")
    obj = safe_load_pickle(pkl)
    if not isinstance(obj, dict) or not obj:
        raise ValueError(f"{pkl}: expected a non-empty dict {{subject: (V, 3) array}}, found {type(obj).__name__}")
    for subject in obj:  # names become archive members (and, unpacked, file names): never ../x or /abs
        check_name(subject, "template name", pkl)
    arrays = {}
    for subject, tpl in obj.items():
        arr = np.asarray(tpl)
        if not isinstance(subject, str) or arr.dtype.kind not in "fiu" or arr.size % 3 or arr.size == 0:
            raise ValueError(f"{pkl}: entry {subject!r} is not a (V, 3) numeric template "
                             f"(got {arr.dtype} {arr.shape})")
        check_finite(arr, f"{pkl}: template of {subject!r}")
        arrays[subject] = arr.astype(np.float32).reshape(-1)
    sizes = {a.size for a in arrays.values()}
    if len(sizes) > 1:
        raise ValueError(f"{pkl}: templates have different vertex counts {sorted(s // 3 for s in sizes)}")
    tmp = out.with_name(f"{temporary_prefix(out)}tmp.npz")  # short enough beside a long name (helper_stem)
    try:
        np.savez(tmp, **arrays)
        os.chmod(tmp, default_file_mode())
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    return out


# ------------------------------------------------------------------------------------------ presets
@dataclass(frozen=True)
class DatasetPreset:
    """Conventions of one dataset in FaceFormer's layout (see the module docstring)."""

    name: str
    source_fps: int                    # frame rate of the vertex files
    mesh_stride: int                   # keep every n-th frame -> fps = source_fps / mesh_stride
    n_vertices: int
    splits: dict = field(default_factory=dict)  # split -> (subjects, (first sentence, last sentence))
    region_files: dict = field(default_factory=dict)  # region name -> relative path of an index list
    masks_pickle: str | None = None    # FLAME_masks.pkl-style {name: indices}
    mask_regions: dict = field(default_factory=dict)  # our region name -> list of mask names
    render_mesh: str = ""              # relative path of the topology mesh (PLY/OBJ)
    units: str = "m"                   # "m": templates checked to be face-sized in metres

    @property
    def fps(self) -> int:
        return self.source_fps // self.mesh_stride


VOCASET_TRAIN = ("FaceTalk_170728_03272_TA FaceTalk_170904_00128_TA FaceTalk_170725_00137_TA "
                 "FaceTalk_170915_00223_TA FaceTalk_170811_03274_TA FaceTalk_170913_03279_TA "
                 "FaceTalk_170904_03276_TA FaceTalk_170912_03278_TA").split()
VOCASET_VAL = "FaceTalk_170811_03275_TA FaceTalk_170908_03277_TA".split()
VOCASET_TEST = "FaceTalk_170809_00138_TA FaceTalk_170731_00024_TA".split()
BIWI_SEEN = "F2 F3 F4 M3 M4 M5".split()
BIWI_UNSEEN = "F1 F5 F6 F7 F8 M1 M2 M6".split()

PRESETS = {
    "vocaset": DatasetPreset(
        "vocaset", source_fps=60, mesh_stride=2, n_vertices=5023,
        splits={"train": (VOCASET_TRAIN, (1, 40)), "val": (VOCASET_VAL, (21, 40)), "test": (VOCASET_TEST, (21, 40))},
        region_files={"lips": "regions/lips.txt", "eyes_forehead": "regions/eyes.txt"},
        masks_pickle="FLAME_masks.pkl",
        mask_regions={"lips": ["lips"], "eyes_forehead": ["eye_region", "forehead"], "upper_face": ["eye_region",
                                                                                                     "forehead"]},
        render_mesh="templates/FLAME_sample.ply", units="m"),
    "biwi": DatasetPreset(
        "biwi", source_fps=25, mesh_stride=1, n_vertices=23370,
        splits={"train": (BIWI_SEEN, (1, 32)), "val": (BIWI_SEEN, (33, 36)), "test_a": (BIWI_SEEN, (37, 40)),
                "test_b": (BIWI_UNSEEN, (37, 40))},
        region_files={"lips": "regions/lve.txt", "upper_face": "regions/fdd.txt"},
        render_mesh="templates/BIWI.ply", units="as-shipped"),
}


def parse_clip_name(name: str) -> tuple[str, int]:
    """FaceFormer's rule: ``"<subject>_<xxNN>"`` -> (subject, NN), e.g. ``F2_e07`` -> ("F2", 7)."""
    stem = Path(name).stem
    if "_" not in stem or not stem[-2:].isdigit():
        raise ValueError(f"clip name {name!r} does not follow FaceFormer's <subject>_<...NN> pattern")
    return "_".join(stem.split("_")[:-1]), int(stem[-2:])


def faceformer_splits(names: list[str], preset: DatasetPreset) -> dict[str, list[str]]:
    """Clip names -> FaceFormer's splits for ``preset`` (clips outside every split are left out)."""
    out: dict[str, list[str]] = {s: [] for s in preset.splits}
    for name in sorted(names):
        subject, sentence = parse_clip_name(name)
        for split, (subjects, (lo, hi)) in preset.splits.items():
            if subject in subjects and lo <= sentence <= hi:
                out[split].append(name)
    return out


def read_index_file(path: str | os.PathLike, n_vertices: int) -> np.ndarray:
    """A vertex index list (comma/space/newline separated, CodeTalker's ``lve.txt`` style) -> int64 indices."""
    path = Path(path)
    text = path.read_text()
    tokens = [t for t in re.split(r"[\s,;\[\]]+", text) if t]
    try:
        idx = np.asarray([int(t) for t in tokens], dtype=np.int64)
    except ValueError as e:
        raise ValueError(f"{path}: expected integer vertex indices, found {str(e).split(':')[-1].strip()}") from e
    if idx.size == 0:
        raise ValueError(f"{path}: lists no vertex indices")
    if idx.min() < 0 or idx.max() >= n_vertices:
        raise ValueError(f"{path}: indices span [{idx.min()}, {idx.max()}], outside the {n_vertices} vertices")
    return idx


def _prepared_here(meta_path: Path) -> bool:
    """Whether ``meta_path`` is a ``metadata.json`` that :func:`prepare_dataset` wrote (``"format": "faceformer"``),
    the only one ``--overwrite`` rebuilds: a corpus of ``generate`` copied here is never replaced."""
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and meta.get("format") == "faceformer"


def prepare_dataset(root: str | os.PathLike, preset: str, overwrite: bool = False) -> dict:
    """Write ``metadata.json``, ``templates.npz``, ``regions.json`` and ``faces.npy`` into a FaceFormer folder.

    Afterwards ``Corpus(root)`` reads it (vertices subsampled by ``mesh_stride``). Returns the metadata.

    The outputs are one set: ``root/metadata.json`` is claimed (a concurrent run fails at once), all four are
    built in a hidden temporary folder inside ``root`` and moved into place only when every one is complete
    (``metadata.json`` last), so a failure, Ctrl-C or SIGTERM leaves the old ones byte-identical. ``templates.npz``
    is rebuilt from ``templates.pkl`` on every run (a stale one of an earlier run is never reused); a folder with
    only a ``templates.npz`` (e.g. from ``convert-templates``) uses that one as it is.
    """
    from ..files import _remove_on_signal, claim, sweep_stale, temporary_prefix

    root = Path(root)
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; known: {sorted(PRESETS)}")
    for sub in ("wav", "vertices_npy"):
        if not (root / sub).is_dir():
            raise FileNotFoundError(f"{root / sub} not found: {root} is not in FaceFormer's layout "
                                    f"(wav/, vertices_npy/, templates.pkl)")
    meta_path = root / "metadata.json"
    with claim(meta_path):
        if meta_path.exists() and not overwrite:
            raise FileExistsError(f"{meta_path} already exists; pass --overwrite to rebuild it")
        if meta_path.exists() and not _prepared_here(meta_path):
            raise FileExistsError(f"{meta_path}: was not written by dualtalker-lite prepare-dataset (no \"format\": "
                                  f"\"faceformer\"); --overwrite rebuilds only that; move it away yourself first")
        sweep_stale(meta_path)
        tmp = Path(tempfile.mkdtemp(dir=root, prefix=temporary_prefix(meta_path), suffix=".tmp"))
        try:
            with _remove_on_signal(tmp) as signals:
                meta = _build_dataset(root, preset, tmp)
                signals.check()
                for name in ("templates.npz", "regions.json", "faces.npy", "metadata.json"):  # metadata last
                    if (tmp / name).exists():
                        os.replace(tmp / name, root / name)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return meta


def _build_dataset(root: Path, preset: str, out: Path) -> dict:
    """:func:`prepare_dataset`'s work: read ``root``, write the outputs into the folder ``out``.

    Clips with both files -> the preset's splits -> the templates (checked, derived from the pickle if need be)
    -> the named regions and the render mesh's faces, where the dataset has them -> ``metadata.json``.
    """
    from ..files import default_file_mode

    p = PRESETS[preset]
    wavs = {w.stem for w in (root / "wav").glob("*.wav")}
    verts = {v.stem for v in (root / "vertices_npy").glob("*.npy")}
    names = sorted(wavs & verts)
    if not names:
        raise ValueError(f"{root}: no clip has both wav/<name>.wav and vertices_npy/<name>.npy")
    splits = faceformer_splits(names, p)
    used = sorted({c for clips in splits.values() for c in clips})
    empty = [s for s, clips in splits.items() if not clips]
    if empty:
        raise ValueError(f"{root}: FaceFormer's {preset} split(s) {empty} match no clip (subject names or "
                         f"sentence numbers differ from the preset?)")
    _check_templates(root, preset, {parse_clip_name(c)[0] for c in used}, out)
    regions = _dataset_regions(root, p)
    if regions:
        (out / "regions.json").write_text(json.dumps(regions))
    mesh = root / p.render_mesh
    if mesh.is_file():
        import trimesh

        np.save(out / "faces.npy", np.asarray(trimesh.load(mesh, process=False, force="mesh").faces, np.int64))
    clips = _clip_table(root, used, splits)
    train_subjects = sorted({clips[c]["subject"] for c in splits.get("train", [])})
    meta = {"format": "faceformer", "dataset": preset, "fps": p.fps, "source_fps": p.source_fps,
            "mesh_stride": p.mesh_stride, "sample_rate": 16000, "n_vertices": p.n_vertices, "units": p.units,
            "max_frame_mismatch": 5, "speakers": sorted({c["subject"] for c in clips.values()}),
            "train_speakers": train_subjects, "emotions": ["neutral"], "splits": splits, "clips": clips,
            "skipped": sorted((wavs | verts) - set(used))}
    (out / "metadata.json").write_text(json.dumps(meta, indent=1))
    for f in out.iterdir():
        os.chmod(f, default_file_mode())
    return meta


def _check_templates(root: Path, preset: str, subjects: set[str], out: Path) -> None:
    """Check that every subject of the splits has a template of the preset's vertex count.

    A ``templates.pkl`` (FaceFormer's) is converted into ``out/templates.npz`` on every run, so the npz is never
    stale; without a pickle the dataset's own ``templates.npz`` is read (and left where it is).
    """
    from ..checks import load_npz

    p = PRESETS[preset]
    npz, pkl = root / "templates.npz", root / "templates.pkl"
    if pkl.exists() or not npz.exists():  # derived from the pickle, every run: never a stale npz
        convert_templates(pkl, out / "templates.npz", overwrite=True)
        t_source, t_name = out / "templates.npz", pkl
    else:
        t_source, t_name = npz, npz
    t = load_npz(t_source, sorted(subjects))
    missing = sorted(subjects - set(t))
    if missing:
        raise ValueError(f"{t_name} has no template for subject(s) {missing}")
    sizes = {t[s].size // 3 for s in subjects}
    if sizes != {p.n_vertices}:
        raise ValueError(f"{root}: templates have {sorted(sizes)} vertices, the {preset} preset expects "
                         f"{p.n_vertices}")


def _dataset_regions(root: Path, p: DatasetPreset) -> dict[str, list[int]]:
    """Named vertex regions of the dataset: from the preset's index files, then from its masks pickle (VOCASET's
    ``FLAME_masks.pkl``).

    An index file wins over the pickle's masks for the same region; a region whose files are absent is left out.
    """
    regions = {}
    for region, rel in p.region_files.items():
        if (root / rel).is_file():
            regions[region] = read_index_file(root / rel, p.n_vertices).tolist()
    if p.masks_pickle and (root / p.masks_pickle).is_file():
        masks = safe_load_pickle(root / p.masks_pickle)
        for region, parts in p.mask_regions.items():
            if region not in regions and all(k in masks for k in parts):
                regions[region] = sorted({int(i) for k in parts for i in np.asarray(masks[k]).reshape(-1)})
    return regions


def _clip_table(root: Path, used: list[str], splits: dict[str, list[str]]) -> dict[str, dict]:
    """``{clip: {subject, sentence_id, split, n_source_frames}}`` of the clips in a split (each .npy is opened
    safely, to read its frame count)."""
    from ..checks import load_npy

    clips = {}
    for name in used:
        subject, sentence = parse_clip_name(name)
        split = next(s for s, c in splits.items() if name in c)
        shape = load_npy(root / "vertices_npy" / f"{name}.npy", f"vertices of clip {name!r}").shape
        clips[name] = {"subject": subject, "sentence_id": sentence, "split": split,
                       "n_source_frames": int(shape[0])}
    return clips


# -------------------------------------------------------------------------------------- commands
def convert_templates_command(args) -> Path:
    """``dualtalker-lite convert-templates`` on the arguments :func:`dualtalker_lite.parsers.convert_templates_parser`
    parsed -> the .npz written."""
    from ..files import claim

    with claim(args.out or Path(args.pickle).with_suffix(".npz")):
        out = convert_templates(args.pickle, args.out, args.overwrite)
    with np.load(out, allow_pickle=False) as npz:
        print(f"{len(npz.files)} templates ({npz[npz.files[0]].size // 3} vertices) -> {out}")
    return out


def prepare_command(args) -> dict:
    """``dualtalker-lite prepare-dataset`` on the arguments :func:`dualtalker_lite.parsers.prepare_parser` parsed -> the
    metadata written."""
    meta = prepare_dataset(args.root, args.preset, args.overwrite)
    sizes = {k: len(v) for k, v in meta["splits"].items()}
    print(f"{args.root}: {len(meta['clips'])} clips at {meta['fps']} fps, {meta['n_vertices']} vertices; "
          f"splits {sizes}; {len(meta['skipped'])} file(s) outside every split -> {Path(args.root) / 'metadata.json'}")
    return meta
