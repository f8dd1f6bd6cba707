"""The container's HEALTHCHECK command (`python -m service.healthcheck`).

It asks /healthz on the port the server was given (SMM_PORT), on 127.0.0.1 when the
server binds every interface, and exits 0 only on a 200: a refused connection or another
status is unhealthy (exit 1), with the reason on stderr.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from service import healthcheck
from service.config import Settings
from tools.local_server import free_port


class _Handler(BaseHTTPRequestHandler):
    status = 200

    def do_GET(self) -> None:
        self.send_response(self.status if self.path == "/healthz" else 404)
        self.end_headers()

    def log_message(self, format: str, *args: object) -> None:
        pass


@pytest.fixture
def probe_target(monkeypatch: pytest.MonkeyPatch) -> Iterator[type[_Handler]]:
    """A stand-in server on SMM_PORT; set the handler's `status` to choose its answer."""
    handler = type("Handler", (_Handler,), {})
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    monkeypatch.setenv("SMM_PORT", str(server.server_address[1]))
    monkeypatch.setenv("SMM_HOST", "0.0.0.0")
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield handler
    server.shutdown()
    server.server_close()


def test_url_follows_the_server_settings() -> None:
    assert healthcheck.healthz_url(Settings(host="0.0.0.0", port=9000)) == (
        "http://127.0.0.1:9000/healthz"
    )
    assert healthcheck.healthz_url(Settings(host="10.0.0.5", port=80)) == (
        "http://10.0.0.5:80/healthz"
    )
    assert healthcheck.healthz_url(Settings(host="::1", port=8000)) == "http://[::1]:8000/healthz"


def test_healthy_when_healthz_answers_200(probe_target: type[_Handler]) -> None:
    assert healthcheck.main() == 0


def test_unhealthy_on_another_status(
    probe_target: type[_Handler], capsys: pytest.CaptureFixture[str]
) -> None:
    probe_target.status = 503
    assert healthcheck.main() == 1
    assert "503" in capsys.readouterr().err


def test_unhealthy_when_nothing_listens(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("SMM_PORT", str(free_port()))
    assert healthcheck.main() == 1
    assert "unhealthy" in capsys.readouterr().err
