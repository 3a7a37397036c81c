"""Where the CLI reaches the service: from the service's own settings, so ``make serve`` and the CLI agree."""

from __future__ import annotations

from app.settings import Settings


def service_url(settings: Settings | None = None) -> str:
    """Where ``make serve`` listens, from the same settings: ``RGB2CLOUD_HOST`` and ``RGB2CLOUD_PORT``.

    A service bound to every interface (0.0.0.0) is reached on the loopback address. The clients
    (``clients/``) take the URL as given and never read the service's settings themselves.
    """
    settings = settings or Settings()
    host = "127.0.0.1" if settings.host in ("0.0.0.0", "::") else settings.host
    return f"http://{host}:{settings.port}"
