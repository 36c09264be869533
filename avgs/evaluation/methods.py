"""What a *method* of the benchmark is: the contract between :mod:`avgs.evaluation.baselines`,
trained checkpoints and the scoring in :mod:`avgs.evaluation.binaural`.

A method is any callable ``(clip: AudioClip, scene: RWAVSScene) -> binaural [2, T]``
(numpy or torch, T = the clip's length), or a :class:`Prediction` when it made its
waveform from predicted magnitudes. It may also define ``applies_to(scene) -> bool``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

if TYPE_CHECKING:
    import torch

    from avgs.data.rwavs import AudioClip, RWAVSScene


class Prediction(NamedTuple):
    """A method's output for one clip when it has magnitudes behind its waveform."""

    binaural: np.ndarray  # [2, T]
    magnitudes: np.ndarray  # [2, F, N_t], the predicted ear magnitudes the waveform was made from


Method = Callable[["AudioClip", "RWAVSScene"], "np.ndarray | torch.Tensor | Prediction"]
