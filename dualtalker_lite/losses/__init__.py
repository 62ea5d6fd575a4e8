"""Training losses, one module per paper: ``dualtalker`` (eqs. 8-11 of DualTalker; re-exported here, so
``from dualtalker_lite.losses import joint_loss`` keeps working), ``reconstruction`` (the baselines' vertex MSE),
``common`` (masked reductions shared by all), ``contact`` (the short recipe's bilabial contact term, a project
deviation added by ``train`` when ``TrainConfig.lip_contact`` is set).
CorrTalk's and EmoFace's losses sit beside them in their own modules."""
from .common import masked_mean
from .corrtalk import CorrTalkWeights
from .dualtalker import (READINGS, LossWeights, ccrl_anchor_losses, ccrl_loss, dual_loss, duality_loss, joint_loss,
                         primal_loss, rbf_kernel_weights)
from .emoface import EmoFaceWeights, emoface_loss
from .reconstruction import ReconstructionWeights, reconstruction_loss

__all__ = ["masked_mean", "primal_loss", "dual_loss", "duality_loss", "rbf_kernel_weights", "READINGS",
           "ccrl_anchor_losses", "ccrl_loss", "LossWeights", "joint_loss", "CorrTalkWeights", "EmoFaceWeights",
           "emoface_loss", "ReconstructionWeights", "reconstruction_loss"]
