"""How the simulator's numerical code runs: the compiled (numba) kernels switched on
or off, and one BLAS thread inside a step.

May import: nothing else of the simulator.
"""
