"""`smm-serve` as a real process, the way the container runs it, with two workers.

Settings come from the environment only: it must listen on SMM_PORT, run SMM_WORKERS
worker processes that each answer, write one JSON access-log line per request and none
of uvicorn's own, and stop on SIGTERM through the app's shutdown.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx

from tools.local_server import LOOPBACK, free_port

PLANAR = {"robot": "planar3r", "task": "position", "target": {"position": [0.5, 0.0]}}


def worker_processes(pid: int) -> list[int]:
    """Children of `pid` that are multiprocessing workers (not its resource tracker)."""
    text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    return [
        int(child)
        for child in text.split()
        if b"spawn_main" in Path(f"/proc/{child}/cmdline").read_bytes()
    ]


def stop(server: subprocess.Popen[bytes]) -> None:
    """SIGTERM, so the supervisor stops its workers; SIGKILL to all of them if it hangs."""
    if server.poll() is not None:
        return
    workers = worker_processes(server.pid)
    server.send_signal(signal.SIGTERM)
    try:
        server.wait(timeout=60)
    except subprocess.TimeoutExpired:
        for pid in [*workers, server.pid]:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        server.wait()


def test_smm_serve_with_two_workers_from_the_environment(tmp_path: Path) -> None:
    port = free_port()
    url = f"http://{LOOPBACK}:{port}"
    env = {
        **os.environ,
        "SMM_HOST": LOOPBACK,
        "SMM_PORT": str(port),
        "SMM_WORKERS": "2",
        "PYTHONUNBUFFERED": "1",
    }
    smm_serve = shutil.which("smm-serve", path=str(Path(sys.executable).parent))
    assert smm_serve is not None, "smm-serve not installed (pip install -e .)"
    log_path = tmp_path / "server.log"
    with log_path.open("w") as log:
        server = subprocess.Popen([smm_serve], env=env, stdout=log, stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + 90
            while True:
                assert server.poll() is None, log_path.read_text()
                assert time.monotonic() < deadline, "not ready:\n" + log_path.read_text()
                try:
                    # Ready means one worker is; wait until both are (each loads the models).
                    if httpx.get(f"{url}/readyz", timeout=1).status_code == 200 and (
                        log_path.read_text().count('"message": "model loaded"') >= 6
                    ):
                        break
                except httpx.TransportError:
                    pass
                time.sleep(0.1)
            assert len(worker_processes(server.pid)) == 2
            answers = [httpx.post(f"{url}/smm", json=PLANAR, timeout=30) for _ in range(4)]
            assert [a.status_code for a in answers] == [200] * 4
            server.send_signal(signal.SIGTERM)
            assert server.wait(timeout=60) in (0, -signal.SIGTERM)
        finally:
            stop(server)
    text = log_path.read_text()
    assert text.count('"message": "request"') >= 5  # readiness polls and the four answers
    assert 'HTTP/1.1" 200' not in text  # uvicorn's own access log is off
    assert text.count('"message": "shut down"') == 2
