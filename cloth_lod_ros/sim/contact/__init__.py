"""Contact: analytic obstacles, particles' contacts with them, rows with two
normals, self-collision (broad and narrow phase) and the reactions between
layers (design §3).

May import: runtime, scene, mesh, physics, solve (the parts below it;
docs/design.md §9).
"""
