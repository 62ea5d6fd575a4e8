r"""The bilabial contact term: a project deviation from every paper, a named training option
(``TrainConfig.lip_contact``), off in the papers' recipe (``TrainConfig.tiny``) and on in the short one
(``TrainConfig.fast``, issue 31).

.. math::

    L_{contact} = \frac{1}{|\mathcal{P}|} \sum_{(b,t) \in \mathcal{P}}
        \big\| s\,(\hat v^{u}_{bt} - \hat v^{l}_{bt}) \big\|^2 \quad (\mathrm{mm}^2)                          (C1)

:math:`\mathcal{P}`: the valid (unpadded) frames whose viseme label is ``PP`` (/p b m/, ``face.visemes``);
:math:`\hat v^u, \hat v^l`: the predicted upper- and lower-lip midpoint vertices (the corpus's ``lip_midpoints``);
s = 1000 (metres to mm). The training objective becomes the model's own loss + λ_c L_contact.

Why: the papers' losses are vertex MSEs over the whole face, where a bilabial closure is two vertices on one or two
frames. Fitted for the short budget, a model puts the lips of a one-frame /p/ about as often 1 mm too open as closed
(on the sample corpus after 30 epochs its lip gap on ``PP`` frames correlates 0.50 with the ground truth's, with an
error of 0.87 mm rms), so the bilabials it closes < 1 mm stay near 0.65 of the training clips' (the ground truth
closes 0.94). This term asks for closed lips on every bilabial frame, as Imitator's lip contact loss does for the
bilabials it detects (Thambiraja et al., "Imitator: Personalized Speech-driven 3D Facial Animation", ICCV 2023).
Measured in ``results/time_to_quality_2core.md`` and ``docs/design-notes.md`` ("The bilabial contact term").

Readings taken (Imitator's own formula is not in this project's papers): one vertex pair, the lip midpoints that
the closure metric measures, pulled to distance 0 (not to the ground truth's distance, which is 0.2-2 mm on the
edge frames of a closure); a mean over the batch's bilabial frames, 0 for a batch without any. What it changes:
the lips close on every frame labelled /p b m/, also the first and last of a closure, where the rig that made the
corpus is still closing or opening them.
"""
from __future__ import annotations

from torch import Tensor

from .common import masked_mean

__all__ = ["bilabial_contact"]


def bilabial_contact(upper: Tensor, lower: Tensor, bilabial: Tensor, scale: float = 1000.0) -> Tensor:
    """Eq. C1: upper, lower (B, T, 3) predicted lip-midpoint positions (metres), bilabial (B, T) bool (the valid
    ``PP`` frames) -> the mean squared midpoint distance in mm² over those frames (a scalar tensor; 0, still in the
    graph, when there are none)."""
    if upper.shape != lower.shape or upper.shape[:-1] != bilabial.shape or upper.shape[-1] != 3:
        raise ValueError(f"bilabial_contact: upper, lower (B, T, 3) and bilabial (B, T), got {tuple(upper.shape)}, "
                         f"{tuple(lower.shape)} and {tuple(bilabial.shape)}")
    gap2 = ((upper - lower) * scale).square().sum(-1)  # (B, T) squared midpoint distance, mm²
    return masked_mean(gap2, bilabial)  # over the bilabial frames; 0 if none (padding never enters)
