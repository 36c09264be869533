"""Scoring: metrics, baselines, codecs and the per-task evaluation over scenes.

- :mod:`.metrics`: MAG, ENV, ILD, T60, C50, EDT as pure functions (docs/design.md, "Metrics and baselines");
  :mod:`.spatial`: the cues of direction and distance, ITD (GCC-PHAT), onset, early ILD, lateralisation
  (docs/design.md, "Spatial cues").
- :mod:`.methods`, :mod:`.baselines`: what a benchmark method is; Mono-Mono, Mono-Energy,
  Stereo-Energy, Oracle-Mask.
- :mod:`.binaural`: the binaural task's scoring (per scene, environment, overall).
- :mod:`.impulse_response`, :mod:`.interpolation`, :mod:`.codecs`: the impulse-response task's
  scoring and its references (nearest / linear interpolation, plain or through Opus / AAC).
"""
