"""The ``avgs`` command line: one module per sub-command (``add_arguments``, ``run``), dispatched by
:mod:`avgs.cli`; :mod:`.flags` makes ``avgs train``'s flags from the config dataclasses."""
