"""``cloth-lod bench``: speed against error from the converged motion (design §5).

``runner`` resolves the options and runs everything, ``plan`` says what to
run (integrator families × meshes, the converged reference's runs),
``worker`` is one run in one pinned process, ``rows`` turns the runs into
table rows and the reference's own error, ``analysis``, ``report`` and
``plot`` write the Markdown summary, the CSV and the plot; ``backends`` is
``--solvers``, ``scenes`` is ``--scenes``; ``performance`` is ``--report``,
one Markdown page (docs/performance.md) from all three modes' output files.
"""

from .runner import BenchError, add_arguments, main, run

__all__ = ["BenchError", "add_arguments", "main", "run"]
