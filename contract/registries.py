"""Where published models live: the user's registry, and the bundled one served beside it.

``fit`` and ``export`` publish into the user's registry (``RGB2CLOUD_REGISTRY``), which
by default is a data folder outside any checkout, so following the README never writes
into tracked files. The models shipped with rgb2cloud stay in the bundled registry
(``RGB2CLOUD_BUNDLED_REGISTRY``, the checkout's or image's ``weights/``) and are served
beside the user's: the service, ``fit`` and ``export`` read the same two settings
(``app.settings.Settings``, the one reader of ``RGB2CLOUD_*``).

A name lives in one registry: where both hold it (a copy of the bundled models mounted
as the user's registry), the user's is the one served.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from contract.card import list_versions
from contract.errors import UserError


def default_registry() -> Path:
    """``$XDG_DATA_HOME/rgb2cloud/models`` (``~/.local/share/rgb2cloud/models``): the user's models by default."""
    data_home = os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share"
    return Path(data_home) / "rgb2cloud" / "models"


def checkout_weights() -> Path:
    """The ``weights/`` folder beside this package: the bundled registry of a checkout or the image."""
    return Path(__file__).resolve().parents[1] / "weights"


def registry_models(registry: Path) -> dict[str, list[str]]:
    """Every model name in one registry with its published versions, oldest first (none if it is absent)."""
    if not Path(registry).is_dir():
        return {}
    names = sorted(p.name for p in Path(registry).iterdir() if p.is_dir() and not p.name.startswith("."))
    return {name: versions for name in names if (versions := list_versions(registry, name))}


@dataclass(frozen=True)
class Registries:
    """The user's registry and the bundled one, read together."""

    own: Path
    bundled: Path

    def owner(self, name: str) -> Path | None:
        """The registry that owns ``name``: the user's where it holds a published version of it, else the
        bundled one where that does, else None. The one rule: an empty or half-written folder owns nothing."""
        for registry in (Path(self.own), Path(self.bundled)):
            if list_versions(registry, name):
                return registry
        return None

    def models(self) -> dict[str, list[str]]:
        """Every servable name with its versions, oldest first: the bundled models, then the user's over them."""
        merged = registry_models(self.bundled)
        merged.update(registry_models(self.own))
        return dict(sorted(merged.items()))

    def folder(self, name: str, version: str) -> Path:
        """The version folder of ``name`` ``version``, in the registry that owns the name (the user's if none)."""
        return (self.owner(name) or Path(self.own)) / name / version

    def check_new_name(self, name: str, registry: Path) -> None:
        """Refuse to publish ``name`` into ``registry`` when the bundled registry owns it: the service would serve
        the user's versions in the bundled model's place (publishing into the bundled registry itself is fine)."""
        bundled = Path(self.bundled)
        if list_versions(bundled, name) and Path(registry).resolve() != bundled.resolve():
            raise UserError(f"--name {name}: a bundled model has this name ({bundled / name}); choose another")

    def bundled_default(self) -> str | None:
        """The bundled registry's model when it holds exactly one: the default when none is named."""
        bundled = registry_models(self.bundled)
        return next(iter(bundled)) if len(bundled) == 1 else None
