"""The simulator: Baraff-Witkin cloth on an adaptive 4-8 mesh (design §1-§4).

Plain numpy/scipy (and PyYAML for scene files): nothing here imports rclpy,
mcap or matplotlib (``test/test_layers.py`` enforces it).  Its parts, bottom
to top (design §9): ``runtime``, ``scene``, ``mesh``, ``physics``, ``solve``,
``contact``, ``integrate``, ``lod``, ``inputs``; a part imports only the ones
before it, the facade (``cloth.py``, ``warm_up.py``) any of them, and no
module one that imports it back.  The public API::

    from cloth_lod_ros.sim import ClothSim
    sim = ClothSim.from_scene("hang_two_corners")
    stats = sim.step()

The names below are imported on first use (PEP 562), so that reading and
checking a scene (``sim.scene``) does not import numba and the compiled
kernels: a scene over the budget is refused in a fraction of a second.
"""

import importlib

_EXPORTS = {"ClothSim": ".cloth", "SceneConfig": ".scene.config",
            "SceneError": ".scene.config", "load_scene": ".scene.config",
            "Pin": ".inputs.pins", "ClothState": ".integrate.state",
            "SimulationError": ".integrate.state", "StepStats": ".integrate.state"}

__all__ = ["ClothSim", "ClothState", "Pin", "StepStats", "SimulationError", "SceneConfig",
           "SceneError", "load_scene"]


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
