"""The mesh renderer's old address. Deprecated: it lives in :mod:`dualtalker_lite.export.render` (the mp4 writer,
:mod:`dualtalker_lite.export.video`, draws with it below the visualisation layer); every name still works here for
one release, with a DeprecationWarning naming its new address (``CHANGELOG.md``)."""
from ..deprecation import moved
from ..export import render as _render

__all__ = list(_render.__all__)
__getattr__ = moved(__name__, {name: (f"{_render.__name__}.{name}", getattr(_render, name)) for name in __all__})
