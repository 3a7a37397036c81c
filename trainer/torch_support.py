"""Which torch the trainer supports: the range the ``train`` extra names, checked before training starts.

The range lives in one place, pyproject.toml's ``train`` extra; this reads it back from the installed
package's metadata. Outside it a fit or a training run would fail somewhere deep (an operator a TorchScript
file calls, an argument an older torch lacks) after minutes of work, so ``fit`` and ``train`` stop at once
with one line instead. A build's local label (``+cpu``, ``+cu130``) is not part of the version compared.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, requires

from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet
from packaging.version import Version

from contract.errors import UserError


def supported_torch() -> SpecifierSet | None:
    """The torch versions the ``train`` extra allows; None where rgb2cloud is not installed as a package."""
    try:
        declared = requires("rgb2cloud") or []
    except PackageNotFoundError:
        return None
    for text in declared:
        requirement = Requirement(text)
        if requirement.name == "torch" and requirement.marker and requirement.marker.evaluate({"extra": "train"}):
            return requirement.specifier
    return None


def check_torch(version: str, supported: SpecifierSet | None) -> None:
    """Raise ``UserError`` in one line if torch ``version`` is outside ``supported``."""
    if supported is None:
        return
    release = Version(version).public  # 2.11.0+cu130 -> 2.11.0
    if not supported.contains(release, prereleases=True):
        raise UserError(
            f"torch {version} is outside the versions the trainer supports (torch{supported}): "
            f"pip install 'torch{supported}', or the CPU build: pip install torch==2.13.0"
        )


def require_supported_torch() -> None:
    """Stop at once, in one line, under a torch the trainer does not support."""
    import torch

    check_torch(torch.__version__, supported_torch())
