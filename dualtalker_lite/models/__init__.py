"""One module per paper, plus baselines: ``dualtalker`` (DualTalker and its FaceFormer-style baseline config),
``corrtalk`` (CorrTalk: hierarchical speech features, strong/weak branches),
``audio_encoder`` (the small wav2vec 2.0 stand-in shared by the models), ``baselines`` (static template, VOCA-style)."""
from .audio_encoder import AudioFeatureExtractor
from .corrtalk import CorrTalk, CorrTalkConfig
from .dualtalker import DualTalker, DualTalkerConfig, faceformer_config

__all__ = ["AudioFeatureExtractor", "DualTalker", "DualTalkerConfig", "faceformer_config", "CorrTalk",
           "CorrTalkConfig"]
