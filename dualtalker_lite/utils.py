"""Old addresses of code written against dualtalker-lite <= 0.1 (``from dualtalker_lite.utils import ...``).

Deprecated: each name still works for one release, with a DeprecationWarning naming its new address (listed in
``CHANGELOG.md``). The helpers live by what they are for: :mod:`~dualtalker_lite.seeding` (``set_seed``),
:mod:`~dualtalker_lite.checks` (shapes, finite values, safe ``.npy`` loads), :mod:`~dualtalker_lite.files` (run
folders, atomic writes) and :mod:`~dualtalker_lite.processes` (worker processes).
"""
from . import checks as _checks, files as _files, processes as _processes, seeding as _seeding
from .deprecation import moved

_NEW = {"set_seed": _seeding, "check_shape": _checks, "load_npy": _checks, "check_finite": _checks,
        "NonFiniteError": _checks, "runs_dir": _files, "atomic_torch_save": _files, "repo_root": _files,
        "default_file_mode": _files, "AtomicOutputDir": _files, "atomic_write_text": _files,
        "watch_parent": _processes}

__all__ = list(_NEW)
__getattr__ = moved(__name__, {name: (f"{module.__name__}.{name}", getattr(module, name))
                               for name, module in _NEW.items()})
