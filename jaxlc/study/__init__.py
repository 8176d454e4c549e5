"""The study layer: the sweep's chunk loop, what a run leaves on disk, the machine it ran on.

In: params pytrees and metrics from ``jaxlc.learn``, reason codes from ``jaxlc.sim``, the
resolved ``Config`` (``jaxlc.config``).
Out: the sweep's chunk loop (``loop.run_sweep``), the run's state and stop signals
(``runstate``, ``signals``), the multi-host glue (``multihost``), the run directory's layout
and atomic writers (``rundir.RunDir``), checkpoints with their metadata (``checkpoint``),
live TensorBoard curves (``tracking``), the host-device count and matmul peak
(``machine``), the run directory's one-writer lock (``lock``), the models' labels and the
summary (``summary``), and runs over disjoint seeds merged into one (``merge``).

Imports: ``jaxlc.config``, ``jaxlc.sim`` and ``jaxlc.learn``; never ``evaluation`` or the
top-level commands (``tests/test_layout.py`` checks it; one named exception there:
``checkpoint`` reads ``jaxlc.__version__`` from the package root).
"""
