"""Building blocks of the models: attention (eqs. 3-4), FaceFormer's positional encoding/biases, the
speaker-aware gate (eq. 5), DualTalker's cross-modal fusion with its dual form (eqs. 6-7, Figs. 2-3), and windowed
attention for long audio (banded encoder attention, sliding-window decoder cache); EmoFace's spirals and SpiralConv3D
(eqs. 1-3) and Mesh Attention (section 3.2)."""
from .attention import FeedForward, KVCache, MultiHeadAttention, multi_head_attention, scaled_dot_product_attention
from .fusion import CrossModalFusion, DualFusionLayer, DualIntegration
from .gates import SpeakerAwareGate
from .mesh_attention import MeshAttention
from .positional import PeriodicPositionalEncoding, alibi_causal_bias, alibi_slopes, alignment_mask
from .spiral import SpiralConv3D, k_rings, spiral_indices, spiral_mask
from .windowed import SlidingKVCache, banded_attention, banded_multi_head_attention, dropped_mass_bound

__all__ = ["scaled_dot_product_attention", "multi_head_attention", "MultiHeadAttention", "KVCache", "FeedForward",
           "PeriodicPositionalEncoding", "alibi_slopes", "alibi_causal_bias", "alignment_mask",
           "SpeakerAwareGate", "DualIntegration", "CrossModalFusion", "DualFusionLayer",
           "banded_attention", "banded_multi_head_attention", "SlidingKVCache", "dropped_mass_bound",
           "k_rings", "spiral_indices", "spiral_mask", "SpiralConv3D", "MeshAttention"]
