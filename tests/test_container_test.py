"""tools/container_test, the parts that run without buildah or root: its targets, its answer
check, its image scan, the server-side helpers and the report it writes.

Every bundled model has a target, and the real app's answer to it (in process) passes
`check_answer` by the references' independent FK; an answer off the target, outside the
joint limits, with a wrong count or another status fails. The image scan finds torch, pip,
a compiler and a download cache planted in a fake root, and nothing in a clean one; the
baked models are compared file by file; hard links count once in the root's size. Log
lines that are not JSON are skipped; the deployment's env and memory limit are read from
deploy/base/deployment.yaml; a child process is found below its parent. Against a real
server on 127.0.0.1 with the settings the container gets, every HTTP check passes, each
request is logged once, and SIGTERM ends it with its "shut down" line. The report is
written only when every check passed, with the keys of the committed docs/container.json
(tools/docs reads it), and its exit status says which; its machine is named with the
processor's generation, as every report names it.
"""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.models.registry import int8_flow_here
from tools.container_test import FIGURES, ROOT
from tools.container_test.__main__ import parse_arguments
from tools.container_test.http_checks import API_KEY, MAX_NUM_SAMPLES, run_http_checks
from tools.container_test.image import baked_model_differences, scan_image, tree_bytes
from tools.container_test.outcomes import Checks
from tools.container_test.read_only import (
    check_flow_kernels,
    deployment_env,
    deployment_memory_limit_bytes,
)
from tools.container_test.report import finish, machine_words
from tools.container_test.server import descendants, json_lines
from tools.container_test.server_checks import check_access_log, check_graceful_stop
from tools.container_test.targets import NEAREST_BOUND_RAD, TARGETS, bundled_models, check_answer
from tools.local_server import LocalServer
from training.machine import Machine


def one_configuration_answer(q: np.ndarray, accepted: int = 1) -> dict[str, Any]:
    """The service's answer shape with the one configuration q (n,)."""
    return {
        "status": "ok",
        "components": [{"configurations": [q.tolist()], "size": 1}],
        "counts": {"accepted": accepted},
    }


def test_every_bundled_model_has_a_target_and_a_nearest_bound() -> None:
    assert bundled_models() == sorted(TARGETS) == sorted(NEAREST_BOUND_RAD)


@pytest.mark.parametrize("model_id", sorted(TARGETS))
def test_the_apps_answer_to_each_target_passes_the_independent_check(
    client: TestClient, model_id: str
) -> None:
    target = TARGETS[model_id]()
    response = client.post("/smm", json=target.body)
    assert response.status_code == 200, response.text
    detail = check_answer(model_id, target, response.json())
    assert "components" in detail and "nearest to the source" in detail


@pytest.mark.parametrize("model_id", sorted(TARGETS))
def test_the_source_configuration_passes_and_a_moved_one_fails(model_id: str) -> None:
    target = TARGETS[model_id]()
    assert max(target.check(target.q_source[None]).values()) < 1e-12
    check_answer(model_id, target, one_configuration_answer(target.q_source))
    moved = target.q_source + 1e-3 * np.eye(len(target.q_source))[1]
    with pytest.raises(AssertionError, match="by the independent FK"):
        check_answer(model_id, target, one_configuration_answer(moved))
    with pytest.raises(AssertionError, match="configurations, counts"):
        check_answer(model_id, target, one_configuration_answer(target.q_source, accepted=2))
    with pytest.raises(AssertionError, match="status no_solution"):
        check_answer(model_id, target, {**one_configuration_answer(target.q_source),
                                        "status": "no_solution"})  # fmt: skip


def test_a_configuration_outside_the_limits_fails_even_on_the_target() -> None:
    target = TARGETS["planar3r-position"]()
    turned = target.q_source + np.array([2 * np.pi, 0.0, 0.0])  # the same tip, |q1| > pi
    with pytest.raises(AssertionError, match="outside the joint limits"):
        check_answer("planar3r-position", target, one_configuration_answer(turned))


def test_the_image_scan_finds_what_the_image_must_not_hold(tmp_path: Path) -> None:
    clean = tmp_path / "clean"
    (clean / "opt/venv/lib/python3.11/site-packages/numpy").mkdir(parents=True)
    (clean / "usr/bin").mkdir(parents=True)
    assert scan_image(clean) == {"torch": [], "pip": [], "compilers": [], "caches": []}
    dirty = tmp_path / "dirty"
    packages = dirty / "opt/venv/lib/python3.11/site-packages"
    (packages / "torch").mkdir(parents=True)
    (packages / "pip").mkdir()
    (dirty / "usr/bin").mkdir(parents=True)
    (dirty / "usr/bin/gcc").touch()
    (dirty / "root/.cache/pip").mkdir(parents=True)
    (dirty / "root/.cache/pip/wheel").touch()
    found = scan_image(dirty)
    assert found["torch"] == ["/opt/venv/lib/python3.11/site-packages/torch"]
    assert found["pip"] == ["/opt/venv/lib/python3.11/site-packages/pip"]
    assert found["compilers"] == ["/usr/bin/gcc"]
    assert "/root/.cache/pip" in found["caches"]


def test_baked_models_are_compared_file_by_file(tmp_path: Path) -> None:
    assert baked_model_differences(ROOT / "models") == []
    missing = baked_model_differences(tmp_path)
    assert "models/robots/iiwa14.urdf" in missing
    assert not [path for path in missing if "__pycache__" in path or path.endswith(".pyc")]


def test_tree_bytes_counts_a_hard_linked_file_once(tmp_path: Path) -> None:
    (tmp_path / "a").write_bytes(b"x" * 100)
    os.link(tmp_path / "a", tmp_path / "b")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "c").write_bytes(b"y" * 20)
    assert tree_bytes(tmp_path) == 120


def test_json_lines_skips_what_is_not_a_json_object() -> None:
    text = '{"message": "ready"}\nINFO: plain text\n{"broken": \n{"message": "shut down"}\n'
    assert json_lines(text) == [{"message": "ready"}, {"message": "shut down"}]


def test_the_deployments_env_and_memory_limit_are_read() -> None:
    env = deployment_env()
    assert env and all(isinstance(v, str) for v in env.values())
    assert "SMM_MAX_IN_FLIGHT" in env
    assert deployment_memory_limit_bytes() >= 2**28  # a quarter GiB at least


def test_a_child_process_is_found_below_its_parent() -> None:
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        assert child.pid in descendants(os.getpid())
    finally:
        child.kill()
        child.wait()


def test_the_flow_kernel_check_reads_each_models_start_up_line(tmp_path: Path) -> None:
    """Passes when every bundled model names what the machine gives an int8 network, fails
    on a model served otherwise or missing."""
    expected = int8_flow_here()
    lines = [
        json.dumps({"message": "model loaded", "model": f"{m}@0123", "flow": expected})
        for m in bundled_models()
    ]
    log = tmp_path / "server.log"
    log.write_text("\n".join(["INFO: started", *lines]))
    passed = Checks()
    check_flow_kernels(log, passed)
    assert passed.failed == []
    other = "onnxruntime" if expected != "onnxruntime" else "compiled int8 layers (AVX2)"
    log.write_text("\n".join([*lines[1:], lines[0].replace(expected, other)]))
    wrong = Checks()
    check_flow_kernels(log, wrong)
    log.write_text("\n".join(lines[1:]))
    check_flow_kernels(log, wrong)
    assert len(wrong.failed) == 2


def test_checks_record_each_outcome_and_go_on() -> None:
    checks = Checks()
    with checks.check("passes") as note:
        note["detail"] = "fine"
    with checks.check("fails"):
        raise AssertionError("wrong")
    assert checks.results == [("passes", True, "fine"), ("fails", False, "AssertionError: wrong")]
    assert checks.failed == ["fails"]


def test_the_report_has_the_committed_schema_and_is_written_only_on_success(
    tmp_path: Path,
) -> None:
    committed = json.loads(FIGURES.read_text())
    figures = {k: v for k, v in committed.items()
               if k not in ("measured_utc", "machine", "timings", "checks")}  # fmt: skip
    passed = Checks()
    with passed.check("Dockerfile builds"):
        pass
    path = tmp_path / "container.json"
    assert finish(passed, figures, {"build_s": 1.0}, 0.0, path) == 0
    record = json.loads(path.read_text())
    assert list(record) == list(committed)
    assert record["checks"] == [{"name": "Dockerfile builds", "ok": True, "detail": ""}]
    assert math.isfinite(record["timings"]["total_s"])
    failed = Checks()
    with failed.check("Dockerfile builds"):
        raise RuntimeError("no")
    elsewhere = tmp_path / "failed.json"
    assert finish(failed, figures, {}, 0.0, elsewhere) == 1
    assert not elsewhere.exists()


def test_the_figures_go_to_docs_container_json_unless_told() -> None:
    assert parse_arguments([]).figures == ROOT / "docs" / "container.json"
    assert parse_arguments(["--figures", "/tmp/x.json"]).figures == Path("/tmp/x.json")
    assert parse_arguments([]).base == "auto"


def test_the_http_checks_pass_against_a_real_server_with_the_containers_settings() -> None:
    checks = Checks()
    figures: dict[str, Any] = {}
    with LocalServer(api_key=API_KEY, max_num_samples=MAX_NUM_SAMPLES) as server:
        request_ids = run_http_checks(server.url, {"X-API-Key": API_KEY}, checks, figures)
        log_path = Path(server._log.name)
        check_access_log(log_path, request_ids, checks)
        assert server.process is not None
        with log_path.open() as log:
            check_graceful_stop("SIGTERM", server.pid, server.process, log, log_path, checks)
    assert checks.failed == [], checks.results
    assert [name for name, _, _ in checks.results][-2:] == [
        "one JSON access-log line per request, none from uvicorn",
        "SIGTERM",
    ]
    assert len(request_ids) == len(set(request_ids)) == 2 + len(bundled_models()) + 2
    assert sorted(figures["first_request_ms"]) == bundled_models()


def test_the_machine_is_named_with_its_generation_as_every_report_names_it() -> None:
    zen4 = Machine("AMD EPYC", 2, "3.11.7", 0.5, generation="family 25 model 17 stepping 1",
                   dot_product="AVX-512 VNNI")  # fmt: skip
    assert machine_words(zen4) == (
        f"AMD EPYC (family 25 model 17 stepping 1, AVX-512 VNNI), 2 cores, {platform.machine()}"
    )
    assert machine_words(Machine("Intel Xeon", 4, "3.11.7", None)).startswith("Intel Xeon, 4 ")
