"""Training: one loop for every task (:mod:`.pipeline`: stage 1, then stage 2 with resume,
evaluation, logs, checkpoints and curves) and each task's hooks (:mod:`.tasks`: the protocol;
:mod:`.binaural`, :mod:`.impulse_responses`, whose early ILD's factor behind a wall is :mod:`.blocked_ild`),
the stage-2 trainer and its losses, audio-aware point management, stage 1 (G from the frames).

Import the submodule you need (``from avgs.train.pipeline import train_scene``).
"""
