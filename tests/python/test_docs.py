"""The guides say each thing once, and their links land: a prose paragraph shared by two places
of README.md and docs/**/*.md fails (both places named, so one can link to the other), and so
does a relative link to a file or heading that does not exist; docs/configuration.md's table of
sections names every section of config/armtwin.toml. The Markdown reader is
support/doc_commands.py's."""

from __future__ import annotations

import re
import subprocess
from itertools import combinations
from pathlib import Path

from support.doc_commands import Paragraph, documents, paragraphs
from support.paths import REPO_ROOT

# A paragraph shorter than this is a phrase, which two guides may well share.
MIN_WORDS = 20
# Copied text: this many words in a row in both places...
SHARED_RUN_WORDS = 12
# ...or this share of the shorter paragraph's three-word sequences found in the other (a copy
# with a few words changed).
SHARED_TRIGRAMS = 0.5


def shared_run(a: list[str], b: list[str]) -> list[str]:
    """The longest run of words both hold (dynamic programming; paragraphs are short)."""
    best, best_end = 0, 0
    previous = [0] * (len(b) + 1)
    for i in range(1, len(a) + 1):
        row = [0] * (len(b) + 1)
        for j in range(1, len(b) + 1):
            if a[i - 1] == b[j - 1]:
                row[j] = previous[j - 1] + 1
                if row[j] > best:
                    best, best_end = row[j], i
        previous = row
    return a[best_end - best:best_end]


def trigrams(words: list[str]) -> set[tuple[str, ...]]:
    return set(zip(words, words[1:], words[2:]))


def duplicates(found: list[Paragraph], root: Path = REPO_ROOT) -> list[str]:
    """Every pair of prose paragraphs that share a passage, each named by its file and line."""
    prose = [p for p in found if len(p.words) >= MIN_WORDS]
    grams = {id(p): trigrams(p.words) for p in prose}
    reports = []
    for a, b in combinations(prose, 2):
        common = grams[id(a)] & grams[id(b)]
        if not common:
            continue
        share = len(common) / min(len(grams[id(a)]), len(grams[id(b)]))
        run = shared_run(a.words, b.words)
        if len(run) >= SHARED_RUN_WORDS or share >= SHARED_TRIGRAMS:
            where = [f"{p.path.relative_to(root)}:{p.line}" for p in (a, b)]
            reports.append(f"{where[0]} and {where[1]} share a paragraph ({share:.0%} of its "
                           f"three-word sequences; in a row: \"{' '.join(run)}\")")
    return reports


def test_no_two_places_of_the_guides_share_a_paragraph():
    found = [paragraph for document in documents() for paragraph in paragraphs(document)]
    assert len(found) > 100, "the reader found too little prose to judge"
    reports = duplicates(found)
    assert not reports, "say it in one place and link to it there:\n" + "\n".join(reports)


def test_the_duplicate_check_names_both_places_of_a_copied_paragraph(tmp_path):
    # The check itself, on a copy with a few words changed: it must not pass everything.
    text = ("A robot is tracked from its first sample on, if it is configured or covered by the "
            "default section; other robots get a rejection event and nothing else, and their "
            "samples are counted.")
    one, two = tmp_path / "one.md", tmp_path / "two.md"
    one.write_text(f"# One\n\n{text}\n")
    changed = text.replace("counted", "dropped")
    two.write_text(f"# Two\n\nIntro.\n\n{changed}\n\n```sh\n{text}\n```\n")
    found = [p for path in (one, two) for p in paragraphs(path)]
    copied = [p for p in found if len(p.words) >= MIN_WORDS]
    assert [(p.path.name, p.line) for p in copied] == [("one.md", 3), ("two.md", 5)]
    reports = duplicates(copied, root=tmp_path)
    assert len(reports) == 1 and "one.md:3" in reports[0] and "two.md:5" in reports[0]


def slug(heading: str) -> str:
    """A heading's anchor as GitHub makes it: lower case, punctuation dropped, spaces as hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    found: set[str] = set()
    seen: dict[str, int] = {}
    in_fence = False
    for line in path.read_text().splitlines():
        if line.strip().startswith("```"):
            in_fence = not in_fence
            continue
        heading = re.match(r"^#{1,6} (.+)$", line)
        if heading and not in_fence:
            base = slug(heading.group(1))
            count = seen.get(base, 0)
            seen[base] = count + 1
            found.add(base if count == 0 else f"{base}-{count}")
    return found


def markdown_files() -> list[Path]:
    listed = subprocess.run(["git", "ls-files", "*.md"], cwd=REPO_ROOT, capture_output=True,
                            text=True, check=True).stdout.split()
    return [REPO_ROOT / name for name in listed if not name.startswith("vendor/")]


def test_every_relative_link_of_the_markdown_finds_its_file_and_heading():
    # Every Markdown file of the checkout (the benchmark pages beside their benches too).
    files = markdown_files()
    assert REPO_ROOT / "crates" / "armtwin-bench" / "README.md" in files
    broken = []
    for document in files:
        text = re.sub(r"```.*?```", "", document.read_text(), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"^(https?:|mailto:)", target):
                continue
            file_part, _, anchor = target.partition("#")
            linked = (document.parent / file_part).resolve() if file_part else document
            if not linked.exists():
                broken.append(f"{document.relative_to(REPO_ROOT)}: {target} (no such file)")
            elif anchor and linked.suffix == ".md" and anchor not in anchors(linked):
                broken.append(f"{document.relative_to(REPO_ROOT)}: {target} (no such heading)")
    assert not broken, "\n".join(broken)


def top_level_sections(headers: list[str]) -> set[str]:
    """The first key of each TOML table header (`[robots."a/b".sensors]` → `robots`)."""
    return {re.split(r'[.\s]', header.strip().strip('[]').strip(), maxsplit=1)[0] for header in headers}


def test_the_configuration_guide_has_a_row_for_every_section_of_the_built_in_configuration():
    # config/armtwin.toml shows every key the parser reads, commented out where it has no default
    # (the Rust test config::documented_keys holds that); docs/configuration.md's table of sections
    # must name each of its sections. A header is a line of its own, commented or not, a comment
    # after it allowed; prose that starts with a header's name is not one.
    built_in = (REPO_ROOT / "config" / "armtwin.toml").read_text().splitlines()
    headers = [m.group(1) for line in built_in
               if (m := re.match(r"^#?\s*(\[\[?[^\]]+\]\]?)\s*(#.*)?$", line))]
    sections = top_level_sections(headers)
    assert {"zenoh", "robots", "sources", "opcua"} <= sections, sections
    guide = (REPO_ROOT / "docs" / "configuration.md").read_text()
    table = guide.split("## Sections", 1)[1]
    rows = [line.split("|")[1] for line in table.splitlines() if line.startswith("| `[")]
    named = top_level_sections(re.findall(r"`(\[\[?[^`]+\]\]?)`", "".join(rows)))
    assert named == sections, (f"docs/configuration.md's sections table leaves out {sorted(sections - named)} "
                               f"and names {sorted(named - sections)}, which config/armtwin.toml has not")
