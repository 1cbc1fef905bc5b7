"""A small valid job file and a writer (shared by the jobs and cli tests)."""

from __future__ import annotations

from pathlib import Path

GOOD = """
name = "small"
[model]
design = "enneper"
[model.options]
size = [2.0, 2.5]
spacing = 0.5
[output]
folder = "out"
"""


def write(tmp_path: Path, text: str, name: str = "job.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path
