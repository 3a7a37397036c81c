"""``python -m app``: serve with uvicorn on RGB2CLOUD_HOST:RGB2CLOUD_PORT."""

from __future__ import annotations

import logging
import sys
import tempfile

import uvicorn
from pydantic import ValidationError
from pydantic_core import ErrorDetails

from app.catalog import ModelCatalog
from app.loading import ModelLoadError
from app.main import create_app
from app.settings import Settings
from app.stream import STREAM_TRANSPORT_FACTOR

log = logging.getLogger("rgb2cloud")


def setting_problem(error: ErrorDetails) -> str:
    """One validation error as a line: the variable and its value, or the whole settings' problem as it is."""
    if not error["loc"]:
        return error["msg"].removeprefix("Value error, ")
    return f"RGB2CLOUD_{'_'.join(map(str, error['loc'])).upper()}={error.get('input')!r}: {error['msg']}"


def unwritable_temp_dir() -> str | None:
    """Why uploads could not be received, or None. The multipart parser spools an upload over 1 MB to a
    temporary file; on a read-only root with no writable /tmp, every large photo would be refused as a body
    that does not parse. Said at startup instead, with the fix."""
    try:
        with tempfile.TemporaryFile():
            return None
    except OSError as e:
        return (
            f"no writable temporary folder ({e}): uploads over 1 MB are spooled there; on a read-only root "
            "filesystem, mount a tmpfs at /tmp (or point TMPDIR at a writable folder)"
        )


def main() -> None:
    """Read the settings and load and verify the default model first: a bad setting or model is one log
    line and exit status 1."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        settings = Settings()
    except ValidationError as e:
        problems = "; ".join(setting_problem(error) for error in e.errors())
        log.critical("cannot start: %s", problems)
        sys.exit(1)
    if (problem := unwritable_temp_dir()) is not None:
        log.critical("cannot start: %s", problem)
        sys.exit(1)
    catalog = ModelCatalog(settings)
    try:
        catalog.load_default()
    except ModelLoadError as e:
        log.critical("cannot start: %s", e)
        sys.exit(1)
    uvicorn.run(
        create_app(settings, catalog),
        host=settings.host,
        port=settings.port,
        log_level="info",
        # A stream frame up to this size is read and, if over the stream's own limit, answered with an error
        # of its own; only beyond it does the WebSocket layer close the stream (1009).
        ws_max_size=STREAM_TRANSPORT_FACTOR * settings.stream_max_frame_bytes,
        # This WebSocket protocol stops reading a connection after each whole message until the stream has taken
        # it: with ws_max_size, that bounds what one client can make the service hold (docs/api.md). Named, not
        # "auto", so the bound does not depend on which WebSocket library happens to be installed.
        ws="websockets-sansio",
        # Frames are JPEG or PNG and answers PNG or raw depth: deflating them again costs both ends more
        # time than it saves on a network.
        ws_per_message_deflate=False,
    )


if __name__ == "__main__":
    main()
