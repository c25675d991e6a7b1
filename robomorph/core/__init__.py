"""Torch-free pieces every layer uses: atomic writes, typed config parsing, errors, names, the run directory."""
