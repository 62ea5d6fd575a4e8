"""Compatibility names for code written against dualtalker-lite <= 0.1 (``from dualtalker_lite.utils import ...``).

The helpers live by what they are for: :mod:`~dualtalker_lite.seeding` (``set_seed``), :mod:`~dualtalker_lite.checks`
(shapes, finite values, safe ``.npy`` loads), :mod:`~dualtalker_lite.files` (run folders, atomic writes) and
:mod:`~dualtalker_lite.processes` (worker processes). The package itself imports from those modules.
"""
from .checks import NonFiniteError, check_finite, check_shape, load_npy
from .files import AtomicOutputDir, atomic_torch_save, atomic_write_text, default_file_mode, repo_root, runs_dir
from .processes import watch_parent
from .seeding import set_seed

__all__ = ["set_seed", "check_shape", "runs_dir", "atomic_torch_save", "repo_root", "load_npy", "check_finite",
           "NonFiniteError", "default_file_mode", "AtomicOutputDir", "atomic_write_text", "watch_parent"]
