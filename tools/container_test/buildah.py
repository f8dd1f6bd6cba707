"""buildah on a private store, and the base image: the real python:3.11-slim pulled, or a
stand-in made with debootstrap and cached as a tarball."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import tempfile
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any, TextIO

BASE_IMAGE = "docker.io/library/python:3.11-slim"
IMAGE = "localhost/smm-service:container-test"
CACHE_DIR = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "smm-ci"
REGISTRY_PROBE = "https://registry-1.docker.io/v2/"
HOST_CA_BUNDLE = Path("/etc/ssl/certs/ca-certificates.crt")

# The stand-in for python:3.11-slim: Debian bookworm's Python 3.11 with venv and pip, made
# to behave like the real image (python and pip on PATH, pip allowed to install).
DEBIAN_SUITE = "bookworm"
DEBIAN_MIRROR = os.environ.get("SMM_DEBIAN_MIRROR", "http://deb.debian.org/debian")
# python3-dev: CPython's headers, which python:3.11-slim ships (its Python is built from
# source) and the compiled kernels' build needs.
STANDIN_PACKAGES = ("python3", "python3-venv", "python3-pip", "python3-dev", "ca-certificates")
STANDIN_LINKS = {
    "python": "/usr/bin/python3",
    "python3": "/usr/bin/python3",
    "pip": "/usr/bin/pip3",
}
STANDIN_ENV = ("PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin", "LANG=C.UTF-8")


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


def image_config(buildah: Buildah, image: str) -> dict[str, Any]:
    """The image's Docker config: Cmd, Entrypoint, User, Env, Healthcheck."""
    inspected = json.loads(buildah("inspect", "--type", "image", image))
    return dict(inspected["Docker"]["config"])


def buildah_version() -> str:
    output = subprocess.run(["buildah", "--version"], capture_output=True, text=True).stdout
    return output.strip()
