"""Animations other tools play (issue 22): glTF 2.0 morph targets with sound, and a self-contained browser viewer.

- :mod:`~dualtalker_lite.export.gltf`: ``write_gltf`` -> ``animation.glb`` (template mesh, PCA morph targets chosen
  by error, one weights animation at the mesh frame rate) + ``animation.wav``; ``read_gltf_animation`` reads it back.
- :mod:`~dualtalker_lite.export.html`: ``viewer_html`` (the HTML string, for notebooks) and ``write_html`` -> one
  .html with three.js, the animation and the audio inlined (no network requests). Its three.js stage,
  ``page/scene.js``, is the live page's too (``live/page`` imports it; the live server serves it).
- :mod:`~dualtalker_lite.export.visemes` (issue 33): ``viseme_curves`` -> the 15 standard viseme weights per frame
  (``viseme_sil`` .. ``viseme_U``), coarticulated as the rig does; ``write_visemes`` -> ``visemes.json`` and
  ``visemes.csv``; ``apply_viseme_weights`` poses any mesh from them.
- :mod:`~dualtalker_lite.export.video`: the mp4 writer (issue 30 moved it here from ``viz``): ``render_video`` ->
  an H.264 mp4 of a clip of any length with the speech muxed in (AAC), written atomically; ``clip_panels`` and
  ``write_mp4``, its two steps, also serve the notebooks' ``viz.animate_clip``.
- :mod:`~dualtalker_lite.export.render`: the mesh renderer the videos and the notebooks' figures draw with
  (matplotlib ``MeshRenderer``, Pillow ``RasterRenderer``); ``viz.render`` re-exports it for notebook 01.

Layering: ``gltf`` and ``html`` import only numpy, pygltflib, soundfile and the standard library; ``visemes`` also
imports ``face`` (the rig's coarticulation), ``files`` and, lazily, ``audio`` and ``recogniser``; ``render`` imports
numpy, matplotlib and Pillow; ``video`` imports ``render`` and ``files``. ``inference`` uses them; this package's
``__init__`` imports ``gltf`` only.
"""
from .gltf import GltfReport, morph_basis, read_gltf_animation, write_gltf

__all__ = ["GltfReport", "morph_basis", "read_gltf_animation", "write_gltf"]
