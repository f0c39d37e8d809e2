"""``cloth-lod bench``: speed against error (design §5).

``runner`` plans the configurations and runs them, ``worker`` is one
configuration in one pinned process, ``report`` writes the CSV, plot and
Markdown summary.
"""

from .runner import BenchError, add_arguments, main, run

__all__ = ["BenchError", "add_arguments", "main", "run"]
