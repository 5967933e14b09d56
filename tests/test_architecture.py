"""The map matches the code (issue 32): docs/architecture.md's table "Who owns what" places
every module of torchhrc/ on a layer, and every import of the package (at the top of a
module, inside a function, or for type checking only) stays in its own entry or goes down."""

from __future__ import annotations

import ast
import re
from functools import cache
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ROOT = REPO / "torchhrc"
DOC = REPO / "docs" / "architecture.md"


def read_map(text: str) -> dict[str, int]:
    """``{entry: layer}`` from the table under "### Who owns what" (an entry is a path under
    torchhrc/: a file, or a folder ending in "/")."""
    section = text.split("### Who owns what", 1)[1].split("\n#", 1)[0]
    entries: dict[str, int] = {}
    for row in re.findall(r"^\| *(\d+) *\| *([^|]+)\|", section, flags=re.MULTILINE):
        for path in re.findall(r"`([^`]+)`", row[1]):
            assert path not in entries, f"{path} is placed twice"
            entries[path] = int(row[0])
    return entries


@cache
def module_file(name: str) -> Path | None:
    """The file of module ``torchhrc[.a.b]`` (a compiled extension: its C source)."""
    path = ROOT.joinpath(*name.split(".")[1:])
    for candidate in (path / "__init__.py", path.with_suffix(".py"), path.with_suffix(".c")):
        if candidate.is_file():
            return candidate
    return None


def statements(body: list[ast.stmt]):  # type: ignore[no-untyped-def]
    """Every statement of ``body``, nested ones too (an import is a statement: the
    expressions need no visit)."""
    for node in body:
        yield node
        for field in ("body", "orelse", "finalbody", "handlers", "cases"):
            inner = getattr(node, field, None)
            if isinstance(inner, list):
                yield from statements(inner)


@cache
def imports(path: Path) -> frozenset[Path]:
    """The torchhrc modules that ``path`` imports anywhere, as files."""
    parts = ["torchhrc", *path.relative_to(ROOT).with_suffix("").parts]
    package = parts[:-1]
    found: set[str] = set()
    for node in statements(ast.parse(path.read_text()).body):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package[: len(package) - node.level + 1]
                base = ".".join(up + ([node.module] if node.module else []))
            for alias in node.names:  # a submodule, or a name of the module `base`
                sub = f"{base}.{alias.name}"
                found.add(sub if module_file(sub) else base)
    files = set()
    for name in found:
        while name.startswith("torchhrc") and module_file(name) is None:
            name = name.rpartition(".")[0]  # `import torchhrc.a.b` without such a file
        if name.split(".")[0] == "torchhrc":
            files.add(module_file(name))
    return frozenset(files - {path})


def entry_of(path: Path, entries: dict[str, int]) -> str | None:
    """The longest entry that holds ``path``."""
    rel = path.relative_to(ROOT).as_posix()
    hits = [e for e in entries if rel == e or (e.endswith("/") and rel.startswith(e))]
    return max(hits, key=len, default=None)


def violations(entries: dict[str, int]) -> list[str]:
    """What in the code disagrees with the map ``entries``, one line each."""
    modules = sorted(ROOT.rglob("*.py"))
    unplaced = [str(p.relative_to(ROOT)) for p in modules if entry_of(p, entries) is None]
    if unplaced:
        return [f"modules the map does not place: {unplaced}"]
    wrong = []
    used = {entry_of(p, entries) for p in modules}
    wrong += [f"a map entry naming no module: {e}" for e in sorted(set(entries) - used)]
    graph = {p: imports(p) for p in modules}
    for path, targets in graph.items():
        here = entry_of(path, entries)
        for target in targets:
            there = entry_of(target, entries)
            if there != here and entries[there] >= entries[here]:
                what = f"{path.relative_to(ROOT)} imports {target.relative_to(ROOT)}"
                wrong.append(f"{here} ({entries[here]}) -> {there} ({entries[there]}): {what}")
    # no circle among the modules (inside one entry too): drop, again and again, the modules
    # that import nothing left; what remains lies on a circle or leads into one
    left = {p: {t for t in ts if t in graph} for p, ts in graph.items()}
    while sinks := {p for p, ts in left.items() if not ts}:
        left = {p: ts - sinks for p, ts in left.items() if p not in sinks}
    if left:
        wrong.append(f"an import circle among: {sorted(str(p.relative_to(ROOT)) for p in left)}")
    return wrong


def test_every_import_goes_down_the_map_and_nothing_closes_a_circle() -> None:
    wrong = violations(read_map(DOC.read_text()))
    assert not wrong, "docs/architecture.md and the code disagree:\n" + "\n".join(wrong)


def test_the_check_sees_an_import_that_runs_back_up() -> None:
    """The check itself, on a map with one entry moved: the forms above the algorithms that
    use them, or a folder left out."""
    entries = read_map(DOC.read_text())
    assert entries["errors.py"] == 0
    moved = {**entries, "solvers/forms/": entries["solvers/__init__.py"] + 1}
    assert any(line.startswith("solvers/") and "-> solvers/forms/" in line
               for line in violations(moved))  # fmt: skip
    without = {e: layer for e, layer in entries.items() if e != "irl/"}
    assert violations(without)[0].startswith("modules the map does not place: ['irl/")
