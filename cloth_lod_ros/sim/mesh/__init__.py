"""The 4-8 mesh: rest meshes, edges and hinges, the run-time hierarchy (pools,
split and merge as invertible values, the operation log, the hash table of
the compiled index), the compact mesh of the active elements and sampling at
material points (paper §3, design §1, §4).

May import: runtime, scene (the parts below it; docs/design.md §9).
"""
