"""deploy/: the manifests render, are valid Kubernetes, and the pod is hardened and sized.

- `kubectl kustomize` renders deploy/base and deploy/overlays/example (offline: kustomize is
  built into kubectl). Skipped, saying so, only where kubectl is not installed.
- kubernetes-validate, strict (an unknown or misspelt field fails), validates every
  rendered object against the schema of Kubernetes 1.30 and of the newest version it
  ships. 1.30 is the oldest Kubernetes that serves every field used here by default: the
  preStop `sleep` action (beta and on by default from 1.30). An object with no schema fails.
- The policy, asserted on the rendered overlay itself, so a regression fails even without
  checkov: a non-root pod as the image's USER with a read-only root file system, no
  privilege escalation, every capability dropped, RuntimeDefault seccomp, no service
  account token and no service-link variables; probes on the service's real /readyz and
  /healthz routes and port; Guaranteed CPU and memory with SMM_WORKERS x
  SMM_MAX_IN_FLIGHT, SMM_WORKERS x SMM_ONNX_THREADS and SMM_WORKERS x SMM_BATCH_THREADS
  equal to the CPU limit and the env a valid Settings;
  a grace period longer than preStop + SMM_SHUTDOWN_DRAIN_S; Prometheus annotations on
  the real /metrics; HPA (autoscaling/v2, CPU), PDB, Service and NetworkPolicy aimed at
  the Deployment's pods.
- checkov (its own virtual environment: its pins conflict with the project's, see
  deploy/checkov-requirements.txt) fails no check on the rendered overlay that
  deploy/checkov-skips.yaml does not list with a reason, and every listed skip still
  fails (no stale skips). Skipped, saying how to install it, where it is not installed.
"""

from __future__ import annotations

import functools
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import kubernetes_validate
import pytest
import yaml
from kubernetes_validate.utils import latest_version

from service.config import Settings
from service.http.paths import OPEN_PATHS
from service.main import create_app

ROOT = Path(__file__).resolve().parent.parent
DEPLOY = ROOT / "deploy"
BASE = DEPLOY / "base"
OVERLAY = DEPLOY / "overlays" / "example"
SKIPS = DEPLOY / "checkov-skips.yaml"
CHECKOV_VENV = ROOT / ".venv-checkov"
OLDEST_KUBERNETES = "1.30"
KINDS = {
    "Deployment",
    "Service",
    "HorizontalPodAutoscaler",
    "PodDisruptionBudget",
    "NetworkPolicy",
}

KUBECTL = shutil.which("kubectl")
needs_kubectl = pytest.mark.skipif(
    KUBECTL is None,
    reason="kubectl is not installed: it renders the kustomizations offline "
    "(`kubectl kustomize`); install it (Debian: apt-get install kubectl) to run these checks",
)


@functools.cache
def render_text(path: Path) -> str:
    """`kubectl kustomize path`: the multi-document YAML that `kubectl apply -k` sends."""
    assert KUBECTL is not None
    result = subprocess.run(
        [KUBECTL, "kustomize", str(path)], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, f"kubectl kustomize {path} failed:\n{result.stderr}"
    return result.stdout


def render(path: Path) -> list[dict[str, Any]]:
    return [doc for doc in yaml.safe_load_all(render_text(path)) if doc]


def only(objects: list[dict[str, Any]], kind: str) -> dict[str, Any]:
    found = [o for o in objects if o["kind"] == kind]
    assert len(found) == 1, f"{len(found)} objects of kind {kind}"
    return found[0]


def pod_spec(objects: list[dict[str, Any]]) -> dict[str, Any]:
    spec: dict[str, Any] = only(objects, "Deployment")["spec"]["template"]["spec"]
    return spec


def container(objects: list[dict[str, Any]]) -> dict[str, Any]:
    containers = pod_spec(objects)["containers"]
    assert len(containers) == 1, [c["name"] for c in containers]
    main: dict[str, Any] = containers[0]
    return main


def env(objects: list[dict[str, Any]]) -> dict[str, str]:
    """The container's environment; every entry a literal value (nothing from elsewhere)."""
    entries = container(objects).get("env", [])
    assert all("value" in e for e in entries), [e["name"] for e in entries if "value" not in e]
    return {e["name"]: e["value"] for e in entries}


def settings_of(objects: list[dict[str, Any]], monkeypatch: pytest.MonkeyPatch) -> Settings:
    """The Settings the pod's server builds: the image's ENV, then the pod's env on top."""
    for name in [n for n in os.environ if n.startswith("SMM_")]:
        monkeypatch.delenv(name)
    for name, value in {**image_env(), **env(objects)}.items():
        monkeypatch.setenv(name, value)
    return Settings()


def image_env() -> dict[str, str]:
    """The SMM_ settings of the Dockerfile's final stage (its ENV lines)."""
    final = (ROOT / "Dockerfile").read_text().split("\nFROM ")[-1]
    return dict(re.findall(r"\b(SMM_[A-Z_]+)=(\S+)", final))


def image_uid() -> int:
    final = (ROOT / "Dockerfile").read_text().split("\nFROM ")[-1]
    users = re.findall(r"^USER (\d+)", final, flags=re.MULTILINE)
    assert users, "the Dockerfile's final stage sets no numeric USER"
    return int(users[-1])


def cpu_cores(quantity: str) -> float:
    """A Kubernetes CPU quantity ("2", "1500m") in cores."""
    return int(quantity[:-1]) / 1000 if quantity.endswith("m") else float(quantity)


def served_routes() -> set[str]:
    """The paths the app serves, from its OpenAPI document (included routers flattened)."""
    return set(create_app(Settings()).openapi()["paths"])


# ---------------------------------------------------------------------------- render, validate


@needs_kubectl
@pytest.mark.parametrize("path", [BASE, OVERLAY], ids=["base", "overlay"])
def test_kustomization_renders_the_service_objects(path: Path) -> None:
    objects = render(path)
    kinds = [o["kind"] for o in objects]
    expected = KINDS | ({"Namespace"} if path == OVERLAY else set())
    assert sorted(kinds) == sorted(expected), kinds


@needs_kubectl
def test_overlay_sets_the_namespace_and_the_image() -> None:
    objects = render(OVERLAY)
    namespace = only(objects, "Namespace")["metadata"]["name"]
    namespaced = [o for o in objects if o["kind"] != "Namespace"]
    assert all(o["metadata"].get("namespace") == namespace for o in namespaced)
    labels = only(objects, "Namespace")["metadata"]["labels"]
    assert labels["pod-security.kubernetes.io/enforce"] == "restricted"
    image = container(objects)["image"]
    assert "/" in image and (":" in image.rsplit("/", 1)[1] or "@sha256:" in image), image
    assert not image.endswith(":latest"), image


@needs_kubectl
@pytest.mark.parametrize("version", [OLDEST_KUBERNETES, latest_version()])
@pytest.mark.parametrize("path", [BASE, OVERLAY], ids=["base", "overlay"])
def test_every_object_is_valid_against_the_kubernetes_schema(path: Path, version: str) -> None:
    for obj in render(path):
        name = f"{obj['kind']}/{obj['metadata']['name']}"
        try:
            kubernetes_validate.validate(obj, version, strict=True)
        except kubernetes_validate.ValidationError as error:
            where = ".".join(str(p) for p in error.path)
            pytest.fail(f"{name} is not valid Kubernetes {version}: {where}: {error.message}")
        except kubernetes_validate.SchemaNotFoundError as error:
            pytest.fail(f"{name}: no schema in Kubernetes {version}: {error.message}")


@needs_kubectl
def test_validation_fails_a_misspelt_field() -> None:
    """The check above can fail: strict validation refuses a field Kubernetes does not know."""
    deployment = only(render(OVERLAY), "Deployment")
    deployment["spec"]["template"]["spec"]["containers"][0]["readinessProbes"] = {}
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(deployment, OLDEST_KUBERNETES, strict=True)


# ---------------------------------------------------------------------------- the pod's policy


@needs_kubectl
def test_pod_runs_hardened_as_the_images_user() -> None:
    objects = render(OVERLAY)
    pod = pod_spec(objects)
    pod_security = pod["securityContext"]
    assert pod_security["runAsNonRoot"] is True
    assert pod_security["runAsUser"] == image_uid()
    assert pod_security["seccompProfile"] == {"type": "RuntimeDefault"}
    assert pod["automountServiceAccountToken"] is False
    # A Service named `smm` would inject SMM_PORT=tcp://...: the service's own setting.
    assert pod["enableServiceLinks"] is False
    for shared in ("hostNetwork", "hostPID", "hostIPC"):
        assert not pod.get(shared), shared
    assert all("emptyDir" in volume for volume in pod.get("volumes", []))

    security = container(objects)["securityContext"]
    assert security["readOnlyRootFilesystem"] is True
    assert security["allowPrivilegeEscalation"] is False
    assert security.get("privileged", False) is False
    assert security["capabilities"] == {"drop": ["ALL"]}
    assert security.get("runAsUser", image_uid()) == image_uid()


@needs_kubectl
def test_probes_ask_the_services_own_routes_on_its_port(monkeypatch: pytest.MonkeyPatch) -> None:
    objects = render(OVERLAY)
    main = container(objects)
    ports = {p["name"]: p["containerPort"] for p in main["ports"]}
    assert ports == {"http": settings_of(objects, monkeypatch).port}
    probes = {kind: main[kind]["httpGet"] for kind in ("readinessProbe", "livenessProbe")}
    assert probes["readinessProbe"]["path"] == "/readyz"
    assert probes["livenessProbe"]["path"] == "/healthz"
    assert main["startupProbe"]["httpGet"]["path"] == "/healthz"
    for probe in [*probes.values(), main["startupProbe"]["httpGet"]]:
        assert probe["port"] in ("http", ports["http"])
        # A route the app serves, open without the API key.
        assert probe["path"] in served_routes() and probe["path"] in OPEN_PATHS


@needs_kubectl
def test_threads_match_the_cpu_limit_and_resources_are_guaranteed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    objects = render(OVERLAY)
    resources = container(objects)["resources"]
    assert resources["requests"] == resources["limits"], "Guaranteed QoS: requests = limits"
    cores = cpu_cores(resources["limits"]["cpu"])
    assert cores == int(cores) >= 1, f"{cores} cores: whole cores, one per computation"
    settings = settings_of(objects, monkeypatch)
    # 0 would divide os.cpu_count(): the node's cores in a container, not the limit.
    assert settings.onnx_threads >= 1, "SMM_ONNX_THREADS must be set in a pod"
    assert settings.batch_threads >= 1, "SMM_BATCH_THREADS must be set in a pod"
    # One computation per core for the pipeline's Python; every session's threads on the
    # process's cores, shared by the computations in flight.
    slots = settings.workers * settings.max_in_flight
    assert slots == cores, f"SMM_WORKERS x SMM_MAX_IN_FLIGHT = {slots}, CPU limit {cores}"
    threads = settings.workers * settings.onnx_threads
    assert threads == cores, f"SMM_WORKERS x SMM_ONNX_THREADS = {threads}, CPU limit {cores}"
    batch = settings.workers * settings.batch_threads
    assert batch == cores, f"SMM_WORKERS x SMM_BATCH_THREADS = {batch}, CPU limit {cores}"
    assert env(objects).get("OPENBLAS_NUM_THREADS") == "1"


@needs_kubectl
def test_every_setting_in_the_pod_env_is_a_real_one(monkeypatch: pytest.MonkeyPatch) -> None:
    objects = render(OVERLAY)
    fields = set(Settings.model_fields)
    unknown = [n for n in env(objects) if n.startswith("SMM_") and n[4:].lower() not in fields]
    assert not unknown, f"not settings of service/config.py: {unknown}"
    settings_of(objects, monkeypatch)  # every value valid (pydantic raises otherwise)


@needs_kubectl
def test_grace_period_outlasts_the_drain(monkeypatch: pytest.MonkeyPatch) -> None:
    objects = render(OVERLAY)
    settings = settings_of(objects, monkeypatch)
    pre_stop_s = container(objects)["lifecycle"]["preStop"]["sleep"]["seconds"]
    grace_s = pod_spec(objects)["terminationGracePeriodSeconds"]
    assert settings.shutdown_drain_s > settings.request_deadline_s
    assert grace_s > pre_stop_s + settings.shutdown_drain_s, (
        f"grace {grace_s} s, preStop {pre_stop_s} s + drain {settings.shutdown_drain_s} s"
    )


@needs_kubectl
def test_prometheus_scrapes_the_metrics_route(monkeypatch: pytest.MonkeyPatch) -> None:
    objects = render(OVERLAY)
    annotations = only(objects, "Deployment")["spec"]["template"]["metadata"]["annotations"]
    assert annotations["prometheus.io/scrape"] == "true"
    assert annotations["prometheus.io/path"] == "/metrics"
    assert "/metrics" in served_routes() and "/metrics" in OPEN_PATHS
    assert int(annotations["prometheus.io/port"]) == container(objects)["ports"][0]["containerPort"]
    # /metrics is per process: one process per pod, or a scrape sees one worker of several.
    assert settings_of(objects, monkeypatch).workers == 1


@needs_kubectl
def test_autoscaler_budget_service_and_policy_aim_at_the_pods() -> None:
    objects = render(OVERLAY)
    deployment = only(objects, "Deployment")
    pod_labels = deployment["spec"]["template"]["metadata"]["labels"]
    assert "replicas" not in deployment["spec"], "the autoscaler owns the replica count"

    def selects(selector: dict[str, str]) -> bool:
        return bool(selector) and all(pod_labels.get(k) == v for k, v in selector.items())

    hpa = only(objects, "HorizontalPodAutoscaler")
    assert hpa["apiVersion"] == "autoscaling/v2"
    target = hpa["spec"]["scaleTargetRef"]
    assert (target["kind"], target["name"]) == ("Deployment", deployment["metadata"]["name"])
    [metric] = hpa["spec"]["metrics"]
    assert metric["resource"]["name"] == "cpu"
    assert metric["resource"]["target"]["type"] == "Utilization"
    assert 0 < metric["resource"]["target"]["averageUtilization"] < 100
    assert 2 <= hpa["spec"]["minReplicas"] <= hpa["spec"]["maxReplicas"]

    pdb = only(objects, "PodDisruptionBudget")
    assert selects(pdb["spec"]["selector"]["matchLabels"])
    # A node drain can proceed with the fewest replicas the autoscaler keeps.
    assert pdb["spec"].get("maxUnavailable", 0) >= 1 or (
        pdb["spec"]["minAvailable"] < hpa["spec"]["minReplicas"]
    )

    service = only(objects, "Service")
    assert selects(service["spec"]["selector"])
    assert [p["targetPort"] for p in service["spec"]["ports"]] == ["http"]

    policy = only(objects, "NetworkPolicy")
    assert selects(policy["spec"]["podSelector"]["matchLabels"])
    assert sorted(policy["spec"]["policyTypes"]) == ["Egress", "Ingress"]
    assert policy["spec"]["egress"] == [], "the service calls nothing: no egress"
    port = container(objects)["ports"][0]["containerPort"]
    assert [p["port"] for rule in policy["spec"]["ingress"] for p in rule["ports"]] == [port]


# ---------------------------------------------------------------------------- checkov


def checkov_command() -> list[str] | None:
    for candidate in (
        CHECKOV_VENV / "bin" / "checkov",
        Path(sys.executable).parent / "checkov",
    ):
        if candidate.is_file():
            return [str(candidate)]
    found = shutil.which("checkov")
    return [found] if found else None


def skip_list() -> dict[str, str]:
    """{check id: reason} of deploy/checkov-skips.yaml."""
    skips = yaml.safe_load(SKIPS.read_text())["skips"]
    listed = {s["id"]: str(s.get("reason", "")).strip() for s in skips}
    assert len(listed) == len(skips), "a check is listed twice"
    return listed


def test_every_checkov_skip_has_a_reason() -> None:
    for check, reason in skip_list().items():
        assert re.fullmatch(r"CKV2?_K8S_\d+", check), check
        assert len(reason) > 40, f"{check}: say why it is skipped"


@needs_kubectl
def test_checkov_fails_no_check_that_is_not_listed(tmp_path: Path) -> None:
    command = checkov_command()
    if command is None:
        pytest.skip(
            "checkov is not installed; it lives in its own venv (its pins conflict with "
            "the project's): python3.11 -m venv .venv-checkov && .venv-checkov/bin/pip "
            "install -r deploy/checkov-requirements.txt (.ci/run does this)"
        )
    rendered = tmp_path / "smm-service.yaml"
    rendered.write_text(render_text(OVERLAY))
    result = subprocess.run(
        [
            *command,
            "--file",
            str(rendered),
            "--framework",
            "kubernetes",
            "--output",
            "json",
            "--quiet",
            "--compact",
            "--skip-download",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "BC_SKIP_MAPPING": "TRUE"},
    )
    assert result.returncode in (0, 1), f"checkov exited {result.returncode}:\n{result.stderr}"
    report = json.loads(result.stdout)
    reports = report if isinstance(report, list) else [report]
    failed = {
        check["check_id"]: f"{check['resource']}: {check['check_name']}"
        for r in reports
        for check in r.get("results", {}).get("failed_checks", [])
    }
    passed = sum(r.get("summary", {}).get("passed", 0) for r in reports)
    assert passed > 0, f"checkov passed no check; did it read the file?\n{result.stdout[:500]}"
    skips = skip_list()
    unlisted = {c: what for c, what in failed.items() if c not in skips}
    assert not unlisted, f"checkov failed checks not in {SKIPS.name}: {unlisted}"
    stale = sorted(set(skips) - set(failed))
    assert not stale, f"listed in {SKIPS.name} but no longer failing (remove them): {stale}"
