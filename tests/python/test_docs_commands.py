"""Every shell command of README.md and docs/**/*.md, read from the Markdown and run, so that the
docs cannot drift from the code; the few that cannot run here are marked in the Markdown and
counted.
The convention and how each command is mapped onto this checkout: support/doc_commands.py. Also:
the README stays a front door, and every relative link of the docs leads to a file."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from support.doc_commands import Ports, blocks, check_build, documents, mapped
from support.paths import REPO_ROOT, router_path
from support.process import Process, free_port, port_accepts, wait_until

COMMAND_TIMEOUT_S = 120
READY_TIMEOUT_S = 30
STREAM_S = 2


def scratch(tmp_path: Path) -> Path:
    """A folder where the docs' repository-relative paths work and whatever they write stays."""
    for folder in ("config", "docker"):
        shutil.copytree(REPO_ROOT / folder, tmp_path / folder)
    (tmp_path / "tests").symlink_to(REPO_ROOT / "tests")
    return tmp_path


@pytest.mark.parametrize("document", documents(), ids=lambda path: path.name)
def test_every_command_of_the_document_runs(document, tmp_path, armtwin_bin):
    workdir = scratch(tmp_path)
    env = dict(os.environ, ARMTWIN_BIN=str(armtwin_bin),
               ARMTWIN_ROUTER=str(router_path(armtwin_bin)), RUST_LOG="armtwin=info")
    ports = Ports(free_port)
    running: dict[str, Process] = {}
    ran = skipped = 0
    try:
        for block in blocks(document):
            where = f"{document.relative_to(REPO_ROOT)}:{block.line}"
            if block.skipped is not None:
                skipped += len(block.commands)
                continue
            # Plain commands in a row run as one script, so that what one sets (`name=g1`)
            # holds for the next, as in a terminal.
            script: list[tuple[str, object]] = []
            for command in block.commands:
                ran += 1
                runs = mapped(command, ports)
                if runs.background or runs.stream or runs.build_check is not None:
                    run_script(script, where, workdir, env)
                    script = []
                    run_one(command, runs, where, workdir, env, running)
                else:
                    script.append((command, runs))
            run_script(script, where, workdir, env)
        for text, process in running.items():
            assert process.running(), f"{text} exited early\n{process.logs()}"
    finally:
        for process in reversed(list(running.values())):
            process.stop()
    print(f"{document.name}: {ran} commands run, {skipped} not run here")


def run_script(script: list[tuple[str, object]], where: str, workdir: Path, env: dict) -> None:
    """Runs plain commands in one bash, stopping at the first that fails."""
    if not script:
        return
    text = "set -e\n" + "\n".join(runs.text for _, runs in script)
    started = time.monotonic()
    result = subprocess.run(["bash", "-c", text], cwd=workdir, env=env, capture_output=True,
                            text=True, timeout=COMMAND_TIMEOUT_S, stdin=subprocess.DEVNULL)
    commands = "\n".join(command for command, _ in script)
    assert result.returncode == 0, (
        f"{where}:\n{commands}\nran as:\n{text}\nexit {result.returncode} after "
        f"{time.monotonic() - started:.1f} s\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}")


def run_one(command: str, runs, where: str, workdir: Path, env: dict, running: dict) -> None:
    context = f"{where}: {command}\nran as: {runs.text}"
    if runs.build_check is not None:
        check_build(runs.build_check)
        return
    if runs.background:
        if runs.text in running and running[runs.text].running():
            return
        name = f"bg{len(running)}"
        process = Process(name, ["bash", "-c", f"exec {runs.text}"], workdir, env).start()
        running[runs.text] = process
        ready = wait_until(lambda: all(port_accepts(port) for port in runs.ports)
                           or not process.running(), READY_TIMEOUT_S)
        if runs.serve:
            ready = ready and process.wait_log("robots claimed", READY_TIMEOUT_S)
        assert ready and process.running(), f"{context}\nnever became ready\n{process.logs()}"
        return
    # A stream (the only other kind) runs until `timeout` ends it (124): it connected and was
    # read for STREAM_S.
    result = subprocess.run(["timeout", str(STREAM_S), "bash", "-c", runs.text], cwd=workdir,
                            env=env, capture_output=True, text=True, timeout=COMMAND_TIMEOUT_S,
                            stdin=subprocess.DEVNULL)
    assert result.returncode in (0, 124), (
        f"{context}\nexit {result.returncode}\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}")


def test_the_readme_is_a_front_door_of_at_most_200_lines():
    readme = (REPO_ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 200
    headings = [line for line in readme.splitlines() if line.startswith("## ")]
    # Prerequisites come before the commands that need them.
    assert headings.index("## Prerequisites") < headings.index("## Two commands")
    assert "## Limitations" in headings
    image = re.search(r"!\[[^\]]*\]\(([^)]+\.png)\)", readme)
    assert image and (REPO_ROOT / image.group(1)).is_file()


def test_every_relative_link_of_the_docs_leads_to_a_file():
    broken = []
    for document in documents():
        text = re.sub(r"```.*?```", "", document.read_text(), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"^(https?:|mailto:|#)", target):
                continue
            path = (document.parent / target.split("#")[0]).resolve()
            if not path.exists():
                broken.append(f"{document.name}: {target}")
    assert not broken, broken
