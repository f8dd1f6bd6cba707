"""The evaluation packages: what they are for, their pins, and the one command that installs them.

Two packages serve the evaluation alone, never training or serving: `eaik` (the Panda's
exact inverse kinematics, the ground truth of training/evaluate/references/panda.py and
so of the judge on the Panda) and `realtime-smm` (Clark and Xie's own code, the report's
Fourier baseline, training/evaluate/baselines/fourier.py). Both declare dependencies the
project must not install, so a second pip command installs them with --no-deps
(`no_deps_command`, which tools/lock.py pins and scripts/test runs); their real
dependencies are in the `train` extra.

`pip install -c constraints.txt -e '.[train]'` alone trains and serves any robot: these
packages are imported only inside the functions that run the Panda's reference or the
Fourier baseline (`requiring`), and a missing one raises `MissingEvaluationPackage`,
whose message names the command.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Iterator
from contextlib import contextmanager

# distribution name -> (version, why its declared dependencies are not installed)
WITHOUT_DEPENDENCIES: dict[str, tuple[str, str]] = {
    # Exact Panda IK, the evaluation's ground truth (training/evaluate/references/panda.py):
    # only eaik.IK_Homogeneous is used, which needs numpy alone; its metadata pulls urchin
    # and a 3-D renderer (pyglet, PyOpenGL, trimesh and 6 more) for a URDF front end the
    # project never imports.
    "eaik": ("1.2.2", "urchin and its renderer, unused"),
    # Clark and Xie's own code, the report's Fourier baseline (baselines/fourier.py): it
    # declares `tdqm`, a misspelling of tqdm that must never be installed; its real
    # dependencies (numpy, scipy, torch, networkx) are in `train`; zarr and platformdirs
    # serve only its own disk cache, which the baseline does not use.
    "realtime-smm": ("0.1.2", "declares tdqm, a misspelling of tqdm"),
}


def no_deps_command() -> str:
    """The pip command that installs WITHOUT_DEPENDENCIES (after the project's)."""
    pins = " ".join(f"{name}=={version}" for name, (version, _) in WITHOUT_DEPENDENCIES.items())
    return f"pip install -c constraints.txt --no-deps {pins}"


def import_name(distribution: str) -> str:
    """The top-level module a distribution of WITHOUT_DEPENDENCIES installs."""
    return distribution.lower().replace("-", "_")


def installed(distribution: str) -> bool:
    """Whether `distribution`'s module can be imported here (found, not imported)."""
    try:
        return importlib.util.find_spec(import_name(distribution)) is not None
    except (ImportError, ValueError):
        return False


class MissingEvaluationPackage(ModuleNotFoundError):
    """An evaluation package is not installed; the message names the install command."""


def missing_message(distribution: str, purpose: str) -> str:
    """Why `purpose` cannot run without `distribution`, and the command that fixes it."""
    if distribution not in WITHOUT_DEPENDENCIES:
        raise ValueError(
            f"{distribution!r} is not an evaluation package; they are "
            f"{sorted(WITHOUT_DEPENDENCIES)}"
        )
    return (
        f"{purpose} needs the evaluation package {distribution} "
        f"{WITHOUT_DEPENDENCIES[distribution][0]}, which is not installed. Training and "
        f"serving do not need it; to run the evaluation, install it with: {no_deps_command()}"
    )


@contextmanager
def requiring(distribution: str, purpose: str) -> Iterator[None]:
    """Around the imports of `distribution`'s modules: its absence raises
    MissingEvaluationPackage naming `purpose` and the install command. A missing module
    other than the package itself (one of its own dependencies) propagates as it is."""
    top = import_name(distribution)
    try:
        yield
    except ModuleNotFoundError as error:
        if error.name is None or error.name.split(".")[0] != top:
            raise
        raise MissingEvaluationPackage(missing_message(distribution, purpose), name=top) from error
