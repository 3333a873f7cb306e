"""Every command in the README, docs/*.md and maps/README.md runs as written.

The commands are the fenced ```bash blocks (and the README's ```python block); each document's
commands run in order, in a workspace of their own laid out as the documents assume, so that a
later command finds what an earlier one wrote. The files the documents name as placeholders
are made here:

==========================  ================================================================
``plan.png``                the bundled office's line drawing (``maps/office_plan.png``)
``rooms.png``               a filled-region plan drawn here
``floor.geojson``           a small floor in longitude/latitude drawn here
``floor.yaml``              the bundled office map (and its plan and access points): the
                            user's own map, which the later steps use; a command that makes
                            ``floor.yaml`` (the alternatives of the README's step 2) runs in
                            a scratch copy of the workspace, so that it stays the office
``walk.txt.gz``             the bundled walk
``survey/ walks/ test/``    walks simulated in the office (surveys on a 4 m grid, 60 s walks)
``beacons.csv``             eight BLE beacons in the office, which the simulated surveys hear
``labelled/ batch/ more/``  the same; ``more/`` without waypoints (walks to grow a map from)
``radiomap.npz aps.csv``    the bundled radio map and fitted access points
``building.yaml``           the bundled office stacked three times (stairs, lift), ``tools/floor_sim.py``
``site1/ venue.cal``        the real ILC site 1 and IPIN 2023 calibration (``../shared/data``)
==========================  ================================================================

``../shared/data`` beside the workspace is the checkout's; a command that needs it skips, with
the reason, when it is absent. A glob over the real logs is cut to its first few files (the
command's options and paths stay as written) so that the real-data commands take seconds, not
the documented minutes. Not run, each skipped with its reason: installing (the fresh-clone
walk-through does that), the test suite itself, opening a viewer, the long measurement
scripts and the EvaalAPI server (their options are checked against their ``--help`` instead),
and ``mapfilter evaal``, which needs a server (its arguments are parsed; a later command reading
the estimates it would write skips too). ``L=path`` sets ``$L`` for the document's later commands.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO

REAL_SHARED = REPO.parent / "shared"
DOCUMENTS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md")), REPO / "maps" / "README.md"]
LOGS_PER_GLOB = 3  # a glob over the real logs is cut to this many (plus any the command names elsewhere)
# scripts that run for minutes to hours: their options are checked against --help
LONG_SCRIPTS = {
    "accuracy_ilc.py": "every ILC set with five seeds: about 20 minutes",
    "sweep_ilc.py": "every ILC floor on three engines: tens of minutes",
    "floor_ilc.py": "every ILC walk with IMU as one building: about 5 minutes",
    "split_ilc.py": "the ILC half-floor split, both floors at 10,000 particles: about 30 minutes",
    "beyond_survey.py": "the IPIN route-out table and the ILC half-floor split: about an hour",
    "radio_region.py": "a path-loss model fitted per AP, every ILC split direction and IPIN route: about 3 minutes",
    "benchmark.py": "generated floor plans through map prepare: minutes",
    "compare_readers.py": "generated floor plans through both drawing readers: minutes",
    "reader_speed.py": "a benchmark: minutes, and its numbers are for a quiet machine",
    "train_segmenter.py": "trains a network: an hour, and needs torch (tools/plans/requirements-train.txt)",
    "floor_sim.py": "ten simulated building walks: 2-10 minutes",
    "bench_filter.py": "a benchmark: minutes, and its numbers are for a quiet machine",
    "bench_startup.py": "a benchmark: minutes (radio maps built, commands run in fresh processes)",
    "bench_command_cost.py": "a benchmark: a minute (a radio map built, commands run in fresh processes)",
    "bench_live_cost.py": "a 4.2-hour live session fed at once: tens of minutes",
    "hostile_inputs.py": "every hostile input in a subprocess: minutes",
    "ipin_eval.py": "the IPIN walk over two floors with every method: minutes",
    "screenshot_rrd.py": "it spawns a viewer (never in tests: without a display it blocks)",
    "evaal_server.py": "the EvaalAPI server: it serves until stopped; tests/evaal/test_evaal_server.py runs it",
}


@dataclasses.dataclass(frozen=True)
class Command:
    document: str  # relative to the repository
    line: int  # of the block in the document
    number: int  # the command's place in its document
    text: str
    language: str = "bash"

    @property
    def needs_real_data(self) -> bool:
        return bool(re.search(r"\.\./shared/data|\bsite1/|\bvenue\.cal\b", self.text))

    @property
    def slow(self) -> bool:
        """In the slow tier: every document's commands but the README's, and the README's on the
        real data or with ``evaluate`` or ``--jobs`` (the fast tier runs the README's quick ones)."""
        return (self.document != "README.md" or self.needs_real_data
                or bool(re.search(r"--jobs|\bevaluate\b", self.text)))

    @property
    def id(self) -> str:
        return f"{self.document}:{self.line}:{self.text.split(' #')[0][:60]}"


def document_commands(path: Path) -> list[Command]:
    """The commands of a document's ```bash blocks (continuation lines joined, comments dropped,
    ``a && b`` two commands) and its ```python blocks if it is the README."""
    text = path.read_text()
    name = str(path.relative_to(REPO))
    found: list[Command] = []
    variables: dict[str, str] = {}
    for match in re.finditer(r"^```(\w*)\n(.*?)^```", text, flags=re.S | re.M):
        language, body = match.group(1), match.group(2)
        line = text[:match.start()].count("\n") + 1
        if language == "python" and path.name == "README.md" and path.parent == REPO:
            found.append(Command(name, line, len(found), body, "python"))
        if language != "bash":
            continue
        for logical in re.sub(r"\\\n\s*", " ", body).splitlines():
            logical = re.sub(r"(^|\s)#.*$", "", logical).strip()
            for part in (p.strip() for p in logical.split(" && ")):
                assignment = re.fullmatch(r"([A-Za-z_]\w*)=(\S+)", part)
                if assignment:  # L=path: later commands get the path where they say $L, as bash gives it
                    variables[assignment.group(1)] = assignment.group(2)
                    continue
                for variable, value in variables.items():
                    part = re.sub(rf"\$(\{{{variable}\}}|{variable}\b)", lambda _, value=value: value, part)
                part = re.sub(r"\s*&$", "", part)  # started in the background: the same command
                if part:
                    found.append(Command(name, line, len(found), part))
    return found


COMMANDS = [command for path in DOCUMENTS for command in document_commands(path)]


def _param(command: Command):
    marks = [pytest.mark.slow] if command.slow else []
    if command.needs_real_data:
        marks.append(pytest.mark.real_data)
    return pytest.param(command, marks=marks, id=command.id)


def test_every_command_block_is_marked_bash():
    """A block holding commands must be ```bash, or the test above would not see it."""
    for path in DOCUMENTS:
        text = path.read_text()
        for match in re.finditer(r"^```(\w*)\n(.*?)^```", text, flags=re.S | re.M):
            if match.group(1) in ("bash", "python"):
                continue
            for line in match.group(2).splitlines():
                assert not re.match(r"\s*(\$ )?(mapfilter |\.venv/bin/|python3? tools/)", line), (
                    f"{path.name}:{text[:match.start()].count(chr(10)) + 1}: a command outside a ```bash block: {line}")


def test_the_documents_hold_commands():
    documents = {c.document for c in COMMANDS}
    assert {"README.md", "docs/self-training.md", "docs/visualisation.md", "docs/building.md"} <= documents
    assert sum(c.document == "README.md" for c in COMMANDS) >= 20


@pytest.mark.parametrize("command", [_param(c) for c in COMMANDS])
def test_documented_command_runs_as_written(command, docs_runner):
    status, message = docs_runner.outcome(command)
    if status == "skip":
        pytest.skip(message)
    assert status == "ok", message


# ---- the workspace ------------------------------------------------------------------------------
# the placeholder beacons.csv: eight beacons on the office's free space (x, y in metres)
OFFICE_BEACONS_XY = ((5.0, 5.0), (19.0, 4.0), (33.0, 6.0), (4.0, 19.0), (34.0, 20.0), (6.0, 33.0), (19.0, 34.0),
                     (32.0, 32.0))


def _beacon_rows(walk, rng) -> str:
    """TYPE_BEACON rows for a simulated walk: each office beacon heard once a second, its RSSI
    the path-loss model's at the walker's position (C -62 dBm, n 2.1) plus 4 dB of noise."""
    import numpy as np

    from mapfilter.sensors.beacons import beacon_rssi_dbm

    rows = []
    for i, xy in enumerate(OFFICE_BEACONS_XY):
        t_s = np.arange(walk.start_t_s + rng.uniform(0.0, 1.0), walk.end_t_s, 1.0)
        distance_m = np.linalg.norm(walk.position_at(t_s) - np.array(xy), axis=1)
        rssi = np.round(beacon_rssi_dbm(distance_m, -62.0, 2.1) + 4.0 * rng.standard_normal(t_s.size))
        for ms, value in zip(np.round(t_s * 1000).astype(np.int64), rssi):
            rows.append((ms, f"{ms}\tTYPE_BEACON\tfda50693\t1\t{i + 1}\t-59\t{int(value)}\t1.0"
                             f"\t00:AB:CD:EF:01:0{i}\t{ms}\n"))
    return "".join(row for _, row in sorted(rows))


def _simulate(plan, aps, path: Path, seed: int, survey: bool = False, waypoints: bool = True) -> None:
    import gzip

    import numpy as np

    from mapfilter.simulate.ilc_writer import write_ilc
    from mapfilter.simulate.walk import SimConfig, simulate_walk

    config = SimConfig(duration_s=None if survey else 60.0, survey=survey, survey_spacing_m=4.0,
                       survey_scans_per_point=1)
    path.parent.mkdir(parents=True, exist_ok=True)
    walk = simulate_walk(plan, aps, config, np.random.default_rng(seed))
    write_ilc(walk, path)
    if survey:  # the surveys hear the beacons of beacons.csv (their rows after the others: readers sort)
        text = gzip.decompress(path.read_bytes()).decode() + _beacon_rows(walk, np.random.default_rng([seed, 1]))
        path.write_bytes(gzip.compress(text.encode(), mtime=0))
    if not waypoints:
        lines = gzip.decompress(path.read_bytes()).decode().splitlines(keepends=True)
        path.write_bytes(gzip.compress("".join(l for l in lines if "\tTYPE_WAYPOINT\t" not in l).encode(), mtime=0))


def _regions_plan(path: Path) -> None:
    """A filled-region plan, 0.05 m/px: a building (dark outline) with filled rooms along a
    transparent corridor, transparent outside."""
    import cv2
    import numpy as np

    image = np.zeros((400, 600, 4), dtype=np.uint8)
    cv2.rectangle(image, (20, 20), (579, 379), (80, 80, 80, 255), 4)
    for x0 in (40, 200, 360):
        image[40:170, x0:x0 + 140] = (245, 235, 195, 255)
        image[230:360, x0:x0 + 140] = (180, 240, 250, 255)
    cv2.imwrite(str(path), image)


def _geojson_floor(path: Path) -> None:
    """A 30 m x 20 m floor with two obstacles, in longitude/latitude (the ILC convention)."""
    lat0, lon0 = 48.0, 11.0
    k = math.cos(math.radians(lat0))

    def lonlat(x_m: float, y_m: float) -> list[float]:
        r = 6378137.0 * k
        y0 = math.log(math.tan(math.pi / 4 + math.radians(lat0) / 2))
        return [lon0 + math.degrees(x_m / r), math.degrees(2 * math.atan(math.exp(y0 + y_m / r)) - math.pi / 2)]

    def polygon(x0, y0, x1, y1):
        return {"type": "Polygon", "coordinates": [[lonlat(x0, y0), lonlat(x1, y0), lonlat(x1, y1), lonlat(x0, y1),
                                                    lonlat(x0, y0)]]}

    features = [{"type": "Feature", "properties": {"type": "floor"}, "geometry": polygon(0, 0, 30, 20)},
                {"type": "Feature", "properties": {}, "geometry": polygon(5, 5, 12, 15)},
                {"type": "Feature", "properties": {}, "geometry": polygon(18, 5, 25, 15)}]
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))


@pytest.fixture(scope="session")
def docs_workspace(tmp_path_factory) -> Path:
    """The files every document's commands start from (copied per document)."""
    import yaml

    from mapfilter.maps.floorplan import FloorPlan
    from mapfilter.sensors.pathloss import AccessPointTable

    base = tmp_path_factory.mktemp("docs") / "workspace"
    base.mkdir()
    shutil.copytree(REPO / "maps", base / "maps")
    (base / "tools").symlink_to(REPO / "tools")
    for name in ("office.png", "office_plan.png", "office_aps.csv"):
        shutil.copy(REPO / "maps" / name, base / name)
    shutil.copy(REPO / "maps" / "office.yaml", base / "floor.yaml")
    shutil.copy(REPO / "maps" / "office_plan.png", base / "plan.png")
    _regions_plan(base / "rooms.png")
    _geojson_floor(base / "floor.geojson")
    shutil.copy(REPO / "maps" / "office_walk.txt.gz", base / "walk.txt.gz")
    shutil.copy(REPO / "maps" / "office_radiomap.npz", base / "radiomap.npz")
    shutil.copy(REPO / "maps" / "office_fitted_aps.csv", base / "aps.csv")
    (base / "beacons.csv").write_text("beacon_id,x,y\n" + "".join(
        f"00:AB:CD:EF:01:0{i},{x},{y}\n" for i, (x, y) in enumerate(OFFICE_BEACONS_XY)))
    plan = FloorPlan.load(REPO / "maps" / "office.yaml")
    aps = AccessPointTable.read_csv(REPO / "maps" / "office_aps.csv")
    for i in (1, 2):
        _simulate(plan, aps, base / "survey" / f"survey_{i}.txt.gz", i, survey=True)
    for folder, seeds in (("walks", (11, 12)), ("test", (21, 22)), ("labelled", (31, 32, 33)), ("batch", (41, 42))):
        for seed in seeds:
            _simulate(plan, aps, base / folder / f"{folder}_{seed}.txt.gz", seed)
    for seed in (51, 52):
        _simulate(plan, aps, base / "more" / f"more_{seed}.txt.gz", seed, waypoints=False)
    sys.path.insert(0, str(REPO / "tools"))
    from floor_sim import make_office_building_with_ap_files

    (base / "office3").mkdir()
    make_office_building_with_ap_files(base / "office3")
    meta = yaml.safe_load((base / "office3" / "building.yaml").read_text())
    for floor in meta["floors"]:
        floor["map"] = f"office3/{floor['map']}"
    (base / "building.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    # the real data, through ../shared as the documents name it
    (base / "site1").symlink_to(Path("..") / "shared" / "data" / "ilc20" / "site1")
    venue = Path("..") / "shared" / "data" / "ipin2023" / "plans"
    (base / "venue.cal").symlink_to(venue / "calib_mapa_Nuremberg.cal")
    (base / "Map_Floor_-01.png").symlink_to(venue / "Map_Floor_-01.png")
    return base


class DocsRunner:
    """Runs each document's commands once, in order, in its own copy of the workspace."""

    def __init__(self, workspace: Path, root: Path, selected: set[Command]) -> None:
        self.workspace, self.root, self.selected = workspace, root, selected
        self.outcomes: dict[Command, tuple[str, str]] = {}
        self.done: set[str] = set()
        self.not_made: set[Path] = set()  # what a command not run would have written

    def outcome(self, command: Command) -> tuple[str, str]:
        if command.document not in self.done:
            self.done.add(command.document)
            self._run_document(command.document)
        return self.outcomes[command]

    def _run_document(self, document: str) -> None:
        where = self.root / document.replace("/", "_")
        shutil.copytree(self.workspace, where / "repo", symlinks=True)
        if REAL_SHARED.is_dir():
            (where / "shared").symlink_to(REAL_SHARED)
        cwd = where / "repo"
        for command in (c for c in COMMANDS if c.document == document):
            if command not in self.selected:
                continue  # deselected (-m, -k): its files are not made either
            try:
                self.outcomes[command] = self._run(command, cwd)
            except Exception as exc:  # noqa: BLE001 - a crash is this command's failure, not the next one's
                self.outcomes[command] = ("fail", f"{command.text}: {type(exc).__name__}: {exc}")

    def _run(self, command: Command, cwd: Path) -> tuple[str, str]:
        if command.needs_real_data and not (REAL_SHARED / "data").is_dir():
            return "skip", (f"needs the real data in {REAL_SHARED / 'data'}, absent (get it with `python3 "
                            "tools/get_data.py`, docs/data.md)")
        if command.language == "python":
            with _in(cwd):
                exec(compile(command.text, command.document, "exec"), {})
            return "ok", ""
        text, redirect = (command.text.split(" > ", 1) + [None])[:2]
        words = shlex.split(text)
        program = words[0]
        if words[1:2] == ["tools/get_data.py"] and "--verify" not in words:
            return "skip", "downloads or writes the real data: tests/test_get_data.py lays it out from local copies"
        if program.endswith("/bin/pip") or words[:3] in (["python3", "-m", "venv"], [".venv/bin/python", "-m", "pytest"]):
            return "skip", "installing and the test suite: the fresh-clone walk-through runs these"
        if program == "apt-get":
            return "skip", "installs a system package"
        if program == "rerun":
            recording = cwd / words[1]
            assert recording.is_file() and recording.stat().st_size > 0, f"{recording} was not written"
            return "skip", f"{words[1]} was written; opening it starts a viewer (never in tests)"
        if "--out floor.yaml" in text:  # another map as floor.yaml: the later steps keep the office
            cwd = cwd.parent / "scratch"
            if not cwd.exists():
                shutil.copytree(self.workspace, cwd, symlinks=True)
        if " | " in text:  # a log piped into a live run: as bash runs it, with this mapfilter first on PATH
            env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
            result = subprocess.run(["bash", "-o", "pipefail", "-c", text], cwd=cwd, capture_output=True, text=True,
                                    timeout=600, env=env)
            assert result.returncode == 0, f"{command.text}: exit {result.returncode}: {result.stderr[-2000:]}"
            assert result.stdout.strip(), f"{command.text}: printed nothing"
            return "ok", ""
        argv = _expand(text, cwd)[1:]
        if program.endswith(("python", "python3")):
            return self._script(argv, cwd, command)
        assert program in ("mapfilter", ".venv/bin/mapfilter"), f"unknown program {program}"
        unmade = [word for word in argv if (cwd / word).resolve() in self.not_made]
        if unmade:
            return "skip", f"reads {unmade[0]}, which a `mapfilter evaal` above writes (not run: it needs a server)"
        if argv[:1] == ["evaal"]:
            return self._evaal(argv, cwd)
        return _mapfilter(_cut_real_logs(argv, cwd), cwd, None if redirect is None else cwd / redirect.strip())

    def _evaal(self, argv: list[str], cwd: Path) -> tuple[str, str]:
        """``mapfilter evaal`` enters a trial on an EvaalAPI server (the competition's, or one the
        document starts): its arguments are parsed as written, and what it would write is noted."""
        from mapfilter.cli import build_parser
        from mapfilter.cli.evaal_cmd import default_out

        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            try:
                args = build_parser().parse_args(argv)
            except SystemExit as exc:
                raise AssertionError(f"mapfilter {' '.join(argv)}: exit {exc.code}: {err.getvalue()[-2000:]}") from None
        self.not_made.add((cwd / (args.out if args.out is not None else default_out(args.trial))).resolve())
        return "skip", ("enters a trial on an EvaalAPI server: its arguments parse (tests/evaal/test_evaal_server.py "
                        "enters trials on a local server)")

    def _script(self, argv: list[str], cwd: Path, command: Command) -> tuple[str, str]:
        script = Path(argv[0]).name
        if script in LONG_SCRIPTS:
            result = subprocess.run([sys.executable, argv[0], "--help"], cwd=cwd, capture_output=True, text=True,
                                    timeout=120)
            assert result.returncode == 0, result.stderr
            unknown = [a.split("=")[0] for a in argv[1:] if a.startswith("--") and a.split("=")[0] not in result.stdout]
            assert not unknown, f"{script} has no option {', '.join(unknown)}"
            return "skip", f"not run ({LONG_SCRIPTS[script]}); its options are those of its --help"
        result = subprocess.run([sys.executable, *argv], cwd=cwd, capture_output=True, text=True, timeout=600)
        assert result.returncode == 0, f"{command.text}: exit {result.returncode}: {result.stderr[-2000:]}"
        return "ok", ""


@contextlib.contextmanager
def _in(cwd: Path):
    old = os.getcwd()
    os.chdir(cwd)
    try:
        yield
    finally:
        os.chdir(old)


def _expand(text: str, cwd: Path) -> list[str]:
    """The words of a command line as bash makes them (globs, quotes, ``$(...)``)."""
    result = subprocess.run(["bash", "-c", f"printf '%s\\0' {text}"], cwd=cwd, capture_output=True, text=True,
                            check=True, timeout=60)
    return result.stdout.split("\0")[:-1]


def _cut_real_logs(argv: list[str], cwd: Path) -> list[str]:
    """Each run of consecutive real logs cut to its first ``LOGS_PER_GLOB`` (keeping any log the
    command names elsewhere, e.g. in ``--exclude``)."""
    real = (REAL_SHARED / "data").resolve()

    def is_real_log(word: str) -> bool:
        path = (cwd / word).resolve() if not os.path.isabs(word) else Path(word).resolve()
        return word.endswith((".txt", ".txt.gz")) and path.is_relative_to(real)

    out, run = [], []
    for word in [*argv, ""]:
        if word and is_real_log(word):
            run.append(word)
            continue
        if run:
            named = [w for w in run if any(Path(w).name.split(".")[0] in other for other in argv if other not in run)]
            first = run[:LOGS_PER_GLOB]
            if "--leave-out" in argv and "route" in argv:  # a route left out needs other routes to survey it
                first = list({_route(w): w for w in reversed(run)}.values())[::-1][:LOGS_PER_GLOB]
            out += [w for w in run if w in first or w in named]
            run = []
        if word:
            out.append(word)
    return out


def _route(log: str) -> str:
    """An IPIN training log's trial (its route), else the log itself."""
    from mapfilter.evaluation.groups import IPIN_TRIAL

    match = IPIN_TRIAL.search(Path(log).name)
    return match.group(1) if match else log


def _mapfilter(argv: list[str], cwd: Path, redirect: Path | None) -> tuple[str, str]:
    from mapfilter.cli import main

    out, err = io.StringIO(), io.StringIO()
    with _in(cwd), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse: a usage error
            code = exc.code
    if redirect is not None:
        redirect.write_text(out.getvalue())
    assert code == 0, f"mapfilter {' '.join(argv)}: exit {code}: {err.getvalue()[-2000:]}"
    return "ok", ""


@pytest.fixture(scope="session")
def docs_runner(request, docs_workspace, tmp_path_factory) -> DocsRunner:
    selected = {item.callspec.params["command"] for item in request.session.items
                if getattr(item, "callspec", None) and isinstance(item.callspec.params.get("command"), Command)}
    return DocsRunner(docs_workspace, tmp_path_factory.mktemp("docs_runs"), selected)


def test_cutting_real_logs_keeps_options_and_named_logs(tmp_path):
    data = REAL_SHARED / "data"
    if not data.is_dir():
        pytest.skip(f"needs {data}")
    logs = sorted(str(p) for p in (data / "ilc20" / "site1" / "F1" / "path_data_files").glob("*.txt.gz"))
    named = Path(logs[10]).name.split(".")[0]
    argv = ["radiomap", "build", "F1.yaml", *logs, "--exclude", named, "--out", "rm.npz"]
    cut = _cut_real_logs(argv, tmp_path)
    assert cut[:3] == argv[:3] and cut[-4:] == argv[-4:]
    assert cut[3:-4] == logs[:LOGS_PER_GLOB] + [logs[10]]
    # a route left out: the first log of each of the first routes
    ipin = sorted(str(p) for p in (data / "ipin2023" / "logs").glob("*.txt.gz"))
    cut = _cut_real_logs(["evaluate", "venue.yaml", *ipin, "--leave-out", "route", "--out", "x"], tmp_path)
    assert [Path(w).name[:40] for w in cut[2:-4]] == [f"IPIN2023_T3_TrainingTrial{t}_repetition01"
                                                       for t in ("01", "02", "03")]
