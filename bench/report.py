"""What the bench scripts share: writing their JSON results."""

from __future__ import annotations

import json
from pathlib import Path


def write_json(path: str | Path, doc) -> None:
    """Write `doc` as indented JSON to `path` (its folder made if missing) and say so."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {path}")
