"""The cloth's physics on a mesh: per-element rest data, the Baraff-Witkin
conditions' forces, energies and kept Jacobians, hinge angles, the air
(design §2).  Each ``*_kernels.py`` compiles the numpy module of the same name.

May import: runtime, scene, mesh (the parts below it; docs/design.md §9).
"""
