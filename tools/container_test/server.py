"""The server in its container, seen from the host: its processes under `buildah run`, their
ids, memory and mounts, its JSON log lines; waiting until it is ready, and stopping it."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import httpx

from tools.container_test.buildah import tail
from tools.procfs import stat_fields

STARTUP_TIMEOUT_S = 120.0


def descendants(pid: int) -> list[int]:
    """Every process below `pid`, from /proc."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError):
            fields = stat_fields(stat.read_text())
            children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, pending = [], [pid]
    while pending:
        for child in children.get(pending.pop(), []):
            found.append(child)
            pending.append(child)
    return found


def command_line(pid: int) -> list[str]:
    with contextlib.suppress(OSError):
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
    return []


def server_pid(buildah_pid: int) -> int:
    """The Python process running smm-serve below `buildah run` (a host pid)."""
    for pid in descendants(buildah_pid):
        argv = command_line(pid)
        if Path(argv[0]).name.startswith("python") and any("smm-serve" in a for a in argv):
            return pid
    raise RuntimeError("no smm-serve process under buildah run")


def process_start_boottime_s(pid: int) -> float:
    """When a process started, in seconds on CLOCK_BOOTTIME (from /proc/<pid>/stat)."""
    fields = stat_fields(Path(f"/proc/{pid}/stat").read_text())
    return int(fields[19]) / os.sysconf("SC_CLK_TCK")


def uids(pid: int) -> list[int]:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("Uid:"):
            return [int(u) for u in line.split()[1:]]
    raise RuntimeError(f"no Uid line for pid {pid}")


def gids(pid: int) -> list[int]:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("Gid:"):
            return [int(g) for g in line.split()[1:]]
    raise RuntimeError(f"no Gid line for pid {pid}")


def peak_rss_bytes(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise RuntimeError(f"no VmHWM line for pid {pid}")


def root_mounts(pid: int) -> list[tuple[str, str]]:
    """(mount point, per-mount options) of every mount a process sees, from its mountinfo."""
    lines = Path(f"/proc/{pid}/mountinfo").read_text().splitlines()
    return [(line.split()[4], line.split()[5]) for line in lines]


def json_lines(text: str) -> list[dict[str, Any]]:
    lines = []
    for line in text.splitlines():
        with contextlib.suppress(json.JSONDecodeError):
            if line.startswith("{"):
                lines.append(json.loads(line))
    return lines


def wait_ready(url: str, server: subprocess.Popen[bytes], log_path: Path) -> float:
    """Poll /readyz until it answers 200; the monotonic time it did."""
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise RuntimeError(
                f"container exited {server.returncode} before ready:\n"
                + tail(log_path.read_text(errors="replace"), 40)
            )
        with contextlib.suppress(httpx.TransportError):
            if httpx.get(f"{url}/readyz", timeout=1.0).status_code == 200:
                return time.monotonic()
        time.sleep(0.02)
    raise RuntimeError(f"/readyz not 200 within {STARTUP_TIMEOUT_S} s")


def stop(server: subprocess.Popen[bytes]) -> None:
    """Make sure the container process and buildah run are gone."""
    if server.poll() is None:
        for pid in reversed(descendants(server.pid)):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        server.kill()
        server.wait(timeout=30)
