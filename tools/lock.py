"""constraints.txt: the exact version of every package the project installs.

One lock for every install: the README's two commands and `.ci/run` pass it to pip
(`pip install -c constraints.txt ...`), and so does the Dockerfile, so the container runs
the versions the tests ran. It pins the dependency closure of `smm-service[train,test]`
as installed in this environment (markers evaluated here: Linux, CPython 3.11), nothing
else that happens to be installed. A local version label is dropped (`torch==2.13.0`,
not `2.13.0+cpu`): the pin then matches the CPU wheel and is what pyproject.toml asks.

    .venv/bin/python -m tools.lock           # rewrite constraints.txt from this environment
    .venv/bin/python -m tools.lock --check   # exit 1, listing the differences, if stale

Two evaluation packages declare dependencies the project must not install, so they are
installed by a second pip command with --no-deps (the README's test command and .ci/run)
and pinned here without their declared closure (`WITHOUT_DEPENDENCIES`, with the command
that installs them, in training/evaluate/packages.py): their real dependencies are in the
`train` extra.
"""

from __future__ import annotations

import argparse
import sys
from importlib import metadata
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

from training.evaluate import packages

ROOT = Path(__file__).resolve().parent.parent
CONSTRAINTS = ROOT / "constraints.txt"
PROJECT = "smm-service"
EXTRAS = ("train", "test")
# The --no-deps packages and the command that installs them live with the code that imports
# them (training/evaluate/packages.py), which names the same command when one is missing.
WITHOUT_DEPENDENCIES = packages.WITHOUT_DEPENDENCIES
no_deps_command = packages.no_deps_command

HEADER = """\
# Exact versions of every package smm-service[train,test] installs (its dependency
# closure on Linux, CPython 3.11). Used by the README's install commands, .ci/run and the
# Dockerfile (pip install -c constraints.txt). Regenerate after changing a dependency:
#   .venv/bin/python -m tools.lock
"""


def _requirements(dist: metadata.Distribution, extras: set[str]) -> list[Requirement]:
    """The requirements of `dist` that apply here, with `extras` requested."""
    applying = []
    for line in dist.requires or []:
        requirement = Requirement(line)
        marker = requirement.marker
        if marker is None or any(marker.evaluate({"extra": e}) for e in extras | {""}):
            applying.append(requirement)
    return applying


def closure(project: str = PROJECT, extras: tuple[str, ...] = EXTRAS) -> dict[str, str]:
    """{canonical name: installed version, local label dropped} of what `project` needs."""
    pins: dict[str, str] = {}
    pending = [(project, set(extras))]
    seen: set[tuple[str, frozenset[str]]] = set()
    while pending:
        name, wanted = pending.pop()
        key = (canonicalize_name(name), frozenset(wanted))
        if key in seen:
            continue
        seen.add(key)
        dist = metadata.distribution(name)  # PackageNotFoundError: the install is incomplete
        if canonicalize_name(name) != canonicalize_name(project):
            pins[canonicalize_name(name)] = Version(dist.version).public
        pending += [(r.name, set(r.extras)) for r in _requirements(dist, wanted)]
    for name in WITHOUT_DEPENDENCIES:  # pinned as installed, closure not followed
        pins[canonicalize_name(name)] = Version(metadata.version(name)).public
    return dict(sorted(pins.items()))


def render(pins: dict[str, str]) -> str:
    return HEADER + "".join(f"{name}=={version}\n" for name, version in pins.items())


def read(path: Path = CONSTRAINTS) -> dict[str, str]:
    """{canonical name: version} of a constraints file of `name==version` lines."""
    pins: dict[str, str] = {}
    for line in path.read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            name, _, version = line.partition("==")
            pins[canonicalize_name(name)] = version
    return pins


def differences(locked: dict[str, str], installed: dict[str, str]) -> list[str]:
    """One line per package whose locked and installed versions differ."""
    return [
        f"{name}: locked {locked.get(name, '-')}, installed {installed.get(name, '-')}"
        for name in sorted(locked.keys() | installed.keys())
        if locked.get(name) != installed.get(name)
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare, do not write")
    args = parser.parse_args(argv)
    installed = closure()
    if not args.check:
        CONSTRAINTS.write_text(render(installed))
        print(f"wrote {CONSTRAINTS.name}: {len(installed)} packages")
        return 0
    stale = differences(read(), installed)
    for line in stale:
        print(line)
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
