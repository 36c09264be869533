"""The audio half of AV-GS: audio points G_a, vicinity search, the acoustic field
network F, the binauralizer B, and :class:`~avgs.acoustics.model.AVGSModel` composing them.

Everything here computes in the scene's *normalised* frame with yaw and direction in
radians; world coordinates and degrees are converted at the public edges
(:mod:`avgs.render.renderer`, the CLI).
"""
