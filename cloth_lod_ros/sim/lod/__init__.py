"""Level of detail: the criterion and the policy that decides splits and merges,
the energy a merge would add, and their compiled kernels (paper §5, design §4).

May import: runtime, scene, mesh, physics, solve, contact, integrate (the parts
below it; docs/design.md §9).
"""
