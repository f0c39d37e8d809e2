"""``python -m cloth_lod_ros.tools.stress``."""

import sys

from .runner import main

sys.exit(main())
