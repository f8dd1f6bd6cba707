"""docs/client.md's clients against a real server: a generated one, and service.client.

The page's `openapi-python-client generate` command runs as written (the server's URL
for port 8000, in a temporary directory, with this environment's bin/ first on PATH so
that the generator's post-hook runs the project's ruff; `--fail-on-warning` fails it if
ruff is missing or part of the document cannot be expressed) against the server's own
/openapi.json. Then:

- the served operation ids are the short ones (`smm`, `smm_batch`, `self_motion`, `list_robots`,
  `healthz`, `readyz`, `metrics`) and name the generated modules, one per operation under
  its tag, each with sync, sync_detailed, asyncio and asyncio_detailed;
- the generated package, imported here, calls the server: `list_robots` lists the served
  models (and the generated robot enum is exactly the served robots); `smm` on the iiwa14
  pose target parses into the generated models with no field the document leaves out,
  every accepted sample in exactly one component, and every returned configuration and
  path point reaches the target by the independent DH forward kinematics of
  training/evaluate/references/iiwa14.py (1e-6 m, 1e-6 rad) within the limits `list_robots` gives;
  `smm_batch`, the probes and a 422 parse into their models;
- the page's Python examples (the generated client's, and service.client's) run as
  written against the server, and print lines of the shape of the page's real output
  (the same words, with every number and model hash masked).
"""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import httpx
import numpy as np
import pytest

from tools.local_server import LocalServer
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose
from training.evaluate.references.rotations import rotation_angle_rad

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "client.md"
DOCUMENTED_URL = "http://127.0.0.1:8000"
PACKAGE = "smm_client"
# api/<tag>/<operation id>: the generated module of every route.
GENERATED_MODULES = {
    "smm/smm",
    "smm/smm_batch",
    "smm/self_motion",
    "robots/list_robots",
    "health/healthz",
    "health/readyz",
    "operations/metrics",
}
POSITION = [0.6501, 0.2011, 0.5018]
ORIENTATION = {"w": 0.2165, "x": -0.1458, "y": 0.9648, "z": 0.0327}
TOLERANCE = 1e-6


def page_section(title: str) -> str:
    """The text of docs/client.md's `## title` section."""
    text = PAGE.read_text()
    return text.split(f"\n## {title}\n", 1)[1].split("\n## ", 1)[0]


def code_blocks(text: str, language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)\n```", text, flags=re.DOTALL)


def shape(line: str) -> str:
    """A printed line with every model hash and number masked, runs of numbers as one."""
    line = re.sub(r"@[0-9a-f]{12}\b", "@<model>", line)
    line = re.sub(r"-?\d+(?:\.\d+)?(?:e-?\d+)?", "<n>", line)
    return re.sub(r"<n>(?:, <n>)+", "<n>, ...", line)


def run_example(section: str, server: LocalServer, cwd: Path) -> None:
    """Run the section's one Python example against `server`; its output has the shape of
    the section's real output (the first text block after the example)."""
    [example] = code_blocks(section, "python")
    documented = code_blocks(section.split(example, 1)[1], "text")[0]
    script = cwd / "page_example.py"
    script.write_text(example.replace(DOCUMENTED_URL, server.url))
    run = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, cwd=cwd, timeout=60
    )
    assert run.returncode == 0, run.stdout + run.stderr
    printed = run.stdout.strip().splitlines()
    assert [shape(line) for line in printed] == [shape(line) for line in documented.splitlines()], (
        run.stdout
    )


def rotation(w: float, x: float, y: float, z: float) -> np.ndarray:
    """(3, 3) rotation matrix of a unit quaternion (normalised first)."""
    w, x, y, z = np.array([w, x, y, z]) / np.linalg.norm([w, x, y, z])
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


@pytest.fixture(scope="module")
def server() -> Iterator[LocalServer]:
    with LocalServer() as running:
        yield running


@pytest.fixture(scope="module")
def generated(server: LocalServer, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The directory holding the package the page's command generates from the server."""
    [command] = [
        block
        for block in code_blocks(
            page_section("Clients in other languages / generated clients"), "sh"
        )
        if "openapi-python-client generate" in block
    ]
    workdir = tmp_path_factory.mktemp("generated")
    bin_dir = Path(sys.executable).parent  # openapi-python-client and ruff of this environment
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}"}
    run = subprocess.run(
        ["bash", "-c", command.replace(DOCUMENTED_URL, server.url)],
        capture_output=True,
        text=True,
        cwd=workdir,
        env=env,
        timeout=120,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert (workdir / PACKAGE / "__init__.py").is_file(), run.stdout
    return workdir


@pytest.fixture(scope="module")
def client_package(generated: Path) -> Iterator[ModuleType]:
    """The generated package, imported here; unimported again afterwards."""
    sys.path.insert(0, str(generated))
    try:
        yield importlib.import_module(PACKAGE)
    finally:
        sys.path.remove(str(generated))
        for name in [n for n in sys.modules if n == PACKAGE or n.startswith(f"{PACKAGE}.")]:
            del sys.modules[name]


def operation(name: str) -> Any:
    """A generated operation module, `smm` -> smm_client.api.smm.smm."""
    [path] = [p for p in GENERATED_MODULES if p.endswith(f"/{name}")]
    return importlib.import_module(f"{PACKAGE}.api.{path.replace('/', '.')}")


def test_the_short_operation_ids_name_the_generated_modules(
    server: LocalServer, generated: Path, client_package: ModuleType
) -> None:
    document = httpx.get(f"{server.url}/openapi.json").json()
    ids = [op["operationId"] for path in document["paths"].values() for op in path.values()]
    assert sorted(ids) == [
        "healthz", "list_robots", "metrics", "readyz", "self_motion", "smm", "smm_batch",
    ]  # fmt: skip
    api = generated / PACKAGE / "api"
    modules = {
        p.relative_to(api).with_suffix("").as_posix()
        for p in api.glob("*/*.py")
        if p.name != "__init__.py"
    }
    assert modules == GENERATED_MODULES
    assert {m.rsplit("/", 1)[1] for m in modules} == set(ids)
    for name in ids:
        module = operation(name)
        for function in ("sync", "sync_detailed", "asyncio", "asyncio_detailed"):
            assert callable(getattr(module, function)), (name, function)


def test_a_pose_target_through_the_generated_client(
    server: LocalServer, client_package: ModuleType
) -> None:
    models = importlib.import_module(f"{PACKAGE}.models")
    with client_package.Client(base_url=server.url, timeout=httpx.Timeout(30.0)) as client:
        robots = operation("list_robots").sync(client=client)
        assert isinstance(robots, models.RobotsResponse), robots
        served = {(m.robot, m.task) for m in robots.models}
        assert ("iiwa14", "pose") in served
        assert {r.value for r in models.SmmRequestRobot} == {robot for robot, _ in served}
        [iiwa] = [m for m in robots.models if (m.robot, m.task) == ("iiwa14", "pose")]
        lower, upper = np.array(iiwa.joint_lower), np.array(iiwa.joint_upper)

        answer = operation("smm").sync(
            client=client,
            body=models.SmmRequest(
                robot=models.SmmRequestRobot.IIWA14,
                task=models.SmmRequestTask.POSE,
                target=models.TargetIn(
                    position=POSITION, orientation=models.QuaternionIn(**ORIENTATION)
                ),
                num_samples=300,
                seed=5,
                tolerance=models.ToleranceIn(position=TOLERANCE, orientation=TOLERANCE),
            ),
        )
        assert isinstance(answer, models.SmmResponse), answer
        assert answer.status == models.SmmResponseStatus.OK
        assert answer.joint_names == iiwa.joint_names
        assert answer.additional_properties == {}  # the document names every field sent
        assert len(answer.components) >= 2
        assert sum(c.size for c in answer.components) == answer.counts.accepted > 0

        goal = rotation(*(ORIENTATION[k] for k in "wxyz"))
        for component in answer.components:
            assert isinstance(component, models.ComponentOut)
            assert component.additional_properties == {}
            # A component no sample hit (size 0, found by tracing) has a path and no members.
            listed = [component.representative, *component.configurations, *(component.path or [])]
            configurations = np.array(listed)
            assert configurations.shape[1] == 7
            assert len(component.configurations) > 0 or component.path, component.id
            pose = iiwa14_pose(configurations)
            position_error = np.linalg.norm(pose[:, :3, 3] - POSITION, axis=1)
            orientation_error = rotation_angle_rad(pose[:, :3, :3], goal[None])
            assert position_error.max() < TOLERANCE, component.id
            assert orientation_error.max() < TOLERANCE, component.id
            assert np.all((configurations >= lower) & (configurations <= upper)), component.id

        batch = operation("smm_batch").sync(
            client=client,
            body=models.SmmBatchRequest(
                robot=models.SmmBatchRequestRobot.PLANAR3R,
                task=models.SmmBatchRequestTask.POSITION,
                num_samples=200,
                include_paths=False,
                targets=[
                    models.BatchTargetIn(target=models.TargetIn(position=[0.5, 0.0])),
                    models.BatchTargetIn(target=models.TargetIn(position=[3.5, 0.0])),
                ],
            ),
        )
        assert isinstance(batch, models.SmmBatchResponse), batch
        assert [r.status.value for r in batch.results] == ["ok", "no_solution"]
        assert isinstance(batch.results[0].answer, models.SmmResponse)

        assert operation("healthz").sync(client=client).status == "alive"
        ready = operation("readyz").sync(client=client)
        assert isinstance(ready, models.ReadinessResponse), ready
        assert ready.status == models.ReadinessResponseStatus.READY

        refused = operation("smm").sync_detailed(
            client=client,
            body=models.SmmRequest(
                robot=models.SmmRequestRobot.PLANAR3R,
                task=models.SmmRequestTask.POSITION,
                target=models.TargetIn(position=[0.5, 0.0, 0.2]),
            ),
        )
        assert refused.status_code == 422
        assert isinstance(refused.parsed, models.HTTPValidationError)
        assert refused.parsed.detail[0].loc == ["body", "target", "position"]


def test_the_pages_generated_client_example_runs_as_documented(
    server: LocalServer, generated: Path
) -> None:
    run_example(page_section("Clients in other languages / generated clients"), server, generated)


def test_the_pages_python_client_example_runs_as_documented(
    server: LocalServer, tmp_path: Path
) -> None:
    section = page_section("Python client")
    [example] = code_blocks(section, "python")
    assert "from service.client import" in example
    run_example(section, server, tmp_path)  # outside the repository, as a planner runs it
