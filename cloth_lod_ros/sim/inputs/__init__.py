"""What moves the cloth from outside: pins, grasps and kinematic obstacles, with
the facade's methods for them (mixins of ``ClothSim``; design §2-§3).

May import: runtime, scene, mesh, physics, solve, contact, integrate, lod (the
parts below it; docs/design.md §9).
"""
