"""The examples of the README and of the documentation pages run as written (README.md and docs/*.md;
docs/development.md, *README examples are tests*): each fenced block is preceded by a marker saying
what becomes of it.

- `<!-- example: run -->`: run against the default cell, served as the quick start serves it
  (`enip-farm serve --http 8044`) in a network namespace of its own, the README's first, then each
  page's in file order; python blocks with this tree's package, sh blocks with bash -e and this
  tree's `enip-farm`. Exit 0, and every `print(...)  # VALUE` line prints VALUE.
- `<!-- example-test -->`: a pytest file, run with pytest.
- `<!-- example: config -->`: a yaml configuration, validated.
- `<!-- example: skip (why) -->`: not run.

Every python and sh block carries one. The quick start itself runs in a fresh venv of the machine's
python3 (`test_quick_start_in_a_fresh_venv`). The pages build into a site with `mkdocs build
--strict` (`test_the_documentation_site_builds_strictly`), and every page is in its nav."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from enip_farm.config import ConfigError, parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from tests.helpers import CLI, ROOT, STARTUP_S, own_network_namespace, read_lines

README = ROOT / "README.md"
PAGES = sorted((ROOT / "docs").glob("*.md"))  # the documentation site's pages (mkdocs.yml)
_MARKER = re.compile(r"<!-- (example-test|example: (\w+)(?: \((.*)\))?) -->")
_CHECKED = ("python", "sh")  # blocks of these languages must say what becomes of them
EXAMPLE_TIMEOUT_S = 120.0


@dataclass(frozen=True)
class Block:
    source: str  # README.md or docs/PAGE.md
    line: int  # 1-based line of the opening fence
    language: str
    text: str
    marker: str | None  # run, pytest, config, skip, or None
    reason: str = ""

    def __str__(self) -> str:
        return f"{self.source}:{self.line} ({self.language})"


def readme_blocks(text: str, source: str = "README.md") -> list[Block]:
    """The fenced blocks at the start of a line, each with the marker on the last non-blank line before it."""
    lines = text.splitlines()
    blocks = []
    i = 0
    while i < len(lines):
        if not lines[i].startswith("```"):
            i += 1
            continue
        language = lines[i][3:].strip()
        end = next((j for j in range(i + 1, len(lines)) if lines[j].startswith("```")), len(lines))
        before = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
        match = _MARKER.fullmatch(before.strip())
        marker = reason = None
        if match:
            marker = "pytest" if match[1] == "example-test" else match[2]
            reason = match[3] or ""
        blocks.append(Block(source, i + 1, language, "\n".join(lines[i + 1:end]) + "\n", marker, reason or ""))
        i = end + 1
    return blocks


BLOCKS = [block for path in (README, *PAGES)
          for block in readme_blocks(path.read_text(), str(path.relative_to(ROOT)))]


def _of(marker: str) -> list[Block]:
    return [block for block in BLOCKS if block.marker == marker]


def test_every_example_says_what_becomes_of_it() -> None:
    unmarked = [str(b) for b in BLOCKS if b.language in _CHECKED and b.marker is None]
    assert not unmarked, ("put <!-- example: run -->, <!-- example: skip (why) --> or <!-- example-test --> right "
                          f"before: {', '.join(unmarked)}")
    unknown = [f"{b}: {b.marker}" for b in BLOCKS if b.marker not in (None, "run", "pytest", "config", "skip")]
    assert not unknown, f"markers are run, config, skip (why) or example-test: {unknown}"
    assert all(b.reason for b in _of("skip")), [str(b) for b in _of("skip") if not b.reason]
    assert all(b.language in _CHECKED for b in _of("run")) and all(b.language == "yaml" for b in _of("config"))
    assert _of("run") and _of("pytest") and _of("config")


def test_the_quick_start_keeps_its_two_commands_and_ci_runs_the_test_command() -> None:
    (quick,) = [b for b in BLOCKS if b.source == "README.md" and b.language == "sh" and "enip-farm serve" in b.text][:1]
    commands = [line.split("  #")[0].strip() for line in quick.text.splitlines()]
    assert len(commands) == 2
    venv = "python3 -m venv .venv && . .venv/bin/activate && "
    assert commands[0] == venv + 'pip install ".[clients]" && enip-farm serve --http 8044'
    assert commands[1] == venv + 'pip install -e ".[test]" && python -m pytest'
    ci = (ROOT / ".ci" / "run").read_text()
    assert commands[1] in ci.splitlines()  # CI runs the README's test command as written
    assert "python3-venv" in ci  # Debian's venv module, for both commands


def test_the_documentation_site_builds_strictly(tmp_path: Path) -> None:
    """`mkdocs build --strict` of docs/ (mkdocs.yml): a broken link or anchor between pages, a page
    outside the nav or any other warning fails it; every page is in the nav."""
    import yaml
    from mkdocs.commands.build import build
    from mkdocs.config import load_config

    config = load_config(str(ROOT / "mkdocs.yml"), strict=True, site_dir=str(tmp_path / "site"))
    build(config)

    def pages_of(nav: object) -> list[str]:
        if isinstance(nav, str):
            return [nav]
        items = nav.values() if isinstance(nav, dict) else nav
        return [page for item in items for page in pages_of(item)]  # type: ignore[union-attr]

    in_nav = pages_of(yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"])
    assert sorted(in_nav) == sorted(path.name for path in PAGES), "every page of docs/ in mkdocs.yml's nav, once"
    assert sorted(path.name for path in (tmp_path / "site").glob("*.html")) == sorted(
        ["404.html", *(name[:-3] + ".html" for name in in_nav)])


def test_the_readme_links_to_pages_and_sections_that_exist() -> None:
    """The README is outside the site: its links into docs/ are checked here, anchors included."""
    from markdown.extensions.toc import slugify

    links = re.findall(r"\]\((docs/[^)#]+)(?:#([^)]+))?\)", README.read_text())
    assert len(links) >= 20
    for target, anchor in links:
        path = ROOT / target
        assert path.is_file(), f"README links to {target}, which is not there"
        if anchor and path.suffix == ".md":
            headings = [slugify(line.lstrip("#").strip().replace("`", ""), "-")
                        for line in path.read_text().splitlines() if line.startswith("#")]
            assert anchor in headings, f"README links to {target}#{anchor}: its headings are {headings}"


@pytest.mark.parametrize("block", _of("config"), ids=str)
def test_readme_configurations_are_valid(block: Block) -> None:
    import yaml

    try:
        build_profiles(parse_config(yaml.safe_load(block.text), str(block)), shipped_catalogue())
    except ConfigError as error:
        pytest.fail(str(error))


@pytest.mark.system
@pytest.mark.parametrize("block", _of("pytest"), ids=str)
def test_readme_example_test_passes(tmp_path: Path, block: Block) -> None:
    example = tmp_path / "test_example.py"
    example.write_text(block.text)
    # cwd is tmp_path: the plugin and the package come from the tree under test through PYTHONPATH (conftest)
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(example)],
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 passed" in result.stdout


# -- the default cell in a network namespace ---------------------------------------------------------


@dataclass
class Cell:
    """The default cell served in a namespace: run commands beside it with `inside`."""

    process: subprocess.Popen
    env: dict[str, str]

    def inside(self, command: list[str], **kwargs: object) -> subprocess.CompletedProcess:
        return subprocess.run(["nsenter", f"--net=/proc/{self.process.pid}/ns/net", *command], capture_output=True,
                              text=True, timeout=EXAMPLE_TIMEOUT_S, env=self.env, **kwargs)  # type: ignore[call-overload]


def _serve_default_cell(prefix: tuple[str, ...], command: list[str], env: dict[str, str], cwd: Path,
                        log: Path) -> subprocess.Popen:
    """The default cell, served by `command` behind `prefix`, once its table and banner are out."""
    with log.open("w") as stderr:
        process = subprocess.Popen([*prefix, *command], stdout=subprocess.PIPE, stderr=stderr, text=True, cwd=cwd,
                                   env=env)
    table = read_lines(process.stdout, 9)  # the header and the default cell's 8 devices
    if len(table) < 9:
        process.wait(timeout=STARTUP_S)
        raise AssertionError(f"the default cell did not start: {table} {log.read_text()}")
    return process


def _stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=STARTUP_S)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=STARTUP_S)
    if process.stdout is not None:
        process.stdout.close()


@pytest.fixture(scope="module")
def default_cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    """`enip-farm serve --http 8044` of this tree in its own namespace; `enip-farm` on PATH is this tree's."""
    prefix = own_network_namespace()
    home = tmp_path_factory.mktemp("readme")
    bin_dir = home / "bin"
    bin_dir.mkdir()
    shim = bin_dir / "enip-farm"
    shim.write_text(f'#!/bin/sh\nexec {sys.executable} -m enip_farm "$@"\n')
    shim.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}"}
    env.pop("ENIP_FARM_API", None)
    env.pop("ENIP_FARM_TOKEN", None)
    process = _serve_default_cell(prefix, [*CLI, "serve", "--http", "8044"], env, ROOT, home / "serve.log")
    try:
        yield Cell(process, env)
    finally:
        _stop(process)


def _printed_values(code: str) -> list[str]:
    """What each `print(...)  # VALUE` line of an example promises, in order."""
    return [line.split("#", 1)[1].strip() for line in code.splitlines()
            if line.strip().startswith("print(") and "#" in line]


@pytest.mark.system
@pytest.mark.parametrize("block", _of("run"), ids=str)
def test_readme_example_runs_against_the_default_cell(default_cell: Cell, tmp_path: Path, block: Block) -> None:
    script = tmp_path / ("example.py" if block.language == "python" else "example.sh")
    script.write_text(block.text)
    command = [sys.executable, str(script)] if block.language == "python" else ["bash", "-e", "-o", "pipefail",
                                                                                 str(script)]
    result = default_cell.inside(command, cwd=ROOT)
    assert result.returncode == 0, f"{block} exited {result.returncode}:\n{block.text}\n{result.stdout}{result.stderr}"
    promised = _printed_values(block.text) if block.language == "python" else []
    if promised:
        assert result.stdout.splitlines()[:len(promised)] == promised, f"{block}:\n{result.stdout}"


# -- the quick start, as written, on the machine's python3 ---------------------------------------------


def _system_python_dir() -> str:
    """Where the machine's own python3 is: Debian's (/usr/bin, which refuses a bare `pip install`)
    when there is one, else the first on PATH."""
    if Path("/usr/bin/python3").exists():
        return "/usr/bin"
    found = shutil.which("python3")
    if found is None:
        pytest.skip("no python3 on PATH")
    return str(Path(found).parent)


@pytest.mark.system
def test_quick_start_in_a_fresh_venv(tmp_path: Path) -> None:
    """The quick start's first command, as written, in a copy of the tree: a venv of the machine's
    python3, `pip install ".[clients]"`, `enip-farm serve --http 8044` (in a namespace); then the
    pycomm3 example with the venv's own Python and `enip-farm io get io1`, nothing from this tree's
    path."""
    prefix = own_network_namespace()
    (quick,) = [b for b in BLOCKS if b.source == "README.md" and b.language == "sh" and "enip-farm serve" in b.text][:1]
    first = quick.text.splitlines()[0].split("  #")[0].strip()
    setup, _, serve = first.rpartition(" && ")  # the venv, its activation and the install; then serve
    assert setup.startswith("python3 -m venv") and setup.endswith('pip install ".[clients]"') and serve.startswith(
        "enip-farm serve")
    tree = tmp_path / "enip-farm"
    files = subprocess.run(["git", "ls-files", "-z"], capture_output=True, text=True, cwd=ROOT, check=True,
                           timeout=STARTUP_S).stdout.split("\0")
    for name in filter(None, files):
        if (ROOT / name).is_file():  # a file deleted in the working tree is not in the copy
            (tree / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, tree / name)
    env = {key: value for key, value in os.environ.items()
           if key not in ("PYTHONPATH", "VIRTUAL_ENV", "ENIP_FARM_API", "ENIP_FARM_TOKEN")}
    env["PATH"] = f"{_system_python_dir()}{os.pathsep}{env['PATH']}"
    installed = subprocess.run(["bash", "-e", "-c", setup], capture_output=True, text=True,
                               cwd=tree, env=env, timeout=600)
    assert installed.returncode == 0, installed.stdout[-3000:] + installed.stderr[-3000:]
    process = _serve_default_cell(prefix, ["bash", "-c", f". .venv/bin/activate && exec {serve}"], env, tree,
                                  tmp_path / "serve.log")
    try:
        cell = Cell(process, env)
        example = next(b for b in _of("run")
                       if b.source == "README.md" and b.language == "python" and "pycomm3" in b.text)
        script = tmp_path / "example.py"
        script.write_text(example.text)
        result = cell.inside([str(tree / ".venv" / "bin" / "python"), str(script)], cwd=tmp_path)
        assert result.returncode == 0, result.stdout + result.stderr
        assert result.stdout.splitlines() == _printed_values(example.text) == ["b'\\x10\\x00'", "DSQC1030"]
        io = cell.inside(["bash", "-c", ". .venv/bin/activate && enip-farm io get io1"], cwd=tree)
        assert io.returncode == 0 and io.stdout.startswith("inputs  0000\noutputs 1000\n"), io.stdout + io.stderr
    finally:
        _stop(process)
    banner = (tmp_path / "serve.log").read_text()
    assert "(the default cell)" in banner and "HTTP API on http://127.0.0.1:8044" in banner
    assert "Traceback" not in banner
