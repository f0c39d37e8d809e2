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
"""

from .cloth import ClothSim
from .scene.config import SceneConfig, SceneError, load_scene
from .inputs.pins import Pin
from .integrate.state import ClothState, SimulationError, StepStats

__all__ = ["ClothSim", "ClothState", "Pin", "StepStats", "SimulationError", "SceneConfig",
           "SceneError", "load_scene"]
