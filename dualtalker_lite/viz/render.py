"""The mesh renderer's old address: it lives in :mod:`dualtalker_lite.export.render` (the mp4 writer,
:mod:`dualtalker_lite.export.video`, draws with it below the visualisation layer). Kept because notebook 01
imports ``draw_mesh`` from here."""
from ..export.render import *  # noqa: F401,F403
from ..export.render import __all__  # noqa: F401
