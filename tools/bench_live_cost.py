"""A long live session's speed at its end against its start: does a chunk cost more the longer the run?

The bundled office walk (two minutes) is played again and again, each time 120 s later, as one
log hours long, and fed to a ``Tracker`` through a ``LogStream`` in 64 KiB pieces, as
``mapfilter track MAP -`` reads standard input. At each hour of log (and the last walk), the same
walk is also fed to a fresh tracker: the speed of a run's start, measured at the same moment, so
that the ratio does not depend on what else the machine does. Printed per checkpoint: the long
run's and the fresh run's log seconds tracked per second of the tracker's own time (reading the
log timed apart), and their ratio: 1 is flat (docs/benchmarks.md).

    .venv/bin/python tools/bench_live_cost.py --hours 4.2 --particles 1000
"""

from __future__ import annotations

import argparse
import gzip
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mapfilter.config import TrackingConfig  # noqa: E402
from mapfilter.maps.building import Building  # noqa: E402
from mapfilter.pipeline.tracker import Tracker, TrackingInputs  # noqa: E402
from mapfilter.sensors.logs import LogStream  # noqa: E402
from mapfilter.sensors.radiomap import RadioMap  # noqa: E402

WALK_S = 120  # the office walk's length: each repetition starts this much later
PIECE_BYTES = 65536  # what one read of standard input gives a live run at most


def repetition(body: list[str], k: int) -> bytes:
    """The walk's records ``k`` walks later (ILC: the first column is the time in ms, and a WiFi
    row's last column the time its access point was last seen)."""
    shift_ms = k * WALK_S * 1000
    out = []
    for line in body:
        fields = line.rstrip("\n").split("\t")
        fields[0] = str(int(fields[0]) + shift_ms)
        if fields[1] == "TYPE_WIFI":
            fields[6] = str(int(fields[6]) + shift_ms)
        out.append("\t".join(fields) + "\n")
    return "".join(out).encode()


def feed(tracker: Tracker, stream: LogStream, data: bytes) -> tuple[float, float, int]:
    """(tracker seconds, reader seconds, rows) of feeding ``data`` in pieces."""
    track_s = read_s = 0.0
    rows = 0
    for i in range(0, len(data), PIECE_BYTES):
        started = time.perf_counter()
        records = stream.feed_bytes(data[i:i + PIECE_BYTES])
        read = time.perf_counter()
        rows += len(tracker.feed(records))
        track_s += time.perf_counter() - read
        read_s += read - started
    return track_s, read_s, rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--hours", type=float, default=4.2, help="hours of log to feed (default 4.2)")
    parser.add_argument("--particles", type=int, default=1000, help="particles (default 1000)")
    args = parser.parse_args(argv)
    lines = gzip.open(REPO / "maps" / "office_walk.txt.gz", "rt").read().splitlines(True)
    header = "".join(line for line in lines if line.startswith("#")).encode()
    body = [line for line in lines if line.strip() and not line.startswith("#")]
    building = Building.load(REPO / "maps" / "office.yaml")
    radio_map = RadioMap.load(REPO / "maps" / "office_radiomap.npz")
    config = TrackingConfig(seed=0).override({"filter.n_particles": args.particles})

    def started() -> tuple[Tracker, LogStream]:
        tracker, stream = Tracker(building, TrackingInputs(radio_map), config), LogStream("the repeated office walk")
        tracker.feed(stream.feed_bytes(header))
        return tracker, stream

    long_run, long_stream = started()
    n_walks = max(2, round(args.hours * 3600 / WALK_S))
    per_hour = 3600 // WALK_S
    print(f"{n_walks} walks of {WALK_S} s ({n_walks * WALK_S / 3600:.1f} h), {args.particles} particles, "
          f"{PIECE_BYTES // 1024} KiB pieces", flush=True)
    feed(*started(), repetition(body, 0))  # numba's kernels loaded before any timing
    ratios = []
    total_track_s = total_read_s = 0.0
    for k in range(n_walks):
        data = repetition(body, k)
        track_s, read_s, rows = feed(long_run, long_stream, data)
        total_track_s, total_read_s = total_track_s + track_s, total_read_s + read_s
        if k in (1, n_walks - 1) or (k + 1) % per_hour == 0:
            fresh_s, _, fresh_rows = feed(*started(), data)
            ratios.append(fresh_s / track_s)
            print(f"walk {k + 1:4d} (log {(k + 1) * WALK_S / 3600:4.2f} h, {len(long_run.stream.rows)} rows so far): "
                  f"the long run {WALK_S / track_s:5.0f}x real time ({rows / track_s:5.0f} rows/s), a fresh run on the "
                  f"same walk {WALK_S / fresh_s:5.0f}x ({fresh_rows / fresh_s:5.0f} rows/s): "
                  f"{fresh_s / track_s:.2f} of a fresh run's speed", flush=True)
    print(f"whole run: tracker {n_walks * WALK_S / total_track_s:.0f}x real time, reader "
          f"{n_walks * WALK_S / total_read_s:.0f}x; the long run's speed against a fresh run's: "
          f"{ratios[0]:.2f} after the second walk, {ratios[-1]:.2f} after the last")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
