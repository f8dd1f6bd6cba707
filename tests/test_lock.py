"""One lock for every install: constraints.txt is current, and every install uses it.

The README's two set-up commands (scripts/serve, scripts/test, which `.ci/run` runs) and
the Dockerfile all pass constraints.txt to pip, so the container runs the versions the
tests ran. The file must pin exactly the dependency closure installed here (`python -m
tools.lock` regenerates it), and every pin must satisfy what pyproject.toml asks.
"""

import re
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

from tools import lock

ROOT = Path(__file__).resolve().parent.parent


def setup_commands() -> list[str]:
    """The shell commands of the README's "Set up" section."""
    readme = (ROOT / "README.md").read_text()
    section = readme.split("\n## Set up\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```sh\n(.*?)\n```", section, flags=re.DOTALL)


def test_constraints_pin_exactly_the_installed_closure() -> None:
    stale = lock.differences(lock.read(), lock.closure())
    assert not stale, "constraints.txt is stale; run .venv/bin/python -m tools.lock:\n" + "\n".join(
        stale
    )


def test_every_dependency_is_pinned_within_what_pyproject_asks() -> None:
    pins = lock.read()
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = project["dependencies"] + [
        d for extra in project["optional-dependencies"].values() for d in extra
    ]
    for line in declared:
        requirement = Requirement(line)
        pinned = pins.get(canonicalize_name(requirement.name))
        assert pinned is not None, f"{requirement.name} is not in constraints.txt"
        assert requirement.specifier.contains(pinned, prereleases=True), (line, pinned)


def test_readme_ci_and_dockerfile_install_with_the_constraints() -> None:
    """The README's commands are the two scripts, which .ci/run runs as written; every pip
    install in them and in the Dockerfile passes constraints.txt."""
    assert setup_commands() == ["./scripts/serve", "./scripts/test"], (
        "the README starts with exactly two set-up commands: ./scripts/serve, ./scripts/test"
    )
    serve = (ROOT / "scripts" / "serve").read_text()
    test = (ROOT / "scripts" / "test").read_text()
    for script in (serve, test):
        installs = [line for line in script.splitlines() if "pip install" in line]
        assert installs, script
        for line in installs:
            assert "-c constraints.txt" in line or "checkov-requirements.txt" in line, line
    assert "pip install -q -c constraints.txt -e .\n" in serve
    assert serve.rstrip().endswith("exec .venv/bin/smm-serve")
    assert "pip install -q -c constraints.txt -e '.[train,test]'" in test
    assert lock.no_deps_command() in test, "the --no-deps packages are installed by the tests"
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert "./scripts/test" in ci and any(line.startswith("./scripts/serve ") for line in ci)
    assert "--constraint constraints.txt" in (ROOT / "Dockerfile").read_text()


def test_packages_installed_without_dependencies_left_out_what_they_declare() -> None:
    """eaik's renderer and realtime-smm's misspelt `tdqm` are not installed; they are pinned."""
    pins = lock.read()
    for name, (version, _) in lock.WITHOUT_DEPENDENCIES.items():
        assert pins[canonicalize_name(name)] == version
    for unwanted in ("tdqm", "urchin", "pyglet"):
        with pytest.raises(metadata.PackageNotFoundError):
            metadata.distribution(unwanted)
