"""Time integration: the state, implicit stages solved by Newton with constraints
and contacts, the schemes made of them and the error-controlled step size
(design §3).

May import: runtime, scene, mesh, physics, solve, contact (the parts below it;
docs/design.md §9).
"""
