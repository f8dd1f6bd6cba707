"""The image's CMD run as built, in a working container with the settings in its env: what
the image holds, the HTTP checks, and what only the running process shows (its user, the
HEALTHCHECK command, its access log, a graceful SIGTERM)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time
from pathlib import Path
from typing import IO, Any

from tools.container_test.buildah import IMAGE, Buildah, image_config, tail
from tools.container_test.http_checks import API_KEY, MAX_NUM_SAMPLES, run_http_checks
from tools.container_test.image import check_image_contents, tree_bytes
from tools.container_test.outcomes import Checks
from tools.container_test.server import (
    gids,
    json_lines,
    process_start_boottime_s,
    server_pid,
    stop,
    uids,
    wait_ready,
)
from tools.local_server import LOOPBACK, free_port

# How long the access-log check waits for the lines of requests already answered: each is
# written once its response has gone out.
ACCESS_LOG_WAIT_S = 5.0


def run_container_checks(buildah: Buildah, store: Path, checks: Checks) -> dict[str, Any]:
    """Start the image's CMD in a working container and check it; the measured figures."""
    figures: dict[str, Any] = {}
    config = image_config(buildah, IMAGE)
    command = [*(config.get("Entrypoint") or []), *(config.get("Cmd") or [])]
    figures["cmd"] = command
    container = buildah("from", "--pull=never", "--name", f"smm-test-{os.getpid()}", IMAGE)
    port = free_port()
    buildah(
        "config",
        "--env",
        f"SMM_PORT={port}",
        "--env",
        f"SMM_API_KEY={API_KEY}",
        "--env",
        f"SMM_MAX_NUM_SAMPLES={MAX_NUM_SAMPLES}",
        container,
    )
    root = Path(buildah("mount", container))
    check_image_contents(root, checks)
    figures["rootfs_bytes"] = tree_bytes(root)

    url = f"http://{LOOPBACK}:{port}"
    log_path = store / "server.log"
    with log_path.open("w") as log:
        started_s = time.monotonic()
        server = buildah.popen(
            "run", "--isolation", "chroot", container, "--", *command, output=log
        )
        try:
            ready_s = wait_ready(url, server, log_path)
            figures["run_to_ready_s"] = round(ready_s - started_s, 2)
            ready_boottime_s = time.clock_gettime(time.CLOCK_BOOTTIME)
            pid = server_pid(server.pid)
            figures["cold_start_s"] = round(ready_boottime_s - process_start_boottime_s(pid), 2)
            request_ids = run_http_checks(url, {"X-API-Key": API_KEY}, checks, figures)
            check_user(pid, config, command, checks)
            check_healthcheck(buildah, container, config, True, checks)
            stopping = "SIGTERM stops the server gracefully"
            check_graceful_stop(stopping, pid, server, log, log_path, checks)
            check_access_log(log_path, request_ids, checks)
            check_healthcheck(buildah, container, config, False, checks)
        finally:
            stop(server)
    if checks.failed:
        print("--- server log (tail) ---\n" + tail(log_path.read_text(errors="replace"), 40))
    return figures


def check_user(pid: int, config: dict[str, Any], command: list[str], checks: Checks) -> None:
    """The server process runs as the image's USER, which is not root."""
    with checks.check("server process runs as the image's non-root USER") as note:
        ids = uids(pid)
        assert all(u != 0 for u in ids), f"uids {ids}"
        user, _, group = str(config.get("User")).partition(":")
        assert str(ids[0]) == user, f"uid {ids[0]}, USER {config.get('User')}"
        assert not group or str(gids(pid)[0]) == group, f"gid {gids(pid)}, USER {user}"
        note["detail"] = (
            f"pid {pid} (on the host), uid {ids[0]}, gid {gids(pid)[0]}, command {command}"
        )


def check_healthcheck(
    buildah: Buildah, container: str, config: dict[str, Any], running: bool, checks: Checks
) -> None:
    """The image's HEALTHCHECK command exits 0 while the server runs, non-zero once not."""
    healthcheck = (config.get("Healthcheck") or {}).get("Test") or []
    if running:
        with checks.check("HEALTHCHECK command exits 0 while the server runs") as note:
            assert healthcheck[:1] == ["CMD"], f"HEALTHCHECK {healthcheck}"
            status = buildah.status(
                "run", "--isolation", "chroot", container, "--", *healthcheck[1:]
            )
            assert status == 0, f"exit status {status}"
            note["detail"] = " ".join(healthcheck[1:])
        return
    with checks.check("HEALTHCHECK command fails once the server stopped") as note:
        status = buildah.status("run", "--isolation", "chroot", container, "--", *healthcheck[1:])
        assert status != 0, "exit status 0 with no server"
        note["detail"] = f"exit status {status}"


def check_graceful_stop(
    name: str,
    pid: int,
    server: subprocess.Popen[bytes],  # `buildah run`
    log: IO[Any],  # the log file the server writes
    log_path: Path,
    checks: Checks,
) -> None:
    """SIGTERM to the server process ends `buildah run` with the app's "shut down" line."""
    with checks.check(name) as note:
        os.kill(pid, signal.SIGTERM)
        code = server.wait(timeout=60)
        log.flush()
        lines = json_lines(log_path.read_text(errors="replace"))
        assert any(line.get("message") == "shut down" for line in lines), "no shut down line"
        note["detail"] = f"buildah run exited {code}"


def check_access_log(log_path: Path, request_ids: list[str], checks: Checks) -> None:
    """One JSON access-log line per request (by its X-Request-ID), none from uvicorn.

    A request's line is written once its response has gone out, so the client can hold the
    last answer before its line is in the file: the log is read again until every request
    has one, for up to ACCESS_LOG_WAIT_S."""
    with checks.check("one JSON access-log line per request, none from uvicorn") as note:
        deadline_s = time.monotonic() + ACCESS_LOG_WAIT_S
        while True:
            text = log_path.read_text(errors="replace")
            access = [line for line in json_lines(text) if line.get("message") == "request"]
            logged = [line["request_id"] for line in access]
            if set(request_ids) <= set(logged) or time.monotonic() > deadline_s:
                break
            time.sleep(0.05)
        uvicorn_access = re.findall(r'"(?:GET|POST) \S+ HTTP/1\.1" \d{3}', text)
        assert not uvicorn_access, f"uvicorn access lines: {uvicorn_access[:3]}"
        twice_or_never = [i for i in request_ids if logged.count(i) != 1]
        assert not twice_or_never, f"request ids not logged exactly once: {twice_or_never}"
        note["detail"] = (
            f"{len(request_ids)} requests, each logged once under its X-Request-ID; 0 uvicorn lines"
        )
