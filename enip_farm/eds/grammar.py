"""The EDS file's syntax (CIP Networks Library Vol. 1, 7-3.3 and 7-3.4): sections `[Name]`, entries
`Keyword = field, field, ...;`, fields made of quoted strings (adjacent ones joined), bare words
(numbers, dates, times, identifiers, an unquoted EPATH's bytes), brace lists `{a, {b, c}}`, or
nothing; `$` comments anywhere outside a string (also between a value and its comma); any line
ending; Latin-1 text. Parsed with a lark grammar (LALR, contextual lexer); every syntax error of a
file is reported, each with its line, and parsing goes on after it. A line holding only a bare word
(no `=`, no `;`) before an entry or a section, as some vendors' files have, is skipped with a warning.

The syntax only: what the sections and entries mean is read by enip_farm/eds/reader.py (and sections.py).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from lark import Lark, Token, Transformer, UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, UnexpectedToken

_GRAMMAR = r"""
start: section*
section: "[" SECTION_NAME "]" entry*
entry: KEYWORD "=" value ("," value)* ";"
value: item*
?item: string | BARE | list
string: STRING+
list: "{" value ("," value)* "}"

SECTION_NAME.-5: /[^\]\r\n]+/
KEYWORD: /[A-Za-z0-9_][A-Za-z0-9_.\-]*/
STRING: /"(\\.|[^"\\\r\n])*"/
BARE: /[^\s,;{}"$=\[][^\s,;{}"$=]*/
COMMENT: /\$[^\r\n]*/
%ignore COMMENT
%ignore /[ \t\f\r\n\x1a]+/
"""

@dataclass(frozen=True)
class Value:
    """One field of an entry: `kind` "string" (the text without quotes), "bare" (its words joined
    by one space), "list" (`items`), "mixed" (strings and words: the text as written) or "empty"
    (`line` 0: the entry's line applies)."""

    kind: str
    text: str
    line: int
    items: tuple[Value, ...] = ()

    @property
    def empty(self) -> bool:
        return self.kind == "empty"


@dataclass
class Entry:
    keyword: str
    line: int
    values: tuple[Value, ...]


@dataclass
class Section:
    name: str
    line: int
    entries: dict[str, Entry] = field(default_factory=dict)
    duplicates: list[Entry] = field(default_factory=list)  # a keyword given again: kept aside


@dataclass
class EdsText:
    """A file's sections in order; `errors`: (line, reason) of every syntax error; `warnings`:
    (line, reason) of what was skipped (a stray word on a line of its own)."""

    sections: dict[str, Section]
    errors: list[tuple[int, str]]
    duplicate_sections: list[Section] = field(default_factory=list)
    warnings: list[tuple[int, str]] = field(default_factory=list)

    def entry(self, section: str, keyword: str) -> Entry | None:
        found = self.sections.get(section)
        return found.entries.get(keyword) if found is not None else None


def _unquote(token: str) -> str:
    body = token[1:-1]
    if "\\" not in body:
        return body
    out, i = [], 0
    while i < len(body):
        if body[i] == "\\" and i + 1 < len(body):
            nxt = body[i + 1]
            out.append({"n": "\n", "t": "\t"}.get(nxt, nxt))
            i += 2
        else:
            out.append(body[i])
            i += 1
    return "".join(out)


class _Build(Transformer):
    """Builds the sections while the LALR parser reduces (no parse tree is kept)."""

    def string(self, tokens: list[Token]) -> Value:
        return Value("string", "".join(_unquote(str(t)) for t in tokens), tokens[0].line)  # type: ignore[arg-type]

    def list(self, values: list[Value]) -> Value:
        line = next((v.line for v in values if v.line), 0)
        return Value("list", "{" + ", ".join(v.text for v in values) + "}", line, tuple(values))

    def value(self, parts: list[Value | Token]) -> Value:
        if not parts:
            return Value("empty", "", 0)
        items = [Value("bare", str(p), p.line) if isinstance(p, Token) else p for p in parts]  # type: ignore[arg-type]
        if len(items) == 1:
            return items[0]
        kind = "bare" if all(v.kind == "bare" for v in items) else "mixed"
        return Value(kind, " ".join(v.text for v in items), items[0].line)

    def entry(self, children: list) -> Entry:
        keyword: Token = children[0]
        return Entry(str(keyword), keyword.line, tuple(children[1:]))  # type: ignore[arg-type]

    def section(self, children: list) -> Section:
        name: Token = children[0]
        section = Section(str(name).strip(), name.line)  # type: ignore[arg-type]
        for entry in children[1:]:
            if entry.keyword in section.entries:
                section.duplicates.append(entry)
            else:
                section.entries[entry.keyword] = entry
        return section

    def start(self, sections: list[Section]) -> EdsText:
        found: dict[str, Section] = {}
        duplicates = []
        for section in sections:
            if section.name in found:
                duplicates.append(section)
            else:
                found[section.name] = section
        return EdsText(found, [], duplicates)


#: The parser, built once (lark's grammar analysis takes milliseconds; parsing is reentrant).
_PARSER = Lark(_GRAMMAR, parser="lalr", lexer="contextual", transformer=_Build())


def _describe(error: UnexpectedInput) -> str:
    if isinstance(error, UnexpectedEOF) or (isinstance(error, UnexpectedToken) and error.token.type == "$END"):
        return "the file ends inside an entry or a list (a ';' or a closing brace missing)"
    if isinstance(error, UnexpectedCharacters):
        if error.char == '"':
            return "a string without its closing quote on the same line"
        return f"unexpected character {error.char!r}"
    token = error.token  # type: ignore[attr-defined]
    if str(token).startswith('"'):  # the lexer's fallback took an unterminated string as another token
        return "a string without its closing quote on the same line"
    if token.type == "EQUAL":
        return "'=' where a value was expected: a ';' missing at the end of the entry before?"
    if token.type == "LSQB":
        return "a section starts inside an entry: a ';' missing at the end of the entry before?"
    if token.type in ("KEYWORD", "SECTION_NAME"):
        return f"{str(token)!r} where an entry or a section was expected"
    return f"unexpected {str(token)!r}"


#: Repairs tried before a file is given up on (each one is an error reported).
_MAX_REPAIRS = 50


def _close_string(text: str, position: int) -> str:
    """A string without its closing quote, closed at the end of its line."""
    end = len(text)
    for stop in ("\r", "\n"):
        found = text.find(stop, position)
        end = found if 0 <= found < end else end
    return text[:end] + '"' + text[end:]


def _repair(text: str, error: UnexpectedInput) -> str | None:
    """The text with the smallest change that lets parsing go past `error`, on the same lines (so
    the lines of later errors are still the file's): a ';' before the keyword of an entry that
    follows one without its ';', a closing quote at the end of a line, a closing brace or ';'
    where the parser needs one, or the offending token blanked out."""
    if isinstance(error, UnexpectedCharacters):
        position = error.pos_in_stream
        if error.char == '"':
            return _close_string(text, position)
        return text[:position] + " " + text[position + 1:]
    if isinstance(error, UnexpectedEOF):
        return text + "}" if "RBRACE" in error.expected else text + ";"
    assert isinstance(error, UnexpectedToken)
    token, accepts = error.token, error.accepts or error.expected
    if token.type == "$END":
        return text + ("}" if "RBRACE" in accepts else ";")
    position = token.start_pos or 0
    if str(token).startswith('"'):
        return _close_string(text, position)
    if token.type == "EQUAL":  # `A = 1` then `B = 2` without the ';': end A's entry before B
        keyword_start = position
        while keyword_start > 0 and text[keyword_start - 1] in " \t":
            keyword_start -= 1
        while keyword_start > 0 and text[keyword_start - 1] not in " \t\r\n,;{}=\"":
            keyword_start -= 1
        return text[:keyword_start] + ";" + text[keyword_start:]
    if "RBRACE" in accepts:
        return text[:position] + "}" + text[position:]
    if "SEMICOLON" in accepts:
        return text[:position] + ";" + text[position:]
    return text[:position] + " " * len(str(token)) + text[position + len(str(token)):]


#: A line with a bare word and nothing else (a comment may follow).
_LONE_WORD = re.compile(r"[ \t]*([A-Za-z0-9_][A-Za-z0-9_.\-]*)[ \t]*(?:\$[^\r\n]*)?")
_BLANK = re.compile(r"[ \t\f\x1a]*(?:\$[^\r\n]*)?")


def _stray_word(text: str, error: UnexpectedInput) -> tuple[int, str, str] | None:
    """(line, word, text without it) when the parser took a stray word, alone on its line, for an
    entry's keyword and then met the next entry, a section or the end of the file instead of '='."""
    if not isinstance(error, UnexpectedToken) or "EQUAL" not in (error.accepts or error.expected):
        return None
    token = error.token
    if token.type not in ("KEYWORD", "LSQB", "$END"):
        return None
    lines = text.splitlines(keepends=True)
    index = (token.line if token.type != "$END" and isinstance(token.line, int) else len(lines) + 1) - 2
    while index >= 0 and _BLANK.fullmatch(lines[index].rstrip("\r\n")):
        index -= 1
    if index < 0:
        return None
    body = lines[index].rstrip("\r\n")
    found = _LONE_WORD.fullmatch(body)
    if found is None:
        return None
    lines[index] = " " * len(body) + lines[index][len(body):]
    return index + 1, found.group(1), "".join(lines)


def parse_eds_text(text: str) -> EdsText:
    """The sections and entries of an EDS's text, and every syntax error with its line: after an
    error the text is repaired as little as it takes (`_repair`) and parsed again."""
    errors: list[tuple[int, str]] = []
    warnings: list[tuple[int, str]] = []
    last_line = text.count("\n") + 1
    for _ in range(_MAX_REPAIRS):
        try:
            result: EdsText = _PARSER.parse(text)  # type: ignore[assignment]
        except UnexpectedInput as error:
            stray = _stray_word(text, error)
            if stray is not None:
                line, word, text = stray
                warnings.append((line, f"{word!r} alone on its line (no '=', no ';'): skipped"))
                continue
            line = getattr(error, "line", None)
            if not isinstance(line, int) or line < 1 or isinstance(error, UnexpectedEOF) or (
                    isinstance(error, UnexpectedToken) and error.token.type == "$END"):
                line = last_line
            if (line, _describe(error)) not in errors:
                errors.append((line, _describe(error)))
            repaired = _repair(text, error)
            if repaired is None or repaired == text:
                break
            text = repaired
            continue
        result.errors, result.warnings = errors, warnings
        return result
    return EdsText({}, errors or [(last_line, "too many errors")], warnings=warnings)


def decode_eds_bytes(data: bytes) -> str:
    """An EDS file's text: UTF-8 where it is (an exported file), else Latin-1 (the EDS character set)."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")
