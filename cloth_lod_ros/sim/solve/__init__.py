"""Linear solves of an implicit stage: the sparsity pattern and assembly, the
per-particle constraints and the projected system, filtered PCG, the lattice
multigrid, the block LDLᵀ with its trailing contact rounds, and the backends
behind one interface (design §3).

May import: runtime, scene, mesh, physics (the parts below it; docs/design.md
§9).
"""
