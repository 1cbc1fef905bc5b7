"""Every command block of README.md and of the manual runs as written, in order, in one temporary folder that holds
a copy of the repository's `jobs/` and `examples/` (the commands are written for the repository root).

The order: README.md, then every page of `mkdocs.yml`'s nav in nav order (a page may use the files an earlier
page's blocks wrote, so the nav keeps the manual's order of stages). How blocks are read (keep to it when you add
a block):

- A **command block** is an indented (four spaces) or fenced block whose first line starts with `fabline `,
  `python ` or `pip ` (run by bash with `set -e`, line by line; `#` comments are fine), or a fenced block
  opened with ```` ```python ```` (run by python). Every other block (JSON, TOML, output listings) is data.
- `<!-- readme-test: skip REASON -->` on the line just before a block skips it; the reason is required and
  says why it cannot run here (hardware, a server that runs until stopped, the install itself, minutes of CPU).
- `<!-- readme-test: file NAME -->` on the line just before a data block writes the block's text to NAME in
  the folder, so that the commands after it use the manual's own example as input.

Blocks share the folder, so a block may use what an earlier one wrote; each is one test, named by its page and
line (`docs/nesting.md:42`), and a failure shows the command's output.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from fabline.cli import build_parser

REPO = Path(__file__).resolve().parent.parent
COMMAND_START = ("fabline ", "python ", "pip ")
MARKER = re.compile(r"<!--\s*readme-test:\s*(skip|file)\s*(.*?)\s*-->")
TIMEOUT_S = 600


@dataclass
class Block:
    page: str          # "README.md" or "docs/<page>.md"
    line: int
    kind: str          # "shell", "python" or "data"
    text: str
    skip: str | None = None
    file: str | None = None


def readme_blocks(text: str, page: str = "README.md") -> list[Block]:
    """The blocks of one page with what the marker line before each says."""
    lines = text.splitlines()
    blocks, k = [], 0
    while k < len(lines):
        line = lines[k]
        marker = MARKER.search(lines[k - 1]) if k else None
        if line.startswith("```"):
            language = line[3:].strip()
            end = next(j for j in range(k + 1, len(lines)) if lines[j].startswith("```"))
            body = "\n".join(lines[k + 1:end])
            kind = "python" if language == "python" else "shell" if body.lstrip().startswith(COMMAND_START) else "data"
            blocks.append(Block(page, k + 1, kind, body))
            k = end + 1
        elif line.startswith("    ") and (k == 0 or not lines[k - 1].strip() or marker):
            end = k
            while end < len(lines) and (lines[end].startswith("    ") or not lines[end].strip()):
                end += 1
            while not lines[end - 1].strip():
                end -= 1
            body = "\n".join(row[4:] for row in lines[k:end])
            blocks.append(Block(page, k + 1, "shell" if body.startswith(COMMAND_START) else "data", body))
            k = end
        else:
            k += 1
            continue
        if marker:
            what, value = marker.groups()
            if what == "skip":
                blocks[-1].skip = value
            else:
                blocks[-1].file = value
    return blocks


def nav_pages(nav) -> list[str]:
    """The pages of a MkDocs nav (a list of pages, `{title: page}` and `{title: [...]}` sections), in order."""
    pages = []
    for entry in nav:
        for item in (entry.values() if isinstance(entry, dict) else [entry]):
            pages += nav_pages(item) if isinstance(item, list) else [item]
    return pages


def manual() -> list[str]:
    """README.md, then the manual's pages in the nav order of mkdocs.yml (paths from the repository root)."""
    config = yaml.safe_load((REPO / "mkdocs.yml").read_text(encoding="utf-8"))
    docs = config.get("docs_dir", "docs")
    return ["README.md"] + [f"{docs}/{page}" for page in nav_pages(config["nav"]) if not page.startswith("http")]


PAGES = manual()
BLOCKS = [block for page in PAGES for block in readme_blocks((REPO / page).read_text(encoding="utf-8"), page)]
RUN = [b for b in BLOCKS if b.kind != "data" or b.file]


def test_every_page_of_the_manual_is_in_the_nav():
    """A page left out of mkdocs.yml's nav would neither be in the site's menu nor have its blocks run here."""
    docs = {p.relative_to(REPO).as_posix() for p in (REPO / "docs").rglob("*.md")}
    assert docs - set(PAGES) == set(), "pages missing from mkdocs.yml's nav"
    assert len(PAGES) == len(set(PAGES)), "a page listed twice in the nav"


def test_the_readme_command_table_names_every_command():
    """README.md's one table of commands has a row for every `fabline` command and subcommand the parser has."""
    def commands(parser, prefix):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for choice in action._choices_actions:
                    sub = action.choices[choice.dest]
                    inner = list(commands(sub, f"{prefix} {choice.dest}"))
                    yield from inner or [f"{prefix} {choice.dest}"]

    readme = (REPO / "README.md").read_text(encoding="utf-8")
    rows = set(re.findall(r"^\| `(fabline [a-z -]+)` \|", readme, flags=re.M))
    assert set(commands(build_parser(), "fabline")) - rows == set(), "commands missing from README's table"


def test_the_readme_links_into_the_manual_resolve():
    """README.md is not part of the MkDocs site, so `mkdocs build --strict` does not check its links: each names a
    page that exists and, after `#`, one of its headings (slugged as MkDocs and GitHub both do)."""
    def slug(heading: str) -> str:
        return re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", heading).strip().lower())

    broken = []
    for target in re.findall(r"\]\((docs/[^)\s]+)\)", (REPO / "README.md").read_text(encoding="utf-8")):
        path, _, anchor = target.partition("#")
        page = REPO / path
        headings = {slug(h) for h in re.findall(r"^#+ (.*)$", page.read_text(encoding="utf-8"), re.M)} \
            if page.is_file() and path.endswith(".md") else set()
        if not page.is_file() or (anchor and anchor not in headings):
            broken.append(target)
    assert not broken, f"README links that lead nowhere: {broken}"


def test_every_skip_states_a_reason_and_every_file_marker_names_a_file():
    for block in BLOCKS:
        assert block.skip is None or len(block.skip.split()) >= 3, f"{block.page}:{block.line}: skip needs a reason"
        assert block.file is None or block.file.strip(), f"{block.page}:{block.line}: file marker needs a name"
    assert sum(b.kind != "data" and not b.skip for b in BLOCKS) >= 10


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("readme")
    for name in ("jobs", "examples"):
        shutil.copytree(REPO / name, root / name)
    return root


@pytest.mark.parametrize("block", RUN, ids=[f"{b.page}:{b.line}" for b in RUN])
def test_readme_block_runs(block, folder):
    if block.skip:
        pytest.skip(f"{block.page}:{block.line}: {block.skip}")
    if block.file:
        target = folder / block.file
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(block.text + "\n", encoding="utf-8")
        return
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""),
           "PYTHONDONTWRITEBYTECODE": "1"}
    if block.kind == "python":
        command = [sys.executable, "-c", block.text]
    else:
        fabline = shutil.which("fabline") or f"{sys.executable} -m fabline"
        script = f"set -e\nfabline() {{ {fabline} \"$@\"; }}\n{block.text}\n"
        command = ["bash", "-c", script]
    done = subprocess.run(command, cwd=folder, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, (f"{block.page}:{block.line} failed (exit {done.returncode}):\n{block.text}\n"
                                  f"--- stdout\n{done.stdout[-3000:]}\n--- stderr\n{done.stderr[-3000:]}")


def test_readme_blocks_leave_nothing_for_git(folder):
    """Every file the manual's blocks wrote (they ran above, in this folder laid out as the repository) is one that
    .gitignore covers, so running them in a checkout leaves its `git status` clean."""
    shipped = {p.relative_to(REPO).as_posix() for name in ("jobs", "examples") for p in (REPO / name).rglob("*")}
    written = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*")
                     if p.is_file() and p.relative_to(folder).as_posix() not in shipped)
    kept = subprocess.run(["git", "check-ignore", "--no-index", "--verbose", "--non-matching", "--stdin"], cwd=REPO,
                          input="\n".join(written), capture_output=True, text=True).stdout.splitlines()
    unignored = [line.split("\t", 1)[1] for line in kept if line.startswith("::")]
    assert not unignored, f"the manual's blocks write files git would show (add them to .gitignore): {unignored[:20]}"
