"""Property-based requests from the committed OpenAPI document find no server error."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO

from harness.service import running_service

#: Real processes, networks or browsers: the full suite (`make test`) runs these, `-m 'not slow'` skips them.
pytestmark = pytest.mark.slow


def test_schemathesis_finds_no_server_error(registry):
    cli = shutil.which("schemathesis") or str(Path(sys.executable).with_name("schemathesis"))
    with running_service(registry=str(registry), threads="1") as running:
        url = running.url
        result = subprocess.run(
            [
                cli,
                "run",
                str(REPO / "openapi" / "openapi.json"),
                "-u",
                url,
                "-c",
                "not_a_server_error",
                "-n",
                "20",
                "--seed",
                "1",
                "--no-color",
            ],
            capture_output=True,
            text=True,
            timeout=600,
        )
    assert result.returncode == 0, result.stdout[-4000:]
    assert " passed" in result.stdout and "failed" not in result.stdout.split("SUMMARY")[-1]
