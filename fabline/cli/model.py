"""CLI for the model stage: `fabline design`, `fabline import`, `fabline inspect`."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the model stage's subcommands."""
