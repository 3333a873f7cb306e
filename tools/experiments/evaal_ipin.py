"""Every IPIN 2023 log through the official EvaalAPI server, online (causal) and offline (smoothed),
beside the same walk tracked from its file (seed 0, and seed 1 for the run-to-run spread): the
table of docs/ipin.md ("Through the server").

Each walk's radio map is the other 28 walks' (leave-one-out, as `mapfilter evaluate
--leave-one-out`); 5,000 particles, seed 0. Per walk: `mapfilter track --smooth` from the file
(the causal track scored at each POSI point by its latest row, the offline one interpolated: the
evaluation's numbers), then the log as a reloadable online trial (V=3, S=15 s; the client is not
held to real time, as a test trial allows) and as an offline trial (S=60 s) on a local server
(tools/evaal_server.py), each scored from the estimates the server kept (`mapfilter score`'s rule),
and each compared with the same client over the log file (`track --evaal-out`: no server).

    .venv/bin/python tools/experiments/evaal_ipin.py --out evaal_ipin      # about 15 minutes on 2 cores
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tools"))
from evaal_server import LocalServer, Trial, missing  # noqa: E402

DATA = REPO.parent / "shared" / "data" / "ipin2023"


def main(argv: list[str] | None = None) -> int:
    from mapfilter.api import build_radio_map
    from mapfilter.cli import main as cli
    from mapfilter.config import TrackingConfig
    from mapfilter.evaal.client import EvaalClient, run_offline, run_online
    from mapfilter.evaal.protocol import read_estimates, score_against_log
    from mapfilter.evaal.replay import replay_offline, replay_online
    from mapfilter.evaluation.metrics import ipin_errors_m
    from mapfilter.evaluation.scoring import score_track
    from mapfilter.maps.building import Building
    from mapfilter.sensors.logs import read_log
    from mapfilter.pipeline.tracker import Tracker, TrackingInputs, track

    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("evaal_ipin"), help="folder for the tables")
    parser.add_argument("--particles", type=int, default=5000)
    parser.add_argument("--limit", type=int, default=None, help="the first N logs only")
    args = parser.parse_args(argv)
    reason = missing()
    if reason is not None:
        print(f"evaal_ipin: {reason}", file=sys.stderr)
        return 1
    args.out.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="evaal_ipin_"))
    venue = work / "venue.yaml"
    assert cli(["map", "import-ipin", str(DATA / "plans" / "calib_mapa_Nuremberg.cal"), "--out", str(venue),
                "--storey-height", "2.8"]) == 0
    building = Building.load(venue)
    logs = sorted((DATA / "logs").glob("*.txt.gz"))[:args.limit]
    recordings = {p: read_log(p, building=building) for p in sorted((DATA / "logs").glob("*.txt.gz"))}
    config = TrackingConfig(seed=0).override({"filter.n_particles": args.particles})
    smooth = config.override({"smooth": True})
    trials = []
    for k, log in enumerate(logs):
        trials += [Trial(f"on{k}", log), Trial(f"off{k}", log, offline=True, slack_s=60.0)]
    rows = []
    pooled: dict[str, list[np.ndarray]] = {}
    with LocalServer(work / "run", trials) as server:
        for k, log in enumerate(logs):
            rec = recordings[log]
            radio_map = build_radio_map(building, [r for p, r in recordings.items() if p != log])
            result = track(building, rec, radio_map, config=smooth)
            other_seed = track(building, rec, radio_map, config=smooth.override({"seed": 1}))
            numbers = {"walk": rec.name, "phone": rec.phone_model, "posi": int(rec.waypoint_t_s.size)}
            for name, tr, causal in (("file_causal", result.causal, True), ("file_offline", result.offline, False),
                                     ("seed1_causal", other_seed.causal, True),
                                     ("seed1_offline", other_seed.offline, False)):
                score = score_track(building, rec, tr, None, causal)
                errors = ipin_errors_m(score.errors.errors_m, score.floor_score.storeys_off)
                pooled.setdefault(name, []).append(errors)
                numbers[name] = float(np.percentile(errors, 75))
            online = run_online(EvaalClient(server.url, f"on{k}"), Tracker(building, TrackingInputs(radio_map), config=config))
            offline = run_offline(EvaalClient(server.url, f"off{k}"), Tracker(building, TrackingInputs(radio_map), config=smooth))
            for name, trial, run in (("online", f"on{k}", online), ("offline", f"off{k}", offline)):
                reply = EvaalClient(server.url, trial).estimates()
                kept_path = args.out / f"{rec.name}_{name}_server.csv"
                kept_path.write_text(reply.text)
                score = score_against_log(read_estimates(kept_path), rec)
                pooled.setdefault(name, []).append(score.competition_errors_m)
                numbers[name] = score.score_m
                numbers[f"{name}_estimates"] = len(run.estimates)
                numbers[f"{name}_wall_s"] = run.wall_s
                numbers[f"{name}_timed_out"] = run.timed_out
            # the same clients over the log file (no server): the same estimates?
            for name, run, replay in (
                    ("online", online, replay_online(Tracker(building, TrackingInputs(radio_map), config=config), log)),
                    ("offline", offline, replay_offline(Tracker(building, TrackingInputs(radio_map), config=smooth), log))):
                a, b = run.estimates, replay.estimates
                numbers[f"{name}_replay_same"] = len(a) == len(b) and all(
                    np.array_equal(getattr(a, f), getattr(b, f)) for f in ("t_s", "lon_deg", "lat_deg", "floor"))
            numbers["online_requests"] = online.requests
            numbers["online_lowest_slack_s"] = online.lowest_slack_s
            numbers["offline_time_left_s"] = offline.slack_left_s
            numbers["offline_reply"] = offline.reply
            rows.append(numbers)
            print(f"{rec.name} ({rec.phone_model}): file causal {numbers['file_causal']:.2f} m, online "
                  f"{numbers['online']:.2f} m ({online.requests} requests, {online.wall_s:.1f} s); file offline "
                  f"{numbers['file_offline']:.2f} m, offline {numbers['offline']:.2f} m ({offline.wall_s:.1f} s); "
                  f"seed 1: {numbers['seed1_causal']:.2f} / {numbers['seed1_offline']:.2f} m; replays the same: "
                  f"{numbers['online_replay_same']}, {numbers['offline_replay_same']}", flush=True)
    with open(args.out / "walks.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    summary = {name: {"ipin_score_all_points": float(np.percentile(np.concatenate(errs), 75)),
                      "mean_of_walk_scores": float(np.mean([r[name] for r in rows])),
                      "points": int(sum(e.size for e in errs))} for name, errs in pooled.items()}
    summary["online_minus_file_causal"] = _spread([r["online"] - r["file_causal"] for r in rows])
    summary["offline_minus_file_offline"] = _spread([r["offline"] - r["file_offline"] for r in rows])
    summary["seed1_minus_seed0_causal"] = _spread([r["seed1_causal"] - r["file_causal"] for r in rows])
    summary["seed1_minus_seed0_offline"] = _spread([r["seed1_offline"] - r["file_offline"] for r in rows])
    summary["replays_same"] = {name: sum(r[f"{name}_replay_same"] for r in rows) for name in ("online", "offline")}
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=1))
    return 0


def _spread(values: list[float]) -> dict[str, float]:
    v = np.array(values)
    return {"mean": float(v.mean()), "min": float(v.min()), "max": float(v.max()),
            "max_abs": float(np.abs(v).max())}


if __name__ == "__main__":
    sys.exit(main())
