"""One module per paper, plus baselines: ``dualtalker`` (DualTalker and its FaceFormer-style baseline config),
``corrtalk`` (CorrTalk: hierarchical speech features, strong/weak branches), ``emoface`` (EmoFace: emotion and
content branches, Mesh Attention, self-growing training),
``audio_encoder`` (the small wav2vec 2.0 stand-in shared by the models), ``baselines`` (static template, VOCA-style)."""
from .audio_encoder import AudioFeatureExtractor
from .corrtalk import CorrTalk, CorrTalkConfig
from .dualtalker import DualTalker, DualTalkerConfig, faceformer_config
from .emoface import EmoFace, EmoFaceConfig

__all__ = ["AudioFeatureExtractor", "DualTalker", "DualTalkerConfig", "faceformer_config", "CorrTalk",
           "CorrTalkConfig", "EmoFace", "EmoFaceConfig"]
