"""benchmarks/recogniser_bilabials.py's count of the /p b m/ a viseme track marks, on a case worked by hand."""
import importlib.util

import numpy as np

from dualtalker_lite.face.visemes import VISEMES
from dualtalker_lite.files import repo_root


def _module():
    path = repo_root() / "benchmarks" / "recogniser_bilabials.py"
    spec = importlib.util.spec_from_file_location("recogniser_bilabials", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_marked_counts_bilabial_segments_with_a_pp_frame_nearby():
    """30 fps, 10 frames, PP only at frame 5; a segment's frames are those whose time lies in it (the closure
    metrics' rule). "p" 0.10-0.15 s covers frames 3-4, widened by one: 2-5, so PP is found; "m" 0.25-0.30 s covers
    frame 8, widened 7-9 (by two 6-10): not found; "b" 0.00-0.01 s covers frame 0: not found; the vowel is not
    counted. Without widening the "p" misses frame 5 too."""
    classes = np.full(10, VISEMES.index("aa"))
    classes[5] = VISEMES.index("PP")
    segments = [("p", 0.10, 0.15), ("a", 0.15, 0.25), ("m", 0.25, 0.30), ("b", 0.0, 0.01)]
    marked = _module().marked
    assert marked(classes, segments, 30.0, tolerance=1) == (1, 3)
    assert marked(classes, segments, 30.0, tolerance=0) == (0, 3)
    assert marked(classes, segments, 30.0, tolerance=2) == (1, 3)
    assert marked(classes, segments, 30.0, tolerance=3) == (2, 3)  # "m" widened to 5-11 reaches frame 5
