"""Behind a wall, the factor on B's early ILD (``RIRConfig.blocked_ild``), fitted once B is trained.

A first sound that comes around walls, through a door and off the walls, reaches the two ears from many
directions, so its first 5 ms's ILD is smaller than the head's shadow of any one direction; B, a function
of the positions, gives such a pose about the ILD of nearby pairs in sight. :func:`fit_factor` scores the
factors 0, 0.1, .. 1 on the training pairs behind a wall by their early ILDs
(:func:`avgs.evaluation.spatial.early_ild`) and keeps the best where it beats B's own (1).
"""

from __future__ import annotations

import numpy as np
import torch

from avgs.config import RIRConfig, STFTConfig

STEPS = 11
"The factors :func:`fit_factor` tries: 0, 0.1, .. 1."

MOST_PAIRS = 256
"At most this many pairs behind a wall scored (evenly spaced): the median is steady, time and memory bounded."


@torch.no_grad()
def fit_factor(model, listener: torch.Tensor, yaw: torch.Tensor, source: torch.Tensor, truth: np.ndarray,
               rir: RIRConfig, stft: STFTConfig, length: int) -> dict:
    """Set ``model``'s ``blocked_ild`` (an :class:`~avgs.acoustics.rir_model.RIRModel` with it) to the factor
    whose responses (``rir``'s phase, the direct sound placed, ``length`` samples) of the pairs behind a wall
    (listener, source ``[A, 3]`` model units, yaw ``[A]`` radians) have early ILDs nearest ``truth [A]`` dB
    by the median absolute error, where it beats 1; else 1 (at most :data:`MOST_PAIRS` of them, evenly spaced).
    Returns the log's record fields."""
    from avgs.acoustics.rir_model import response_waveform
    from avgs.evaluation import spatial

    if listener.shape[0] > MOST_PAIRS:
        keep = torch.linspace(0, listener.shape[0] - 1, MOST_PAIRS).round().long()
        listener, yaw, source, truth = listener[keep], yaw[keep], source[keep], np.asarray(truth)[keep.numpy()]
    b, X = model.binauralizer, model.points.X
    model.eval()
    listener, yaw, source = listener.to(X), yaw.to(X), source.to(X)
    cache = model.precompute()
    logs = torch.cat([model.log_magnitudes(listener[c], yaw[c], source[c], cache)[0]
                      for c in torch.arange(listener.shape[0]).split(16)])
    mags = model.magnitudes(logs)  # [A, 2, F, N]
    errors = []  # (median error dB, factor)
    for k in np.linspace(0.0, 1.0, STEPS):
        b.blocked_ild.fill_(float(k))
        wave = response_waveform(mags, length, stft, rir.phase, rir.phase_iterations,
                                 direct=model.direct_sound(listener, yaw, source)).cpu().numpy()  # [A, 2, L]
        predicted = np.array([spatial.early_ild(w, float(stft.sample_rate)) for w in wave])
        errors.append((float(np.median(np.abs(predicted - truth))), float(k)))
    best, factor = min(errors, key=lambda e: (e[0], -e[1]))  # ties: the larger factor (nearer B's own)
    factor = factor if best < errors[-1][0] else 1.0
    b.blocked_ild.fill_(factor)
    return {"factor": factor, "early_ild_error_db": [errors[-1][0], best]}
