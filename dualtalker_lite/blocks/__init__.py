"""Building blocks of the models: attention (eqs. 3-4), FaceFormer's positional encoding/biases, the
speaker-aware gate (eq. 5), FaceFormer's decoder layer (``faceformer_layer``: self-attention, cross-attention with
the alignment bias, feed-forward, and its one-frame step), DualTalker's cross-modal fusion composed around it with
its dual form (eqs. 6-7, Figs. 2-3), windowed
attention for long audio (banded encoder attention, sliding-window decoder cache, the encoder run
block by block in overlapping windows: ``feature_windows``), the audio feature extractor
(``audio_encoder``, a small wav2vec 2.0 stand-in) and the FaceFormer-style autoregressive ``decoder`` that every
model composes, CorrTalk's facial activity intensity (``fai``) and hierarchical speech encoder (SpeechFormer blocks
at four levels, the weight generator), and EmoFace's spirals and SpiralConv3D (eqs. 1-3) and Mesh Attention
(section 3.2)."""
from .audio_encoder import AudioFeatureExtractor, TransformerEncoderLayer
from .attention import FeedForward, MultiHeadAttention, multi_head_attention, scaled_dot_product_attention
from .decoder import MotionDecoder, autoregressive_chunks, autoregressive_reference
from .faceformer_layer import FaceFormerLayer
from .feature_windows import FeatureWindows, encoder_window
from .fusion import DualFusionLayer, DualIntegration
from .gates import SpeakerAwareGate
from .hierarchical import HierarchicalFeatureExtractor, SpeechFormerBlock, WeightGenerator, window_radius
from .mesh_attention import MeshAttention
from .positional import PeriodicPositionalEncoding, alibi_causal_bias, alibi_slopes, alignment_mask
from .spiral import SpiralConv3D, k_rings, spiral_indices, spiral_mask
from .windowed import SlidingKVCache, banded_attention, banded_multi_head_attention, dropped_mass_bound

__all__ = ["AudioFeatureExtractor", "TransformerEncoderLayer", "MotionDecoder", "autoregressive_chunks",
           "autoregressive_reference", "FeatureWindows", "encoder_window", "scaled_dot_product_attention",
           "multi_head_attention", "MultiHeadAttention",
           "FeedForward",
           "PeriodicPositionalEncoding", "alibi_slopes", "alibi_causal_bias", "alignment_mask",
           "SpeakerAwareGate", "FaceFormerLayer", "DualIntegration", "DualFusionLayer",
           "banded_attention", "banded_multi_head_attention", "SlidingKVCache", "dropped_mass_bound",
           "SpeechFormerBlock", "HierarchicalFeatureExtractor", "WeightGenerator", "window_radius",
           "k_rings", "spiral_indices", "spiral_mask", "SpiralConv3D", "MeshAttention"]
