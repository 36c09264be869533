"""Training: losses, the stage-2 loop, the two-stage pipeline, logs and curves.

Import the submodule you need (``from avgs.train.pipeline import train_scene``).
"""
