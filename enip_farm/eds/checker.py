"""eds-pie, the independent checker of the EDS files `enip-farm eds export` writes: its parse and
the warnings and errors it logs, collected rather than printed.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from enip_farm.eds.entries import EdsError


class _Collector(logging.Handler):
    """The messages one parse logs: records of the thread that parses (another thread's parse
    logs to the same logger meanwhile)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.thread = threading.get_ident()
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.thread == self.thread:
            self.messages.append(record.getMessage())


@contextmanager
def _eds_pie_messages() -> Iterator[_Collector]:
    """eds-pie's warnings and errors, collected rather than printed. Its modules call
    `logging.basicConfig(level=DEBUG)` when first imported; a handler on the root logger meanwhile
    makes that call do nothing, so the process's logging is left as it was."""
    root = logging.getLogger()
    guard = logging.NullHandler()
    root.addHandler(guard)
    try:
        import eds_pie.eds_pie  # noqa: F401 (imported for its side effect, once)
    finally:
        root.removeHandler(guard)
    logger = logging.getLogger("eds_pie")
    level = logger.level
    logger.setLevel(logging.INFO)  # not the lexer's line per token; put back afterwards
    collector = _Collector()
    logger.addHandler(collector)
    try:
        yield collector
    finally:
        logger.removeHandler(collector)
        logger.setLevel(level)


def parse_eds(text: str) -> tuple[Any, list[str]]:
    """eds-pie's parse of an EDS (its `EDS` object) and the warnings and errors its checker logged.
    Raises EdsError for text it cannot parse."""
    with _eds_pie_messages() as messages:
        from eds_pie.eds_pie import CIP_EDS

        try:
            eds = CIP_EDS(text)
        except Exception as error:  # eds-pie raises plain Exception for syntax errors
            raise EdsError(f"not an EDS file eds-pie can read ({error})") from None
    return eds, messages.messages
