"""``python -m app``: serve with uvicorn on RGB2CLOUD_HOST:RGB2CLOUD_PORT."""

from __future__ import annotations

import logging
import sys

import uvicorn

from app.catalog import ModelCatalog
from app.loading import ModelLoadError
from app.main import create_app
from app.settings import Settings

log = logging.getLogger("rgb2cloud")


def main() -> None:
    """Load and verify the default model first, so a bad one is one log line and exit status 1."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    settings = Settings()
    catalog = ModelCatalog(settings)
    try:
        catalog.load_default()
    except ModelLoadError as e:
        log.critical("cannot start: %s", e)
        sys.exit(1)
    uvicorn.run(create_app(settings, catalog), host=settings.host, port=settings.port, log_level="info")


if __name__ == "__main__":
    main()
