"""Evaluation metrics, by what they measure.

- :mod:`~dualtalker_lite.metrics.vertex`: lip vertex error (LVE), upper-face dynamics deviation (FDD), emotional vertex
  error (EVE), per-vertex error maps and the lip-sync metrics (bilabial closures, vowel opening, lip-distance
  correlation, lip motion ratio), each in the papers' published convention and in the text's reading.
- :mod:`~dualtalker_lite.metrics.emotion`: EmoFace's "right emotion" measures (brow raise, smile width) and the
  emotion classifier's accuracy.

Every name of :mod:`~dualtalker_lite.metrics.vertex` is importable from here (``from dualtalker_lite.metrics import
lve_euclidean``).
"""

from . import emotion
from .vertex import (
    as_sequences,
    lve_published,
    lve_euclidean,
    fdd_published,
    fdd_paper,
    eve,
    lip_distance,
    mean_vertex_error,
    evaluate,
    BILABIALS,
    OPEN_VOWELS,
    segment_frames,
    segment_extrema,
    closure_rate,
    curve_correlation,
    motion_ratio,
    lip_sync_metrics,
)

__all__ = [
    "emotion",
    "as_sequences",
    "lve_published",
    "lve_euclidean",
    "fdd_published",
    "fdd_paper",
    "eve",
    "lip_distance",
    "mean_vertex_error",
    "evaluate",
    "BILABIALS",
    "OPEN_VOWELS",
    "segment_frames",
    "segment_extrema",
    "closure_rate",
    "curve_correlation",
    "motion_ratio",
    "lip_sync_metrics",
]
