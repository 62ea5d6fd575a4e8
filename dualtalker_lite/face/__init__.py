"""Procedural talking face: template head, rig controls, speakers, phoneme -> viseme -> control tracks.

numpy + trimesh only (no torch), so corpus-generation workers import it cheaply.

- ``mesh``      ``build_template`` -> ``TemplateMesh`` (vertices, faces, named regions, lip midpoints); ``lip_distance``
- ``rig``       ``FaceRig(speaker).animate(controls (T, C)) -> (T, V, 3)``; ``CONTROL_NAMES``
- ``speakers``  ``Speaker`` (head proportions + speaking style), ``make_speakers``
- ``visemes``   espeak phonemes -> ``VISEMES``; Cohen-Massaro ``coarticulate``
- ``upper``     weak motion that follows the speech: stress/F0 brow raises, cheeks, boundary blinks; ``pitch_track``
- ``motion``    emotions, blinks and brow drift; ``clip_controls`` (what the corpus generator calls)
"""
from .mesh import REGION_NAMES, FaceShape, TemplateMesh, build_template, lip_distance
from .motion import EMOTIONS, blink_track, clip_controls, emotion_controls, idle_controls
from .rig import CONTROL_INDEX, CONTROL_NAMES, CONTROL_RANGES, CONTROL_REGIONS, FaceRig, control_vector
from .speakers import Speaker, make_speakers
from .visemes import (PHONEME_TO_VISEME, PHONEMES, VISEMES, coarticulate, phoneme_to_viseme, phonemes_to_visemes,
                      split_diphthong, viseme_ids)

__all__ = ["REGION_NAMES", "FaceShape", "TemplateMesh", "build_template", "lip_distance",
           "EMOTIONS", "blink_track", "clip_controls", "emotion_controls", "idle_controls",
           "CONTROL_INDEX", "CONTROL_NAMES", "CONTROL_RANGES", "CONTROL_REGIONS", "FaceRig", "control_vector",
           "Speaker", "make_speakers",
           "PHONEME_TO_VISEME", "PHONEMES", "VISEMES", "coarticulate", "phoneme_to_viseme", "phonemes_to_visemes",
           "split_diphthong", "viseme_ids"]
