"""Mutation testing of the core (issue 32): does a small change of the product code fail a test?

Cosmic Ray (`pip install -e ".[mutation]"`) makes the mutants; this script decides which to run and
with which tests, so that no mutant runs the whole suite and a run stays within its time budget:
- per package (`PACKAGES`): the modules mutated, and the fast test files that guard them (their
  unit and integration tests: `-m "not system"`);
- a seeded sample of mutation *sites* (a module, a line, a column), one operator drawn per site, so
  the sample spreads over the code rather than over the operators; a site's rank is a hash of its
  text, so the sample of unchanged code stays the same as others change the code around it; no
  mutant of an annotation (a string, never evaluated: equivalent by construction);
- each mutant in a scratch copy of the tree (the checkout is never written), its tests run with
  `pytest -x`, the run niced; a package stops starting mutants once its budget (seconds) is spent.

A mutant is killed (a test failed, or the tests ran past 3x their clean time), survived, or
equivalent: a survivor whose key (module::definition::operator::line) bench/mutation-equivalents.md
lists, with the reason no test can tell it from the real code. The score of a package is
killed / (run - equivalent). `--named` runs the mutations issue 32 found surviving (NAMED: seven),
applied by hand (each must be killed). Not a CI step: it takes minutes.

    python bench/mutation.py [--package cip --package protocol] [--sample 40] [--budget-s 600]
                             [--seed 32] [--omit-tests tests/test_x.py] [--json out.json]
    python bench/mutation.py --named
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
EQUIVALENTS = ROOT / "bench" / "mutation-equivalents.md"
VARY = "tests/test_values_that_vary.py"
PINNED = "tests/test_pinned_details.py"  # what the mutants that survived showed no test pinned
PATHS = "tests/test_pinned_paths.py"  # the same, for the class-1 path and the I/O thread's heap


@dataclass(frozen=True)
class Package:
    modules: tuple[str, ...]  # globs under the repository root
    tests: tuple[str, ...]  # fast test files: each mutant runs these (those that exist), -x
    definitions: dict[str, tuple[str, ...]] = field(default_factory=dict)  # module -> only these functions


PACKAGES: dict[str, Package] = {
    "protocol": Package(
        ("enip_farm/protocol/*.py", "enip_farm/protocol/safety/*.py"),
        ("tests/test_protocol.py", "tests/test_framing_and_state.py", "tests/test_encapsulation_errors.py",
         "tests/test_cip_services_unit.py", "tests/test_safety.py", "tests/test_safety_multicast.py", VARY, PINNED)),
    "cip": Package(
        ("enip_farm/cip/*.py", "enip_farm/cip/safety/*.py"),
        ("tests/test_connection_table.py", "tests/test_cip_services_unit.py", "tests/test_cip_errors.py",
         "tests/test_connection_events.py", "tests/test_declared_connections.py", "tests/test_attributes.py",
         "tests/test_safety_supervisor.py", "tests/test_limits_unit.py", "tests/test_safety.py",
         "tests/test_safety_multicast.py", "tests/test_report_unit.py", VARY, PINNED)),
    "device-faults": Package(  # the faults and the farm's fault timers
        ("enip_farm/device/faults.py", "enip_farm/device/fault_kinds.py", "enip_farm/device/fault_type.py",
         "enip_farm/farm/faulting.py"),
        ("tests/test_device.py", VARY, PINNED, "tests/test_control.py", "tests/test_pinned_faults.py")),
    "device-cyclic": Package(  # one device's class-1 path: cyclic I/O, its lock, its target
        ("enip_farm/device/cyclic.py", "enip_farm/device/guard.py", "enip_farm/device/target.py"),
        ("tests/test_device.py", "tests/test_reset_effect.py", VARY, PINNED, "tests/test_report_unit.py",
         "tests/test_implicit.py", "tests/test_report.py", PATHS, "tests/test_pinned_impaired.py")),
    "server-class1": Package(  # the I/O thread and its sockets
        ("enip_farm/server/implicit.py", "enip_farm/server/batch.py", "enip_farm/server/waits.py"),
        ("tests/test_implicit.py", "tests/test_batch.py", PINNED, "tests/test_supervision.py", PATHS)),
}

#: The mutations issue 32 found surviving: (name, module, the code, the mutated code, tests).
NAMED: tuple[tuple[str, str, str, str, tuple[str, ...]], ...] = (
    ("stale check without & 0xFFFFFFFF", "enip_farm/cip/io_packets.py",
     "not 0 < (sequence - last) & 0xFFFFFFFF < _HALF", "not 0 < (sequence - last) < _HALF", (VARY,)),
    ("timeout from the T->O RPI", "enip_farm/cip/connection.py",
     "self.timeout_ns = self.o_t_rpi * 1000", "self.timeout_ns = self.t_o_rpi * 1000", (VARY,)),
    ("a fault lasts 3x its duration_s", "enip_farm/farm/faulting.py",
     "loop.time() + fault.duration_ns / 1e9", "loop.time() + 3 * fault.duration_ns / 1e9", (VARY,)),
    ("a fault lasts 1/4 of its duration_s", "enip_farm/farm/faulting.py",
     "loop.time() + fault.duration_ns / 1e9", "loop.time() + fault.duration_ns / 4e9", (VARY,)),
    ("delay drawn from [max, 4 max]", "enip_farm/device/fault_kinds.py",
     "random.uniform(self.delay_ms, self.max_delay_ms)", "random.uniform(self.max_delay_ms, 4 * self.max_delay_ms)",
     (VARY,)),
    ("the first watchdog undercuts the timeout", "enip_farm/cip/connection.py",
     "self.opened_at + max(self.timeout_ns, self.first_watchdog_ns)",
     "self.opened_at + (self.first_watchdog_ns or self.timeout_ns)", (VARY,)),
    ("a fault set again keeps the old end timer", "enip_farm/farm/faulting.py",
     "            self._forget(name, fault.name)\n            previous", "            previous", (VARY,)),
)


def scratch_copy() -> Path:
    """The tree as git sees it (tracked and untracked, not ignored) plus the built extension, in a
    temporary folder: mutants are written there, never into the checkout."""
    listed = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT, check=True,
                            capture_output=True).stdout.decode().split("\0")
    target = Path(tempfile.mkdtemp(prefix="enip-farm-mutation-"))
    for name in [n for n in listed if n] + [str(p.relative_to(ROOT)) for p in (ROOT / "enip_farm").rglob("*.so")]:
        source = ROOT / name
        if source.is_file():
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target / name)
    return target


def pytest_command(tests: list[str]) -> list[str]:
    return [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "-m", "not system", *tests]


def run_tests(scratch: Path, tests: list[str], timeout: float) -> tuple[str, float, str]:
    """('passed' | 'failed' | 'timeout', seconds, the output's tail), run in the scratch copy (its
    enip_farm is first on sys.path: `python -m` puts the working directory there)."""
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "PYTHONPATH": str(scratch)}
    started = time.monotonic()
    try:
        done = subprocess.run(pytest_command(tests), cwd=scratch, env=env, capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        return "timeout", time.monotonic() - started, ""
    outcome = "passed" if done.returncode == 0 else "failed"
    return outcome, time.monotonic() - started, (done.stdout + done.stderr)[-2000:]


def equivalents() -> dict[str, str]:
    """key -> reason, from the table rows of bench/mutation-equivalents.md (`| key | reason |`)."""
    if not EQUIVALENTS.exists():
        return {}
    rows = re.findall(r"^\|\s*`([^`]+)`\s*\|\s*(.+?)\s*\|\s*$", EQUIVALENTS.read_text(), re.MULTILINE)
    return dict(rows)


def mutation_key(scratch: Path, spec) -> str:
    line = (scratch / spec.module_path).read_text().splitlines()[spec.start_pos[0] - 1].strip()
    return f"{spec.module_path}::{spec.definition_name}::{spec.operator_name}::{line}"


def _annotations(path: Path) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """The spans of a module's annotations: strings under `from __future__ import annotations`,
    never evaluated, so a mutant there is equivalent by construction (left out of the population)."""
    spans = []
    for node in ast.walk(ast.parse(path.read_text())):
        found = [getattr(node, "returns", None), getattr(node, "annotation", None)]
        spans += [((a.lineno, a.col_offset), (a.end_lineno, a.end_col_offset)) for a in found if a is not None]
    return spans


def _rank(*parts: object) -> str:
    return hashlib.sha256(":".join(map(str, parts)).encode()).hexdigest()


def sample_mutants(scratch: Path, package: Package, sample: int, seed: str,
                   replay: dict[str, str] | None = None) -> tuple[list, int, int]:
    """(the sampled mutation specs, all mutants, all sites) of a package. A site is ranked by a hash
    of the seed, its module, its line's text and its column, and so is each operator at a site: the
    sample stays the same when the code changes elsewhere (a new line only adds a site)."""
    from cosmic_ray.commands.init import _all_work_items  # the enumeration `cosmic-ray init` does

    modules = sorted({p.relative_to(scratch) for pattern in package.modules for p in scratch.glob(pattern)})
    sites: dict[str, list] = defaultdict(list)
    total = 0
    cwd = os.getcwd()
    os.chdir(scratch)  # module paths relative to the scratch copy
    try:
        texts = {str(m): m.read_text().splitlines() for m in modules}
        annotations = {str(m): _annotations(m) for m in modules}
        for item in _all_work_items(modules, {}):
            spec = item.mutations[0]
            module = str(spec.module_path)
            only = package.definitions.get(module)
            if only is not None and spec.definition_name not in only:
                continue
            if any(a <= spec.start_pos < b for a, b in annotations[module]):
                continue
            total += 1
            line = texts[module][spec.start_pos[0] - 1].strip()
            sites[_rank(seed, module, line, spec.start_pos[1])].append(spec)
    finally:
        os.chdir(cwd)
    chosen = sorted(sites)[:sample]
    if replay is not None:  # the survivors of an earlier run, wherever their lines are now (a module split)
        candidates = [spec for site in sorted(sites) for spec in sites[site] if spec_key(spec, texts) in replay]
        again = [spec for spec in candidates if replay[spec_key(spec, texts)] in (None, _mutated_line(scratch, spec))]
        return again, total, len(sites)
    return [min(sites[site], key=lambda s: _rank(site, s.operator_name)) for site in chosen], total, len(sites)


def spec_key(spec, texts: dict[str, list[str]]) -> str:
    """A mutant's key without its module: definition::operator::line (the line before the mutation)."""
    line = texts[str(spec.module_path)][spec.start_pos[0] - 1].strip()
    return f"{spec.definition_name}::{spec.operator_name}::{line}"


def _mutated_line(scratch: Path, spec) -> str | None:
    from cosmic_ray.mutating import mutate_code
    from cosmic_ray.plugins import get_operator

    code = mutate_code((scratch / spec.module_path).read_text(), get_operator(spec.operator_name)(), spec.occurrence)
    return None if code is None else code.splitlines()[spec.start_pos[0] - 1].strip()


def run_package(name: str, package: Package, args: argparse.Namespace, known: dict[str, str]) -> dict:
    from cosmic_ray.mutating import use_mutation
    from cosmic_ray.plugins import get_operator

    scratch = scratch_copy()
    try:
        tests = [t for t in package.tests if (scratch / t).exists() and t not in args.omit_tests]
        clean, clean_s, output = run_tests(scratch, tests, 600)
        if clean != "passed":
            return {"package": name, "error": f"the tests fail without a mutant:\n{output}"}
        again = None
        if args.replay is not None:  # only the survivors of an earlier run
            again = {r["key"].split("::", 1)[1]: r.get("mutated") for s in json.loads(args.replay.read_text())
                     for r in s.get("results", []) if r["verdict"] == "survived" and s["package"] == name}
        specs, total, sites = sample_mutants(scratch, package, args.sample, f"{args.seed}:{name}", again)
        results: list[dict] = []
        deadline = time.monotonic() + args.budget_s
        for spec in specs:
            if time.monotonic() > deadline:
                break
            key = mutation_key(scratch, spec)
            cwd = os.getcwd()
            os.chdir(scratch)
            try:
                with use_mutation(Path(spec.module_path), get_operator(spec.operator_name)(), spec.occurrence) as (
                        _, mutated):
                    if mutated is None:
                        continue
                    outcome, seconds, output = run_tests(scratch, tests, 3 * clean_s + 10)
                    changed = mutated.splitlines()[spec.start_pos[0] - 1].strip()
            finally:
                os.chdir(cwd)
            verdict = {"passed": "survived", "failed": "killed", "timeout": "killed"}[outcome]
            if verdict == "survived" and key in known:
                verdict = "equivalent"
            results.append({"key": key, "verdict": verdict, "seconds": round(seconds, 1), "line": spec.start_pos[0],
                            "occurrence": spec.occurrence, "mutated": changed})
            print(f"  {name}: {verdict:10} {key}", flush=True)
        counts = {v: sum(r["verdict"] == v for r in results) for v in ("killed", "survived", "equivalent")}
        scored = counts["killed"] + counts["survived"]
        return {"package": name, "tests": tests, "mutants": total, "sites": sites, "sampled": len(specs),
                "run": len(results), **counts, "score": round(counts["killed"] / scored, 3) if scored else None,
                "clean_s": round(clean_s, 1), "results": results}
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def run_named(args: argparse.Namespace) -> list[dict]:
    """Each of NAMED by hand: the tests must pass on the real code and fail on the mutant."""
    scratch = scratch_copy()
    rows = []
    try:
        for name, module, code, mutated, tests in NAMED:
            path = scratch / module
            original = path.read_text()
            tests = [t for t in tests if t not in args.omit_tests]
            if original.count(code) != 1:
                rows.append({"mutation": name, "verdict": f"not applicable: {code!r} not found once in {module}"})
                continue
            real, _, _ = run_tests(scratch, tests, 600)
            path.write_text(original.replace(code, mutated))
            try:
                outcome, seconds, output = run_tests(scratch, tests, 600)
            finally:
                path.write_text(original)
            failed = [line for line in output.splitlines() if line.startswith("FAILED")]
            verdict = "killed" if outcome != "passed" else "survived"
            rows.append({"mutation": name, "real code": real, "verdict": verdict, "by": failed[:1]})
            print(f"  {name}: real code {real}, mutant {rows[-1]['verdict']} {' '.join(failed[:1])}", flush=True)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--package", action="append", choices=sorted(PACKAGES), help="default: all")
    parser.add_argument("--sample", type=int, default=40, help="mutation sites per package")
    parser.add_argument("--budget-s", type=float, default=600, help="no new mutant after this long, per package")
    parser.add_argument("--seed", default="32")
    parser.add_argument("--omit-tests", action="append", default=[], help="a test file left out (the 'before')")
    parser.add_argument("--named", action="store_true", help=f"the {len(NAMED)} mutations of issue 32, by hand")
    parser.add_argument("--replay", type=Path, help="run only the survivors of this earlier --json")
    parser.add_argument("--json", type=Path, help="write the results here")
    args = parser.parse_args()
    os.nice(10)  # a shared machine: the tests this starts inherit it
    if args.named:
        report: object = run_named(args)
    else:
        known = equivalents()
        report = []
        for name in args.package or list(PACKAGES):
            summary = run_package(name, PACKAGES[name], args, known)
            report.append(summary)
            print(json.dumps({k: v for k, v in summary.items() if k != "results"}), flush=True)
        print("\npackage         score   killed  survived  equivalent  run/sampled  mutants (sites)")
        for s in report:
            if "error" in s:
                print(f"{s['package']:15} error: {s['error'][:200]}")
                continue
            score = "-" if s["score"] is None else f"{s['score']:.0%}"
            print(f"{s['package']:15} {score:>5}   {s['killed']:6}  {s['survived']:8}  {s['equivalent']:10}  "
                  f"{s['run']:4}/{s['sampled']:<6}  {s['mutants']} ({s['sites']})")
        for s in report:
            for r in s.get("results", []):
                if r["verdict"] == "survived":
                    print(f"SURVIVED {r['key']}\n      -> {r['mutated']}")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
