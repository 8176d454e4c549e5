"""The study layer: what a run leaves on disk and the machine it ran on.

In: params pytrees and metrics from ``jaxlc.learn``, reason codes from ``jaxlc.sim``, the
resolved ``Config`` (``jaxlc.config``).
Out: the run directory's layout and atomic writers (``rundir.RunDir``), checkpoints with
their metadata (``checkpoint``), live TensorBoard curves (``tracking``), the host-device
count and matmul peak (``machine``), the run directory's one-writer lock (``lock``), the
summary's Markdown (``summary``), and runs over disjoint seeds merged into one (``merge``).

Imports: ``jaxlc.config``, ``jaxlc.sim`` and ``jaxlc.learn``; never ``evaluation`` or the
top-level commands (``tests/test_layout.py`` checks it; one named exception there:
``checkpoint`` reads ``jaxlc.__version__`` from the package root).
"""
