"""``cloth-lod sweep SPEC.yaml``: many runs of a scene, on Dask (docs/sweeps.md).

``spec`` reads a sweep file and expands it into runs (each with its resolved
scene and a deterministic id), ``task`` is one run as it runs on a worker,
``cluster`` opens the Dask client (a LocalCluster by default, or
``--scheduler``), checks the workers and runs the tasks (the runner that
``cloth-lod bench --scheduler/--workers`` uses too), ``table`` writes the
table of every run's parameters and numbers, and ``command`` is the command.
"""

from .command import add_arguments, run

__all__ = ["add_arguments", "run"]
