"""Signal processing shared by every part: the STFT pair and magnitudes (:mod:`.spectra`,
re-exported here: ``from avgs import dsp; dsp.stft(x, cfg)``), fast Griffin-Lim on a
frame-major STFT pair (:mod:`.phase_retrieval`) and the synthesis' compiled loops (:mod:`.kernels`).
"""

from avgs.dsp.spectra import istft, magnitude, n_frames, stft, window

__all__ = ["istft", "magnitude", "n_frames", "stft", "window"]
