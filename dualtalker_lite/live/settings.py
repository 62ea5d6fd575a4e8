"""What a live session trades, :class:`LiveSettings`, in a module that imports nothing heavy: ``dualtalker-lite live
--help`` shows its defaults without loading torch (:mod:`dualtalker_lite.choices`). The streaming parts that use it:
:mod:`dualtalker_lite.live.stream`, which re-exports it."""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["LiveSettings", "EARS", "student_latency_s"]

EARS = ("hama", "student")   # who hears the visemes live (LiveSettings.ears)


def student_latency_s(lookahead: int) -> float:
    """The student's track: frame f's id needs audio up to f / fps + this (``StreamingStudentVisemes``): 20 ms (the
    student frame after f / fps) + ``lookahead`` frames of 20 ms + 16 ms (the STFT's half window)."""
    return (1 + lookahead) * 0.02 + 0.016


@dataclass
class LiveSettings:
    """What a live session trades: look-ahead (latency) against agreement with the offline animation, and past
    context and hop against cost. Defaults measured in ``docs/live.md``."""
    lookahead_s: float = 0.25     # recogniser look-ahead (was 0.2: 0.25 with ahead_frames 0 meets the closure target
                                  # on all 255 real-voice prompts at a 50 ms smaller budget than 0.2 with 3; live.md)
    past_s: float = 2.0           # recogniser context before the first frame not yet final (was 0.6, results/live.md)
    hop_s: float = 0.2            # hama runs once per hop of new audio
    past_frames: int = 60         # audio-encoder context (mesh frames) before a decoded frame
    ahead_frames: int = 0         # audio-encoder look-ahead (mesh frames) after it (was 3: fewer close the lips
                                  # more often live, at a little less agreement with offline; results/live.md)
    ears: str = "student"         # who hears the visemes: "student" (StreamingStudentVisemes: its own look-ahead,
                                  # no hop, no past_s; the default since it met the live targets, docs/ears.md) or
                                  # "hama" (StreamingVisemes, the settings above)

    def latency_s(self, fps: float = 30.0, lag_s: float = 0.02, window_s: float = 0.1,
                  student_lookahead: int | None = None) -> float:
        """The algorithmic latency (no compute): frame f's vertices need audio up to f / fps + this at most (hama:
        in a pause; during speech window_s is cut to the distance to the frame's nearest spike, StreamingVisemes;
        the student: :func:`student_latency_s` of its look-ahead)."""
        if self.ears == "student":
            return student_latency_s(student_lookahead or 0) + self.ahead_frames / fps
        return self.lookahead_s + lag_s + window_s + self.ahead_frames / fps
