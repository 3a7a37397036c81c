"""Podman on our machines: the settings this sandbox needs, a stand-in base image, and the service's image.

The serving image is built from the Dockerfile as users build it and run as they run it, with podman
(Debian's package) instead of a Docker engine, which our machines do not run. Three things differ from
a user's machine, each said here once:

- **The sandbox's limits.** The runtime is ``runc``, cgroups are managed by ``cgroupfs`` (no systemd), and
  containers get no ulimits of their own (the sandbox refuses raising RLIMIT_NOFILE). These go in a
  ``containers.conf``, and the storage driver in a ``storage.conf`` (``overlay``, the kernel's: ``vfs``, which
  needs nothing of the kernel, copies every layer whole and built the image several times slower here).
  ``podman_env`` points podman at both, so ``podman`` and ``podman-compose`` run with no flags of their own.
- **No image registry is reachable**, so ``python:3.11-slim`` cannot be pulled. ``standin_base`` builds a
  stand-in from Debian's packages: bookworm's Python 3.11 in a venv first on ``PATH`` (as the official
  image puts its Python first), and this machine's CA bundle with pip pointed at it, for the package
  registries. The Dockerfile takes it through ``--build-arg BASE``.
- **Builds reach the registries through the host's network** (``--network host``).

Images are kept in the machine's container storage, so a second run reuses them. The stand-ins' tags
carry a hash of this file, so a changed recipe builds afresh.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import httpx

from harness.service import free_port

REPO = Path(__file__).resolve().parents[1]
#: Where podman's settings for this sandbox are written.
SETTINGS = Path(tempfile.gettempdir()) / "rgb2cloud-podman"
#: The recipe the stand-ins were built by: this file.
RECIPE = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:12]
#: The stand-in for ``python:3.11-slim``, and what the Dockerfile builds from it.
BASE = f"localhost/rgb2cloud-standin/python:3.11-slim-{RECIPE}"
IMAGE = "localhost/rgb2cloud:test"
#: nginx from Debian's package on the same stand-in, for the compose recipe's balancer.
NGINX_IMAGE = f"localhost/rgb2cloud-standin/nginx:bookworm-{RECIPE}"
#: The compose project the tests bring up: never the recipe's own (``rgb2cloud``), which may be running.
PROJECT = "rgb2cloud-test"
#: The machine's CA bundle: the package registries are reached through it.
CA_BUNDLE = Path("/etc/ssl/certs/ca-certificates.crt")
#: The stand-in's Python: a venv, first on PATH (a symlink to a venv's python would not start the venv).
VENV = "/opt/python"
PATH = f"{VENV}/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"

CONTAINERS_CONF = """\
[containers]
# The sandbox refuses raising RLIMIT_NOFILE, which podman does for every container by default.
default_ulimits = []

[engine]
runtime = "runc"
cgroup_manager = "cgroupfs"
events_logger = "file"
"""
STORAGE_CONF = """\
[storage]
driver = "overlay"
runroot = "/run/containers/storage"
graphroot = "/var/lib/containers/storage"
"""


@functools.cache
def settings_env() -> tuple[tuple[str, str], ...]:
    """Writes this sandbox's settings once; the variables that point podman at them."""
    SETTINGS.mkdir(parents=True, exist_ok=True)
    (SETTINGS / "containers.conf").write_text(CONTAINERS_CONF)
    (SETTINGS / "storage.conf").write_text(STORAGE_CONF)
    return (
        ("CONTAINERS_CONF", str(SETTINGS / "containers.conf")),
        ("CONTAINERS_STORAGE_CONF", str(SETTINGS / "storage.conf")),
    )


def podman_env() -> dict[str, str]:
    """The environment that points ``podman`` (and ``podman-compose``) at this sandbox's settings."""
    return os.environ | dict(settings_env())


def podman(*args: str, check: bool = True, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    """``podman ARGS`` with this sandbox's settings; its output captured as text."""
    result = subprocess.run(["podman", *args], env=podman_env(), capture_output=True, text=True, timeout=timeout)
    if check and result.returncode != 0:
        raise RuntimeError(f"podman {' '.join(args)} failed ({result.returncode}): {result.stderr[-2000:]}")
    return result


def why_not() -> str | None:
    """Why podman cannot run containers here, in words, or None when it can."""
    missing = [tool for tool in ("podman", "runc", "debootstrap") if shutil.which(tool) is None]
    if missing:
        return f"{', '.join(missing)} not installed (`make test` installs them with apt-get, as root)"
    if importlib.util.find_spec("podman_compose") is None:
        return "podman-compose is not installed in this environment (the dev extra has it)"
    if os.geteuid() != 0:
        return "podman's storage and networks here need root"
    info = podman("info", "--format", "json", check=False, timeout=120)
    if info.returncode != 0:
        last = (info.stderr.strip().splitlines() or ["no message"])[-1]
        return f"`podman info` failed ({info.returncode}): {last}"
    return None


def exists(image: str) -> bool:
    """Whether the machine's container storage holds ``image``."""
    return podman("image", "exists", image, check=False).returncode == 0


def standin_base(tag: str = BASE) -> str:
    """The stand-in for ``python:3.11-slim``, built once from Debian bookworm's packages (``debootstrap``)."""
    if exists(tag):
        return tag
    with tempfile.TemporaryDirectory(prefix="rgb2cloud-base-", dir="/var/tmp") as scratch:
        root = Path(scratch) / "root"
        debootstrap(root)
        shutil.copy(CA_BUNDLE, root / CA_BUNDLE.relative_to("/"))
        subprocess.run(["chroot", str(root), "/usr/bin/python3", "-m", "venv", VENV], check=True, timeout=300)
        # What debian:bookworm-slim (python:3.11-slim's base) leaves out: the downloaded packages, apt's
        # lists, documentation, manual pages and translations.
        for folder in ("var/cache/apt", "var/lib/apt/lists", "usr/share/doc", "usr/share/man", "usr/share/locale"):
            shutil.rmtree(root / folder)
            (root / folder).mkdir()
        (root / "var/cache/apt/archives/partial").mkdir(parents=True)
        (root / "var/lib/apt/lists/partial").mkdir()
        root.chmod(0o755)  # mktemp's 700 would lock the image's uid 10001 out of /
        archive = Path(scratch) / "root.tar"
        with tarfile.open(archive, "w") as tar:
            tar.add(root, arcname=".")
        changes = [f"ENV PATH={PATH}", f"ENV PIP_CERT={CA_BUNDLE}", "ENV LANG=C.UTF-8", 'CMD ["python3"]']
        podman("import", *(arg for change in changes for arg in ("--change", change)), str(archive), tag)
    return tag


def debootstrap(root: Path) -> None:
    """Debian bookworm's minimal base with Python into ``root``; what debootstrap said if it fails. Its /proc and
    /sys mounts are undone whatever happens, so the folder can be removed."""
    command = ["debootstrap", "--variant=minbase", "--include=python3,python3-venv,ca-certificates", "bookworm"]
    try:
        result = subprocess.run(
            [*command, str(root), "http://deb.debian.org/debian"], capture_output=True, text=True, timeout=900
        )
    finally:
        for mount in (root / "proc", root / "sys"):
            if os.path.ismount(mount):
                subprocess.run(["umount", "--lazy", str(mount)], check=False)
    if result.returncode != 0:
        raise RuntimeError(f"debootstrap failed ({result.returncode}): {(result.stdout + result.stderr)[-3000:]}")


def build(context: Path, tag: str, base: str, containerfile: Path | None = None) -> float:
    """``podman build`` in the Docker format (the OCI format drops HEALTHCHECK); the seconds it took."""
    started = time.perf_counter()
    args = ["build", "--format", "docker", "--network", "host", "--build-arg", f"BASE={base}", "-t", tag]
    podman(*args, *(["-f", str(containerfile)] if containerfile else []), str(context), timeout=1200)
    return time.perf_counter() - started


def nginx_image(base: str, tag: str = NGINX_IMAGE) -> str:
    """Debian's nginx on the stand-in: the balancer's image where ``nginx:1.27`` cannot be pulled."""
    if exists(tag):
        return tag
    with tempfile.TemporaryDirectory(prefix="rgb2cloud-nginx-") as scratch:
        containerfile = Path(scratch) / "Containerfile"
        containerfile.write_text(
            "ARG BASE\nFROM ${BASE}\n"
            "RUN apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends"
            " nginx-light && rm -rf /var/lib/apt/lists/*\n"
        )
        build(Path(scratch), tag, base, containerfile)
    return tag


def layers(image: str) -> list[tuple[str, int]]:
    """(the step that made it, bytes it adds) for each layer of ``image``, oldest first."""
    newest_first = json.loads(podman("history", "--format", "json", "--no-trunc", image).stdout)
    return [(entry["CreatedBy"], int(entry["size"])) for entry in reversed(newest_first)]


def image_bytes(image: str) -> int:
    """The image's size as podman reports it: every layer, the base's included."""
    return int(json.loads(podman("image", "inspect", image).stdout)[0]["Size"])


def wait_ready(url: str, container: str, started: float, timeout_s: float = 120) -> float:
    """Seconds from ``started`` (a ``perf_counter``) until ``url/readyz`` answers 200; the container's log in
    the error if it never does."""
    while time.perf_counter() - started < timeout_s:
        try:
            if httpx.get(f"{url}/readyz", timeout=2).status_code == 200:
                return time.perf_counter() - started
        except httpx.HTTPError:
            pass
        state = podman("inspect", "--format", "{{.State.Status}}", container, check=False).stdout.strip()
        if state in ("exited", "stopped"):
            break
        time.sleep(0.2)
    log = podman("logs", container, check=False)
    raise RuntimeError(f"{container} never became ready: {(log.stdout + log.stderr)[-3000:]}")


@dataclass(frozen=True)
class Container:
    """A running container: its name, the service's URL on this machine, and how long it took to be ready."""

    name: str
    url: str
    ready_s: float

    def run(self, *command: str) -> subprocess.CompletedProcess[str]:
        """``podman exec``: a command inside the container, as its user."""
        return podman("exec", self.name, *command, check=False)


@contextmanager
def running(image: str, *options: str) -> Iterator[Container]:
    """``podman run IMAGE`` with port 8000 published on a free loopback port, as users run it; removed after."""
    port = free_port()
    name = f"rgb2cloud-test-{port}"
    started = time.perf_counter()
    try:
        podman("run", "--detach", "--name", name, "--publish", f"127.0.0.1:{port}:8000", *options, image)
        url = f"http://127.0.0.1:{port}"
        yield Container(name, url, wait_ready(url, name, started))
    finally:
        podman("rm", "--force", "--time", "10", name, check=False)


def compose(
    *args: str, override: Path, env: dict[str, str] | None = None, check: bool = True
) -> subprocess.CompletedProcess[str]:
    """``podman-compose`` on ``deploy/compose.yaml`` as shipped, as project ``PROJECT``, with ``override``
    naming the images and ``env`` setting the variables the recipe reads."""
    files = ["-p", PROJECT, "-f", str(REPO / "deploy" / "compose.yaml"), "-f", str(override)]
    result = subprocess.run(
        [sys.executable, "-m", "podman_compose", *files, *args],
        env=podman_env() | (env or {}), capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    if check and result.returncode != 0:
        raise RuntimeError(f"podman-compose {' '.join(args)} failed: {(result.stdout + result.stderr)[-3000:]}")
    return result


def replicas(service: str, count: int) -> list[str]:
    """The containers podman-compose names for ``count`` replicas of ``service`` in ``PROJECT``."""
    return [f"{PROJECT}_{service}_{i}" for i in range(1, count + 1)]


def wait_healthy(container: str, started: float, timeout_s: float = 180) -> float:
    """Seconds from ``started`` until the container's own HEALTHCHECK passes (``podman healthcheck run``).

    For containers no port reaches: podman 4.3 runs health checks only from systemd timers, which this
    sandbox has not, so the check is run here instead."""
    while time.perf_counter() - started < timeout_s:
        if podman("healthcheck", "run", container, check=False).returncode == 0:
            return time.perf_counter() - started
        time.sleep(1)
    log = podman("logs", container, check=False)
    raise RuntimeError(f"{container} never became healthy: {(log.stdout + log.stderr)[-3000:]}")
