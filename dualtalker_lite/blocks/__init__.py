"""Building blocks of the models: attention (eqs. 3-4), FaceFormer's positional encoding/biases, the
speaker-aware gate (eq. 5) and DualTalker's cross-modal fusion with its dual form (eqs. 6-7, Figs. 2-3)."""
from .attention import FeedForward, KVCache, MultiHeadAttention, multi_head_attention, scaled_dot_product_attention
from .fusion import CrossModalFusion, DualFusionLayer, DualIntegration
from .gates import SpeakerAwareGate
from .positional import PeriodicPositionalEncoding, alibi_causal_bias, alibi_slopes, alignment_mask

__all__ = ["scaled_dot_product_attention", "multi_head_attention", "MultiHeadAttention", "KVCache", "FeedForward",
           "PeriodicPositionalEncoding", "alibi_slopes", "alibi_causal_bias", "alignment_mask",
           "SpeakerAwareGate", "DualIntegration", "CrossModalFusion", "DualFusionLayer"]
