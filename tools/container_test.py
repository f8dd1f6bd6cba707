"""The container test: build the Dockerfile with buildah, run the image's own command, check it.

    sudo .venv/bin/python -m tools.container_test        # .ci/run runs this (as root)

What it checks, over HTTP on 127.0.0.1 against the image's CMD (run with
`buildah run --isolation chroot`, which shares the host's network):

- GET /healthz answers 200; GET /readyz answers 200 and lists every model bundled in
  models/, each loaded and verified (sha256 against its manifest) at start-up;
- POST /smm for every bundled model: every returned configuration reaches the target
  within the requested tolerance by a forward kinematics independent of the image (the
  references in training/evaluate/references/: the planar 3R's closed form, the iiwa14's
  DH table, the Panda's URDF read in float64), lies within the joint limits, and the
  configuration the target was made from is close to an answer;
- settings reach the process from the environment (`docker run -e`): SMM_PORT,
  SMM_API_KEY (401 without the key, 200 with it) and SMM_MAX_NUM_SAMPLES (413 beyond);
- one access-log line per request, the service's JSON one, none from uvicorn;
- the image's HEALTHCHECK command exits 0 while the server runs, non-zero once it stopped;
- the server process runs as the image's non-root USER;
- the image holds no torch, no pip, no compiler, no pip or apt download cache, and /app
  holds the models only;
- SIGTERM stops the server gracefully (the app's "shut down" log line);
- then the image once more as the Kubernetes pod runs it (deploy/base/deployment.yaml: its
  env, a read-only root file system and no writable volume, not even /tmp): a write to /
  fails with EROFS even as root; the server's / is mounted read-only; the service's
  imports find current bytecode in /opt/venv (none compiled at each start); /readyz 200
  with every model; a checked POST /smm per model; the peak RSS with every computation
  slot busy at SMM_MAX_NUM_SAMPLES stays under the pod's memory limit; SIGTERM drains.

Figures, printed and written to docs/container.json (docs/deployment.md quotes them): the image
size (and its base's), the cold start (server process start to /readyz answering 200),
the read-only run's RSS (ready, and peak) and the time of each step.

The base image is the real python:3.11-slim when a registry answers; otherwise a stand-in
built with debootstrap from the Debian mirror (bookworm: Python 3.11), cached as a tarball
under ~/.cache/smm-ci so that later runs skip debootstrap. Everything happens in a private
buildah store (vfs driver, chroot isolation) in a temporary directory that is removed at
the end, with the containers and images in it. Needs root, buildah and, for the
stand-in, debootstrap (.ci/run installs both).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import platform
import re
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import httpx
import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from tools.local_server import LOOPBACK, free_port
from training.evaluate.references.iiwa14 import LIMITS_RAD as IIWA14_LIMITS_RAD
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose
from training.evaluate.references.planar3r import planar3r_position
from training.evaluate.references.rotations import rotation_angle_rad
from training.evaluate.references.urdf_chain import read_chain

ROOT = Path(__file__).resolve().parent.parent
FIGURES = ROOT / "docs" / "container.json"
DEPLOYMENT = ROOT / "deploy" / "base" / "deployment.yaml"
BASE_IMAGE = "docker.io/library/python:3.11-slim"
IMAGE = "localhost/smm-service:container-test"
CACHE_DIR = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "smm-ci"
REGISTRY_PROBE = "https://registry-1.docker.io/v2/"
HOST_CA_BUNDLE = Path("/etc/ssl/certs/ca-certificates.crt")

# The stand-in for python:3.11-slim: Debian bookworm's Python 3.11 with venv and pip, made
# to behave like the real image (python and pip on PATH, pip allowed to install).
DEBIAN_SUITE = "bookworm"
DEBIAN_MIRROR = os.environ.get("SMM_DEBIAN_MIRROR", "http://deb.debian.org/debian")
STANDIN_PACKAGES = ("python3", "python3-venv", "python3-pip", "ca-certificates")
STANDIN_LINKS = {
    "python": "/usr/bin/python3",
    "python3": "/usr/bin/python3",
    "pip": "/usr/bin/pip3",
}
STANDIN_ENV = ("PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin", "LANG=C.UTF-8")

# Settings passed to the container as environment variables, and checked.
API_KEY = secrets.token_hex(16)
MAX_NUM_SAMPLES = 2000
STARTUP_TIMEOUT_S = 120.0

# Slack on the tolerance when an answer is checked with the independent FK: the URDF is
# read in float32 by the export, so it agrees with the exact DH table to ~3e-8 m only.
FK_SLACK = 1e-7


# ---------------------------------------------------------------------------- buildah


class Buildah:
    """buildah on a private store: its own root and runroot, the vfs driver."""

    def __init__(self, store: Path) -> None:
        self.prefix = [
            "buildah",
            "--root",
            str(store / "root"),
            "--runroot",
            str(store / "runroot"),
            "--storage-driver",
            "vfs",
        ]

    def __call__(self, *args: str, timeout_s: float = 300.0, log: Path | None = None) -> str:
        """Run `buildah args`; its stdout, stripped. Output goes to `log` when given."""
        command = [*self.prefix, *args]
        if log is None:
            result = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s)
            output, errors = result.stdout, result.stderr
        else:
            with log.open("w") as handle:
                result = subprocess.run(
                    command, stdout=handle, stderr=subprocess.STDOUT, text=True, timeout=timeout_s
                )
            output, errors = "", tail(log.read_text(errors="replace"), 60)
        if result.returncode != 0:
            raise RuntimeError(f"{' '.join(command)} exited {result.returncode}:\n{errors}")
        return output.strip()

    def popen(self, *args: str, output: TextIO) -> subprocess.Popen[bytes]:
        return subprocess.Popen(
            [*self.prefix, *args], stdout=output, stderr=subprocess.STDOUT, start_new_session=True
        )

    def result(self, *args: str, timeout_s: float = 120.0) -> subprocess.CompletedProcess[str]:
        """`buildah args`, whatever its exit status: its status, stdout and stderr."""
        return subprocess.run(
            [*self.prefix, *args], capture_output=True, text=True, timeout=timeout_s
        )

    def status(self, *args: str, timeout_s: float = 60.0) -> int:
        """Exit status of `buildah args` (its output discarded)."""
        return subprocess.run(
            [*self.prefix, *args], capture_output=True, timeout=timeout_s
        ).returncode


def tail(text: str, lines: int) -> str:
    return "\n".join(text.splitlines()[-lines:])


def registry_reachable(timeout_s: float = 5.0) -> bool:
    """True when Docker Hub's registry answers at all (401 without a token counts)."""
    try:
        urllib.request.urlopen(REGISTRY_PROBE, timeout=timeout_s)
    except urllib.error.HTTPError:
        return True
    except OSError:
        return False
    return True


def mounts_under(path: Path) -> list[str]:
    """Mount points at or below `path`, deepest first."""
    prefix = str(path.resolve())
    points = [line.split()[1] for line in Path("/proc/mounts").read_text().splitlines()]
    inside = [p for p in points if p == prefix or p.startswith(prefix + "/")]
    return sorted(inside, key=len, reverse=True)


def remove_tree(path: Path) -> None:
    """rm -r `path`, after unmounting anything left mounted inside it (never through one)."""
    for point in mounts_under(path):
        subprocess.run(["umount", "--lazy", point], check=False)
    if mounts_under(path):
        raise RuntimeError(f"{path}: still has mounts inside, left in place: {mounts_under(path)}")
    shutil.rmtree(path, ignore_errors=True)


def standin_tarball() -> tuple[Path, bool]:
    """The cached debootstrap root file system of the stand-in base; (path, was cached)."""
    recipe = json.dumps([DEBIAN_SUITE, DEBIAN_MIRROR, STANDIN_PACKAGES, STANDIN_LINKS, 1])
    key = hashlib.sha256(recipe.encode()).hexdigest()[:12]
    tarball = CACHE_DIR / f"python3.11-slim-standin-{DEBIAN_SUITE}-{key}.tar"
    if tarball.is_file():
        return tarball, True
    if shutil.which("debootstrap") is None:
        raise RuntimeError("no registry answers and debootstrap is not installed for a stand-in")
    CACHE_DIR.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="standin-", dir=CACHE_DIR))
    try:
        rootfs = work / "rootfs"
        subprocess.run(
            [
                "debootstrap",
                "--variant=minbase",
                f"--include={','.join(STANDIN_PACKAGES)}",
                DEBIAN_SUITE,
                str(rootfs),
                DEBIAN_MIRROR,
            ],
            check=True,
            capture_output=True,
            timeout=900,
        )
        # Like python:3.11-slim: pip may install into the system Python (no PEP 668 marker),
        # python and pip are on PATH in /usr/local/bin, no package lists or .debs are kept.
        (rootfs / "usr/lib/python3.11/EXTERNALLY-MANAGED").unlink(missing_ok=True)
        for name, target in STANDIN_LINKS.items():
            (rootfs / "usr/local/bin" / name).symlink_to(target)
        for cache in ("var/cache/apt/archives", "var/lib/apt/lists"):
            for entry in (rootfs / cache).glob("*"):
                if entry.is_file():
                    entry.unlink()
        partial = tarball.with_suffix(".partial")
        subprocess.run(
            ["tar", "--numeric-owner", "-C", str(rootfs), "-cf", str(partial), "."], check=True
        )
        partial.rename(tarball)
    finally:
        remove_tree(work)
    return tarball, False


def import_standin(buildah: Buildah, tarball: Path) -> None:
    """Commit the stand-in root file system as python:3.11-slim in the private store."""
    container = buildah("from", "scratch")
    root = buildah("mount", container)
    subprocess.run(
        ["tar", "--numeric-owner", "-xpf", str(tarball), "-C", root], check=True, timeout=300
    )
    buildah("umount", container)
    env_args = [arg for pair in STANDIN_ENV for arg in ("--env", pair)]
    buildah("config", *env_args, "--cmd", "python3", container)
    buildah("commit", "--rm", "--format", "docker", container, BASE_IMAGE, timeout_s=600)


def image_size_bytes(buildah: Buildah, image: str) -> int:
    """Uncompressed size of an image: the sum of its layers (uncompressed tars in the store)."""
    inspected = json.loads(buildah("inspect", "--type", "image", image))
    manifest = json.loads(inspected["Manifest"])
    return sum(int(layer["size"]) for layer in manifest["layers"])


# ---------------------------------------------------------------------------- targets


@dataclass(frozen=True)
class Target:
    """A request for one bundled model and how to check its answer independently."""

    body: dict[str, Any]
    q_source: np.ndarray  # the configuration the target was made from
    check: Callable[[np.ndarray], dict[str, float]]  # (B, n) -> largest errors
    within_limits: Callable[[np.ndarray], np.ndarray]  # (B, n) -> (B,)
    distance: Callable[[np.ndarray, np.ndarray], np.ndarray]  # (B, n), (n,) -> (B,) rad


def planar3r_target() -> Target:
    q_source = np.array([0.4, 1.1, -0.7])
    goal = planar3r_position(q_source[None])[0]
    body = {
        "robot": "planar3r",
        "task": "position",
        "target": {"position": goal.tolist()},
        "tolerance": {"position": 1e-6},
        "reference_configuration": q_source.tolist(),
        "seed": 7,
    }
    return Target(
        body=body,
        q_source=q_source,
        check=lambda q: {
            "position": float(np.linalg.norm(planar3r_position(q) - goal, axis=1).max())
        },
        within_limits=lambda q: np.all(np.abs(q) <= np.pi, axis=-1),
        # Every joint is continuous: differences wrap to (-pi, pi].
        distance=lambda q, r: np.linalg.norm(np.angle(np.exp(1j * (q - r))), axis=-1),
    )


def spatial_target(
    robot: str,
    task: str,
    q_source: np.ndarray,  # (n,)
    pose: Callable[[np.ndarray], np.ndarray],  # (B, n) -> (B, 4, 4), the independent FK
    lower_rad: np.ndarray,  # (n,)
    upper_rad: np.ndarray,  # (n,)
) -> Target:
    """A spatial arm's target made from q_source, checked by its independent FK `pose`."""
    goal = pose(q_source[None])[0]  # (4, 4)
    target: dict[str, Any] = {"position": goal[:3, 3].tolist()}
    tolerance = {"position": 1e-6}
    if task == "pose":
        x, y, z, w = Rotation.from_matrix(goal[:3, :3]).as_quat()
        target["orientation"] = {"w": w, "x": x, "y": y, "z": z}
        tolerance["orientation"] = 1e-6

    def check(q: np.ndarray) -> dict[str, float]:
        reached = pose(q)  # (B, 4, 4)
        errors = {"position": float(np.linalg.norm(reached[:, :3, 3] - goal[:3, 3], axis=1).max())}
        if task == "pose":
            goal_rotation = np.broadcast_to(goal[:3, :3], reached[:, :3, :3].shape)
            errors["orientation"] = float(
                rotation_angle_rad(reached[:, :3, :3], goal_rotation).max()
            )
        return errors

    body = {
        "robot": robot,
        "task": task,
        "target": target,
        "tolerance": tolerance,
        "reference_configuration": q_source.tolist(),
        "seed": 7,
    }
    return Target(
        body=body,
        q_source=q_source,
        check=check,
        within_limits=lambda q: np.all(
            (q >= lower_rad - 1e-12) & (q <= upper_rad + 1e-12), axis=-1
        ),
        distance=lambda q, r: np.linalg.norm(q - r, axis=-1),  # limited joints: no wrap
    )


def iiwa14_target(task: str) -> Target:
    """The iiwa14 checked by the paper's DH table (references.iiwa14)."""
    q_source = np.array([0.3, 0.6, 0.0, -1.2, 0.0, 0.9, 0.0])
    return spatial_target(
        "iiwa14", task, q_source, iiwa14_pose, -IIWA14_LIMITS_RAD, IIWA14_LIMITS_RAD
    )


def panda_target(task: str) -> Target:
    """The Panda checked by the float64 URDF chain of the references (not
    pytorch-kinematics, not the served chain.json kernel)."""
    chain = read_chain(ROOT / "models" / "robots" / "panda.urdf", "panda_hand_tcp", "panda_link0")
    q_source = np.array([0.3, -0.4, 0.2, -2.0, 0.1, 1.8, 0.5])
    return spatial_target("panda", task, q_source, chain.pose, chain.lower, chain.upper)


# Every bundled model needs an entry here: a model without an independent check fails.
TARGETS: dict[str, Callable[[], Target]] = {
    "planar3r-position": planar3r_target,
    "iiwa14-pose": lambda: iiwa14_target("pose"),
    "iiwa14-position": lambda: iiwa14_target("position"),
    "panda-pose": lambda: panda_target("pose"),
    "panda-position": lambda: panda_target("position"),
}
# How close (joint-space norm, rad) some answer must come to the source configuration.
# The 4-D position SMM is sampled sparsely at 1000 samples: a looser bound.
NEAREST_BOUND_RAD = {
    "planar3r-position": 0.3,
    "iiwa14-pose": 0.3,
    "iiwa14-position": 1.5,
    "panda-pose": 0.3,
    "panda-position": 1.5,
}


def bundled_models() -> list[str]:
    return sorted(p.parent.name for p in (ROOT / "models").glob("*/manifest.json"))


# ---------------------------------------------------------------------------- checks


@dataclass
class Checks:
    """Each check's outcome, in order; a failing check is recorded and the run goes on."""

    results: list[tuple[str, bool, str]] = field(default_factory=list)

    @contextlib.contextmanager
    def check(self, name: str) -> Iterator[dict[str, str]]:
        note: dict[str, str] = {}
        try:
            yield note
        except Exception as error:  # a failed check, whatever raised it
            self.results.append((name, False, f"{type(error).__name__}: {error}"))
            print(f"FAIL {name}: {type(error).__name__}: {error}", flush=True)
        else:
            self.results.append((name, True, note.get("detail", "")))
            print(
                f"ok   {name}" + (f": {note['detail']}" if note.get("detail") else ""), flush=True
            )

    @property
    def failed(self) -> list[str]:
        return [name for name, ok, _ in self.results if not ok]


def descendants(pid: int) -> list[int]:
    """Every process below `pid`, from /proc."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError):
            fields = stat.read_text().rsplit(")", 1)[1].split()
            children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, pending = [], [pid]
    while pending:
        for child in children.get(pending.pop(), []):
            found.append(child)
            pending.append(child)
    return found


def command_line(pid: int) -> list[str]:
    with contextlib.suppress(OSError):
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
    return []


def server_pid(buildah_pid: int) -> int:
    """The Python process running smm-serve below `buildah run` (a host pid)."""
    for pid in descendants(buildah_pid):
        argv = command_line(pid)
        if Path(argv[0]).name.startswith("python") and any("smm-serve" in a for a in argv):
            return pid
    raise RuntimeError("no smm-serve process under buildah run")


def process_start_boottime_s(pid: int) -> float:
    """When a process started, in seconds on CLOCK_BOOTTIME (from /proc/<pid>/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[19]) / os.sysconf("SC_CLK_TCK")


def uids(pid: int) -> list[int]:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("Uid:"):
            return [int(u) for u in line.split()[1:]]
    raise RuntimeError(f"no Uid line for pid {pid}")


def gids(pid: int) -> list[int]:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("Gid:"):
            return [int(g) for g in line.split()[1:]]
    raise RuntimeError(f"no Gid line for pid {pid}")


def image_config(buildah: Buildah, image: str) -> dict[str, Any]:
    """The image's Docker config: Cmd, Entrypoint, User, Env, Healthcheck."""
    inspected = json.loads(buildah("inspect", "--type", "image", image))
    return dict(inspected["Docker"]["config"])


def check_answer(model_id: str, target: Target, answer: dict[str, Any]) -> str:
    """Raise unless every configuration of `answer` is exact and within the limits."""
    assert answer["status"] == "ok", f"status {answer['status']}"
    configurations = [q for c in answer["components"] for q in c["configurations"]]
    q = np.array(configurations, dtype=float).reshape(len(configurations), -1)
    counts = answer["counts"]
    assert len(q) == counts["accepted"] > 0, f"{len(q)} configurations, counts {counts}"
    assert sum(c["size"] for c in answer["components"]) == counts["accepted"]
    errors = target.check(q)
    for kind, error in errors.items():
        bound = target.body["tolerance"][kind] + FK_SLACK
        assert error <= bound, f"{kind} error {error:.3g} > {bound:.3g} by the independent FK"
    assert np.all(target.within_limits(q)), "a configuration outside the joint limits"
    nearest = float(target.distance(q, target.q_source).min())
    assert nearest <= NEAREST_BOUND_RAD[model_id], f"nearest answer {nearest:.3f} rad away"
    worst = ", ".join(f"max {k} error {v:.1e}" for k, v in errors.items())
    return (
        f"{len(answer['components'])} components, {len(q)} configurations, {worst}, "
        f"nearest to the source {nearest:.3f} rad"
    )


def scan_image(root: Path) -> dict[str, list[str]]:
    """What the image must not hold, found by walking its root file system."""
    found: dict[str, list[str]] = {"torch": [], "pip": [], "compilers": [], "caches": []}
    for directory, subdirs, files in os.walk(root):
        relative = "/" + str(Path(directory).relative_to(root)).lstrip(".")
        packages = relative.endswith(("/site-packages", "/dist-packages"))
        for name in subdirs + files:
            # A distribution, not a vendored shim such as scipy's array_api_compat/torch.
            if re.fullmatch(r"(torch|pytorch_kinematics)(-.*\.dist-info)?", name) and packages:
                found["torch"].append(f"{relative}/{name}")
        if relative.startswith("/opt/venv") and ("pip" in subdirs or "pip" in files):
            found["pip"].append(f"{relative}/pip")
        if relative.endswith("/.cache") and (subdirs or files):
            found["caches"].append(relative)
    for compiler in ("gcc", "cc", "g++", "c++", "clang", "make"):
        for bin_dir in ("usr/bin", "usr/local/bin", "opt/venv/bin"):
            if (root / bin_dir / compiler).exists():
                found["compilers"].append(f"/{bin_dir}/{compiler}")
    for cache in ("root/.cache/pip", "var/cache/apt/archives/partial"):
        if (root / cache).is_dir() and any((root / cache).iterdir()):
            found["caches"].append(f"/{cache}")
    return found


def baked_model_differences(baked: Path) -> list[str]:
    """Files of the repository's models/ missing from `baked` or different there."""
    differing = []
    for path in sorted((ROOT / "models").rglob("*")):
        # What .dockerignore keeps out of the build context is not expected in the image.
        ignored = "__pycache__" in path.parts or path.suffix in (".pyc", ".pt", ".npz")
        if path.is_file() and not ignored:
            copy = baked / path.relative_to(ROOT / "models")
            if not copy.is_file() or copy.read_bytes() != path.read_bytes():
                differing.append(str(path.relative_to(ROOT)))
    return differing


def tree_bytes(root: Path) -> int:
    """Bytes of the regular files under `root` (each counted once)."""
    seen: set[tuple[int, int]] = set()
    total = 0
    for directory, _, files in os.walk(root):
        for name in files:
            info = os.lstat(os.path.join(directory, name))
            if (info.st_dev, info.st_ino) not in seen:
                seen.add((info.st_dev, info.st_ino))
                total += info.st_size
    return total


# ---------------------------------------------------------------------------- the run


def run_container_checks(buildah: Buildah, store: Path, checks: Checks) -> dict[str, Any]:
    """Start the image's CMD in a working container and check it; the measured figures."""
    figures: dict[str, Any] = {}
    config = image_config(buildah, IMAGE)
    command = [*(config.get("Entrypoint") or []), *(config.get("Cmd") or [])]
    healthcheck = (config.get("Healthcheck") or {}).get("Test") or []
    figures["cmd"] = command
    container = buildah("from", "--pull=never", "--name", f"smm-test-{os.getpid()}", IMAGE)
    port = free_port()
    buildah(
        "config",
        "--env",
        f"SMM_PORT={port}",
        "--env",
        f"SMM_API_KEY={API_KEY}",
        "--env",
        f"SMM_MAX_NUM_SAMPLES={MAX_NUM_SAMPLES}",
        container,
    )
    root = Path(buildah("mount", container))
    with checks.check(
        "image holds no torch, pip, compiler or cache; /app holds the repo's models only"
    ) as note:
        found = scan_image(root)
        assert not any(found.values()), found
        app = sorted(p.name for p in (root / "app").iterdir())
        assert app == ["models"], f"/app holds {app}"
        differing = baked_model_differences(root / "app" / "models")
        assert not differing, f"/app/models differs from models/: {differing}"
        note["detail"] = f"{sum(1 for _ in root.rglob('*'))} files scanned"
    figures["rootfs_bytes"] = tree_bytes(root)

    url = f"http://{LOOPBACK}:{port}"
    log_path = store / "server.log"
    key = {"X-API-Key": API_KEY}
    with log_path.open("w") as log:
        started_s = time.monotonic()
        server = buildah.popen(
            "run", "--isolation", "chroot", container, "--", *command, output=log
        )
        try:
            ready_s = wait_ready(url, server, log_path)
            figures["run_to_ready_s"] = round(ready_s - started_s, 2)
            ready_boottime_s = time.clock_gettime(time.CLOCK_BOOTTIME)
            pid = server_pid(server.pid)
            figures["cold_start_s"] = round(ready_boottime_s - process_start_boottime_s(pid), 2)
            request_ids = run_http_checks(url, key, checks, figures)

            with checks.check("server process runs as the image's non-root USER") as note:
                ids = uids(pid)
                assert all(u != 0 for u in ids), f"uids {ids}"
                user, _, group = str(config.get("User")).partition(":")
                assert str(ids[0]) == user, f"uid {ids[0]}, USER {config.get('User')}"
                assert not group or str(gids(pid)[0]) == group, f"gid {gids(pid)}, USER {user}"
                note["detail"] = (
                    f"pid {pid} (on the host), uid {ids[0]}, gid {gids(pid)[0]}, command {command}"
                )

            with checks.check("HEALTHCHECK command exits 0 while the server runs") as note:
                assert healthcheck[:1] == ["CMD"], f"HEALTHCHECK {healthcheck}"
                status = buildah.status(
                    "run", "--isolation", "chroot", container, "--", *healthcheck[1:]
                )
                assert status == 0, f"exit status {status}"
                note["detail"] = " ".join(healthcheck[1:])

            with checks.check("SIGTERM stops the server gracefully") as note:
                os.kill(pid, signal.SIGTERM)
                code = server.wait(timeout=60)
                log.flush()
                lines = json_lines(log_path.read_text(errors="replace"))
                assert any(line.get("message") == "shut down" for line in lines), (
                    "no shut down line"
                )
                note["detail"] = f"buildah run exited {code}"

            with checks.check("one JSON access-log line per request, none from uvicorn") as note:
                text = log_path.read_text(errors="replace")
                access = [line for line in json_lines(text) if line.get("message") == "request"]
                logged = [line["request_id"] for line in access]
                uvicorn_access = re.findall(r'"(?:GET|POST) \S+ HTTP/1\.1" \d{3}', text)
                assert not uvicorn_access, f"uvicorn access lines: {uvicorn_access[:3]}"
                twice_or_never = [i for i in request_ids if logged.count(i) != 1]
                assert not twice_or_never, f"request ids not logged exactly once: {twice_or_never}"
                note["detail"] = (
                    f"{len(request_ids)} requests, each logged once under its X-Request-ID; "
                    "0 uvicorn lines"
                )

            with checks.check("HEALTHCHECK command fails once the server stopped") as note:
                status = buildah.status(
                    "run", "--isolation", "chroot", container, "--", *healthcheck[1:]
                )
                assert status != 0, "exit status 0 with no server"
                note["detail"] = f"exit status {status}"
        finally:
            stop(server)
    if checks.failed:
        print("--- server log (tail) ---\n" + tail(log_path.read_text(errors="replace"), 40))
    return figures


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


def root_mounts(pid: int) -> list[tuple[str, str]]:
    """(mount point, per-mount options) of every mount a process sees, from its mountinfo."""
    lines = Path(f"/proc/{pid}/mountinfo").read_text().splitlines()
    return [(line.split()[4], line.split()[5]) for line in lines]


def peak_rss_bytes(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise RuntimeError(f"no VmHWM line for pid {pid}")


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
    container = buildah("from", "--pull=never", "--name", f"smm-test-ro-{os.getpid()}", IMAGE)
    port = free_port()
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
    url = f"http://{LOOPBACK}:{port}"
    log_path = store / "server-read-only.log"
    try:
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

        with log_path.open("w") as log:
            server = buildah.popen(
                "run", "--isolation", "chroot", container, "--", *command, output=log
            )
            try:
                wait_ready(url, server, log_path)
                pid = server_pid(server.pid)
                figures["read_only_rss_ready_bytes"] = peak_rss_bytes(pid)
                with checks.check(
                    "read-only root: the server's / is read-only, no writable volume"
                ) as note:
                    mounts = root_mounts(pid)
                    options = dict(mounts)
                    assert options["/"].split(",")[0] == "ro", f"/ mounted {options['/']}"
                    runtime = RUNTIME_MOUNTS
                    writable = sorted(
                        point
                        for point, opts in mounts
                        if opts.split(",")[0] == "rw" and not point.startswith(runtime)
                    )
                    assert not writable, f"writable mounts: {writable}"
                    note["detail"] = f"/ {options['/']}; /tmp not writable either"
                run_read_only_http_checks(url, pid, checks, figures)

                with checks.check("read-only root: SIGTERM stops the server gracefully") as note:
                    os.kill(pid, signal.SIGTERM)
                    code = server.wait(timeout=60)
                    log.flush()
                    lines = json_lines(log_path.read_text(errors="replace"))
                    assert any(line.get("message") == "shut down" for line in lines)
                    note["detail"] = f"buildah run exited {code}"
            finally:
                stop(server)
    finally:
        subprocess.run(["umount", str(root)], check=False)
    if checks.failed:
        print(
            "--- read-only server log (tail) ---\n" + tail(log_path.read_text(errors="replace"), 40)
        )
    return figures


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


def json_lines(text: str) -> list[dict[str, Any]]:
    lines = []
    for line in text.splitlines():
        with contextlib.suppress(json.JSONDecodeError):
            if line.startswith("{"):
                lines.append(json.loads(line))
    return lines


def wait_ready(url: str, server: subprocess.Popen[bytes], log_path: Path) -> float:
    """Poll /readyz until it answers 200; the monotonic time it did."""
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise RuntimeError(
                f"container exited {server.returncode} before ready:\n"
                + tail(log_path.read_text(errors="replace"), 40)
            )
        with contextlib.suppress(httpx.TransportError):
            if httpx.get(f"{url}/readyz", timeout=1.0).status_code == 200:
                return time.monotonic()
        time.sleep(0.02)
    raise RuntimeError(f"/readyz not 200 within {STARTUP_TIMEOUT_S} s")


def run_http_checks(
    url: str, key: dict[str, str], checks: Checks, figures: dict[str, Any]
) -> list[str]:
    """The HTTP checks against a running server; the request ids of their requests."""
    request_ids: list[str] = []
    with httpx.Client(base_url=url, timeout=60.0) as client:

        def get(path: str, **kwargs: Any) -> httpx.Response:
            response = client.get(path, **kwargs)
            request_ids.append(response.headers.get("x-request-id", "missing"))
            return response

        def post(body: dict[str, Any], **kwargs: Any) -> httpx.Response:
            response = client.post("/smm", json=body, **kwargs)
            request_ids.append(response.headers.get("x-request-id", "missing"))
            return response

        with checks.check("GET /healthz answers 200") as note:
            response = get("/healthz")
            assert response.status_code == 200, response.text
            note["detail"] = response.text

        served: dict[str, str] = {}
        with checks.check("GET /readyz answers 200 with every bundled model verified") as note:
            response = get("/readyz")
            assert response.status_code == 200, response.text
            readiness = response.json()
            served = {m.split("@")[0]: m for m in readiness["models"]}
            assert sorted(served) == bundled_models(), f"served {sorted(served)}"
            assert readiness["failed"] == [], readiness["failed"]
            note["detail"] = ", ".join(readiness["models"])

        for model_id in bundled_models():
            with checks.check(
                f"POST /smm {model_id}: answers verified by an independent FK"
            ) as note:
                elapsed_ms, note["detail"] = post_and_check(post, model_id, served, key)
                figures.setdefault("first_request_ms", {})[model_id] = round(elapsed_ms)

        with checks.check("SMM_API_KEY from the environment: 401 without the key") as note:
            response = post(TARGETS["planar3r-position"]().body)
            assert response.status_code == 401, response.status_code
            note["detail"] = response.json()["detail"]

        with checks.check("SMM_MAX_NUM_SAMPLES from the environment: 413 beyond it") as note:
            body = {**TARGETS["planar3r-position"]().body, "num_samples": MAX_NUM_SAMPLES + 1}
            response = post(body, headers=key)
            assert response.status_code == 413, response.status_code
            note["detail"] = str(response.json()["detail"])[:120]
    return request_ids


def post_and_check(
    post: Callable[..., httpx.Response],
    model_id: str,
    served: dict[str, str],
    headers: dict[str, str],
) -> tuple[float, str]:
    """POST /smm for a bundled model and check the answer by its independent FK; (ms, detail)."""
    assert model_id in TARGETS, f"no independent check for bundled model {model_id}"
    target = TARGETS[model_id]()
    started = time.perf_counter()
    response = post(target.body, headers=headers)
    elapsed_ms = (time.perf_counter() - started) * 1e3
    assert response.status_code == 200, f"{response.status_code} {response.text[:300]}"
    answer = response.json()
    assert answer["model"] == served.get(model_id), answer["model"]
    return elapsed_ms, check_answer(model_id, target, answer) + f", {elapsed_ms:.0f} ms"


def stop(server: subprocess.Popen[bytes]) -> None:
    """Make sure the container process and buildah run are gone."""
    if server.poll() is None:
        for pid in reversed(descendants(server.pid)):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        server.kill()
        server.wait(timeout=30)


def buildah_version() -> str:
    output = subprocess.run(["buildah", "--version"], capture_output=True, text=True).stdout
    return output.strip()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--base",
        choices=("auto", "registry", "standin"),
        default="auto",
        help="the python:3.11-slim to build on: pulled (registry), the debootstrap stand-in, "
        "or the first that works (auto, the default)",
    )
    parser.add_argument(
        "--figures", type=Path, default=FIGURES, help="where to write the measured figures"
    )
    args = parser.parse_args(argv)
    if shutil.which("buildah") is None:
        print("container test: buildah is not installed (apt-get install buildah)")
        return 2
    if os.geteuid() != 0:
        print("container test: needs root (buildah with the vfs driver and chroot isolation)")
        return 2

    checks = Checks()
    figures: dict[str, Any] = {"buildah": buildah_version()}
    timings: dict[str, float] = {}
    started = time.monotonic()
    store = Path(tempfile.mkdtemp(prefix="smm-buildah-"))
    buildah = Buildah(store)
    try:
        step = time.monotonic()
        use_registry = args.base == "registry" or (args.base == "auto" and registry_reachable())
        if use_registry:
            buildah("pull", BASE_IMAGE, timeout_s=600)
            figures["base"] = f"{BASE_IMAGE} (pulled)"
        else:
            tarball, cached = standin_tarball()
            timings["debootstrap_s" if not cached else "standin_cached_s"] = round(
                time.monotonic() - step, 1
            )
            import_standin(buildah, tarball)
            figures["base"] = (
                f"stand-in for python:3.11-slim: debootstrap --variant=minbase {DEBIAN_SUITE} "
                f"+ {', '.join(STANDIN_PACKAGES)} (no registry reachable)"
            )
        timings["base_s"] = round(time.monotonic() - step, 1)
        print(f"base: {figures['base']} ({timings['base_s']} s)", flush=True)

        step = time.monotonic()
        build_args = ["bud", "--isolation", "chroot", "--pull=never", "--format", "docker"]
        if HOST_CA_BUNDLE.is_file():  # RUN steps reach PyPI through the host's trust store
            build_args += ["--volume", f"{HOST_CA_BUNDLE}:{HOST_CA_BUNDLE}:ro"]
        build_log = store / "build.log"
        with checks.check("Dockerfile builds") as note:
            buildah(
                *build_args,
                "--tag",
                IMAGE,
                "--file",
                str(ROOT / "Dockerfile"),
                str(ROOT),
                timeout_s=900,
                log=build_log,
            )
            note["detail"] = f"{time.monotonic() - step:.0f} s"
        timings["build_s"] = round(time.monotonic() - step, 1)
        if not checks.failed:
            figures["image_bytes"] = image_size_bytes(buildah, IMAGE)
            figures["base_bytes"] = image_size_bytes(buildah, BASE_IMAGE)
            figures["added_bytes"] = figures["image_bytes"] - figures["base_bytes"]
            step = time.monotonic()
            figures.update(run_container_checks(buildah, store, checks))
            timings["run_and_checks_s"] = round(time.monotonic() - step, 1)
            step = time.monotonic()
            figures.update(run_read_only_checks(buildah, store, checks))
            timings["read_only_run_s"] = round(time.monotonic() - step, 1)
    except Exception as error:  # a step that is not a check: the test fails, cleanly
        checks.results.append(("container test ran to the end", False, str(error)))
        print(f"FAIL {error}", flush=True)
    finally:
        step = time.monotonic()
        buildah.status("rm", "--all")
        buildah.status("rmi", "--all", "--force", timeout_s=300)
        remove_tree(store)
        timings["cleanup_s"] = round(time.monotonic() - step, 1)
    return finish(checks, figures, timings, started, args.figures)


def finish(
    checks: Checks,
    figures: dict[str, Any],
    timings: dict[str, float],
    started: float,
    path: Path,
) -> int:
    """Print the figures, write them to `path` when every check passed; the exit status."""
    timings["total_s"] = round(time.monotonic() - started, 1)
    record = {
        "measured_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "machine": f"{os.cpu_count()} cores, {platform.machine()}",
        **figures,
        "timings": timings,
        "checks": [{"name": n, "ok": ok, "detail": d} for n, ok, d in checks.results],
    }
    mib = 1024 * 1024
    if "image_bytes" in figures:
        print(
            f"image: {figures['image_bytes'] / mib:.0f} MiB (base {figures['base_bytes'] / mib:.0f}"
            f" MiB + {figures['added_bytes'] / mib:.0f} MiB of ours)"
        )
    if "cold_start_s" in figures:
        print(
            f"cold start: {figures['cold_start_s']} s from process start to /readyz 200 "
            f"({figures['run_to_ready_s']} s from `buildah run`)"
        )
    print("timings: " + ", ".join(f"{k} {v}" for k, v in timings.items()))
    failed = checks.failed
    if failed:
        print(f"container test FAILED: {len(failed)} of {len(checks.results)} checks: {failed}")
        return 1
    path.write_text(json.dumps(record, indent=2) + "\n")
    print(f"container test passed: {len(checks.results)} checks; figures in {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
