"""RobotWare's configuration file format (EIO.cfg, SYS.cfg ...), read and written.

What is known of it (public configuration files; ABB's manuals are not public): a header line
`EIO:CFG_1.0:6:1::` (domain, format version, optionally the RobotWare version); sections, each a
type name on its own line ending in a colon (`EIO_SIGNAL:`), usually after a line holding only
`#`; entries, each one logical line of `-Attribute value` pairs, where a value is a quoted string,
a bare number or word, and a boolean attribute is a bare flag with no value (`-Invert`). A long
entry continues on the next line: the line ends in a backslash and the next one is indented.
Entries are usually separated by blank lines; text after `#` on a `#` line is a comment.

Parsing keeps every section and attribute it does not know (the importer decides what they mean);
only lines that fit none of the shapes above are errors, each naming the file and the line.

A file cut short is refused (`cut_short`): the files RobotWare and its tools write end with their
last entry's last line and a line break (the public EIO.cfg files seen, and tests/data/EIO.cfg), so
a file that ends inside a line (no final line break), on a continuation (`\\`), or after a `#` line
or a section line (the separators that come before an entry) was cut. A file that ends with blank
lines may have been cut between entries or edited by hand: it is read, with a warning that says so.
A file cut exactly after an entry's line break looks whole: nothing in the format tells it apart.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

#: An attribute's value: a quoted or bare string, a bare number, or True for a bare flag.
Value = str | int | float | bool

_HEADER = re.compile(r"^(?P<domain>[A-Za-z_][A-Za-z0-9_]*):CFG_(?P<version>\d+(?:\.\d+)*):(?P<rest>.*)$")
_SECTION = re.compile(r"^(?P<name>[A-Za-z_][A-Za-z0-9_]*):$")
_TOKEN = re.compile(r'\s*(?:-(?P<attribute>[A-Za-z_][A-Za-z0-9_]*)(?=[\s"]|$)|"(?P<quoted>[^"]*)"'
                    r'|(?P<bare>[^\s"]+)|(?P<open>"))')
_ATTRIBUTE_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_INT = re.compile(r"^[+-]?\d+$")
_FLOAT = re.compile(r"^[+-]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][+-]?\d+)?$")

INDENT = " " * 6  # as RobotWare writes entries
MAX_LINE = 79  # tools that write the file keep lines under 80 characters


class CfgError(ValueError):
    """A file that cannot be read as a configuration file; one line per problem, `file:line: ...`."""


@dataclass(frozen=True)
class Entry:
    """One entry: its section, its attributes in file order, and the line it starts on."""

    section: str
    attributes: dict[str, Value]
    line: int

    def get(self, name: str) -> Value | None:
        return self.attributes.get(name)

    def text(self) -> str:
        """The entry on one line, as the file would hold it unwrapped."""
        return " ".join(_pair(name, value) for name, value in self.attributes.items())

    def describe(self) -> str:
        """How messages name the entry: its section and its -Name, if it has one."""
        name = self.attributes.get("Name")
        return f"{self.section} {str(name)!r}" if name is not None else self.section


@dataclass(frozen=True)
class CfgFile:
    source: str  # the file's name, for messages
    header: str  # the first line as it was
    domain: str  # EIO, SYS, MOC ...
    entries: tuple[Entry, ...]
    sections: dict[str, int]  # every section line, by name: the line of its first appearance
    warnings: tuple[str, ...] = field(default=())

    def where(self, line: int) -> str:
        return f"{self.source}:{line}"


def parse_value(token: str) -> int | float | str:
    """A bare token: an integer, a decimal number, or a word as it is."""
    if _INT.match(token):
        return int(token)
    if _FLOAT.match(token):
        return float(token)
    return token


def parse_cfg(text: str, source: str = "<cfg>") -> CfgFile:
    """Read a configuration file. Raises CfgError listing every malformed line; what is merely
    unknown (sections, attributes) is kept for the caller, and oddities that lose nothing (an
    attribute given twice) are in `warnings`."""
    lines = text.lstrip("\ufeff").splitlines()
    first = next((i for i, line in enumerate(lines) if line.strip()), None)
    header = _HEADER.match(lines[first].strip()) if first is not None else None
    if header is None:
        found = repr(lines[first].strip()[:40]) if first is not None else "an empty file"
        raise CfgError(f"{source}:{(first or 0) + 1}: not a RobotWare configuration file: expected a header "
                       f"like EIO:CFG_1.0:6:1::, found {found}")
    errors: list[str] = []
    warnings: list[str] = []
    entries: list[Entry] = []
    sections: dict[str, int] = {}
    section: str | None = None
    index = first + 1  # type: ignore[operator]
    while index < len(lines):
        number = index + 1
        stripped = lines[index].strip()
        index += 1
        if not stripped or stripped.startswith("#"):
            continue
        match = _SECTION.match(stripped)
        if match:
            section = match["name"]
            sections.setdefault(section, number)
            continue
        if not stripped.startswith("-"):
            errors.append(f"{source}:{number}: expected an entry (-Attribute value ...), a section line (NAME:) "
                          f"or a # line, found {stripped[:40]!r}")
            continue
        parts = [(number, stripped)]
        while parts[-1][1].endswith("\\"):
            if index >= len(lines):
                break  # the file ends on a continuation: cut_short says so
            if not lines[index].strip() or lines[index].strip().startswith("#"):
                errors.append(f"{source}:{parts[-1][0]}: the line ends in a continuation (\\) but no indented "
                              "line of the entry follows")
                break
            parts.append((index + 1, lines[index].strip()))
            index += 1
        attributes = _attributes(parts, source, errors, warnings)
        if section is None:
            errors.append(f"{source}:{number}: an entry before any section line (such as EIO_SIGNAL:)")
        elif attributes is not None:
            entries.append(Entry(section, attributes, number))
    cut = cut_short(text, lines, source)
    if cut:
        errors.append(cut)
    elif (blank := trailing_blank(lines, source)) is not None:
        warnings.append(blank)
    if errors:
        raise CfgError("\n".join(errors))
    return CfgFile(source, lines[first].strip(), header["domain"], tuple(entries), sections,  # type: ignore[index]
                   tuple(warnings))


def cut_short(text: str, lines: list[str], source: str) -> str | None:
    """Why the file looks cut short, naming its last line, or None: see the module's docstring."""
    if not lines:
        return None
    advice = "it looks cut short (a copy that stopped?): take the whole file again"
    if not text.endswith(("\n", "\r")):
        return (f"{source}:{len(lines)}: the file ends inside this line (no line break after it): {advice}; "
                "if it is whole, end its last line with a line break")
    last = max((i for i, line in enumerate(lines) if line.strip()), default=0)
    stripped = lines[last].strip()
    if stripped.endswith("\\"):
        what = "a line that continues (\\) on a line that is not there"
    elif stripped == "#" or _SECTION.match(stripped):
        what = f"{'a # line' if stripped == '#' else 'the section line ' + stripped} and no entry after it"
    else:
        return None
    return f"{source}:{last + 1}: the file ends with {what}, where RobotWare ends with an entry's line: {advice}"


def trailing_blank(lines: list[str], source: str) -> str | None:
    """A warning where the file ends with blank lines after its last entry (cut between entries, or
    a hand edit: both happen), or None."""
    last = max((i for i, line in enumerate(lines) if line.strip()), default=0)
    if last == len(lines) - 1 or _HEADER.match(lines[last].strip()) is not None:
        return None
    return (f"{source}:{len(lines)}: the file ends with a blank line, where RobotWare ends with an entry's line: "
            "if it was copied, check that the copy is whole (it may have stopped between entries)")


def _attributes(parts: list[tuple[int, str]], source: str, errors: list[str],
                warnings: list[str]) -> dict[str, Value] | None:
    """The attributes of one entry's lines (continuations joined); None after an error."""
    text = ""
    starts: list[tuple[int, int]] = []  # (offset in text, file line)
    for number, part in parts:
        part = part.removesuffix("\\")
        if text and text.count('"') % 2 == 0:
            text += " "
        starts.append((len(text), number))
        text += part

    def line_at(offset: int) -> int:
        return [number for start, number in starts if start <= offset][-1]

    attributes: dict[str, Value] = {}
    pending: str | None = None
    position = 0
    while position < len(text):
        match = _TOKEN.match(text, position)
        if match is None or match.end() == position:  # only trailing blanks are left
            break
        position = match.end()
        where = f"{source}:{line_at(match.start(match.lastgroup or 0))}"
        if match["open"] is not None:
            errors.append(f"{where}: a quoted string is not closed")
            return None
        if match["attribute"] is not None:
            if pending is not None:
                attributes[pending] = True  # the previous attribute was a flag
            pending = match["attribute"]
            if pending in attributes:
                warnings.append(f"{where}: -{pending} is given twice in one entry; the last value counts")
                del attributes[pending]
            continue
        value: Value = match["quoted"] if match["quoted"] is not None else parse_value(match["bare"])
        if pending is None:
            shown = f'"{value}"' if match["quoted"] is not None else str(value)
            errors.append(f"{where}: the value {shown} follows no -Attribute")
            return None
        attributes[pending] = value
        pending = None
    if pending is not None:
        attributes[pending] = True
    return attributes


# -- writing ----------------------------------------------------------------------------------------


def format_value(name: str, value: Value) -> str | None:
    """A value as the file holds it (None for a flag); ValueError for one the format cannot hold."""
    if value is True:
        return None
    if isinstance(value, bool):
        raise ValueError(f"-{name}: a flag is either present or left out, not false")
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return str(int(value)) if value.is_integer() and abs(value) < 1e15 else repr(value)
    if '"' in value or "\n" in value or "\r" in value:
        raise ValueError(f"-{name}: {value!r} holds a double quote or a line break, which the format cannot hold")
    return f'"{value}"'


def _pair(name: str, value: Value) -> str:
    text = format_value(name, value)
    return f"-{name}" if text is None else f"-{name} {text}"


def format_entry(attributes: list[tuple[str, Value]]) -> list[str]:
    """One entry as indented lines of at most MAX_LINE characters, each but the last ending in a
    backslash; an attribute and its value stay on one line unless together they are too long."""
    pairs = []
    for name, value in attributes:
        if not _ATTRIBUTE_NAME.match(name):
            raise ValueError(f"-{name} is not an attribute name (letters, digits, _)")
        pairs.append(_pair(name, value))
    room = MAX_LINE - len(INDENT) - 1  # the backslash
    lines: list[str] = []
    current = ""
    for pair in pairs:
        pieces = [pair] if len(pair) <= room else pair.split(" ", 1)
        for piece in pieces:
            if current and len(current) + 1 + len(piece) > room:
                lines.append(current)
                current = piece
            else:
                current = f"{current} {piece}" if current else piece
    lines.append(current)
    return [INDENT + line + ("\\" if i < len(lines) - 1 else "") for i, line in enumerate(lines)]


def write_cfg(header: str, sections: list[tuple[str, list[list[tuple[str, Value]]]]]) -> str:
    """A whole file: the header, then each section after a `#` line, its entries separated by
    blank lines. ValueError for a value the format cannot hold."""
    out = [header]
    for name, entries in sections:
        out += ["#", f"{name}:"]
        for attributes in entries:
            out.append("")
            out += format_entry(attributes)
    return "\n".join(out) + "\n"
