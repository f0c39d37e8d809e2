"""``cloth-lod stress``: the hard-case stability suite (design §10).

``cases`` defines the cases and their bounds, ``runner`` runs and checks them.
"""

from .cases import CASES, Bounds, Case, Event, Variant
from .runner import (RunResult, add_arguments, build_scene, format_table, main, run,
                     run_case, run_cases)

__all__ = ["Variant", "Bounds", "Event", "Case", "CASES", "RunResult", "build_scene",
           "run_case", "run_cases", "format_table", "add_arguments", "run", "main"]
