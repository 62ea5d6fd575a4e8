"""One module per paper, plus the baselines. Each model composes ``blocks/`` (the shared FaceFormer-style
``blocks.decoder.MotionDecoder``, the audio feature extractor ``blocks.audio_encoder``, the paper's own blocks) and its
paper's ``losses`` module; no model imports another model.

- ``faceformer``  the FaceFormer-style baseline: audio feature extractor + one MotionDecoder
- ``dualtalker``  DualTalker: primal task (a MotionDecoder with DualTalker's fusion) + dual task (lip reading)
- ``corrtalk``    CorrTalk: hierarchical speech features, strong and weak MotionDecoders joined by an FAI mask
- ``emoface``     EmoFace: emotion and content branches (two MotionDecoders), Mesh Attention, self-growing training
- ``baselines``   static template and a VOCA-style sliding-window regressor
- ``contract``    what every model offers (the ``TalkingFaceModel`` Protocol) and the optional hooks (``contract.hook``)
- ``bounds``      the config half of the contract: each field's range and the model's size, checked before a layer of
                  a checkpoint's model is built
- ``registry``    the one table of models (name -> class, config, builder) that checkpoints, runner and CLI read
"""
from .baselines import StaticTemplate, VocaConfig, VocaStyle
from .corrtalk import CorrTalk, CorrTalkConfig
from .dualtalker import DualTalker, DualTalkerConfig
from .emoface import EmoFace, EmoFaceConfig
from .faceformer import FaceFormer, FaceFormerConfig

__all__ = ["FaceFormer", "FaceFormerConfig", "DualTalker", "DualTalkerConfig", "CorrTalk", "CorrTalkConfig",
           "EmoFace", "EmoFaceConfig", "StaticTemplate", "VocaConfig", "VocaStyle"]
