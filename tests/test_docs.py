"""The user documentation holds together: README.md is a short page whose first code block gives the two
commands that set everything up (one renders the demo, one runs the tests, the one CI runs), and every
relative link in README.md and docs/*.md reaches a file that exists, and a heading of it where the link
names one (anchors as GitHub makes them from headings)."""
from __future__ import annotations

import os
import re

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
README = os.path.join(ROOT, "README.md")
DOCS = os.path.join(ROOT, "docs")
README_MAX_BYTES = 8192
COMMANDS = ("python3 dev.py demo", "python3 dev.py test")

FENCE = re.compile(r"^\s*(```|~~~)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
# [text](target) and ![alt](target), the target up to whitespace or the closing parenthesis (an optional
# "title" may follow); the text may hold one level of brackets (an image inside a link).
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
INLINE_CODE = re.compile(r"`+[^`]*`+")


def markdown_files() -> list[str]:
    pages = sorted(os.path.join(DOCS, name) for name in os.listdir(DOCS) if name.endswith(".md"))
    return [README, *pages]


def prose_lines(path: str) -> list[tuple[int, str]]:
    """(line number, text) of the lines outside fenced code blocks, inline code removed."""
    lines, fenced = [], False
    with open(path, encoding="utf-8") as f:
        for number, line in enumerate(f, 1):
            if FENCE.match(line):
                fenced = not fenced
                continue
            if not fenced:
                lines.append((number, INLINE_CODE.sub("", line)))
    return lines


def code_blocks(path: str) -> list[list[str]]:
    """The lines of each fenced code block, in order."""
    blocks, current = [], None
    with open(path, encoding="utf-8") as f:
        for line in f:
            if FENCE.match(line):
                if current is None:
                    current = []
                else:
                    blocks.append(current)
                    current = None
            elif current is not None:
                current.append(line.rstrip("\n"))
    return blocks


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: the rendered text lower-cased, punctuation dropped (but hyphens and
    underscores), spaces turned into hyphens."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)   # a link's text, not its target
    text = text.replace("`", "").strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: str) -> set[str]:
    """Every heading's anchor in a Markdown file; repeated headings get -1, -2, ... as on GitHub."""
    seen: dict[str, int] = {}
    found = set()
    for _, line in prose_lines(path):
        match = HEADING.match(line)
        if not match:
            continue
        base = slug(match.group(2))
        count = seen.get(base, 0)
        seen[base] = count + 1
        found.add(base if count == 0 else f"{base}-{count}")
    return found


def relative_links(path: str) -> list[tuple[int, str]]:
    """(line number, target) of the links that point inside the repository (no scheme, no mailto)."""
    links = []
    for number, line in prose_lines(path):
        for target in LINK.findall(line):
            if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target):   # https:, mailto:, ...
                continue
            links.append((number, target))
    return links


def broken(path: str) -> list[str]:
    """One message per relative link of `path` whose file, or heading, does not exist."""
    problems = []
    for number, target in relative_links(path):
        file_part, _, anchor = target.partition("#")
        where = os.path.normpath(os.path.join(os.path.dirname(path), file_part)) if file_part else path
        name = f"{os.path.relpath(path, ROOT)}:{number}: {target}"
        if not os.path.exists(where):
            problems.append(f"{name}: no file {os.path.relpath(where, ROOT)}")
        elif anchor and (not where.endswith(".md") or anchor not in anchors(where)):
            problems.append(f"{name}: no heading #{anchor} in {os.path.relpath(where, ROOT)}")
    return problems


@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: os.path.relpath(p, ROOT))
def test_every_relative_link_reaches_a_file_and_heading(path):
    assert broken(path) == []


def test_readme_is_a_short_page():
    size = os.path.getsize(README)
    assert size <= README_MAX_BYTES, f"README.md is {size} bytes; its details belong in docs/"


def test_readme_starts_with_the_two_commands():
    blocks = code_blocks(README)
    assert blocks, "README.md has no code block"
    commands = [line.split("#", 1)[0].strip() for line in blocks[0]]
    assert [c for c in commands if c] == list(COMMANDS)
    first_code_line = next(number for number, line in enumerate(open(README, encoding="utf-8"), 1)
                           if FENCE.match(line))
    assert first_code_line <= 5, "the commands come first, right under the title"


def test_ci_runs_the_readme_test_command():
    with open(os.path.join(ROOT, ".ci", "run"), encoding="utf-8") as f:
        ci = f.read()
    assert re.search(r"dev\.py test\b", ci)


def test_every_docs_page_is_linked_from_the_readme():
    linked = {os.path.normpath(os.path.join(ROOT, target.partition("#")[0]))
              for _, target in relative_links(README)}
    pages = [p for p in markdown_files() if p != README]
    assert [os.path.relpath(p, ROOT) for p in pages if p not in linked] == []


def test_slugs_and_links_are_read_as_github_reads_them():
    assert slug("Render farms (Flamenco and the like)") == "render-farms-flamenco-and-the-like"
    assert slug("What the materials scene's noise is made of") == "what-the-materials-scenes-noise-is-made-of"
    assert slug("`python -m ember` and [Ray](https://docs.ray.io)") == "python--m-ember-and-ray"
    line = "See [a](docs/a.md#x), ![b](docs/b.png \"t\"), [c](https://x.org) and `[d](nowhere.md)`."
    assert LINK.findall(INLINE_CODE.sub("", line)) == ["docs/a.md#x", "docs/b.png", "https://x.org"]
