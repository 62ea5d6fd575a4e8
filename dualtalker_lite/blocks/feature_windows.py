"""Audio features of a long clip, encoded block by block in overlapping windows: memory flat in the clip length.

Generation decodes frames in blocks of ``chunk`` (``blocks.decoder.autoregressive_chunks``). Frame t of the decoder
reads the encoded features X at a few frames around t only (FaceFormer's centred alignment: t - (w-1)//2 .. t + w//2;
DualTalker's eq. 6: X_t; EmoFace's Mesh Attention: the last few frames). So the features of block [start, stop)
need only exist for the frames ``[start - left, stop + right)``, and every audio encoder of the package is *local*:
its output at t depends on the input frames t - R .. t + R only, R its receptive field
(``AudioFeatureExtractor.receptive_field``: convolutions + band radius per layer). Hence, per block:

    features wanted:  frames [lo, hi) = [start - left, stop + right) ∩ [0, T)
    audio encoded:    A[a:b], a = max(0, lo - R) rounded down to a multiple of the period p,  b = min(T, hi + R)
    kept:             encode(A[a:b])[lo - a : hi - a]                                          (B, hi - lo, d)

Why this is exact (to float rounding) whenever R >= the receptive field:

- Frames near a window edge differ from the whole-clip encoding in two ways only: a 'same' convolution sees zeros
  beyond the edge, and banded attention sees fewer keys. Both reach at most R frames into the window (each
  convolution k // 2 frames, each banded layer its radius), and every kept frame is at least R frames from a
  window edge that is not also a clip edge (where the window and the clip agree anyway).
- The periodic positional encoding adds PPE((t - a) mod p) to the window's frame t - a; with a a multiple of p that
  is PPE(t mod p), the phase of the absolute frame, as in the whole-clip encoding.
- Everything else (projections, LayerNorms, the padding mask, per-frame statistics) is per frame.

Memory beyond the input features A (B, T, D_a): one window, O(chunk + 2 R + p) frames, instead of O(T). The cost is
encoding the margins twice (each block also encodes R frames on both sides). An encoder that is not local (a band
radius of None: whole-clip attention) has no finite R: ``margin=None`` then encodes the whole clip once, as before.

:class:`FeatureWindows` holds the input and the encoder (any function of an audio window and its padding mask to
one or several per-frame feature tensors), and hands out the features of one block at a time (:meth:`load`);
``FeatureWindows.precomputed`` wraps features already computed for the whole clip (the reference path, training).
"""
from __future__ import annotations

from typing import Callable, Iterator, Sequence

import torch
from torch import Tensor

__all__ = ["Encode", "encoder_window", "FeatureWindows"]

# (A window (B, n, D_a), its padding mask (B, n) or None) -> per-frame features [(B, n, ...), ...]
Encode = Callable[[Tensor, "Tensor | None"], Sequence[Tensor]]


def encoder_window(lo: int, hi: int, length: int, margin: int, period: int = 1) -> tuple[int, int]:
    """The audio frames [a, b) to encode for exact features of frames [lo, hi) of a clip of ``length`` frames:
    ``margin`` frames more on each side, clipped to the clip, a rounded down to a multiple of ``period`` (so the
    periodic positional encoding's phase of every frame is that of its absolute index)."""
    if margin < 0 or period < 1:
        raise ValueError(f"need margin >= 0 and period >= 1, got margin={margin}, period={period}")
    a = max(0, lo - margin)
    return a - a % period, min(length, hi + margin)


class FeatureWindows:
    """Per-frame features of a clip of T frames, computed for one block of frames at a time.

    ``encode``: audio window (B, n, D_a), mask (B, n) or None -> list of features (B, n, ...) (e.g. [X] or
    [F_strong, F_weak]); ``audio`` A (B, T, D_a): a tensor or anything sliced ``A[:, a:b]`` into one (the
    ``animate`` command's on-disk ``streaming.SpooledFeatures``); ``mask`` (B, T) True on valid frames; ``margin``:
    frames encoded on each side of what is asked for, the encoder's receptive field (None: encode the whole clip
    once); ``period``: of the encoder's periodic positional encoding (window starts are multiples of it); ``left``/
    ``right``: frames before/after each block that the consumer reads (e.g. a fusion over the last frames).
    """

    def __init__(self, encode: Encode | None, audio: Tensor | None, mask: Tensor | None = None,
                 margin: int | None = None, period: int = 1, left: int = 0, right: int = 0):
        if margin is not None and margin < 0 or period < 1 or left < 0 or right < 0:
            raise ValueError(f"need margin >= 0 (or None), period >= 1, left/right >= 0, got margin={margin}, "
                             f"period={period}, left={left}, right={right}")
        self.encode, self.audio, self.mask = encode, audio, mask
        self.length = 0 if audio is None else audio.shape[1]  # T
        self.margin, self.period, self.left, self.right = margin, period, left, right
        self._whole: list[Tensor] | None = None  # features of the whole clip (margin None / precomputed)
        self.offset, self.current = 0, None  # first frame and features of the block loaded last

    @classmethod
    def precomputed(cls, features: Sequence[Tensor]) -> "FeatureWindows":
        """Features already computed for the whole clip, [(B, T, ...), ...]: blocks are views of them."""
        stream = cls(None, None)
        stream._whole, stream.length = list(features), features[0].shape[1]
        stream.current = stream._whole  # the whole clip is loaded (the reference loop reads any frame)
        return stream

    def load(self, start: int, stop: int, left: int = 0, right: int = 0) -> tuple[int, list[Tensor]]:
        """Features of frames [lo, hi) = [start - left, stop + right) ∩ [0, T) (``left``/``right`` at least the
        stream's own) -> (lo, [(B, hi - lo, ...), ...]); they become the :meth:`frames` readable until the next load."""
        lo = max(0, start - max(left, self.left))
        hi = min(self.length, stop + max(right, self.right))
        if self._whole is None and self.margin is None:  # a global encoder: the whole clip, once
            with self._full_precision():
                self._whole = list(self.encode(self.audio[:, :self.length], self.mask))  # a tensor even if A
                # is a window reader (streaming.SpooledFeatures)
        if self._whole is not None:
            feats = [f[:, lo:hi] for f in self._whole]  # views
        else:
            a, b = encoder_window(lo, hi, self.length, self.margin, self.period)
            mask = None if self.mask is None else self.mask[:, a:b]  # (B, b - a)
            with self._full_precision():
                feats = [f[:, lo - a:hi - a] for f in self.encode(self.audio[:, a:b], mask)]  # (B, hi - lo, ...)
        self.offset, self.current = lo, feats
        return lo, feats

    def _full_precision(self):
        """The encoder runs outside the caller's autocast (``animate --amp`` wraps each block): in the model's own
        dtype, as when the features were computed before the first block."""
        return torch.autocast(self.audio.device.type, enabled=False)

    def frames(self, lo: int, hi: int) -> list[Tensor]:
        """Absolute frames [lo, hi) of the block loaded last -> [(B, hi - lo, ...), ...] (views)."""
        n = self.current[0].shape[1]
        if lo < self.offset or hi > self.offset + n:
            raise IndexError(f"frames [{lo}, {hi}) are outside the loaded block [{self.offset}, {self.offset + n})")
        return [f[:, lo - self.offset:hi - self.offset] for f in self.current]

    def blocks(self, chunk: int) -> Iterator[tuple[int, list[Tensor]]]:
        """Every frame once: (start, features of frames [start, start + chunk) ∩ [0, T)) for start = 0, chunk, ...
        (a streaming pass, e.g. to pool statistics over the clip)."""
        for start in range(0, self.length, chunk):
            stop = min(self.length, start + chunk)
            self.load(start, stop)
            yield start, self.frames(start, stop)
