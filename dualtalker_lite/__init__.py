"""dualtalker-lite: tested, notebook-first implementations of DualTalker, CorrTalk and EmoFace.

Layout (data -> features -> blocks -> models -> losses -> metrics -> training -> visualisation):

- ``dualtalker_lite.face``     procedural face rig: template mesh, regions, rig controls, speakers, visemes
- ``dualtalker_lite.data``     espeak-ng speech, clip synthesis, corpus generator, Dataset/collate
- ``dualtalker_lite.audio``    audio I/O, resampling, log-mel features (pluggable extractors)
- ``dualtalker_lite.blocks``   attention, positional encodings/biases, speaker-aware gate, dual integration
- ``dualtalker_lite.models``   one module per paper, plus baselines
- ``dualtalker_lite.losses``   primal/dual regression, duality regularisation, CCRL
- ``dualtalker_lite.metrics``  LVE, FDD, EVE, lip distance
- ``dualtalker_lite.train``    plain training loop, checkpoints
- ``dualtalker_lite.viz``      matplotlib renders, mp4 with sound, pythreejs viewer
"""
__version__ = "0.1.0"
__all__ = ["check_shape", "set_seed", "__version__"]


def __getattr__(name: str):
    # Lazy: `import dualtalker_lite.data.speech` (run in many short-lived worker processes while
    # generating a corpus) must not pay for importing torch.
    if name in ("check_shape", "set_seed"):
        from . import utils

        return getattr(utils, name)
    raise AttributeError(f"module 'dualtalker_lite' has no attribute {name!r}")
