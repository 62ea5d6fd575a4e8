"""Animations other tools play (issue 22): glTF 2.0 morph targets with sound, and a self-contained browser viewer.

- :mod:`~dualtalker_lite.export.gltf`: ``write_gltf`` -> ``animation.glb`` (template mesh, PCA morph targets chosen
  by error, one weights animation at the mesh frame rate) + ``animation.wav``; ``read_gltf_animation`` reads it back.
- :mod:`~dualtalker_lite.export.html`: ``viewer_html`` (the HTML string, for notebooks) and ``write_html`` -> one
  .html with three.js, the animation and the audio inlined (no network requests).

Layering: this subpackage imports only numpy, pygltflib, soundfile and the standard library; ``inference`` uses it.
"""
from .gltf import GltfReport, morph_basis, read_gltf_animation, write_gltf

__all__ = ["GltfReport", "morph_basis", "read_gltf_animation", "write_gltf"]
