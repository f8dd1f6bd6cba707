"""The image run as the Kubernetes pod runs it (deploy/base/deployment.yaml): the pod's env,
a read-only root file system and no writable volume, not even /tmp; the checks only that
run can make, and the peak memory against the pod's limit."""

from __future__ import annotations

import json
import os
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import yaml

from service.manifest import MANIFEST_FILE, REPO_MODELS_DIR, Manifest
from service.models.registry import ONNX_FLOW, int8_flow_here
from tools.container_test import ROOT
from tools.container_test.buildah import IMAGE, Buildah, image_config, tail
from tools.container_test.http_checks import post_and_check
from tools.container_test.outcomes import Checks
from tools.container_test.server import (
    json_lines,
    peak_rss_bytes,
    root_mounts,
    server_pid,
    stop,
    wait_ready,
)
from tools.container_test.server_checks import check_graceful_stop
from tools.container_test.targets import TARGETS, bundled_models
from tools.local_server import LOOPBACK, free_port

DEPLOYMENT = ROOT / "deploy" / "base" / "deployment.yaml"

# Run inside the image: import what the server imports and list the modules whose source
# would be compiled at import because no current bytecode lies beside it (the root is
# read-only and PYTHONDONTWRITEBYTECODE is set, so nothing would be written: it would be
# compiled again at every start).
BYTECODE_PROBE = """
import importlib.util, json, os, sys
import service.main, service.api.smm, service.models.registry
def current(spec):
    try:
        with open(spec.cached, "rb") as f:
            head = f.read(16)
        with open(spec.origin, "rb") as f:
            source = f.read()
    except OSError:
        return False
    if head[:4] != importlib.util.MAGIC_NUMBER:
        return False
    if int.from_bytes(head[4:8], "little") & 1:
        return head[8:16] == importlib.util.source_hash(source)
    st = os.stat(spec.origin)
    return (int.from_bytes(head[8:12], "little"), int.from_bytes(head[12:16], "little")) == (
        int(st.st_mtime) & 0xFFFFFFFF, st.st_size & 0xFFFFFFFF)
modules = [m.__spec__ for m in list(sys.modules.values()) if getattr(m, "__spec__", None)]
sources = [s for s in modules if s.origin and s.origin.endswith(".py") and s.cached]
stale = [s.origin for s in sources if not current(s)]
print(json.dumps({"modules": len(sources), "stale": stale}))
"""


# What `buildah run` itself mounts in a container; a pod's runtime mounts its own of these.
RUNTIME_MOUNTS = (
    "/proc",
    "/sys",
    "/dev",
    "/etc/hosts",
    "/etc/hostname",
    "/etc/resolv.conf",
    "/run/.containerenv",
    "/run/secrets",
)


def run_read_only_checks(buildah: Buildah, store: Path, checks: Checks) -> dict[str, Any]:
    """Run the image's CMD on a read-only root file system with the Kubernetes pod's env.

    buildah run has no --read-only: the working container's root (a directory in the vfs
    store) is bind-mounted read-only over itself, so the bind mount of the root that
    `buildah run --isolation chroot` makes is read-only too (it inherits the flag). No
    writable /tmp or other volume is given: what the pod needs writable, this run has not.
    buildah 1.28 exits 2 after the command (a panic as it removes its mount points from the
    read-only root), whatever the command's status: the checks read the command's output.
    """
    figures: dict[str, Any] = {}
    config = image_config(buildah, IMAGE)
    command = [*(config.get("Entrypoint") or []), *(config.get("Cmd") or [])]
    port = free_port()
    container, root = read_only_container(buildah, port)
    url = f"http://{LOOPBACK}:{port}"
    log_path = store / "server-read-only.log"
    try:
        check_read_only_probes(buildah, container, checks)
        with log_path.open("w") as log:
            server = buildah.popen(
                "run", "--isolation", "chroot", container, "--", *command, output=log
            )
            try:
                wait_ready(url, server, log_path)
                check_flow_kernels(log_path, checks)
                pid = server_pid(server.pid)
                figures["read_only_rss_ready_bytes"] = peak_rss_bytes(pid)
                check_read_only_mounts(pid, checks)
                run_read_only_http_checks(url, pid, checks, figures)
                stopping = "read-only root: SIGTERM stops the server gracefully"
                check_graceful_stop(stopping, pid, server, log, log_path, checks)
            finally:
                stop(server)
    finally:
        subprocess.run(["umount", str(root)], check=False)
    if checks.failed:
        print(
            "--- read-only server log (tail) ---\n" + tail(log_path.read_text(errors="replace"), 40)
        )
    return figures


def read_only_container(buildah: Buildah, port: int) -> tuple[str, Path]:
    """A working container of the image with the pod's env, its root bind-mounted read-only
    over itself; (container, its root on the host)."""
    container = buildah("from", "--pull=never", "--name", f"smm-test-ro-{os.getpid()}", IMAGE)
    pod_env = {**deployment_env(), "SMM_PORT": str(port)}
    buildah("config", *[a for k, v in pod_env.items() for a in ("--env", f"{k}={v}")], container)
    root = Path(buildah("mount", container))
    # buildah binds files over /etc/hosts, /etc/resolv.conf, /etc/hostname and
    # /run/.containerenv, creating any that is missing: on a read-only root it cannot, so
    # they are made first (a pod's runtime binds its own over them the same way).
    for mount_point in ("etc/hosts", "etc/resolv.conf", "etc/hostname", "run/.containerenv"):
        (root / mount_point).touch()
    subprocess.run(["mount", "--bind", str(root), str(root)], check=True)
    subprocess.run(["mount", "-o", "remount,bind,ro", str(root)], check=True)
    return container, root


def check_read_only_probes(buildah: Buildah, container: str, checks: Checks) -> None:
    """Commands in the read-only container: a write to / fails even as root, and the
    service's imports find current bytecode in /opt/venv."""
    with checks.check("read-only root: a write to / fails with EROFS, even as root") as note:
        probe = "open('/read-only-probe', 'w')"
        result = buildah.result(
            "run", "--isolation", "chroot", "--user", "0:0", container, "--",
            "python", "-c", probe,
        )  # fmt: skip
        assert "OSError: [Errno 30] Read-only file system" in result.stderr, result.stderr[:500]
        note["detail"] = "OSError: [Errno 30] Read-only file system"

    with checks.check(
        "read-only root: the service's imports find current bytecode in /opt/venv"
    ) as note:
        result = buildah.result(
            "run", "--isolation", "chroot", container, "--", "python", "-c", BYTECODE_PROBE
        )
        assert result.stdout.startswith("{"), result.stderr[:500]
        probe_out = json.loads(result.stdout.strip().splitlines()[-1])
        ours = [p for p in probe_out["stale"] if p.startswith("/opt/venv/")]
        assert not ours, f"{len(ours)} modules compiled at every start: {ours[:5]}"
        note["detail"] = (
            f"{probe_out['modules']} modules from source files; without current bytecode: "
            f"0 in /opt/venv, {len(probe_out['stale'])} of the base's Python"
        )


def check_flow_kernels(log_path: Path, checks: Checks) -> None:
    """Each model's start-up line names what evaluates its flow network: the compiled int8
    layers on the kernel this processor gives them (the container's is this machine's, and
    for AMX the kernel must grant the tiles inside it too), onnxruntime for a float32
    network or on a processor with none of AMX, VNNI and AVX2."""
    int8_flow = int8_flow_here()
    with checks.check(
        "read-only root: int8 flow networks on the compiled layers where AMX, VNNI or AVX2 is"
    ) as note:
        loaded = [
            line
            for line in json_lines(log_path.read_text(errors="replace"))
            if line.get("message") == "model loaded"
        ]
        flows = {str(line["model"]).split("@")[0]: line.get("flow") for line in loaded}
        assert sorted(flows) == bundled_models(), f"loaded {sorted(flows)}"
        for model_id, flow in flows.items():
            manifest = Manifest.model_validate_json(
                (REPO_MODELS_DIR / model_id / MANIFEST_FILE).read_bytes()
            )
            int8 = manifest.defaults.sampler.precision == "int8"
            expected = int8_flow if int8 else ONNX_FLOW
            assert flow == expected, f"{model_id}: {flow!r}, expected {expected!r}"
        note["detail"] = f"int8 on {int8_flow} here: " + ", ".join(
            sorted(f"{m} {f}" for m, f in flows.items())
        )


def check_read_only_mounts(pid: int, checks: Checks) -> None:
    """The server's / is mounted read-only and no other mount of its is writable."""
    with checks.check("read-only root: the server's / is read-only, no writable volume") as note:
        mounts = root_mounts(pid)
        options = dict(mounts)
        assert options["/"].split(",")[0] == "ro", f"/ mounted {options['/']}"
        writable = sorted(
            point
            for point, opts in mounts
            if opts.split(",")[0] == "rw" and not point.startswith(RUNTIME_MOUNTS)
        )
        assert not writable, f"writable mounts: {writable}"
        note["detail"] = f"/ {options['/']}; /tmp not writable either"


def run_read_only_http_checks(url: str, pid: int, checks: Checks, figures: dict[str, Any]) -> None:
    """/readyz, a checked POST /smm per model, and the peak memory at full computation slots."""
    with httpx.Client(base_url=url, timeout=60.0) as client:

        def post(body: dict[str, Any], **kwargs: Any) -> httpx.Response:
            return client.post("/smm", json=body, **kwargs)

        served: dict[str, str] = {}
        with checks.check("read-only root: GET /readyz 200, every bundled model verified") as note:
            readiness = client.get("/readyz").json()
            assert readiness["status"] == "ready", readiness
            served = {m.split("@")[0]: m for m in readiness["models"]}
            assert sorted(served) == bundled_models(), f"served {sorted(served)}"
            note["detail"] = ", ".join(readiness["models"])

        for model_id in bundled_models():
            with checks.check(f"read-only root: POST /smm {model_id}, verified") as note:
                _, note["detail"] = post_and_check(post, model_id, served, {})

        # The pod's memory limit against the worst the settings allow: every computation
        # slot busy with a request of SMM_MAX_NUM_SAMPLES samples of the model with the
        # largest connect stage (iiwa14 position, a 4-D fibre).
        settings_env = deployment_env()
        slots = int(settings_env.get("SMM_MAX_IN_FLIGHT", "2"))
        samples = int(settings_env.get("SMM_MAX_NUM_SAMPLES", "10000"))
        limit = deployment_memory_limit_bytes()
        with checks.check(
            f"read-only root: peak RSS with {slots} x {samples}-sample requests under the "
            "pod's memory limit"
        ) as note:
            body = {**TARGETS["iiwa14-position"]().body, "num_samples": samples}
            with ThreadPoolExecutor(slots) as pool:
                statuses = list(pool.map(lambda _: post(body).status_code, range(slots)))
            assert statuses == [200] * slots, statuses
            peak = peak_rss_bytes(pid)
            figures["read_only_peak_rss_bytes"] = peak
            assert peak < limit, f"peak RSS {peak / 2**20:.0f} MiB, limit {limit / 2**20:.0f} MiB"
            note["detail"] = f"{peak / 2**20:.0f} MiB of {limit / 2**20:.0f} MiB"


def deployment_env() -> dict[str, str]:
    """The literal env of the Kubernetes Deployment's container (deploy/base/deployment.yaml)."""
    documents = yaml.safe_load_all(DEPLOYMENT.read_text())
    deployment = next(d for d in documents if d and d["kind"] == "Deployment")
    [container] = deployment["spec"]["template"]["spec"]["containers"]
    return {e["name"]: str(e["value"]) for e in container.get("env", [])}


def deployment_memory_limit_bytes() -> int:
    documents = yaml.safe_load_all(DEPLOYMENT.read_text())
    deployment = next(d for d in documents if d and d["kind"] == "Deployment")
    [container] = deployment["spec"]["template"]["spec"]["containers"]
    quantity = str(container["resources"]["limits"]["memory"])
    units = {"Ki": 2**10, "Mi": 2**20, "Gi": 2**30}
    return int(quantity[:-2]) * units[quantity[-2:]] if quantity[-2:] in units else int(quantity)
