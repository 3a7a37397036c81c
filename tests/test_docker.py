"""The Dockerfile, without a Docker engine: hadolint, then its install and start steps in a clean venv."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
import venv
from pathlib import Path

import httpx
import pytest
from conftest import REPO, TUM_FRAME

from harness.service import free_port

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
    assert steps[0] == ("FROM", "python:3.11-slim")
    user = [arg for kw, arg in steps if kw == "USER"]
    assert user and not user[-1].startswith(("0", "root"))
    assert any(kw == "HEALTHCHECK" for kw, _ in steps)
    env = " ".join(arg for kw, arg in steps if kw == "ENV")
    assert (
        "RGB2CLOUD_PORT=" in env and "RGB2CLOUD_BUNDLED_REGISTRY=weights" in env and "RGB2CLOUD_REGISTRY=/models" in env
    )
    copied = [arg.split()[0] for kw, arg in steps if kw == "COPY"]
    assert "weights" in copied and "tests" not in copied


def test_install_and_start_steps_in_a_clean_venv(tmp_path):
    """Replays COPY, RUN, ENV, CMD and HEALTHCHECK: the serving install has no torch and serves."""
    context = tmp_path / "srv"
    context.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("VIRTUAL_ENV", "PYTHON", "RGB2CLOUD_"))}
    venv.create(tmp_path / "venv", with_pip=True)
    bin_dir = tmp_path / "venv" / "bin"
    env["PATH"] = f"{bin_dir}{os.pathsep}{env['PATH']}"
    cmd = healthcheck = None
    for keyword, argument in instructions():
        if keyword == "COPY":
            *sources, destination = argument.split()
            for source in sources:
                target = context / destination / source if destination.endswith("/") else context / destination
                if (REPO / source).is_dir():
                    shutil.copytree(REPO / source, target, ignore=shutil.ignore_patterns("__pycache__"))
                else:
                    shutil.copy(REPO / source, target)
        elif keyword == "RUN" and "pip install" in argument:
            subprocess.run(argument, shell=True, cwd=context, env=env, check=True, capture_output=True)
        elif keyword == "ENV":
            env.update(dict(pair.split("=", 1) for pair in argument.split()))
        elif keyword == "CMD":
            cmd = json.loads(argument)
        elif keyword == "HEALTHCHECK":
            healthcheck = json.loads(argument[argument.index("CMD") + 3 :])
    python = str(bin_dir / "python")
    no_torch = subprocess.run(
        [python, "-c", "import importlib.util as u; print(u.find_spec('torch') is None)"],
        capture_output=True,
        text=True,
        env=env,
    )
    assert no_torch.stdout.strip() == "True", "the serving install pulled in torch"

    env |= {"RGB2CLOUD_HOST": "127.0.0.1", "RGB2CLOUD_PORT": str(free_port()), "RGB2CLOUD_THREADS": "1"}
    log = tmp_path / "service.log"  # a file, not a pipe: an undrained pipe fills and blocks the service
    with open(log, "w") as out:
        server = subprocess.Popen(
            [python if c == "python" else c for c in cmd], cwd=context, env=env, stdout=out, stderr=subprocess.STDOUT
        )
    try:
        url = f"http://127.0.0.1:{env['RGB2CLOUD_PORT']}"
        for _ in range(300):
            assert server.poll() is None, log.read_text()
            check = subprocess.run([python if c == "python" else c for c in healthcheck], env=env, capture_output=True)
            if check.returncode == 0:
                break
            time.sleep(0.2)
        else:
            pytest.fail("HEALTHCHECK never passed")
        r = httpx.post(f"{url}/depth", files={"image": (TUM_FRAME / "TUM_color.png").read_bytes()}, timeout=60)
        assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    finally:
        server.terminate()
        server.wait(timeout=10)
