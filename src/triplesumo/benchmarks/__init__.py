"""Speed measurements (never timed tests): ``triplesumo bench env`` (:mod:`.env`) and
``triplesumo bench train`` (:mod:`.train`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def report(table: str, result: dict[str, Any], json_path: str | None) -> None:
    """Print a benchmark's table and, when asked, write its results as JSON."""
    print(table)
    if json_path:
        path = Path(json_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {path}")
