"""The shell commands of the Markdown documentation, read from the files, and how each is run here.

The convention, for README.md and docs/**/*.md:

* A fenced block whose info string is ``sh`` holds commands: one per line, a line ending in ``\\``,
  a here-document or an open quote continuing it. ``#`` lines are prose.
* A block right after ``<!-- not run here: REASON -->`` is counted as skipped, with its reason
  (a Docker daemon, a real controller, root). Every other ``sh`` block is run.
* Other blocks (``toml``, ``python``, ``json``) are examples, not commands.

How a command runs here (:func:`mapped`): in bash, in a scratch folder holding copies of
``config/`` and ``docker/`` and a link to ``tests/`` (the docs' paths work, nothing is written
into the checkout), with

* ``cargo run --release --``, ``target/release/armtwin`` and a leading ``armtwin`` as the debug
  binary under test (``$ARMTWIN_BIN``), ``target/release/armtwin-router`` and a leading
  ``armtwin-router`` as the router beside it;
* plain commands in a row run as one bash script (``set -e``), so that a variable one sets holds
  for the next, as in a terminal;
* ``cargo build`` checked, not run: each ``-p`` is a workspace package and each feature one of
  its package's (the test command has built the debug binaries);
* every loopback port replaced by a free one, the same number by the same port throughout a
  document; ``serve`` without ``-l`` listening, and ``replay`` without ``-e`` connecting, at the
  replacement of 7447, the built-in default's endpoint; ``replay`` without ``--speed`` at
  ``--max-rate``;
* ``serve``, ``armtwin-router`` and lines ending in ``&`` started in the background, ready once
  the loopback ports on their command line accept (and a ``serve`` has claimed its robots), and
  stopped at the end of the document; an identical one already running is reused; ``curl -N``
  (a stream) read for two seconds.
"""

from __future__ import annotations

import re
import shlex
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from .paths import REPO_ROOT

NOT_RUN = re.compile(r"^<!--\s*not run here:\s*(.+?)\s*-->$")
FENCE = re.compile(r"^```(\S*)\s*$")
DEFAULT_ENDPOINT_PORT = 7447


@dataclass
class Block:
    """One ``sh`` block: where it starts, its commands, and why it is not run (if it is not)."""

    path: Path
    line: int
    commands: list[str]
    skipped: str | None


def documents() -> list[Path]:
    return [REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").rglob("*.md"))]


def blocks(path: Path) -> list[Block]:
    """Every ``sh`` block of the Markdown file, in order."""
    found = []
    lines = path.read_text().splitlines()
    previous = ""
    index = 0
    while index < len(lines):
        fence = FENCE.match(lines[index])
        if not fence:
            if lines[index].strip():
                previous = lines[index].strip()
            index += 1
            continue
        end = index + 1
        while end < len(lines) and lines[end].strip() != "```":
            end += 1
        if fence.group(1) == "sh":
            reason = NOT_RUN.match(previous)
            found.append(Block(path, index + 1, split_commands(lines[index + 1:end]),
                               reason.group(1) if reason else None))
        elif NOT_RUN.match(previous):
            raise AssertionError(f"{path}:{index + 1}: 'not run here' before a {fence.group(1) or 'plain'} block")
        previous = ""
        index = end + 1
    return found


@dataclass
class Paragraph:
    """One prose paragraph: where it starts and its words, normalised."""

    path: Path
    line: int
    words: list[str]


LIST_ITEM = re.compile(r"^\s*(?:[-*+]|\d+\.)\s")
NOT_PROSE = ("|", "#", "<!--", "![")


def paragraphs(path: Path) -> list[Paragraph]:
    """The prose of the Markdown file: runs of text lines between blank lines, each list item a
    paragraph of its own. Fenced blocks (indented ones too), tables, headings, comments and images
    are not prose. Words are compared as read: links by their text, without `` ` ``, ``*`` and
    ``_``, in lower case, whitespace collapsed."""
    found: list[Paragraph] = []
    current: list[str] = []
    start = 0
    in_fence = False

    def close() -> None:
        if current:
            found.append(Paragraph(path, start, _words(" ".join(current))))
            current.clear()

    for number, line in enumerate(path.read_text().splitlines(), 1):
        text = line.strip()
        if text.startswith("```"):
            close()
            in_fence = not in_fence
            continue
        if in_fence or not text or text.startswith(NOT_PROSE):
            close()
            continue
        if LIST_ITEM.match(line):
            close()
        if not current:
            start = number
        current.append(text)
    close()
    return found


def _words(text: str) -> list[str]:
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
    return re.sub(r"[`*_]", "", text).lower().split()


def split_commands(lines: list[str]) -> list[str]:
    """The block's commands: continuation lines, here-documents and open quotes joined."""
    commands: list[str] = []
    current: list[str] = []
    terminator = None
    for line in lines:
        if not current and (not line.strip() or line.lstrip().startswith("#")):
            continue
        current.append(line)
        if terminator is not None:
            if line.strip() != terminator:
                continue
            terminator = None
        else:
            heredoc = re.search(r"<<-?\s*'?\"?(\w+)", line)
            if heredoc:
                terminator = heredoc.group(1)
                continue
        text = "\n".join(current)
        if text.endswith("\\") or not _complete(text):
            continue
        commands.append(text)
        current = []
    if current:
        raise AssertionError(f"an unfinished command: {chr(10).join(current)}")
    return commands


def _complete(text: str) -> bool:
    try:
        shlex.split(text, comments=True)
    except ValueError:
        return False
    return True


@dataclass
class Ports:
    """The documented port numbers of one document, each with the free port it runs on here."""

    free_port: object
    chosen: dict[int, int] = field(default_factory=dict)

    def __call__(self, documented: int) -> int:
        if documented not in self.chosen:
            self.chosen[documented] = self.free_port()
        return self.chosen[documented]


@dataclass
class Mapped:
    """A command as it runs here."""

    text: str
    background: bool = False
    stream: bool = False
    ports: list[int] = field(default_factory=list)
    serve: bool = False
    build_check: list[str] | None = None


BINARY = '"$ARMTWIN_BIN"'
ROUTER = '"$ARMTWIN_ROUTER"'


def mapped(command: str, ports: Ports) -> Mapped:
    """``command`` as the docs test runs it (see the module's doc)."""
    text = command.strip()
    if text.startswith("cargo build"):
        return Mapped(text, build_check=shlex.split(text, comments=True))
    text = text.replace("cargo run --release --", BINARY)
    text = text.replace("target/release/armtwin-router", ROUTER)
    text = text.replace("target/release/armtwin", BINARY)
    text = re.sub(r"(^|&&\s*|\|\s*|;\s*)armtwin-router(?=\s)", lambda m: m.group(1) + ROUTER, text)
    text = re.sub(r"(^|&&\s*|\|\s*|;\s*)armtwin(?=\s)", lambda m: m.group(1) + BINARY, text)
    text = re.sub(r"127\.0\.0\.1:(\d+)", lambda m: f"127.0.0.1:{ports(int(m.group(1)))}", text)
    text = re.sub(r"--rest-http-port (\d+)\b", lambda m: f"--rest-http-port {ports(int(m.group(1)))}", text)
    background = text.endswith("&")
    text = text.rstrip("& ").rstrip()
    words = shlex.split(text.replace(BINARY, "ARMTWIN").replace(ROUTER, "ROUTER"), comments=True)
    default_endpoint = f"tcp/127.0.0.1:{ports(DEFAULT_ENDPOINT_PORT)}"
    serve = words[:2] == ["ARMTWIN", "serve"]
    if serve and not {"-l", "--listen"} & set(words) and not _client(words):
        text += f" -l {default_endpoint}"
    if words[:2] == ["ARMTWIN", "replay"]:
        if not {"-e", "--connect"} & set(words):
            text += f" -e {default_endpoint}"
        if "--speed" not in words and "--max-rate" not in words:
            text += " --max-rate"
    stream = words[:1] == ["curl"] and "-N" in words
    return Mapped(
        text,
        background=background or serve or words[:1] == ["ROUTER"],
        stream=stream,
        ports=sorted({int(port) for port in re.findall(r"127\.0\.0\.1:(\d+)", text)}
                     | {int(port) for port in re.findall(r"--rest-http-port (\d+)", text)}),
        serve=serve,
    )


def _client(words: list[str]) -> bool:
    for flag in ("-m", "--mode"):
        if flag in words and words.index(flag) + 1 < len(words):
            return words[words.index(flag) + 1] == "client"
    return False


def check_build(words: list[str]) -> None:
    """A documented ``cargo build``: its packages are the workspace's and its features theirs."""
    packages = {}
    for manifest in (REPO_ROOT / "crates").glob("*/Cargo.toml"):
        spec = tomllib.loads(manifest.read_text())
        packages[spec["package"]["name"]] = set(spec.get("features", {}))
    named = [value for flag, value in zip(words, words[1:]) if flag in ("-p", "--package")]
    for package in named:
        assert package in packages, f"cargo build -p {package}: no such workspace package"
    for flag, value in zip(words, words[1:]):
        if flag == "--features":
            for feature in value.split(","):
                package, _, name = feature.rpartition("/")
                owners = [package] if package else named
                assert any(name in packages.get(owner, ()) for owner in owners), \
                    f"cargo build --features {feature}: no such feature"
