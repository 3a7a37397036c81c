"""Write the service's OpenAPI document: ``python -m app.openapi [path]``.

The committed ``openapi/openapi.json`` is this output; a test fails when they drift.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from app.main import create_app
from app.settings import Settings

DEFAULT_PATH = Path("openapi/openapi.json")


def document() -> str:
    return json.dumps(create_app(Settings()).openapi(), indent=2, sort_keys=True) + "\n"


if __name__ == "__main__":
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_PATH
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(document())
    print(f"wrote {path}")
