"""Scenes: the typed configuration with SI units, scene YAML read within bounds,
the built-in scene files and ``key=value`` overrides (design §10).  Every part
may read the configuration's types.

May import: runtime (the parts below it; docs/design.md §9).
"""
