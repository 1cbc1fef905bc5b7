"""Every command block of README.md runs as written, in order, in one temporary folder that holds a copy of the
repository's `jobs/` and `examples/` (the README's commands are written for the repository root).

How README blocks are read (keep to it when you add a block):

- A **command block** is an indented (four spaces) or fenced block whose first line starts with `fabline `,
  `python ` or `pip ` (run by bash with `set -e`, line by line; `#` comments are fine), or a fenced block
  opened with ```` ```python ```` (run by python). Every other block (JSON, TOML, output listings) is data.
- `<!-- readme-test: skip REASON -->` on the line just before a block skips it; the reason is required and
  says why it cannot run here (hardware, a server that runs until stopped, the install itself, minutes of CPU).
- `<!-- readme-test: file NAME -->` on the line just before a data block writes the block's text to NAME in
  the folder, so that the commands after it use the README's own example as input.

Blocks run in README order and share the folder, so a block may use what an earlier one wrote; each is one test,
named by its line, and a failure shows the command's output.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
COMMAND_START = ("fabline ", "python ", "pip ")
MARKER = re.compile(r"<!--\s*readme-test:\s*(skip|file)\s*(.*?)\s*-->")
TIMEOUT_S = 600


@dataclass
class Block:
    line: int
    kind: str          # "shell", "python" or "data"
    text: str
    skip: str | None = None
    file: str | None = None


def readme_blocks(text: str) -> list[Block]:
    """The README's blocks with what the marker line before each says."""
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
            blocks.append(Block(k + 1, kind, body))
            k = end + 1
        elif line.startswith("    ") and (k == 0 or not lines[k - 1].strip() or marker):
            end = k
            while end < len(lines) and (lines[end].startswith("    ") or not lines[end].strip()):
                end += 1
            while not lines[end - 1].strip():
                end -= 1
            body = "\n".join(row[4:] for row in lines[k:end])
            blocks.append(Block(k + 1, "shell" if body.startswith(COMMAND_START) else "data", body))
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


BLOCKS = readme_blocks((REPO / "README.md").read_text(encoding="utf-8"))
RUN = [b for b in BLOCKS if b.kind != "data" or b.file]


def test_every_skip_states_a_reason_and_every_file_marker_names_a_file():
    for block in BLOCKS:
        assert block.skip is None or len(block.skip.split()) >= 3, f"README line {block.line}: skip needs a reason"
        assert block.file is None or block.file.strip(), f"README line {block.line}: file marker needs a name"
    assert sum(b.kind != "data" and not b.skip for b in BLOCKS) >= 10


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("readme")
    for name in ("jobs", "examples"):
        shutil.copytree(REPO / name, root / name)
    return root


@pytest.mark.parametrize("block", RUN, ids=[f"line{b.line}" for b in RUN])
def test_readme_block_runs(block, folder):
    if block.skip:
        pytest.skip(f"README line {block.line}: {block.skip}")
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
    assert done.returncode == 0, (f"README line {block.line} failed (exit {done.returncode}):\n{block.text}\n"
                                  f"--- stdout\n{done.stdout[-3000:]}\n--- stderr\n{done.stderr[-3000:]}")


def test_readme_blocks_leave_nothing_for_git(folder):
    """Every file the README's blocks wrote (they ran above, in this folder laid out as the repository) is one that
    .gitignore covers, so running them in a checkout leaves its `git status` clean."""
    shipped = {p.relative_to(REPO).as_posix() for name in ("jobs", "examples") for p in (REPO / name).rglob("*")}
    written = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*")
                     if p.is_file() and p.relative_to(folder).as_posix() not in shipped)
    kept = subprocess.run(["git", "check-ignore", "--no-index", "--verbose", "--non-matching", "--stdin"], cwd=REPO,
                          input="\n".join(written), capture_output=True, text=True).stdout.splitlines()
    unignored = [line.split("\t", 1)[1] for line in kept if line.startswith("::")]
    assert not unignored, f"README blocks write files git would show (add them to .gitignore): {unignored[:20]}"
