"""`enip-farm scenario validate|run`: a scenario (enip_farm/scenario/) checked against a cell, or run
on a farm of it started here (`--config`) or on a running farm (`--api`): a progress line per step,
then the verdict table; exit status 0 passed, 1 failed or cancelled, 2 a scenario or cell that cannot
run (every defect `file:line: reason`); `--junit FILE` writes the verdicts as JUnit XML."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import click

from enip_farm.cli.options import config_option, token_option

_scenario_path = click.argument("path", type=click.Path(exists=True, dir_okay=False, path_type=Path))


def _checked(path: Path, config_path: Path | None) -> tuple[Any, Any]:
    """The cell and the scenario parsed against it; a defect: its lines on stderr, exit 2."""
    from enip_farm.cli.cell import load_cell
    from enip_farm.device.build import build_profiles
    from enip_farm.device.signals import SignalMap
    from enip_farm.eds.reader import eds_catalogue
    from enip_farm.scenario.parse import ScenarioError, load_scenario, signal_check

    config = load_cell(config_path)
    maps = {profile.name: SignalMap(profile) for profile in build_profiles(config, eds_catalogue())}
    try:
        return config, load_scenario(str(path), config, signal_check(maps))
    except ScenarioError as error:
        click.echo(str(error), err=True)
        sys.exit(2)


@click.group()
def scenario() -> None:
    """Check or run a scenario: a cell's test case as a timeline of faults, stimuli and waits, with
    expectations and a verdict."""


@scenario.command()
@_scenario_path
@config_option
def validate(path: Path, config_path: Path | None) -> None:
    """Check a scenario against a cell without running it."""
    _, parsed = _checked(path, config_path)
    click.echo(f"{path}: {len(parsed.steps)} steps, {len(parsed.expectations)} expectations: can run")


@scenario.command()
@_scenario_path
@config_option
@click.option("--api", default=None, help="run it on this running farm's HTTP API instead of a farm started here")
@token_option
@click.option("--junit", "junit_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="write the verdicts as JUnit XML to this file")
def run(path: Path, config_path: Path | None, api: str | None, token: str | None, junit_path: Path | None) -> None:
    """Run a scenario: a line per step as it happens, then the verdict table; exit 0 if it passed."""
    if api is not None:
        result = _remote(path, api, token)
    else:
        from enip_farm.cli.cell import make_farm

        config, parsed = _checked(path, config_path)
        farm = make_farm(config)
        with farm.running_in_thread():
            result = farm.run_scenario(parsed, progress=click.echo).as_dict()
    from enip_farm.scenario.verdict import ScenarioResult, StepOutcome, Verdict

    outcome = ScenarioResult(result["name"], result["status"], [StepOutcome(**s) for s in result["steps"]],
                             [Verdict(**v) for v in result["verdicts"]], result["duration_s"])
    click.echo(outcome.table())
    if junit_path is not None:
        outcome.junit().write(str(junit_path))
    sys.exit(0 if outcome.passed else 1)


def _remote(path: Path, api: str, token: str | None) -> dict[str, Any]:
    """POST /scenarios, then its progress lines as they come, then its result."""
    from enip_farm.cli.api import call

    def refused(error: Any) -> None:
        if error.status == 422:
            click.echo(error.detail, err=True)
            sys.exit(2)

    started = call(api, token, "POST", "/scenarios", refused, json={"text": path.read_text(), "source": str(path)})
    shown = 0
    while True:
        state = call(api, token, "GET", f"/scenarios/{started['id']}")
        for line in state["progress"][shown:]:
            click.echo(line)
        shown = len(state["progress"])
        if "result" in state:
            return state["result"]
        if state["status"] == "error":
            click.echo(f"scenario run {started['id']} ended in an error (see the farm's log)", err=True)
            sys.exit(1)
        time.sleep(0.1)


COMMANDS = (scenario,)
