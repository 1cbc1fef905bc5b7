"""The stages' import order (issue 26): data flows one way, from model to machine, and no import runs back.

Every import in the package (at module level, inside functions and under TYPE_CHECKING alike) is read from the
code and checked against the floors below. A package may import its own modules, any floor below its own and
nothing above; packages on one floor do not import each other. What two stages share lives below both.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "fabline"

FLOORS = [
    ("",),                                  # the ground floor's modules: errors, fileio, units, naming, ...
    ("machine", "mechanics", "shop"),       # shared concepts: G-code and machines; materials and the structural
                                            # rule; sheet stock and layers
    ("model",),
    ("geometry",),
    ("design",),                            # designs from a surface measure their network with geometry
    ("unroll",),
    ("nest", "analysis"),                   # analysis reads the network, its geometry and the parts' settings
    ("export",),
    ("link", "survey", "assembly"),  # assembly: the site's plan, from the model and the unroll's parts
    ("jobs",),
    ("cli",),
]
FLOOR = {package: level for level, packages in enumerate(FLOORS) for package in packages}


def package_of(module: str) -> str:
    """`fabline.nest.svg` -> "nest"; a top-level module (`fabline.errors`) -> "" (the ground floor)."""
    parts = module.split(".")
    if len(parts) > 1 and (PACKAGE / parts[1]).is_dir():
        return parts[1]
    return "cli" if parts[-1] == "__main__" else ""


def imports_of(path: Path) -> list[tuple[int, str]]:
    """Every fabline module `path` imports, with its line."""
    module = ".".join(("fabline", *path.relative_to(PACKAGE).with_suffix("").parts))
    package_parts = module.split(".")[: -1 if path.name != "__init__.py" else -1]
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names if alias.name.startswith("fabline")]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package_parts[: len(package_parts) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            if name.startswith("fabline"):
                found.append((node.lineno, name))
    return found


def against_the_flow() -> list[str]:
    problems = []
    for path in sorted(PACKAGE.rglob("*.py")):
        own = package_of(".".join(("fabline", *path.relative_to(PACKAGE).with_suffix("").parts)))
        for line, name in imports_of(path):
            other = package_of(name)
            if other == own or other == "" and name == "fabline":
                continue
            if FLOOR[other] > FLOOR[own] or FLOOR[other] == FLOOR[own]:
                problems.append(f"{path.relative_to(PACKAGE.parent)}:{line}: {own or 'ground'} imports {name} "
                                f"({other or 'ground'} is {'above' if FLOOR[other] > FLOOR[own] else 'beside'} it)")
    return problems


def test_every_package_has_a_floor():
    packages = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert packages == set(FLOOR) - {""}, f"a package without a floor (or a floor without a package): {packages ^ (set(FLOOR) - {''})}"


def test_no_import_runs_against_the_flow():
    problems = against_the_flow()
    assert not problems, "imports against the stage order:\n" + "\n".join(problems)


def test_the_check_sees_an_import_against_the_flow(tmp_path, monkeypatch):
    """The check itself: an import of export planted in nest, and one of a sibling on the same floor, are found."""
    import shutil

    copy = tmp_path / "fabline"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__", "static", "*.toml"))
    (copy / "nest" / "planted.py").write_text("def f():\n    from fabline.export.toolpath import Toolpath\n")
    (copy / "shop" / "planted.py").write_text("from fabline.machine import load_machine\n")
    monkeypatch.setitem(globals(), "PACKAGE", copy)
    problems = against_the_flow()
    assert any("nest/planted.py:2: nest imports fabline.export.toolpath (export is above it)" in p for p in problems)
    assert any("shop/planted.py:1: shop imports fabline.machine (machine is beside it)" in p for p in problems)
    assert len(problems) == 2, problems


def test_the_link_reads_in_one_sitting():
    """Every module of the link under 400 lines: the streamer is a composition of parts (connection, controller,
    sender, ledger, stopping, recovery), each small enough to read through."""
    long = {str(p.relative_to(PACKAGE)): n for p in (PACKAGE / "link").rglob("*.py")
            if (n := len(p.read_text(encoding="utf-8").splitlines())) >= 400}
    assert not long, f"modules of 400 lines or more: {long}"
