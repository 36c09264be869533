"""``avgs sweep``: a grid of training runs (scenes x settings x seeds) on Ray, resumable.

- :mod:`avgs.sweep.spec`: what a sweep is (:class:`SweepSpec`, from a TOML file and the
  command line) and its expansion into :class:`Run` s, each with a run folder that stays the
  same across restarts: ``OUT/<scene>/<setting>/seed<k>/``.
- :mod:`avgs.sweep.state`: what a run folder holds (finished, interrupted, new; a fresh score).
- :mod:`avgs.sweep.lock`: one writer per run folder (held by a run and the subprocesses it starts).
- :mod:`avgs.sweep.execute`: one run as ``avgs train`` (``--resume`` when interrupted, retried)
  and ``avgs eval`` subprocesses; plain Python, runs on any Ray worker.
- :mod:`avgs.sweep.cluster`: the only module that imports Ray: places the runs by the CPU
  threads and GPU share each asks for, a progress bar across runs, cancels on interrupt.
- :mod:`avgs.sweep.results`: every run's score into one JSON and tables (mean and spread
  over seeds per scene, environment and overall; which runs ran, failed and why).

Ray is an optional extra (``pip install 'avgs[scale]'``); nothing else imports it.
"""
