"""Command-line tools: ``cloth-lod`` (run, compare, bench, stress, bags), pictures (design §9)."""
