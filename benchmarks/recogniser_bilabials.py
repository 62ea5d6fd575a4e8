"""How many /p b m/ the phoneme recogniser's viseme track marks: the ceiling of the phonetic tables' closures.

    .venv/bin/python benchmarks/recogniser_bilabials.py [--splits test_a test_emo_a] [--tolerance 1]

The phonetic tables test every model on the recogniser's (hama's) viseme tracks of the test audio, so a model can
close its lips only where the track says PP. For each split this prints how many of the corpus's /p b m/ segments
have a PP frame in the track within ``--tolerance`` mesh frames of the segment (the tracks come from the
recogniser's cache when the tables have been run; otherwise about a CPU minute per split). Against it read the
tables' "closed < 2 mm at /p b m/" column (issue 31: at the short recipe every trained row sits at this fraction).
"""
import argparse

import numpy as np

from dualtalker_lite.experiments.runner import load_data, test_features
from dualtalker_lite.face.visemes import VISEMES
from dualtalker_lite.metrics import BILABIALS, segment_extrema

PP = VISEMES.index("PP")


def marked(classes: np.ndarray, segments, fps: float, tolerance: int = 1) -> tuple[int, int]:
    """Per-frame viseme ids (T,) and phone segments [(symbol, start s, end s), ...] -> (bilabial segments with a PP
    frame among their frames widened by ``tolerance`` each side; bilabial segments). The frames of a segment are
    the closure metrics' (``metrics.segment_frames``, through ``segment_extrema``)."""
    found = segment_extrema((classes == PP).astype(float), segments, BILABIALS, reduce="max", fps=fps,
                            tolerance_frames=tolerance)
    return int((found > 0).sum()), len(found)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--splits", nargs="+", default=["test_a"])
    ap.add_argument("--tolerance", type=int, default=1, help="mesh frames each side of a segment (default 1)")
    args = ap.parse_args()
    data = load_data()
    corpus = data["corpus"]
    for split in args.splits:
        tracks = test_features(data, split, "visemes")
        hit = total = 0
        for i in range(len(tracks)):
            item = tracks[i]
            h, t = marked(item["audio"].argmax(-1).numpy(), corpus.meta(item["name"])["phonemes"], corpus.fps,
                          args.tolerance)
            hit, total = hit + h, total + t
        print(f"{split}: the recogniser's track marks PP at {hit} of {total} /p b m/ ({hit / total:.3f}), "
              f"within {args.tolerance} frame(s)")


if __name__ == "__main__":
    main()
