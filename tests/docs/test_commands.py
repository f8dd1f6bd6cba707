"""Every shell command the README and the docs show is checked: this test runs each one
that no other check covers, as written, and expects it to succeed. It runs them in a copy
of the working tree, with SMM_MODELS_DIR set to the copy's models/, so that a command that
writes (a training writes its model) leaves this checkout as it was; a command that calls
localhost:8000 gets a real server there, and one below a `# in a directory of your own`
comment runs in an empty directory. HTTP calls run in tests/docs/test_examples.py, the two
set-up commands in .ci/run; a command marked `# long job:` or `# not run by the tests:` is
listed with its reason on the development page (the `commands-not-run` block)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tools.docs.commands import Command, commands_in, documented_commands
from tools.docs.pages import ROOT
from tools.local_server import LocalServer

COMMANDS = documented_commands()
RUN = [command for command in COMMANDS if command.kind == "run"]
VENV_BIN = Path(sys.executable).parent


def git_status() -> str:
    return subprocess.run(
        ["git", "status", "--porcelain"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout


SHOWN_HOSTS = ("localhost:8000", "127.0.0.1:8000")


@pytest.fixture(scope="module")
def working_copy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The working tree's files (tracked, and untracked ones git does not ignore), copied,
    with the compiled kernels the README's install builds in place (`pip install -e .`)."""
    names = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.split(b"\0")
    copy = tmp_path_factory.mktemp("working-copy")
    for name in filter(None, names):
        source = ROOT / name.decode()
        if source.is_file():  # not a file deleted from the working tree
            (copy / name.decode()).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, copy / name.decode())
    for built in (ROOT / "service").glob("*/_*.so"):  # pipeline/_native, models/_int8_mlp
        shutil.copy2(built, copy / built.relative_to(ROOT))
    return copy


@pytest.mark.parametrize("command", RUN, ids=[c.text.split("\n")[0][:60] for c in RUN])
def test_a_documented_command_runs_as_written(
    command: Command, request: pytest.FixtureRequest, working_copy: Path, tmp_path: Path
) -> None:
    before = git_status()
    env = {
        **os.environ,
        "PATH": f"{VENV_BIN}{os.pathsep}{os.environ['PATH']}",
        "SMM_MODELS_DIR": str(working_copy / "models"),
    }
    text = command.text.replace(".venv/bin/", f"{VENV_BIN}/")
    if any(host in text for host in SHOWN_HOSTS):
        live: LocalServer = request.getfixturevalue("server")
        for host in SHOWN_HOSTS:
            text = text.replace(host, live.url.removeprefix("http://"))
    result = subprocess.run(
        ["bash", "-c", text],
        cwd=tmp_path if command.elsewhere else working_copy,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, f"{command.page}: {command.text}\n{result.stderr[-3000:]}"
    assert git_status() == before, f"{command.page}: {command.text} changed this checkout"


def test_every_marked_command_gives_its_reason() -> None:
    for command in COMMANDS:
        if command.marker is not None:
            assert len(command.reason or "") >= 10, f"{command.page}: {command.text}"


def test_docker_and_cluster_commands_are_marked() -> None:
    """A command that needs a Docker engine or a cluster cannot run here: it says so."""
    for command in COMMANDS:
        if command.text.startswith(("docker ", "kubectl apply", "kubectl -n")):
            assert command.marker is not None, f"{command.page}: {command.text}"


def test_commands_are_split_and_classified_as_a_reader_reads_them() -> None:
    page = (
        "```sh\n"
        "# long job: about 50 min on 2 cores\n"
        "smm-train --robot r \\\n    --task pose\n"
        "smm-train --robot r --task position\n\n"
        "curl -s localhost:8000/smm -d '{\"a\":\n  1}'\n"
        "./scripts/test\n"
        "python -m tools.docs --check\n\n"
        "# in a directory of your own:\n"
        "openapi-python-client generate --url http://127.0.0.1:8000/openapi.json\n"
        "```\n"
    )
    found = commands_in(page, "p.md")
    assert [c.kind for c in found] == ["long job", "long job", "http", "setup", "run", "run"]
    assert [c.elsewhere for c in found] == [False] * 5 + [True]
    assert found[0].text == "smm-train --robot r \\\n    --task pose"
    assert found[0].reason == "about 50 min on 2 cores"
    assert found[2].text.endswith("1}'")
