"""A griffe extension that reads torchhrc's docstring conventions for the API reference.

The docstrings follow Google style with three habits of the project (and of Sphinx) that
griffe's Google parser does not know; this extension rewrites them before parsing, so the
source keeps one style for ``help()``, doctests and the site:

* ``Example:`` (singular) is the examples section (griffe only knows ``Examples:``), so its
  ``>>>`` lines render as code;
* ``a, b, c: text`` in an ``Args:`` / ``Attributes:`` section documents each name;
* Sphinx roles (``:class:`~torchhrc.pomdp.POMDP```, ``:func:`.belief.update```, a bare
  ``:class:`ModelError```) become mkdocs-autorefs cross-references, resolved as Sphinx does:
  an absolute path, a name in the scope of the documented object (its module's imports
  included), or the unique object whose path ends with the name. A torchhrc reference that
  resolves to nothing stays a cross-reference to its written target, so ``mkdocs build
  --strict`` fails on it (a dead reference); references outside torchhrc (``torch.Tensor``)
  render as code.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

_ROLE = re.compile(r":(?:py:)?(class|func|meth|mod|attr|data|exc|obj):`(~?)([^`<>]+?)`")
_SECTION = re.compile(
    r"^(\s*)(Args|Arguments|Parameters|Attributes|Keyword Args|Other Parameters):\s*$"
)
_GROUPED = re.compile(r"^(\s+)(\w+(?:\s*,\s*\w+)+)\s*:\s(.*)$")
_EXAMPLE = re.compile(r"^(\s*)Example:\s*$")


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


def _continues(lines: list[str], j: int, item_indent: int) -> bool:
    """Line ``j`` belongs to the item above: indented deeper, or blank before such a line."""
    if lines[j].strip():
        return _indent(lines[j]) > item_indent
    return j + 1 < len(lines) and bool(lines[j + 1].strip()) and _indent(lines[j + 1]) > item_indent


def _split_grouped(text: str) -> str:
    lines = text.split("\n")
    out: list[str] = []
    section_indent: int | None = None
    item_indent: int | None = None
    i = 0
    while i < len(lines):
        line = lines[i]
        stripped = line.strip()
        indent = len(line) - len(line.lstrip())
        if (m := _SECTION.match(line)) is not None:
            section_indent, item_indent = len(m.group(1)), None
            out.append(line)
            i += 1
            continue
        if section_indent is not None and stripped and indent <= section_indent:
            section_indent = item_indent = None
        if section_indent is not None and stripped:
            if item_indent is None:
                item_indent = indent
            if indent == item_indent and (g := _GROUPED.match(line)) is not None:
                continuation = []
                j = i + 1
                while j < len(lines) and _continues(lines, j, item_indent):
                    continuation.append(lines[j])
                    j += 1
                for name in (n.strip() for n in g.group(2).split(",")):
                    out.append(f"{g.group(1)}{name}: {g.group(3)}")
                    out.extend(continuation)
                i = j
                continue
        out.append(line)
        i += 1
    return "\n".join(out)


class TorchHRCDocstrings(griffe.Extension):
    """Rewrite the docstrings of the loaded package (module docstring)."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        objects: dict[str, griffe.Object] = {}
        self._collect(pkg, objects)
        self._objects = objects
        self._paths = set(objects)
        for obj in objects.values():
            if obj.docstring is not None:
                obj.docstring.value = self._rewrite(obj.docstring.value, obj)

    def _collect(self, obj: griffe.Object, out: dict[str, griffe.Object]) -> None:
        out[obj.path] = obj
        for member in obj.members.values():
            if member.is_alias:
                continue
            self._collect(member, out)  # type: ignore[arg-type]

    def _member(self, node: griffe.Object, name: str, depth: int = 0) -> griffe.Object | None:
        """``node``'s member ``name``: a re-export read as its target, an inherited member
        (a dataclass field of a base class) found in the bases."""
        member = node.members.get(name)
        if member is not None:
            return self._objects.get(member.target_path) if member.is_alias else member
        if not node.is_class or depth > 8:
            return None
        for base in node.bases:  # type: ignore[attr-defined]
            path = getattr(base, "canonical_path", None) or str(base)
            parent = self._objects.get(path) or self._member(node.module, path)
            found = None if parent is None else self._member(parent, name, depth + 1)
            if found is not None:
                return found
        return None

    def _follow(self, name: str) -> str | None:
        """The path where ``name`` is documented, read through re-exports and inherited
        members: ``torchhrc.pomdp.MOMDP.initial`` -> ``torchhrc.pomdp.base.MOMDPBase.initial``."""
        head, *rest = name.split(".")
        node = self._objects.get(head)
        for part in rest:
            node = None if node is None else self._member(node, part)
        return None if node is None else node.path

    def _resolve(self, target: str, scope: griffe.Object) -> str | None:
        name = target.lstrip(".")
        if name in self._paths:
            return name
        if self._follow(name) in self._paths:
            return self._follow(name)
        node: griffe.Object | None = scope
        while node is not None:  # the documented object's scopes, innermost first
            head, _, rest = name.partition(".")
            member = node.members.get(head)
            if member is not None:
                base = member.target_path if member.is_alias else member.path
                full = f"{base}.{rest}" if rest else base
                if full in self._paths:
                    return full
                if self._follow(full) in self._paths:
                    return self._follow(full)
            node = node.parent
        suffix = [p for p in self._paths if p.endswith("." + name)]
        return suffix[0] if len(suffix) == 1 else None

    def _rewrite(self, text: str, obj: griffe.Object) -> str:
        text = "\n".join(_EXAMPLE.sub(r"\1Examples:", line) for line in text.split("\n"))
        text = _split_grouped(text)

        def link(match: re.Match[str]) -> str:
            short, target = match.group(2) == "~", match.group(3).strip().removesuffix("()")
            shown = target.lstrip(".").rsplit(".", 1)[-1] if short else target.lstrip(".")
            resolved = self._resolve(target, obj)
            if resolved is not None and any(p.startswith("_") for p in resolved.split(".")):
                return f"`{shown}`"  # an internal object: named, not part of the reference
            if resolved is not None:
                return f"[`{shown}`][{resolved}]"
            if target.startswith((".", "torchhrc")) or "." not in target:
                if not target.startswith(".") and "." not in target and target[:1].islower():
                    return f"`{shown}`"  # a bare lowercase name (a builtin or parameter)
                return f"[`{shown}`][{target.lstrip('.')}]"  # dead: autorefs warns
            return f"`{shown}`"

        return _ROLE.sub(link, text)
