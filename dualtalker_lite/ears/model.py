"""The student: a small causal conv net that hears visemes with a fixed look-ahead (issue 47, docs/ears.md).

Input: log-mel frames ``X`` (B, T, 80) at a **20 ms hop**, the teacher's (``ears.teacher``: hama's own frame
rate, so its posteriors need no resampling and the student runs half the frames of a 10 ms hop):
:func:`student_features` is ``audio.log_mel_spectrogram`` with ``hop_length`` 320 (Hann 25 ms, n_fft 512, 80 HTK
mels, ``1 + N // 320`` frames, frame t centred on sample ``320 t`` as hama's frame t). Output: logits over the 15
visemes of :data:`~dualtalker_lite.face.visemes.VISEMES` per frame, (B, T, 15).

The net is *causal*: every convolution is padded on the left only, so its raw output ``h_u`` depends on
``X_{<=u}``. The look-ahead is a delay: the prediction for frame t is the raw output at ``u = t + L``

    y_t = head(h_{t+L}),   h_u = f(X_{u-R+1 .. u}),   R = 1 + (k - 1) * sum(dilations)

so y_t reads the input frames ``<= t + L`` only (L = ``lookahead`` frames, 3 = 60 ms by default; the STFT window
adds 16 ms, ``n_fft / 2`` samples, before a frame can be computed from audio). After the last frame the input is
padded with L frames of digital silence, ``log(1e-6)`` (:data:`SILENCE`), whole or streamed alike.

Architecture (nanoGPT-sized, :class:`StudentConfig`): per-mel normalisation (buffers set from the training data)
-> pointwise projection 80 -> C -> one residual :class:`Block` per dilation d (causal depthwise conv,
layer norm per frame, pointwise MLP C -> 2C -> C) -> layer norm -> linear head C -> 15. The default (C 128, 4
blocks, dilations 1 2 4 8, kernel 5) has ~0.28 M parameters (1.1 MB in float32), R = 61 frames (1.2 s of past).

:class:`StudentStream` runs the same net on chunks of any size (audio or feature frames): each conv keeps its last
``(k - 1) d`` inputs, every frame goes through the net exactly once, and the outputs equal :meth:`Student.forward`
of the whole utterance (``tests/test_ears_model.py``).

Weights: :func:`save_student` writes config, normalisation, weights and provenance (command, commit) in one small
torch file that :func:`load_student` reads with ``weights_only=True``; a missing or corrupt file is one
:class:`StudentWeightsError` line. The package's own weights live at :func:`default_weights_path`.
:class:`StudentExtractor` is the ``student`` front end: posteriors resampled to the mesh rate (:func:`to_mesh_rate`).
"""
from __future__ import annotations

import hashlib
import math
import os
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from ..audio import LOG_EPS, N_FFT, N_MELS, SAMPLE_RATE, log_mel_spectrogram, mel_filterbank
from ..face.visemes import VISEMES
from ..provenance import provenance

__all__ = ["StudentConfig", "Block", "Student", "StudentStream", "student_features", "SILENCE", "HOP", "HOP_S",
           "WEIGHTS_ENV", "WEIGHTS_FORMAT", "TRAIN_HINT", "StudentWeightsError", "default_weights_path",
           "save_student", "load_student", "calibrate_student", "to_mesh_rate", "StudentExtractor"]

HOP = 320                           # samples per student frame: 20 ms at 16 kHz, hama's (the teacher's) hop
HOP_S = HOP / SAMPLE_RATE           # 0.02 s
SILENCE = math.log(LOG_EPS)         # -13.8: the log-mel of digital silence, the padding after the last frame
WEIGHTS_ENV = "DUALTALKER_STUDENT_WEIGHTS"   # overrides the shipped weights' path (tests, experiments)
WEIGHTS_FORMAT = 1
PP = VISEMES.index("PP")            # the viseme of /p b m/
TRAIN_HINT = ("train them with `python -m dualtalker_lite.ears.distil --data SHARDS --out PATH` "
              "(docs/ears.md, 'Distillation')")


def student_features(wave: np.ndarray | torch.Tensor) -> torch.Tensor:
    """The student's input: log-mel (1 + N // 320, 80) of a 16 kHz wave, 20 ms hop (``audio.log_mel_spectrogram``)."""
    return log_mel_spectrogram(wave, hop_length=HOP)


@dataclass
class StudentConfig:
    """The student's sizes and look-ahead; the default is the shipped one's, :meth:`tiny` for tests."""

    n_mels: int = N_MELS            # input features per frame
    n_visemes: int = len(VISEMES)   # 15 output classes
    channels: int = 128             # C
    kernel: int = 5                 # k of every depthwise conv
    dilations: tuple = (1, 2, 4, 8) # one block per dilation
    lookahead: int = 3              # L frames of future input (3 x 20 ms = 60 ms)
    dropout: float = 0.1
    pp_bias: float = 0.0            # b: log-odds added to the PP logit after training (calibrate_student)

    @classmethod
    def tiny(cls, **overrides) -> "StudentConfig":
        """A few thousand parameters: for tests and notebooks."""
        return cls(**{"channels": 16, "kernel": 3, "dilations": (1, 2), "lookahead": 1, **overrides})

    @property
    def receptive_field(self) -> int:
        """R: input frames that one raw output reads (its own and R - 1 past ones)."""
        return 1 + (self.kernel - 1) * sum(self.dilations)


class Block(nn.Module):
    """x + MLP(LN(x + DWConv_causal(x))): one causal depthwise conv (time) then a pointwise MLP (channels)."""

    def __init__(self, cfg: StudentConfig, dilation: int):
        super().__init__()
        self.context = (cfg.kernel - 1) * dilation                       # past frames the conv reads
        self.conv = nn.Conv1d(cfg.channels, cfg.channels, cfg.kernel, dilation=dilation, groups=cfg.channels)
        self.norm = nn.LayerNorm(cfg.channels)
        self.mlp = nn.Sequential(nn.Linear(cfg.channels, 2 * cfg.channels), nn.GELU(),
                                 nn.Linear(2 * cfg.channels, cfg.channels), nn.Dropout(cfg.dropout))

    def forward(self, x: torch.Tensor, past: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """x (B, n, C) new frames; past (B, context, C) the frames before them (None: zeros, the utterance's start).
        Returns the block's output (B, n, C) and the new ``past`` (the last ``context`` inputs)."""
        if past is None:
            past = x.new_zeros(x.shape[0], self.context, x.shape[2])
        seq = torch.cat([past, x], dim=1)                                 # (B, context + n, C)
        h = self.conv(seq.transpose(1, 2)).transpose(1, 2)                # (B, n, C): valid conv = causal
        y = x + self.mlp(self.norm(x + h))                                # (B, n, C)
        return y, seq[:, seq.shape[1] - self.context:]


class Student(nn.Module):
    """The causal viseme recogniser: (B, T, n_mels) log-mel -> (B, T, 15) viseme logits, look-ahead L frames."""

    def __init__(self, cfg: StudentConfig):
        super().__init__()
        self.cfg = cfg
        self.register_buffer("mean", torch.zeros(cfg.n_mels))            # per-mel input normalisation,
        self.register_buffer("std", torch.ones(cfg.n_mels))              # set by distil from its training data
        self.proj = nn.Linear(cfg.n_mels, cfg.channels)
        self.blocks = nn.ModuleList(Block(cfg, d) for d in cfg.dilations)
        self.norm = nn.LayerNorm(cfg.channels)
        self.head = nn.Linear(cfg.channels, cfg.n_visemes)

    def raw(self, x: torch.Tensor, pasts: list | None = None) -> tuple[torch.Tensor, list]:
        """The causal net without the delay: x (B, n, n_mels) -> logits h_u (B, n, 15) and each block's new past."""
        h = self.proj((x - self.mean) / self.std)                         # (B, n, C)
        new = []
        for i, block in enumerate(self.blocks):
            h, p = block(h, None if pasts is None else pasts[i])          # (B, n, C)
            new.append(p)
        y = self.head(self.norm(h))                                        # (B, n, 15)
        if self.cfg.pp_bias:     # the calibrated decision: softmax(y + b e_PP), i.e. PP's odds times exp(b)
            y = y + self.cfg.pp_bias * F.one_hot(torch.tensor(PP), y.shape[-1]).to(y.dtype)
        return y, new

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (B, T, n_mels) a whole utterance -> y (B, T, 15), y_t = h_{t+L} (L silence frames padded at the end)."""
        L = self.cfg.lookahead
        pad = x.new_full((x.shape[0], L, x.shape[2]), SILENCE)
        h, _ = self.raw(torch.cat([x, pad], dim=1))                        # (B, T + L, 15)
        return h[:, L:]                                                    # (B, T, 15)

    @torch.no_grad()
    def posteriors(self, wave: np.ndarray | torch.Tensor) -> torch.Tensor:
        """Viseme posteriors (1 + N // 320, 15) of one 16 kHz wave, whole (eval mode)."""
        was = self.training
        self.eval()
        p = self(student_features(wave)[None]).softmax(-1)[0]
        self.train(was)
        return p


class _LogMelStream:
    """``student_features`` from audio chunks: frame t is computed once samples ``<= 320 t + 255`` have arrived."""

    def __init__(self):
        self.buf = torch.zeros(N_FFT // 2)          # center=True: the wave is zero-padded by n_fft / 2 on the left
        self.n_samples, self.n_frames = 0, 0         # samples received, frames emitted
        self.window = F.pad(torch.hann_window(400), ((N_FFT - 400) // 2, (N_FFT - 400 + 1) // 2))  # as torch.stft
        self.fb = mel_filterbank(N_FFT, N_MELS, SAMPLE_RATE)

    def push(self, wave: torch.Tensor, final: bool = False) -> torch.Tensor:
        """New samples (n,) -> the log-mel frames (m, 80) now complete; ``final``: pad the end, emit the rest."""
        wave = torch.as_tensor(wave, dtype=torch.float32).reshape(-1)              # (n,)
        self.buf = torch.cat([self.buf, wave])
        self.n_samples += wave.shape[0]
        if final:
            self.buf = torch.cat([self.buf, torch.zeros(N_FFT // 2)])
        total = 1 + self.n_samples // HOP if final else None
        m = (self.buf.shape[0] - N_FFT) // HOP + 1 if self.buf.shape[0] >= N_FFT else 0
        m = m if total is None else min(m, total - self.n_frames)
        if m <= 0:
            return torch.zeros(0, N_MELS)
        frames = self.buf[:(m - 1) * HOP + N_FFT].unfold(0, N_FFT, HOP) * self.window  # (m, n_fft)
        spec = torch.fft.rfft(frames, dim=1)                                       # (m, 257)
        out = torch.log((spec.real ** 2 + spec.imag ** 2) @ self.fb.T + LOG_EPS)   # (m, 80)
        self.buf, self.n_frames = self.buf[m * HOP:], self.n_frames + m
        return out


class StudentStream:
    """Runs a :class:`Student` on chunks: ``push`` features (n, n_mels) or ``push_audio`` samples, ``finish`` at the
    end; each returns the posteriors (m, 15) of the frames whose look-ahead has arrived, each frame exactly once.
    ``frames_computed`` counts the frames the net has run on (T + L for an utterance of T frames: no re-runs)."""

    def __init__(self, student: Student):
        self.student = student.eval()
        self.pasts = None                            # each block's last (k - 1) d inputs; None: the start (zeros)
        self.frames_in, self.frames_computed, self.frames_out = 0, 0, 0
        self.mel = None                              # a _LogMelStream once audio is pushed

    @torch.no_grad()
    def push(self, features: torch.Tensor) -> torch.Tensor:
        """Feature frames (n, n_mels) -> posteriors (m, 15) of frames t with t + L now in (m may be 0)."""
        x = torch.as_tensor(features, dtype=torch.float32).reshape(-1, self.student.cfg.n_mels)
        if x.shape[0] == 0:
            return torch.zeros(0, self.student.cfg.n_visemes)
        h, self.pasts = self.student.raw(x[None], self.pasts)            # (1, n, 15): n new raw outputs
        self.frames_in += x.shape[0]
        self.frames_computed += x.shape[0]
        skip = max(0, self.student.cfg.lookahead - (self.frames_in - x.shape[0]))  # raw u < L belong to no frame
        out = h[0, skip:].softmax(-1)                                      # (m, 15)
        self.frames_out += out.shape[0]
        return out

    def push_audio(self, wave: np.ndarray | torch.Tensor) -> torch.Tensor:
        """16 kHz samples (n,) -> posteriors (m, 15): the log-mel frames they complete, through :meth:`push`."""
        self.mel = self.mel or _LogMelStream()
        return self.push(self.mel.push(torch.as_tensor(wave)))

    def finish(self) -> torch.Tensor:
        """The end of the utterance: the remaining audio frames, then L silence frames -> the last posteriors."""
        rest = [self.push(self.mel.push(torch.zeros(0), final=True))] if self.mel is not None else []
        pad = torch.full((self.student.cfg.lookahead, self.student.cfg.n_mels), SILENCE)
        return torch.cat(rest + [self.push(pad)])


class StudentWeightsError(ValueError):
    """A student weights file that is missing or unreadable (its message is one line)."""


def default_weights_path() -> Path:
    """``$DUALTALKER_STUDENT_WEIGHTS``, else the weights shipped in the package: ``ears/weights/student.pt``."""
    return Path(os.environ.get(WEIGHTS_ENV) or Path(__file__).resolve().parent / "weights" / "student.pt")


def save_student(student: Student, path: str | os.PathLike, command: str, extra: dict | None = None) -> Path:
    """Write config, weights (with the normalisation) and provenance (command, commit, time) to ``path``."""
    stamp = provenance(command)
    record = {"format": WEIGHTS_FORMAT, "config": {**asdict(student.cfg), "dilations": list(student.cfg.dilations)},
              "state_dict": {k: v.detach().clone() for k, v in student.state_dict().items()},
              "provenance": {"command": stamp["command"], "commit": stamp["commit"], "created": stamp["created"],
                             **(extra or {})}}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(record, tmp)
    os.replace(tmp, path)
    return path


def load_student(path: str | os.PathLike | None = None) -> tuple[Student, dict]:
    """(student in eval mode, provenance) from a :func:`save_student` file (default: :func:`default_weights_path`).
    One :class:`StudentWeightsError` line when it is missing, unreadable or not a student's weights file."""
    path = Path(path) if path is not None else default_weights_path()
    if not path.is_file():
        raise StudentWeightsError(f"student weights not found at {path}: {TRAIN_HINT}")
    try:
        record = torch.load(path, map_location="cpu", weights_only=True)
        if not isinstance(record, dict) or record.get("format") != WEIGHTS_FORMAT:
            raise ValueError(f"not a format-{WEIGHTS_FORMAT} student weights file")
        known = {f.name for f in fields(StudentConfig)}
        cfg = StudentConfig(**{k: v for k, v in record["config"].items() if k in known})
        cfg.dilations = tuple(cfg.dilations)
        student = Student(cfg)
        student.load_state_dict(record["state_dict"])
    except Exception as e:  # noqa: BLE001 -- any failure to read is the same one line
        reason = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise StudentWeightsError(f"student weights at {path} are corrupt or not a student's ({reason}); "
                                  f"{TRAIN_HINT}") from None
    return student.eval(), dict(record.get("provenance", {}))


def calibrate_student(weights: str | os.PathLike, pp_bias: float, out: str | os.PathLike, command: str) -> Path:
    """Write the student at ``weights`` again with ``cfg.pp_bias = pp_bias`` (the same parameters and
    normalisation) to ``out``; its provenance keeps the training's (``trained``) and adds this ``command``. The
    bias moves the decision, not the net: every posterior becomes ``softmax(y + b e_PP)``, PP's odds against each
    other viseme multiplied by ``exp(b)`` (a prior shift), so more frames near a closure say PP, and some vowel
    frames too. ``benchmarks/student_gate.py`` measures that trade on the face and chooses b (docs/ears.md)."""
    if not math.isfinite(pp_bias) or abs(pp_bias) > 10:
        raise ValueError(f"pp_bias must be a finite number within +-10, got {pp_bias}")
    student, trained = load_student(weights)
    student.cfg.pp_bias = float(pp_bias)
    return save_student(student, out, command,
                        {"pp_bias": float(pp_bias), "trained": trained.get("trained", trained)})


def to_mesh_rate(posteriors: torch.Tensor, n_frames: int, fps: float, first: int = 0,
                 offset: int = 0) -> torch.Tensor:
    """(L, 15) posteriors at the 20 ms hop -> (n_frames - first, 15) at mesh frame times f / fps for f = ``first``
    .. ``n_frames - 1``, linearly interpolated (rows still sum to 1), held at the last frame past the end.
    ``offset``: ``posteriors[0]`` is student frame ``offset`` (a stream that forgot its older frames)."""
    last = offset + posteriors.shape[0] - 1                                        # the newest student frame
    pos = (torch.arange(first, n_frames, dtype=torch.float64) / fps / HOP_S).clamp(0, last)   # (T,)
    i0 = pos.floor().long()
    i1 = (i0 + 1).clamp(max=last)
    w = (pos - i0).float()[:, None]                                                # (T, 1)
    return (1 - w) * posteriors[i0 - offset] + w * posteriors[i1 - offset]         # (T, 15)


class StudentExtractor:
    """The ``student`` front end (``front_ends.FRONT_ENDS``): ``(wave, n_frames) -> (n_frames, 15)`` viseme
    posteriors at ``fps`` mesh frames per second, from the weights at ``weights`` (default:
    :func:`default_weights_path`); ``stream`` gives the same from blocks through :class:`StudentStream`.
    ``hard``: one-hot of each frame's argmax instead (what hama's ``visemes`` track is: ``front_ends.at_test``)."""

    front_end = "student"

    def __init__(self, fps: int = 30, weights: str | os.PathLike | None = None, hard: bool = False):
        self.path = Path(weights) if weights is not None else default_weights_path()
        self.student, self.provenance = load_student(self.path)
        self.fps, self.sample_rate, self.dim = fps, SAMPLE_RATE, self.student.cfg.n_visemes
        self.hard = hard     # one-hot of the argmax per mesh frame: the student as hama's hard track (front_ends.at_test)

    def weights_hash(self) -> str:
        """The first 16 hex digits of the weights file's sha256 (a checkpoint records which student fed it)."""
        return hashlib.sha256(self.path.read_bytes()).hexdigest()[:16]

    def settings(self) -> dict:
        """``{"name": "student", "settings": {...}}``, a checkpoint's ``features`` entry."""
        return {"name": "student", "settings": {"fps": self.fps, "sample_rate": self.sample_rate, "dim": self.dim,
                                                "lookahead": self.student.cfg.lookahead, "visemes": list(VISEMES),
                                                "weights": self.weights_hash()}}

    @classmethod
    def from_settings(cls, features: dict, source: str = "checkpoint",
                      weights: str | os.PathLike | None = None) -> "StudentExtractor":
        """Rebuild from :meth:`settings`; one ValueError line when these weights are not the ones recorded."""
        s = dict(features.get("settings", {}))
        ex = cls(fps=s.get("fps", 30), weights=weights)
        mine = ex.settings()["settings"]
        for key in ("weights", "visemes", "dim", "lookahead"):
            if key in s and s[key] != mine[key]:
                raise ValueError(f"{source}: trained with the student's {key} {s[key]!r}, {ex.path} has {mine[key]!r}")
        return ex

    def __call__(self, wave: np.ndarray | torch.Tensor, n_frames: int) -> torch.Tensor:
        """(n_frames, 15) float32 posteriors at the mesh frame times."""
        if n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {n_frames}")
        return self._out(to_mesh_rate(self.student.posteriors(wave), n_frames, self.fps))

    def _out(self, p: torch.Tensor) -> torch.Tensor:
        return F.one_hot(p.argmax(-1), p.shape[-1]).float() if self.hard else p

    def stream(self, blocks, n_samples: int, n_frames: int) -> torch.Tensor:
        """:meth:`__call__` of a wave given as blocks (an iterable, or a callable returning one), never whole."""
        stream = StudentStream(self.student)
        parts = [stream.push_audio(b) for b in (blocks() if callable(blocks) else blocks)]
        return self._out(to_mesh_rate(torch.cat(parts + [stream.finish()]), n_frames, self.fps))
