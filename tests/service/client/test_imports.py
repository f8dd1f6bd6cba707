"""client: importable with only httpx and pydantic, the server's other dependencies blocked.

A planner installs the client to call the service, not to run it: a fresh interpreter
whose import system refuses numpy, scipy, scikit-learn, onnxruntime, fastapi, starlette,
uvicorn, prometheus_client, pydantic-settings and torch imports `service.client`, builds
and serialises a request, and loads no module of service/ but the client and the wire
models.
"""

from __future__ import annotations

import subprocess
import sys

SCRIPT = """
import sys

BLOCKED = {
    "numpy", "scipy", "sklearn", "onnxruntime", "fastapi", "starlette", "uvicorn",
    "prometheus_client", "pydantic_settings", "torch",
}


class Refuse:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ImportError(f"{name} is blocked: the client must not need it")
        return None


sys.meta_path.insert(0, Refuse())

from service.client import QuaternionIn, SmmClient, SmmRequest, TargetIn

request = SmmRequest(
    robot="iiwa14",
    task="pose",
    target=TargetIn(position=[0.5, 0.1, 0.6], orientation=QuaternionIn(w=0, x=1, y=0, z=0)),
)
request.model_dump_json()
SmmClient("http://127.0.0.1:9").close()
print(" ".join(sorted(m for m in sys.modules if m.split(".")[0] == "service")))
"""


def test_the_client_imports_without_the_server_dependencies() -> None:
    result = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    loaded = set(result.stdout.split())
    assert loaded == {
        "service",
        "service.client",
        "service.client.client",
        "service.client.errors",
        "service.client.retry",
        "service.wire",
    }
