"""The command line's choices that its ``--help`` shows, in a module that imports nothing, so that ``dualtalker-lite
--help`` and every ``dualtalker-lite COMMAND --help`` answer without loading torch (about 5 s on a busy laptop; the
work's modules are imported only when a command runs, :mod:`dualtalker_lite.cli`).

Each value is defined here once and the module that works with it imports it from here (and re-exports it):

- :data:`FAST_EPOCHS`       the short recipe's epochs per model (:mod:`dualtalker_lite.train`, ``train --epochs``)
- :data:`FEATURES`          the front ends ``--features`` offers, the default first (:mod:`dualtalker_lite.front_ends`)
- :data:`FORMATS`           ``animate --format``'s formats and :data:`FORMAT_ALIASES` (:mod:`dualtalker_lite.inference`)
- :data:`PLUGINS_ENV`       the variable naming plugin modules (:mod:`dualtalker_lite.models.registry`)
- :data:`TINY_EPOCHS`       ``train --recipe tiny``'s default epochs (:mod:`dualtalker_lite.cli`)
- :data:`TRAINABLE_MODELS`  the package's own trainable models, in the registry's order (``train --model``; the
                            registry builds them, and a test checks that it registers exactly these)

The live server's defaults are :class:`dualtalker_lite.live.settings.LiveSettings`, light for the same reason.
"""
from __future__ import annotations

__all__ = ["EARS", "FAST_EPOCHS", "FEATURES", "FORMATS", "FORMAT_ALIASES", "PLUGINS_ENV", "TINY_EPOCHS",
           "TRAINABLE_MODELS"]

FAST_EPOCHS = {"dualtalker": 20, "faceformer": 30, "corrtalk": 10, "emoface": 4}
EARS = ("visemes", "student")  # front ends that hear the same 15 viseme classes (front_ends.at_test, --front-end)
FEATURES = ("visemes", "logmel")  # the phonetic route (the default: it animates real voices), the papers' log-mel
FORMATS = ("npy", "obj", "gltf", "html", "mp4", "visemes")
FORMAT_ALIASES = {"glb": "gltf"}  # the .glb's old name: now the morph-target file (the flip-book is gone)
PLUGINS_ENV = "DUALTALKER_PLUGINS"
TINY_EPOCHS = 45
TRAINABLE_MODELS = ("voca", "faceformer", "dualtalker", "corrtalk", "emoface")
