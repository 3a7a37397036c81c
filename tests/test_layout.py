"""The house's rules, checked: which package may import which, and what the service loads."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

from conftest import REPO

PACKAGES = ("contract", "app", "trainer", "lab", "cli")
#: Who may import whom. The contract is the base; the service and the trainer stand on it apart;
#: the CLI assembles both; the research tooling stands on everything (its CLI shares the product's
#: options) and nothing stands on it.
ALLOWED = {
    "contract": set(),
    "app": {"contract"},
    "trainer": {"contract"},
    "cli": {"contract", "app", "trainer"},
    "lab": {"contract", "trainer", "cli"},
}


def _imports(path: Path) -> set[str]:
    """Top-level names of every module a file imports, lazily inside functions included."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_packages_import_only_downwards():
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            ours = _imports(path) & set(PACKAGES) - {package}
            assert ours <= ALLOWED[package], f"{path.relative_to(REPO)} imports {sorted(ours - ALLOWED[package])}"


def test_the_contract_never_imports_torch():
    for path in sorted((REPO / "contract").rglob("*.py")):
        assert "torch" not in _imports(path), path


def test_starting_the_service_loads_only_the_contract_and_the_service():
    """Import what ``python -m app`` imports and build the app; list the project files that got loaded."""
    code = """
import json, sys
import app.__main__, app.main, app.openapi
from app.main import create_app
create_app()
print(json.dumps(sorted(name for name in sys.modules)))
"""
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    loaded = json.loads(result.stdout)
    ours = {name for name in loaded if name.split(".")[0] in PACKAGES}
    assert {name.split(".")[0] for name in ours} == {"app", "contract"}, sorted(ours)
    assert "torch" not in loaded
    for name in ours:  # and no file of ours that it loads imports torch, even lazily
        path = REPO / Path(*name.split("."))
        file = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
        assert "torch" not in _imports(file), f"{file.relative_to(REPO)} imports torch"


def test_the_serving_image_copies_the_contract_and_the_service_only():
    copied = [line.split()[1] for line in (REPO / "Dockerfile").read_text().splitlines() if line.startswith("COPY ")]
    assert {"contract", "app"} <= set(copied)
    assert not {"trainer", "lab", "cli", "tests", "configs", "docs"} & set(copied)


def test_product_files_stay_small():
    for package in ("contract", "app", "trainer", "cli"):
        for path in sorted((REPO / package).rglob("*.py")):
            lines = len(path.read_text().splitlines())
            assert lines <= 400, f"{path.relative_to(REPO)} has {lines} lines"
