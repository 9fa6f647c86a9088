"""The `enip-farm` command. Each module of this package holds one group of commands and imports
only click at its top: what a command needs (the farm, pydantic, httpx, FastAPI) is imported when
it runs, so `enip-farm --help` and `enip-farm io get` start fast (bench/cli_startup.py).

serve.py and running.py: `serve`; cell.py: loading a cell for a command; cells.py: `validate`,
`models`, `addresses`, `probe` (prober.py), `compose`; io.py: `io get|set|watch`; faults.py:
`fault`, `reset`; scenario.py: `scenario validate|run`; report.py: `report` (the controller under
test, judged; --junit); api.py: those commands' calls to the HTTP API (enip_farm/control/client.py);
eds.py, eio.py, captures.py (`golden`, `learn`); engines.py: `stack`, `k8s`, `fleet-api`.
"""

from __future__ import annotations

import sys
from typing import Any

import click

from enip_farm.cli import captures, cells, eds, eio, engines, faults, io, report, scenario, serve

#: Modules the HTTP client imports when they are installed and no command uses: httpx's own command
#: line (with rich and pygments, which import-linter brings), and trio (which selenium brings), whose
#: support httpcore loads for async clients on trio. Marked missing in the CLI's process, they cost
#: `enip-farm io get` nothing instead of most of its start (bench/cli_startup.py).
UNUSED = ("httpx._main", "trio")


class Main(click.Group):
    def main(self, *args: Any, **kwargs: Any) -> Any:  # type: ignore[override]
        """Run a command with UNUSED marked missing; the marks go when it returns (a test calling the
        CLI in its own process keeps the modules it has)."""
        marked = [name for name in UNUSED if name not in sys.modules]
        for name in marked:
            sys.modules[name] = None  # type: ignore[assignment]  # `import` raises ImportError
        try:
            return super().main(*args, **kwargs)
        finally:
            for name in marked:
                if sys.modules.get(name, "") is None:
                    del sys.modules[name]


@click.group(cls=Main)
@click.version_option(package_name="enip-farm")
def main() -> None:
    """Virtual EtherNet/IP I/O devices (ABB scalable I/O) for testing robot controller software."""


for _module in (serve, cells, io, faults, report, scenario, eds, captures, eio, engines):
    for _command in _module.COMMANDS:
        main.add_command(_command)
