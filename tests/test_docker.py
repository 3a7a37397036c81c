"""The Dockerfile as text: hadolint, and the shape users rely on. tests/test_image.py builds and runs it."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO

#: Real processes, networks or browsers: the full suite (`make test`) runs these, `-m 'not slow'` skips them.
pytestmark = pytest.mark.slow

DOCKERFILE = REPO / "Dockerfile"


def instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, argument) pairs with line continuations joined and comments dropped."""
    text = re.sub(r"\\\n\s*", " ", DOCKERFILE.read_text())
    pairs = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            keyword, _, argument = line.partition(" ")
            pairs.append((keyword.upper(), argument.strip()))
    return pairs


def test_hadolint_is_clean():
    hadolint = shutil.which("hadolint") or str(Path(sys.executable).with_name("hadolint"))
    result = subprocess.run([hadolint, str(DOCKERFILE)], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_image_shape():
    steps = instructions()
    assert steps[:2] == [("ARG", "BASE=python:3.11-slim"), ("FROM", "${BASE}")]  # users get the official base
    user = [arg for kw, arg in steps if kw == "USER"]
    assert user and not user[-1].startswith(("0", "root"))
    assert any(kw == "HEALTHCHECK" for kw, _ in steps)
    env = " ".join(arg for kw, arg in steps if kw == "ENV")
    assert (
        "RGB2CLOUD_PORT=" in env and "RGB2CLOUD_BUNDLED_REGISTRY=weights" in env and "RGB2CLOUD_REGISTRY=/models" in env
    )
    copied = [arg.split()[0] for kw, arg in steps if kw == "COPY"]
    assert "weights" in copied and "tests" not in copied
