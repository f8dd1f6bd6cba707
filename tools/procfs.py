"""What Linux's /proc says of a process: its stat fields, resident memory and CPU time.

The tools that start or watch a server (the local server, the soak, the container test)
read the same files the same way through these.
"""

from __future__ import annotations

import os
from pathlib import Path


def stat_fields(stat_text: str) -> list[str]:
    """The fields of a /proc/<pid>/stat line after the command name (in parentheses,
    which may hold spaces): field k of proc(5), counted from 1, is item k - 3."""
    return stat_text.rsplit(")", 1)[1].split()


def resident_memory_bytes(pid: int) -> int:
    """Resident set size of a process, from /proc (Linux)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise RuntimeError(f"no VmRSS for pid {pid}")


def cpu_seconds(pid: int) -> float:
    """CPU time a process has spent, user and system, every thread (the kernel counts in
    clock ticks, 10 ms on most systems)."""
    fields = stat_fields(Path(f"/proc/{pid}/stat").read_text())
    utime, stime = int(fields[11]), int(fields[12])  # proc(5) fields 14 and 15
    return (utime + stime) / os.sysconf("SC_CLK_TCK")
