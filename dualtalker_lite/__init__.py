"""dualtalker-lite: tested, notebook-first implementations of DualTalker, CorrTalk and EmoFace.

Layers, lowest first (docs/architecture.md; ``tests/test_architecture.py`` keeps imports pointing down):

- foundations: ``face`` (procedural face rig), ``audio`` (I/O, log-mel), ``recogniser`` (phoneme recogniser front-end),
  ``export`` (glTF, HTML), ``seeding``, ``checks``, ``files``, ``processes``, ``console``,
  ``provenance`` (command, commit and machine of a results file)
- data and blocks: ``data`` (speech, corpus, datasets); ``blocks`` (attention, positional biases, the shared
  FaceFormer-style ``decoder``, the audio feature extractor, each paper's building blocks)
- models and losses: ``models`` (one module per paper, plus the baselines), ``losses`` (one module per paper)
- training and evaluation: ``train``, ``checkpoints``, ``metrics``
- applications: ``experiments``, ``inference``, ``streaming``, ``viz``
- front ends: ``cli``, ``demo``, ``viz.widgets``
"""
__version__ = "0.1.0"
__all__ = ["check_shape", "set_seed", "__version__"]


def __getattr__(name: str):
    # Lazy: `import dualtalker_lite.data.speech` (run in many short-lived worker processes while
    # generating a corpus) must not pay for importing torch.
    if name == "check_shape":
        from .checks import check_shape

        return check_shape
    if name == "set_seed":
        from .seeding import set_seed

        return set_seed
    raise AttributeError(f"module 'dualtalker_lite' has no attribute {name!r}")
