"""Speakers: each has its own head (``FaceShape``) and its own speaking style (gains, asymmetry, resting face).

Identity must be *visible in the motion*, not only in the template (DualTalker's speaker-aware gate and
EmoFace's style code need something to learn), so every speaker gets:

* ``gains``: multipliers on the speech-driven controls (one opens the jaw wide, another barely does);
* ``asymmetry``: smiles are stronger on one side, ``smile_left *= 1 + asymmetry``, ``smile_right *= 1 - asymmetry``;
* ``rest``: resting offsets (a slight permanent smile, raised brows, a mouth that hangs open a little);
* ``articulation``: overall amplitude of speech movements; ``blink_rate``: blinks per second;
* ``accent``, ``accent_lead``, ``pitch_brow``, ``cheek``, ``boundary_blink``: how this speaker's brows, cheeks
  and blinks follow the speech (``face/upper.py``).

``make_speakers(n, seed)`` draws them deterministically; speaker ``i`` also gets one strong *signature trait*
(cycling through ``SIGNATURES``) so that the differences are easy to see and to learn.

Summary: ``Speaker`` is a JSON-able dataclass (``to_dict``/``from_dict``); ``FaceRig(speaker)`` builds its rig.
Exercises: (1) animate the same controls on two speakers side by side; (2) add a "lisper" signature.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .mesh import BASE_VERTICES, FaceShape
from .rig import CONTROL_NAMES

__all__ = ["Speaker", "make_speakers", "SIGNATURES"]

# (field, relative spread) of the head proportions drawn per speaker, uniform in [1 - s, 1 + s] x default.
_SHAPE_SPREAD = {"head_width": 0.06, "head_height": 0.05, "head_depth": 0.05, "eye_height": 0.3,
                 "eye_spacing": 0.06, "eye_width": 0.08, "brow_height": 0.15, "nose_length": 0.1,
                 "nose_depth": 0.2, "philtrum": 0.12, "mouth_width": 0.1, "lip_thickness": 0.2,
                 "lip_fullness": 0.25, "lip_gap": 0.35, "jaw_length": 0.1, "jaw_width": 0.06, "chin_depth": 0.3}
# The controls speech drives (their gains vary per speaker); brows/eyes get gains for the idle motion.
_GAIN_CONTROLS = ("jaw_open", "lip_pucker", "lip_stretch", "smile_left", "smile_right", "upper_lip_raise",
                  "lower_lip_depress", "mouth_frown", "brow_raise", "brow_furrow", "cheek_puff")
# Signature traits: (name, gains, rest offsets, asymmetry, articulation).
SIGNATURES = (
    ("wide jaw", {"jaw_open": 1.4, "lower_lip_depress": 1.3}, {"jaw_open": 0.03}, 0.0, 1.05),
    ("asymmetric smile", {"smile_left": 1.3, "lip_stretch": 1.2}, {"smile_left": 0.25, "smile_right": 0.05}, 0.45, 1.0),
    ("rounded lips", {"lip_pucker": 1.45, "lip_stretch": 0.7, "jaw_open": 0.85}, {"lip_pucker": 0.12}, 0.0, 1.0),
    ("restrained", {"jaw_open": 0.8, "lip_stretch": 0.8}, {"lip_press": 0.1}, 0.0, 0.8),
    ("expressive brows", {"brow_raise": 1.8, "upper_lip_raise": 1.3}, {"brow_raise": 0.2}, -0.2, 1.1),
    ("sullen", {"mouth_frown": 1.5, "jaw_open": 0.9}, {"mouth_frown": 0.25, "brow_furrow": 0.2}, -0.35, 0.95),
)


@dataclass
class Speaker:
    """One synthetic speaker: head proportions + speaking style. All fields are plain JSON types."""

    name: str
    shape: FaceShape = field(default_factory=FaceShape)
    gains: dict[str, float] = field(default_factory=dict)      # control -> multiplier on speech (default 1)
    rest: dict[str, float] = field(default_factory=dict)       # control -> resting offset (default 0)
    asymmetry: float = 0.0                                     # > 0: the left side smiles more
    articulation: float = 1.0                                  # amplitude of all speech movements
    blink_rate: float = 0.28                                   # blinks per second
    signature: str = ""                                        # the trait that makes this speaker recognisable
    n_vertices: int = BASE_VERTICES                            # mesh resolution of this speaker's rig
    # Upper-face motion that follows the audio (face/upper.py); drawn from a separate stream (corpus v2).
    accent: float = 0.2                                        # brow_raise per pitch-accent pulse (~1.6 mm)
    accent_lead: float = 0.05                                  # s the brow pulse starts before the stressed vowel
    pitch_brow: float = 0.012                                  # brow_raise per semitone of F0 above the median
    cheek: float = 0.25                                        # cheek_puff per unit of smile + 0.6 lip_stretch
    boundary_blink: float = 0.6                                # blink probability at a pause (phrase boundary)

    def gain_vector(self) -> np.ndarray:
        """(C,) speech gains in CONTROL_NAMES order."""
        return np.array([self.gains.get(n, 1.0) for n in CONTROL_NAMES])

    def rest_vector(self) -> np.ndarray:
        """(C,) resting offsets in CONTROL_NAMES order."""
        return np.array([self.rest.get(n, 0.0) for n in CONTROL_NAMES])

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "Speaker":
        """A ``speakers.json`` entry -> Speaker; ValueError if it lacks rig parameters (see
        :func:`missing_rig_parameters`: defaults would silently build another face) or has unknown fields."""
        missing = missing_rig_parameters(d)
        if missing:
            shown = ", ".join(missing[:4]) + (f" and {len(missing) - 4} more" if len(missing) > 4 else "")
            raise ValueError(f"lacks rig parameters ({shown}); default ones would give another face than the "
                             f"speaker's: regenerate the corpus or restore the entry")
        d = dict(d)
        d["shape"] = FaceShape(**d.get("shape", {}))
        unknown = set(d) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(f"unknown Speaker fields {sorted(unknown)}")
        return cls(**d)


def missing_rig_parameters(d: object) -> list[str]:
    """The rig parameters a ``speakers.json`` entry lacks (``[]`` if complete): its head proportions (``shape``,
    every :class:`FaceShape` field) and ``n_vertices``. :meth:`Speaker.from_dict` would fill them with the
    defaults of an average head, a face up to ~17 mm off the speaker the corpus was made from."""
    if not isinstance(d, dict):
        return ["shape", "n_vertices"]
    shape = d.get("shape")
    if not isinstance(shape, dict):
        missing = ["shape"]
    else:
        missing = [f"shape.{f.name}" for f in dataclasses.fields(FaceShape) if f.name not in shape]
    return missing + [k for k in ("n_vertices",) if k not in d]


def _r(x: float) -> float:
    return round(float(x), 5)


def make_speakers(n: int, seed: int = 0, n_vertices: int = BASE_VERTICES) -> list[Speaker]:
    """``n`` deterministic speakers named SPK01, SPK02, ...: random proportions and style + a signature trait."""
    rng = np.random.default_rng(seed)
    rng_v2 = np.random.default_rng([seed, 2])  # upper-face style: a separate stream keeps the v1 draws unchanged
    base = FaceShape()
    speakers = []
    for i in range(n):
        shape = FaceShape(**{k: _r(getattr(base, k) * (1.0 + rng.uniform(-s, s))) for k, s in _SHAPE_SPREAD.items()})
        gains = {k: rng.lognormal(0.0, 0.12) for k in _GAIN_CONTROLS}
        rest = {"smile_left": rng.normal(0.0, 0.05), "smile_right": rng.normal(0.0, 0.05),
                "brow_raise": rng.normal(0.0, 0.08), "jaw_open": abs(rng.normal(0.0, 0.015))}
        name_sig, g_sig, r_sig, asym, artic = SIGNATURES[i % len(SIGNATURES)]
        brows = {"expressive brows": 1.6, "restrained": 0.6}.get(name_sig, 1.0)
        upper = {"accent": brows * rng_v2.uniform(0.16, 0.26), "accent_lead": rng_v2.uniform(0.02, 0.09),
                 "pitch_brow": brows * rng_v2.uniform(0.008, 0.018), "cheek": rng_v2.uniform(0.15, 0.35),
                 "boundary_blink": rng_v2.uniform(0.45, 0.85)}
        for k, g in g_sig.items():
            gains[k] = gains.get(k, 1.0) * g
        for k, r in r_sig.items():
            rest[k] = rest.get(k, 0.0) + r
        speakers.append(Speaker(
            name=f"SPK{i + 1:02d}", shape=shape,
            gains={k: _r(v) for k, v in gains.items()}, rest={k: _r(v) for k, v in rest.items()},
            asymmetry=_r(asym + rng.normal(0.0, 0.05)), articulation=_r(artic * rng.uniform(0.92, 1.08)),
            blink_rate=_r(rng.uniform(0.2, 0.4)), signature=name_sig, n_vertices=int(n_vertices),
            **{k: _r(v) for k, v in upper.items()}))
    return speakers
