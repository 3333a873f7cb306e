"""Run the IPIN competition's EvaalAPI server on 127.0.0.1 with trials made from GetSensorData
logs: for tests, the tools and practice.

The server is a third-party test fixture (../shared/third_party/evaalapi: the organisers'
evaalapi.py, AGPL-3.0-or-later; read its NOTICE.md and RUNNING.md): it is run as it is, from its
own folder, in a run folder of ours (its evaalapi.yaml lists our trials, trials/ holds the logs,
decompressed), and talked to over HTTP. Its Python needs the server's pinned requirements, in a
virtual environment of its own (``.ci/run`` makes ``.venv-evaalapi`` in the checkout).

    from evaal_server import LocalServer, Trial, missing
    with LocalServer(run_dir, [Trial("t01", log_path), Trial("t01off", log_path, offline=True)]) as server:
        server.url   # http://127.0.0.1:PORT/evaalapi/

As a script: ``python tools/evaal_server.py LOG... [--dir DIR] [--port 54321] [--slowdown 3]
[--slack 15] [--scoring]`` serves each log as the trials ``TRACE_online`` and ``TRACE_offline``
until it is stopped: Ctrl-C in the foreground; started in the background (``&``), the shell's
Ctrl-C never reaches it, and ``kill PID`` (SIGTERM; the banner names the PID) stops it and its
server.
"""

from __future__ import annotations

import argparse
import dataclasses
import gzip
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# where the fixture and its Python are looked for (EVAALAPI_DIR, EVAALAPI_PYTHON override them)
FIXTURE = Path(os.environ.get("EVAALAPI_DIR", REPO.parent / "shared" / "third_party" / "evaalapi"))
PYTHON = Path(os.environ.get("EVAALAPI_PYTHON", REPO / ".venv-evaalapi" / "bin" / "python"))
STARTUP_S = 30.0  # the server answers within a second or two; a shared machine may be slow


@dataclasses.dataclass(frozen=True)
class Trial:
    """One trial of the server: a log served online (V >= 1) or offline (V = 0)."""

    name: str
    log: Path  # a GetSensorData log, plain or .gz
    offline: bool = False
    slowdown: float = 3.0  # V (online); the competition's 3
    slack_s: float = 15.0  # S: online the competition's 15 s; offline the time allowed to post
    reloadable: bool = True  # a test trial; False: a scoring trial (and 423 for requests faster than real time)
    initial: str | None = None  # lon,lat,floor; None: the log's first POSI point


def missing() -> str | None:
    """Why the server cannot run here (None: it can)."""
    if not (FIXTURE / "evaalapi.py").is_file():
        return f"the EvaalAPI server is absent: {FIXTURE}/evaalapi.py (../shared must sit beside the checkout)"
    if not PYTHON.is_file():
        return (f"no Python with the EvaalAPI server's requirements: {PYTHON} (make it with `python3 -m venv "
                f".venv-evaalapi && .venv-evaalapi/bin/pip install -r {FIXTURE}/requirements.txt`, as .ci/run does)")
    check = subprocess.run([str(PYTHON), "-c", "import flask, flask_compress, parse, markdown, pygments, yaml"],
                           capture_output=True, text=True)
    if check.returncode != 0:
        return f"{PYTHON} lacks the EvaalAPI server's requirements: {check.stderr.strip().splitlines()[-1:]}"
    return None


def first_posi(log: Path) -> str:
    """``lon,lat,floor`` of a log's first POSI row (the initial position the trials here give)."""
    with _open(log) as handle:
        for line in handle:
            if line.startswith("POSI;"):
                fields = line.strip().split(";")
                return f"{fields[4]},{fields[3]},{int(fields[5])}"
    raise ValueError(f"{log}: no POSI row for the initial position")


def _open(log: Path):
    return gzip.open(log, "rt", encoding="ascii") if log.suffix == ".gz" else open(log, encoding="ascii")


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


class LocalServer:
    """The EvaalAPI server on 127.0.0.1 in ``run_dir`` with ``trials`` (a context manager)."""

    def __init__(self, run_dir: Path, trials: list[Trial], port: int | None = None) -> None:
        self.run_dir = Path(run_dir)
        self.trials = list(trials)
        self.port = port
        self.process: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/evaalapi/"

    def write_trials(self) -> None:
        """The run folder: evaalapi.yaml with the trials, trials/ with their logs as plain text (and
        without what the server wrote there for them in an earlier run)."""
        folder = self.run_dir / "trials"
        folder.mkdir(parents=True, exist_ok=True)
        entries = []
        for trial in self.trials:
            datafile = f"{trial.name}.txt"
            with _open(trial.log) as source, open(folder / datafile, "w", encoding="ascii") as target:
                shutil.copyfileobj(source, target)
            for made in (f"{trial.name}.log.xz", f"{trial.name}.est"):  # an earlier run's (a scoring trial
                (folder / made).unlink(missing_ok=True)  # with a log of its own would refuse to start)
            initial = trial.initial or first_posi(trial.log)
            entries.append(f"{trial.name}:\n    datafile: {datafile}\n    commsep: '%'\n    sepch: ';'\n"
                           f"    V: {0 if trial.offline else trial.slowdown:g}\n    S: {trial.slack_s:g}\n"
                           f"    inipos: '{initial}'\n    offline: {trial.offline}\n"
                           f"    reloadable: {trial.reloadable}\n")
        (self.run_dir / "evaalapi.yaml").write_text("\n".join(entries))

    def start(self) -> None:
        reason = missing()
        if reason is not None:
            raise RuntimeError(reason)
        self.write_trials()
        for _ in range(3):  # a port taken between the probe and the start: another one
            self.port = self.port or _free_port()
            log = open(self.run_dir / "server.log", "a")
            self.process = subprocess.Popen(
                [str(PYTHON), "-m", "flask", "--app", str(FIXTURE / "evaalapi.py"), "run", "--host", "127.0.0.1",
                 "--port", str(self.port)], cwd=self.run_dir, stdout=log, stderr=subprocess.STDOUT)
            log.close()
            if self._wait_until_up():
                return
            self.stop()
            self.port = None
        raise RuntimeError(f"the EvaalAPI server did not start: see {self.run_dir / 'server.log'}")

    def _wait_until_up(self) -> bool:
        deadline = time.monotonic() + STARTUP_S
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                return False
            try:
                with urllib.request.urlopen(f"{self.url}revision", timeout=2) as reply:
                    return reply.status == 200
            except OSError:
                time.sleep(0.2)
        return False

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.process = None

    def __enter__(self) -> LocalServer:
        self.start()
        return self

    def __exit__(self, *exc_info) -> None:
        self.stop()


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False,
                                     description="Serve GetSensorData logs as EvaalAPI trials on 127.0.0.1 "
                                                 "(TRACE_online and TRACE_offline per log) until stopped: Ctrl-C in the "
                                                 "foreground, kill PID in the background (the banner names it).")
    parser.add_argument("logs", type=Path, nargs="+", metavar="LOG")
    parser.add_argument("--dir", type=Path, default=Path("evaal_run"), help="the run folder (default: evaal_run)")
    parser.add_argument("--port", type=int, default=54321)
    parser.add_argument("--slowdown", type=float, default=3.0, help="V of the online trials (default: 3)")
    parser.add_argument("--slack", type=float, default=15.0, help="S of the online trials (default: 15 s)")
    parser.add_argument("--offline-slack", type=float, default=60.0, help="S of the offline trials (default: 60 s)")
    parser.add_argument("--scoring", action="store_true", help="non-reloadable online trials, as in the competition")
    args = parser.parse_args(argv)
    trials = []
    for log in args.logs:
        trace = log.name.removesuffix(".gz").removesuffix(".txt")
        trials.append(Trial(f"{trace}_online", log, slowdown=args.slowdown, slack_s=args.slack,
                            reloadable=not args.scoring))
        trials.append(Trial(f"{trace}_offline", log, offline=True, slack_s=args.offline_slack))
    signal.signal(signal.SIGTERM, _interrupt)  # a terminated tool stops its server too
    with LocalServer(args.dir, trials, args.port) as server:
        # in the background (`&`) the shell's Ctrl-C never reaches this process: SIGTERM does
        print(f"EvaalAPI on {server.url}: trials {', '.join(t.name for t in trials)}; stop it with Ctrl-C in the "
              f"foreground, or kill {os.getpid()} in the background", flush=True)
        try:
            server.process.wait()
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
