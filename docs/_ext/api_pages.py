"""MkDocs hook: the API reference pages, generated at build time from the package's layout.

One page per subpackage of ``torchhrc`` (``api/<subpackage>.md``) and one for the top-level
modules (``api/torchhrc.md``). A page renders the package's own public names (its ``__all__``
minus re-exports, which are documented where they are defined) and every public module below
it, each with its ``__all__``; private modules (``_name``) are left out. A module added to the
package appears in the reference without editing any page, and the "API reference" section of
``mkdocs.yml``'s nav is filled with the generated pages.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import griffe
from mkdocs.structure.files import File, Files

_PACKAGE = "torchhrc"
_SECTION = "API reference"


def _root(config: Any) -> Path:
    return Path(config["config_file_path"]).resolve().parent


def _modules(root: Path) -> dict[str, list[str]]:
    """``{page: [module paths]}``; page ``torchhrc`` holds the top-level modules."""
    pages: dict[str, list[str]] = {_PACKAGE: []}
    for path in sorted((root / _PACKAGE).rglob("*.py")):
        parts = path.relative_to(root).with_suffix("").parts
        if any(p.startswith("_") for p in parts):  # private modules, and __init__
            continue
        dotted = ".".join(parts)
        page = _PACKAGE if len(parts) == 2 else parts[1]
        pages.setdefault(page, []).append(dotted)
    for init in sorted((root / _PACKAGE).glob("*/__init__.py")):
        pages.setdefault(init.parent.name, [])
    return pages


def _own_names(package: griffe.Module) -> list[str]:
    names = []
    for name in package.exports or ():
        name = name if isinstance(name, str) else str(name)
        member = package.members.get(name)
        if member is not None and not member.is_alias and not member.is_module:
            names.append(name)
    return names


def _intro(loaded: griffe.Module, path: str) -> list[str]:
    obj = loaded if path == _PACKAGE else loaded[path.split(".", 1)[1]]
    lines = [f"::: {path}", "    options:", "      show_root_heading: true"]
    own = _own_names(obj)  # type: ignore[arg-type]
    if own:
        lines += ["      members:", *(f"        - {n}" for n in own)]
    else:
        lines.append("      members: false")
    return [*lines, ""]


def _page(loaded: griffe.Module, page: str, modules: list[str]) -> str:
    package = _PACKAGE if page == _PACKAGE else f"{_PACKAGE}.{page}"
    lines = [f"# {package}", "", *_intro(loaded, package)]
    introduced = {package}
    for module in modules:
        parent = module.rsplit(".", 1)[0]
        if parent not in introduced:  # a nested subpackage (torchhrc.tasks.place_and_drill)
            introduced.add(parent)
            lines += _intro(loaded, parent)
        lines += [f"::: {module}", ""]
    return "\n".join(lines).rstrip() + "\n"


def on_config(config: Any) -> Any:
    pages = _modules(_root(config))
    entries = [{f"{_PACKAGE}" if p == _PACKAGE else f"{_PACKAGE}.{p}": f"api/{p}.md"}
               for p in [_PACKAGE, *sorted(k for k in pages if k != _PACKAGE)]]  # fmt: skip
    for item in config["nav"] or []:
        if isinstance(item, dict) and _SECTION in item:
            item[_SECTION] = entries
    return config


def on_files(files: Files, config: Any) -> Files:
    root = _root(config)
    loaded = griffe.load(_PACKAGE, search_paths=[str(root)], resolve_aliases=False)
    for page, modules in _modules(root).items():
        files.append(
            File.generated(config, f"api/{page}.md", content=_page(loaded, page, modules))  # type: ignore[arg-type]
        )
    return files
