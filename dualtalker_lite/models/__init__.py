"""One module per paper, plus baselines: ``dualtalker`` (DualTalker and its FaceFormer-style baseline config),
``audio_encoder`` (the small wav2vec 2.0 stand-in shared by the models), ``baselines`` (static template, VOCA-style)."""
from .audio_encoder import AudioFeatureExtractor
from .dualtalker import DualTalker, DualTalkerConfig, faceformer_config

__all__ = ["AudioFeatureExtractor", "DualTalker", "DualTalkerConfig", "faceformer_config"]
