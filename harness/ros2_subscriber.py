"""The independent ROS 2 subscriber (``tests/dds_subscriber/``, Debian's Cyclone DDS C library): built, and run.

The tests read what ``rgb2cloud stream --ros2`` publishes with it; ``bench/stream.py`` uses it as the node that
takes every message, so publishing is measured against a subscriber that is really there.
"""

from __future__ import annotations

import os
import random
import subprocess
from pathlib import Path

SOURCES = Path(__file__).resolve().parents[1] / "tests" / "dds_subscriber"
#: Cyclone DDS on the loopback interface only, multicast on, for the stream and the subscriber alike:
#: discovery and data never leave this machine, and a capture on ``lo`` sees all of it.
LOOPBACK = (
    "<CycloneDDS><Domain><General><Interfaces>"
    '<NetworkInterface address="127.0.0.1" multicast="true"/>'
    "</Interfaces></General></Domain></CycloneDDS>"
)
#: The same with 16 MB socket receive buffers, which full-resolution clouds (4.9 MB a message) need
#: (docs/robotics.md); Cyclone DDS refuses to start unless the kernel allows that much (net.core.rmem_max).
LOOPBACK_16MB = LOOPBACK.replace("</General>", '</General><Internal><SocketReceiveBufferSize min="16MB"/></Internal>')


def build_subscriber(folder: Path) -> Path:
    """The subscriber, built in ``folder``: idlc generates the types' C code, gcc links it with libddsc."""
    subprocess.run(["idlc", "-l", "c", "-o", str(folder), str(SOURCES / "ros2_types.idl")], check=True)
    sources = [str(SOURCES / "ros2_subscriber.c"), str(folder / "ros2_types.c")]
    binary = folder / "ros2_subscriber"
    subprocess.run(["gcc", "-O2", "-Wall", "-I", str(folder), "-o", str(binary), *sources, "-lddsc"], check=True)
    return binary


def loopback_env(domain: int, config: str = LOOPBACK) -> dict[str, str]:
    return {**os.environ, "CYCLONEDDS_URI": config, "ROS_DOMAIN_ID": str(domain)}


def fresh_domain() -> int:
    """A domain of its own for each run: two runs on one machine never hear each other."""
    return random.randint(1, 200)


class Subscription:
    """The subscriber running in ``domain``: ``topics`` as ``/topic=pkg/msg/Type[@transient_local]:COUNT``,
    each sample kept in ``out`` (None: only counted), Cyclone DDS configured by ``config``."""

    def __init__(
        self,
        binary: Path,
        domain: int,
        out: Path | None,
        topics: list[str],
        timeout_s: float = 120,
        config: str = LOOPBACK,
    ):
        if out is not None:
            out.mkdir(parents=True, exist_ok=True)
        self.out, self.topics = out, topics
        self.process = subprocess.Popen(
            [str(binary), str(domain), str(timeout_s), "-" if out is None else str(out), *topics],
            env=loopback_env(domain, config),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert self.process.stdout.readline().strip() == "ready", self.process.communicate()

    def first_sample(self) -> None:
        """Waits until the first sample has come (the subscriber prints a line per sample it keeps)."""
        assert self.process.stdout.readline(), self.process.communicate()

    def wait(self, timeout_s: float = 60) -> None:
        """Until every topic has its count; fails with what was missing."""
        _, err = self.process.communicate(timeout=timeout_s)
        assert self.process.returncode == 0, err

    def received(self, timeout_s: float = 60) -> list[list[bytes]]:
        """Every topic's payloads in order, once the subscriber has them all."""
        self.wait(timeout_s)
        assert self.out is not None
        return [
            [(self.out / f"{k}-{n}.cdr").read_bytes() for n in range(int(spec.rpartition(":")[2]))]
            for k, spec in enumerate(self.topics)
        ]
