"""Result files that are never half-written: write a temporary file beside, then rename."""

from __future__ import annotations

import json
import os
from typing import Any


def write_text(path: str, text: str) -> None:
    """Writes ``text`` to ``path`` so that a reader sees the old file or the new one, never a part."""
    tmp = f"{path}.tmp"
    with open(tmp, "w", newline="") as f:
        f.write(text)
    os.replace(tmp, path)


def write_json(path: str, obj: Any) -> None:
    """:func:`write_text` of ``obj`` as indented JSON (NaN allowed, as in metrics files)."""
    write_text(path, json.dumps(obj, indent=1) + "\n")
