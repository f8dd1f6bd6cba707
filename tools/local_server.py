"""Run the service as a real uvicorn process on 127.0.0.1, for tests and load runs.

`LocalServer` starts `uvicorn service.main:create_app --factory` on a free loopback
port with `SMM_*` settings from its arguments, waits until /readyz answers, and stops
the process with SIGTERM (SIGKILL only if it does not exit). Its JSON log lines go to
a file that `log_lines()` reads back.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import TracebackType
from typing import Any

import httpx

from tools.procfs import cpu_seconds, resident_memory_bytes

LOOPBACK = "127.0.0.1"


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind((LOOPBACK, 0))
        return int(probe.getsockname()[1])


class LocalServer:
    def __init__(self, startup_timeout_s: float = 60.0, **settings: Any) -> None:
        """`settings`: Settings fields (`max_in_flight=1`), passed as SMM_* variables."""
        self.port = free_port()
        self.url = f"http://{LOOPBACK}:{self.port}"
        self.startup_timeout_s = startup_timeout_s
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.env.update({f"SMM_{k.upper()}": str(v) for k, v in settings.items()})
        # The log file outlives this call: the server process writes it until it stops.
        self._log = tempfile.NamedTemporaryFile(  # noqa: SIM115
            prefix="smm-server-", suffix=".log", delete=False
        )
        self.process: subprocess.Popen[bytes] | None = None

    @property
    def pid(self) -> int:
        assert self.process is not None, "server not started"
        return self.process.pid

    def start(self) -> LocalServer:
        command = [
            sys.executable,
            "-m",
            "uvicorn",
            "service.main:create_app",
            "--factory",
            "--host",
            LOOPBACK,
            "--port",
            str(self.port),
            "--no-access-log",
        ]
        self.process = subprocess.Popen(
            command,
            env=self.env,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            cwd=Path(__file__).resolve().parent.parent,
        )
        deadline = time.monotonic() + self.startup_timeout_s
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(
                    f"server exited with {self.process.returncode} during start-up:\n"
                    + self.log_text()
                )
            try:
                if httpx.get(f"{self.url}/readyz", timeout=1.0).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        self.stop()
        raise RuntimeError(
            f"server not ready within {self.startup_timeout_s} s:\n{self.log_text()}"
        )

    def rss_bytes(self) -> int:
        return resident_memory_bytes(self.pid)

    def cpu_s(self) -> float:
        return cpu_seconds(self.pid)

    def log_text(self) -> str:
        return Path(self._log.name).read_text(errors="replace")

    def log_lines(self) -> list[dict[str, Any]]:
        """The server's JSON log lines (uvicorn's own plain lines skipped)."""
        lines = []
        for line in self.log_text().splitlines():
            if line.startswith("{"):
                try:
                    lines.append(json.loads(line))
                except json.JSONDecodeError:
                    continue
        return lines

    def terminate(self) -> None:
        """SIGTERM: uvicorn stops accepting and drains requests in flight."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)

    def wait(self, timeout_s: float) -> int:
        assert self.process is not None
        return self.process.wait(timeout=timeout_s)

    def stop(self, timeout_s: float = 30.0) -> int | None:
        """Terminate and wait; SIGKILL if it does not exit in `timeout_s`. The exit code."""
        if self.process is None:
            return None
        self.terminate()
        try:
            code = self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            code = self.process.wait()
        self._log.close()
        return code

    def __enter__(self) -> LocalServer:
        return self.start()

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        self.stop()
        Path(self._log.name).unlink(missing_ok=True)
