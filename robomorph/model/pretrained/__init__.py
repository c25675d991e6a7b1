"""Models shipped with the package, found by a bare name: ``Predictor.from_pretrained(NAME)``.

Each one is a model folder as ``robomorph export`` writes it (``model.safetensors`` and
``config.json``), kept in a sub-folder of this one named by the model, with a ``README.md``
card saying what it was trained on, its budget and its figures on the real arms, measured. The
folders ship in the wheel (``pyproject.toml``'s package data), so loading one needs no network.
"""

from __future__ import annotations

import os
from pathlib import Path

from robomorph.model.files import CONFIG_FILE

SHIPPED_DIR = Path(__file__).resolve().parent


def available() -> list[str]:
    """The names of the shipped models, sorted."""
    return sorted(p.name for p in SHIPPED_DIR.iterdir() if (p / CONFIG_FILE).is_file())


def resolve(path: str) -> str:
    """``path`` itself where it exists or names a place (it has a folder separator or a suffix); a bare
    name of a shipped model otherwise: that model's folder. A bare name that is neither is returned
    unchanged, for the reader to refuse with its own message (which then lists the shipped names)."""
    text = os.fspath(path)
    if os.path.exists(text) or os.sep in text or "/" in text or text in (".", ".."):
        return text
    return str(SHIPPED_DIR / text) if text in available() else text
