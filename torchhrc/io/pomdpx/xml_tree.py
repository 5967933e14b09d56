"""The XML element tree of a ``.pomdpx`` file: expat with line numbers (for error
messages), ElementTree's C builder as the fast path; document type declarations and
entities are refused."""

from __future__ import annotations

from typing import Any
from xml.etree import ElementTree
from xml.parsers import expat

from torchhrc.errors import ParseError

__all__: list[str] = []  # private parts; the public names are the package's


class _Node:
    """An XML element with its 1-based line (expat tree; ElementTree drops lines)."""

    __slots__ = ("attrib", "children", "line", "parts", "tag")

    def __init__(self, tag: str, attrib: dict[str, str], line: int) -> None:
        self.tag = tag
        self.attrib = attrib
        self.line = line
        self.children: list[_Node] = []
        self.parts: list[str] = []

    @property
    def text(self) -> str:
        return "".join(self.parts)

    def find(self, tag: str) -> _Node | None:
        return next((c for c in self.children if c.tag == tag), None)

    def __iter__(self) -> Any:
        return iter(self.children)

    def __len__(self) -> int:
        return len(self.children)


def _text(node: Any) -> str:
    """The text of an element (a :class:`_Node` or an ``ElementTree`` element)."""
    return node.text or ""


def _line(node: Any) -> int | None:
    """The 1-based line of a :class:`_Node`; None for an ``ElementTree`` element."""
    return getattr(node, "line", None)


class _Refused(Exception):
    def __init__(self, reason: str, line: int) -> None:
        self.reason, self.line = reason, line


def _parse_xml(data: bytes | str, path: str) -> _Node:
    """The element tree of ``data``; DTDs and entity declarations are refused."""
    parser = expat.ParserCreate("utf-8" if isinstance(data, str) else None)
    parser.buffer_text = True
    root = _Node("", {}, 0)
    stack = [root]

    def start(tag: str, attrib: dict[str, str]) -> None:
        node = _Node(tag, attrib, parser.CurrentLineNumber)
        stack[-1].children.append(node)
        stack.append(node)

    def end(tag: str) -> None:
        stack.pop()

    def chars(text: str) -> None:
        stack[-1].parts.append(text)

    def refuse(*_: Any) -> None:
        raise _Refused(
            "document type declarations and entities are not allowed", parser.CurrentLineNumber
        )

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    parser.StartDoctypeDeclHandler = refuse
    parser.EntityDeclHandler = refuse
    parser.ExternalEntityRefHandler = refuse  # type: ignore[assignment]
    try:
        parser.Parse(data, True)
    except _Refused as e:
        raise ParseError(e.reason, path=path, line=e.line) from None
    except expat.ExpatError as e:
        raise ParseError(
            f"malformed XML: {expat.ErrorString(e.code)}",
            path=path,
            line=e.lineno,
            column=e.offset + 1,
        ) from None
    if not root.children:
        raise ParseError("no XML element", path=path)
    return root.children[0]


_REFUSED_MARKUP = (b"<!DOCTYPE", b"<!ENTITY")


def _parse_xml_fast(data: bytes | str) -> Any:
    """The root element parsed by ``ElementTree``'s C builder (no line numbers), or None when
    the document must go through :func:`_parse_xml` (a document type declaration or an entity
    to refuse, or malformed XML: that path reports the line)."""
    raw = data.encode("utf-8") if isinstance(data, str) else data
    if any(marker in raw for marker in _REFUSED_MARKUP):
        return None
    parser = ElementTree.XMLParser(encoding="utf-8" if isinstance(data, str) else None)
    try:
        parser.feed(raw)
        return parser.close()
    except ElementTree.ParseError:
        return None
