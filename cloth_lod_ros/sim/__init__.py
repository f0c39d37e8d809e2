"""The simulator: Baraff-Witkin cloth on an adaptive 4-8 mesh (design §1-§4).

Plain numpy/scipy (and PyYAML for scene files): nothing here imports rclpy,
mcap or matplotlib (``test/test_layers.py`` enforces it).  The public API::

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
