"""Every measured number in the docs, with the command that produced it; the quick ones re-run.

Run before a release:

    .venv/bin/python tools/docs_numbers.py                 # list: each number, its command or NO COMMAND
    .venv/bin/python tools/docs_numbers.py --run           # and re-run the quick commands' printouts
    .venv/bin/python tools/docs_numbers.py --run --all docs/ipin.md   # the long and real-data ones too

A number here is a measured one: a decimal (``4.17``, ``0.96``) or a percentage, outside code
(command blocks and inline code are not results). Each is put down to a command:

- a printout (a fenced block without a language) to the ``bash`` block before it in its section;
- a paragraph, a list or a table to the commands its section shows (its ``bash`` blocks);
- anything after ``<!-- command: CMD -->`` to CMD, until the next heading (for numbers whose
  command is elsewhere, e.g. the README's printout of its first command).

A number with none of these is listed as NO COMMAND. ``--run`` runs the ``bash`` block of each
printout in a scratch folder beside the checkout (``maps``, ``tools``, ``.venv`` linked, and
``../shared`` as the checkout sees it) and checks that every number of the printout is in what
it prints now, times of a run (``causal 0.4 s``, ``in 3.1 s``, ``12x real time``) excepted. Quick
means: the bundled example only, no real data, no ``evaluate`` or ``--jobs``, no long script;
``--all`` runs the rest too. The exit code is 1 when a re-run number changed (and, with
``--strict``, when a number has no command).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOCUMENTS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
# a measured number: a decimal, or a percentage (thousands separators allowed)
NUMBER = re.compile(r"(?<![\w.\-/])(\d{1,3}(?:,\d{3})+(?:\.\d+)?|\d+\.\d+|\d+(?:\.\d+)?(?=\s?%))(?![\w.])")
# a version, not a measurement ("ILC 2.0", "rerun-sdk 0.41", "Python 3.11")
VERSION = re.compile(r"(?:ILC|Python|numba|rerun(?:-sdk)?|[Vv]ersion|sdk|pip|setuptools)\s+v?$")
# a run's own time: it differs from run to run (the number is group 1)
RUN_TIME = re.compile(r"(?:causal|offline|in|took|runtime|after|:)\s+(\d+(?:\.\d+)?)\s?s\b|(\d+(?:\.\d+)?)x real time")
# scripts that run for minutes to hours: re-run only with --all
LONG = ("accuracy_ilc.py", "sweep_ilc.py", "floor_ilc.py", "floor_sim.py", "bench_", "hostile_inputs.py",
        "ipin_eval.py", "screenshot_rrd.py", "evaal_server.py", "live_latency.py", "docs_numbers.py")


@dataclasses.dataclass
class Number:
    document: str
    line: int
    text: str  # the number as written
    where: str  # printout | prose
    context: str  # its line
    command: str | None  # the command that produced it
    status: str = ""  # after --run: ok | CHANGED | not re-run (why)


@dataclasses.dataclass
class Printout:
    document: str
    line: int
    body: str
    command: str | None


def _strip_code(line: str) -> str:
    """A line without its inline code and link targets (no results there)."""
    line = re.sub(r"`[^`]*`", " ", line)
    return re.sub(r"\]\([^)]*\)", "]", line)


def read_document(path: Path) -> tuple[list[Number], list[Printout]]:
    """The numbers of one document, each with its command, and its printouts."""
    name = str(path.relative_to(REPO)) if path.is_relative_to(REPO) else str(path)
    lines = path.read_text().splitlines()
    numbers: list[Number] = []
    printouts: list[Printout] = []
    section_commands: list[str] = []  # the bash blocks of the current section
    named: str | None = None  # <!-- command: ... --> in force
    last_bash: str | None = None  # the section's latest bash block
    pending: list[Number] = []  # prose numbers of the section, given its first command when it comes
    i = 0

    def close_section() -> None:
        for number in pending:
            if number.command is None and section_commands:
                number.command = section_commands[0]
        pending.clear()

    while i < len(lines):
        line = lines[i]
        if line.startswith("#") and not line.startswith("#!"):
            close_section()
            section_commands, named, last_bash = [], None, None
            i += 1
            continue
        comment = re.match(r"\s*<!--\s*command:\s*(.*?)\s*-->", line)
        if comment:
            named = comment.group(1)
            i += 1
            continue
        fence = re.match(r"\s*```(\w*)\s*$", line)
        if fence:
            language, start = fence.group(1), i
            i += 1
            body = []
            while i < len(lines) and not re.match(r"\s*```\s*$", lines[i]):
                body.append(lines[i])
                i += 1
            i += 1
            text = "\n".join(body)
            if language == "bash":
                command = re.sub(r"\\\n\s*", " ", text).strip()
                section_commands.append(command)
                last_bash = command
            elif language in ("", "text", "console"):
                command = named or last_bash
                printouts.append(Printout(name, start + 1, text, command))
                for k, body_line in enumerate(body):
                    for match in NUMBER.finditer(body_line):
                        numbers.append(Number(name, start + 2 + k, match.group(1), "printout", body_line.strip(),
                                              command))
            continue
        prose = _strip_code(line)
        for match in NUMBER.finditer(prose):
            if VERSION.search(prose[:match.start()]):
                continue
            number = Number(name, i + 1, match.group(1), "prose", line.strip(), named)
            numbers.append(number)
            if named is None:
                pending.append(number)
        i += 1
    close_section()
    return numbers, printouts


def is_quick(command: str) -> bool:
    """Whether a command block runs in seconds on the bundled example alone."""
    return not (re.search(r"\.\./shared/data|\bsite1/|venue\.|\bevaluate\b|--jobs|pip install|pytest|\bgit\b", command)
                or any(script in command for script in LONG))


def run_block(command: str, timeout_s: float) -> str:
    """What a bash block prints (stdout and stderr), run in a scratch folder beside the checkout."""
    scratch = Path(tempfile.mkdtemp(prefix="docs-numbers-", dir=REPO.parent if os.access(REPO.parent, os.W_OK)
                                    else None))
    try:
        work = scratch / "mapfilter"
        work.mkdir()
        for name in ("maps", "tools", ".venv", "mapfilter"):
            if (REPO / name).exists():
                (work / name).symlink_to(REPO / name)
        if (REPO.parent / "shared").exists() and not (scratch / "shared").exists():
            (scratch / "shared").symlink_to(REPO.parent / "shared")
        env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
        done = subprocess.run(["bash", "-c", command], cwd=work, env=env, capture_output=True, text=True,
                              timeout=timeout_s)
        return done.stdout + done.stderr
    except subprocess.TimeoutExpired as exc:
        return f"(timed out after {timeout_s:g} s) " + (exc.stdout or b"").decode(errors="replace")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def check_printout(printout: Printout, numbers: list[Number], output: str) -> None:
    """Mark the printout's numbers ok or CHANGED against what its command prints now."""
    now = {match.group(1) for match in NUMBER.finditer(output)}
    for number in numbers:
        if number.document != printout.document or number.where != "printout" or not (
                printout.line < number.line <= printout.line + printout.body.count("\n") + 1):
            continue
        times = {m.group(1) or m.group(2) for m in RUN_TIME.finditer(number.context)}
        if number.text in times:
            number.status = "not compared (a run's time)"
        elif number.text in now:
            number.status = "ok"
        else:
            number.status = "CHANGED"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("documents", nargs="*", type=Path, help="markdown files (default: README.md and docs/*.md)")
    parser.add_argument("--run", action="store_true", help="re-run the quick commands' printouts and compare")
    parser.add_argument("--all", action="store_true", help="with --run: the long and real-data commands too")
    parser.add_argument("--strict", action="store_true", help="exit 1 when a number has no command")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per command block (default 600)")
    args = parser.parse_args(argv)
    numbers: list[Number] = []
    printouts: list[Printout] = []
    for path in [p.resolve() for p in args.documents] or DOCUMENTS:
        found, shown = read_document(path)
        numbers += found
        printouts += shown
    if args.run:
        for printout in printouts:
            mine = [n for n in numbers if n.document == printout.document and n.where == "printout"
                    and printout.line < n.line <= printout.line + printout.body.count("\n") + 1]
            if not mine:
                continue
            if printout.command is None:
                continue
            if not (args.all or is_quick(printout.command)):
                for number in mine:
                    number.status = "not re-run (long or real data: --all)"
                continue
            print(f"running {printout.document}:{printout.line}: {printout.command.splitlines()[0][:100]}",
                  file=sys.stderr, flush=True)
            check_printout(printout, numbers, run_block(printout.command, args.timeout))
    for number in numbers:
        command = number.command.splitlines()[0][:70] if number.command else "NO COMMAND"
        status = f"  [{number.status}]" if number.status else ""
        print(f"{number.document}:{number.line}: {number.text:>10}  {command}{status}\n    {number.context[:100]}")
    without = sum(n.command is None for n in numbers)
    changed = [n for n in numbers if n.status == "CHANGED"]
    checked = sum(n.status == "ok" for n in numbers)
    print(f"{len(numbers)} numbers in {len({n.document for n in numbers})} documents: {len(numbers) - without} with "
          f"their command, {without} with NO COMMAND" + (f"; re-run: {checked} as printed, {len(changed)} CHANGED"
                                                        if args.run else ""))
    return 1 if changed or (args.strict and without) else 0


if __name__ == "__main__":
    raise SystemExit(main())
