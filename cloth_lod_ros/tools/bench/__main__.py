"""``python -m cloth_lod_ros.tools.bench`` (also the benchmark's worker processes)."""

import sys

from .runner import main

sys.exit(main())
