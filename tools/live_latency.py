"""How soon a live run prints its first estimate: ``mapfilter track MAP -`` fed a log at its own pace.

The log's lines are written to the command's standard input when their time comes (the log's
own timestamps, from its first record; ``--speed`` to replay faster), and each CSV row it
prints is stamped when it arrives. Printed: the time from writing the line that completes the
first usable scan (the scan's last row, and the first record after it, which tells the reader the
scan is complete) to the first estimate, and the same for every row (the lag of each estimate
behind the record that completed it).

    .venv/bin/python tools/live_latency.py maps/office.yaml maps/office_walk.txt.gz --radiomap maps/office_radiomap.npz
"""

from __future__ import annotations

import argparse
import gzip
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def _line_time_s(line: str) -> float | None:
    """The record time of an ILC (ms, first column) or GetSensorData (s, second column) line."""
    if not line.strip() or line[0] in "#%":
        return None
    try:
        if "\t" in line:
            return float(line.split("\t", 1)[0]) / 1000.0
        return float(line.split(";")[1])
    except (ValueError, IndexError):
        return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("map")
    parser.add_argument("log", type=Path)
    parser.add_argument("--radiomap")
    parser.add_argument("--speed", type=float, default=1.0, help="replay this many times faster than real time")
    parser.add_argument("--seconds", type=float, default=20.0, help="stop after this much of the log")
    args = parser.parse_args(argv)

    opener = gzip.open if args.log.suffix == ".gz" else open
    with opener(args.log, "rt", errors="replace") as handle:
        lines = handle.readlines()
    times = [_line_time_s(line) for line in lines]
    first = next(t for t in times if t is not None)
    command = [sys.executable, "-m", "mapfilter", "track", args.map, "-"]
    if args.radiomap:
        command += ["--radiomap", args.radiomap]
    started = time.perf_counter()
    process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                               text=True, cwd=REPO, bufsize=1)
    rows: list[tuple[float, float]] = []  # (arrival s since start, row time in log seconds)

    def read() -> None:
        for text in process.stdout:
            if text.startswith("t_s"):
                continue
            rows.append((time.perf_counter() - started, float(text.split(",")[0]) - first))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    written: list[tuple[float, float]] = []  # (write s since start, record time in log seconds)
    for line, t in zip(lines, times):
        if t is not None:
            if t - first > args.seconds:
                break
            wait = (t - first) / args.speed - (time.perf_counter() - started)
            if wait > 0:
                time.sleep(wait)
            written.append((time.perf_counter() - started, t - first))
        process.stdin.write(line)
        process.stdin.flush()
    process.stdin.close()
    process.wait(timeout=120)
    reader.join(timeout=10)
    if not rows:
        print("no estimate printed", file=sys.stderr)
        return 1
    write_s, record_s = np.array(written).T
    lags = []
    for arrived, row_t in rows:
        # the row is complete once the first record after its time has been written
        k = int(np.searchsorted(record_s, row_t, side="right"))
        if k < len(write_s):
            lags.append(arrived - write_s[k])
    doc = {"log": str(args.log), "speed": args.speed, "rows": len(rows),
           "first_estimate_row_time_s": rows[0][1],
           "first_estimate_lag_s": lags[0] if lags else None,
           "median_lag_s": float(np.median(lags)) if lags else None,
           "max_lag_s": float(np.max(lags)) if lags else None}
    print(json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
