"""The house's rules, checked: which package may import which, and what the service loads."""

from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
import tomllib
from importlib.metadata import PackageNotFoundError, packages_distributions, requires
from pathlib import Path

from conftest import REPO

PACKAGES = ("contract", "app", "clients", "recordings", "trainer", "lab", "cli", "harness")
#: Who may import whom. The contract is the base; the service, the clients and the trainer stand on it
#: apart (the clients run beside a camera and never need the service's code, nor the service theirs);
#: the CLI assembles them; the research tooling stands on everything (its CLI shares the product's
#: options) and nothing stands on it.
ALLOWED = {
    "contract": set(),
    "app": {"contract"},
    "clients": {"contract"},
    "recordings": {"contract"},
    "trainer": {"contract", "recordings"},
    "cli": {"contract", "app", "clients", "recordings", "trainer"},
    "lab": {"contract", "recordings", "trainer", "cli"},
    "harness": {"contract", "app", "recordings"},
}
#: What the serving image holds (the Dockerfile copies these and nothing else of ours).
SERVING = ("contract", "app")


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


def test_the_recordings_readers_load_no_torch_and_nothing_of_the_trainer():
    """Every module of ``recordings`` imported in a fresh interpreter: no torch, no trainer in ``sys.modules``."""
    modules = sorted(f"recordings.{p.stem}" for p in (REPO / "recordings").glob("*.py") if p.stem != "__init__")
    code = f"import json, sys\nfor m in {modules!r}: __import__(m)\nprint(json.dumps(sorted(sys.modules)))"
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    loaded = json.loads(result.stdout)
    assert len(modules) > 15 and set(modules) <= set(loaded)
    assert "torch" not in loaded and not [m for m in loaded if m.split(".")[0] in ("trainer", "app", "lab")]


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
    assert set(SERVING) <= set(copied)
    assert not {"recordings", "trainer", "lab", "cli", "harness", "tests", "bench", "configs", "docs"} & set(copied)


def _name(requirement: str) -> str:
    return re.split(r"[<>=!~;\[ (]", requirement, maxsplit=1)[0].lower().replace("_", "-")


def _serving_distributions() -> set[str]:
    """The serving install: pyproject's base dependencies and what they require in turn (no extras)."""
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    pending = [_name(spec) for spec in project["dependencies"]]
    found: set[str] = set()
    while pending:
        name = pending.pop()
        if name in found:
            continue
        found.add(name)
        try:
            required = requires(name) or []
        except PackageNotFoundError:  # required only on other Pythons or platforms
            continue
        for requirement in required:
            if "extra ==" not in requirement:
                pending.append(_name(requirement))
    return found


def test_the_serving_packages_import_only_the_serving_install():
    """Everything contract/ and app/ import is the standard library, themselves, or a declared serving
    dependency: no test or benchmark harness, no test tool, nothing the torch-free image lacks."""
    declared = _serving_distributions()
    owners = packages_distributions()
    optional = {"torch"}  # app/torchscript.py: the optional backend, imported only when chosen
    checked = 0
    for package in SERVING:
        for path in sorted((REPO / package).rglob("*.py")):
            for name in _imports(path) - set(SERVING) - set(sys.stdlib_module_names) - optional - {"__future__"}:
                distributions = {d.lower().replace("_", "-") for d in owners.get(name, [name])}
                assert distributions & declared, f"{path.relative_to(REPO)} imports {name}, not in the serving install"
                checked += 1
    assert checked > 10  # the check saw the service's real imports


def test_product_files_stay_small():
    for package in ("contract", "app", "recordings", "trainer", "cli"):
        for path in sorted((REPO / package).rglob("*.py")):
            lines = len(path.read_text().splitlines())
            assert lines <= 400, f"{path.relative_to(REPO)} has {lines} lines"


def test_no_function_outside_the_tests_runs_over_80_lines():
    """A function a reader cannot see whole is split into ones that each do one thing."""
    long = []
    for folder in (*PACKAGES, "bench"):
        for path in sorted((REPO / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    lines = node.end_lineno - node.lineno + 1
                    if lines > 80:
                        long.append(f"{path.relative_to(REPO)}:{node.lineno} {node.name} ({lines} lines)")
    assert not long, long
