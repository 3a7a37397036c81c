"""What machine this is, in words, for training records and benchmark tables. Torch-free."""

from __future__ import annotations

import os
import platform
from pathlib import Path


def cpu_description() -> str:
    """'<CPU model>, <N> cores' from /proc/cpuinfo where it exists."""
    name = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{name}, {os.cpu_count()} cores"


#: The CPU flags that decide how fast training runs in bf16 and int8: native bf16 dot products
#: (AVX512-BF16), matrix tiles (AMX), and int8 dot products (VNNI).
SPEED_FLAGS = ("avx512_bf16", "amx_bf16", "amx_tile", "avx512_vnni", "avx_vnni")


def cpu_flags() -> set[str]:
    """The CPU's feature flags from /proc/cpuinfo (empty where there is none)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()
