"""Everything that turns a trained model into sound and pictures of it.

- :mod:`.renderer`: :class:`SceneRenderer`, the one object the CLI, benchmarks and viewer use
  (world coordinates, degrees, clamping, headroom, caches).
- :mod:`.tasks`: the seam between the renderer and a task's model (:class:`~.tasks.TaskModel`,
  one per task, chosen once from the checkpoint's ``task``): :mod:`.binaural` (masks, the
  paper's RWAVS task) and :mod:`.impulse_response` (predicted responses, sources anywhere).
- :mod:`.streaming`, :mod:`.mid_phase_stream`: block-by-block rendering equal to one shot.
- :mod:`.propagation_map`, :mod:`.listener_view`, :mod:`.prune`: the level map over the floor,
  G seen from the listener's head, and a checkpoint cut to a region.

Import the submodule you need; ``avgs.SceneRenderer`` is the short name of the renderer.
"""
