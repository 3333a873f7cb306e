"""Floors from WiFi: a building's radio map with floor labels, a per-scan floor vote, an HMM.

- :func:`build_building_radio_map` makes one radio map of survey logs of several floors, each
  scan's floor taken from its waypoints where they name floors (a walk that changes floor), else
  from the log's header (``FloorName``); every reference point keeps its floor and its position
  in that floor's frame.
- :func:`load_building_radio_map` reads such a radio map and refuses one whose floors are not a
  building's (:func:`check_building_radio_map`).
- :func:`floor_vote_log_likelihood` weighs each floor for each scan: the k nearest reference
  points in signal space over *all* floors (the KWNN distance of Chang et al.) vote, and a
  floor's likelihood is its share of the votes, softened by a pseudo-count so one scan can
  never rule a floor out (the Lund thesis detects the floor from the summed RSSI per floor;
  nearest neighbours use the same fingerprints without a per-floor AP model).
- :func:`floor_hmm` smooths those per-scan likelihoods over the walk with a hidden Markov
  model whose floor changes are rare (a rate per second): forward probabilities (causal)
  and the Viterbi path (the whole walk).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.sensors.radiomap import RadioMap, _distances_to_references, build_radio_map
from mapfilter.sensors.recording import Recording

# k = 4 as for the KWNN fixes (Chang et al.), and a pseudo-count of one vote per floor: a
# unanimous scan weighs its floor (4 + 1) / 1 = 5 times (1.6 nats) above a floor with no vote,
# so a few scans decide and one odd scan cannot outvote a walk (docs/accuracy.md).
DEFAULT_VOTE_K = 4
DEFAULT_VOTE_PSEUDO_COUNT = 1.0
# A floor change every 10 minutes or so at most: walkers ride a lift or stairs rarely
DEFAULT_FLOOR_CHANGE_RATE_PER_S = 1.0 / 600.0


def build_building_radio_map(recordings: Sequence[Recording], floor_of_recording: Sequence[int | None],
                             floor_names: Sequence[str], use_steps: bool = False) -> RadioMap:
    """One radio map of a building: the points of every survey log, each labelled with its floor.

    A log whose waypoints name their floors (``Recording.waypoint_floor``: GetSensorData POSI
    rows, simulated walks) labels each scan by the floor of its waypoint interval: a scan
    between two waypoints of one floor is on that floor, and a scan between waypoints of two
    floors (the walker on the stairs or in the lift) is left out, its floor and position
    unknown. Any other log is on ``floor_of_recording[i]``, the index (into ``floor_names``) of
    its floor (from its header, see ``maps.building.Building.floor_of_log``; None only for a
    log with waypoint floors). Positions stay in each floor's frame.
    """
    if len(recordings) != len(floor_of_recording):
        raise ValueError("one floor per recording")
    radio_map = build_radio_map(recordings, None, use_steps=use_steps)
    point_floor = np.full(len(radio_map), -1, dtype=np.int64)
    for trace, (rec, floor) in enumerate(zip(recordings, floor_of_recording)):
        mine = np.flatnonzero(radio_map.trace == trace)
        if rec.waypoint_floor is not None and len(rec.waypoint_floor) == rec.waypoint_t_s.size:
            point_floor[mine] = _interval_floors(rec, radio_map.t_s[mine], floor_names)
        elif floor is None:
            raise MapfilterError("the log names no floor for its points: it cannot survey a building", rec.path)
        else:
            point_floor[mine] = int(floor)
    keep = point_floor >= 0
    labelled = RadioMap(radio_map.xy_m[keep], radio_map.ap_keys, radio_map.rssi_dbm[keep], radio_map.t_s[keep],
                        radio_map.trace[keep], radio_map.source_traces, None, point_floor[keep], list(floor_names))
    labelled._floor_cv_errors = None  # computed (per floor) when saved
    return labelled


def _interval_floors(recording: Recording, t_s: np.ndarray, floor_names: Sequence[str]) -> np.ndarray:
    """(P,) the floor index of each time between two of the log's waypoints when both are on one
    floor, else -1 (between two floors; a floor the building lacks is refused)."""
    index = {name: i for i, name in enumerate(floor_names)}
    unknown = sorted({f for f in recording.waypoint_floor if f not in index})
    if unknown:
        raise MapfilterError(f"the log's waypoints are on floor {unknown[0]!r}, which the building does not have "
                             f"(floors: {', '.join(floor_names)})", recording.path)
    wp_floor = np.array([index[f] for f in recording.waypoint_floor], dtype=np.int64)
    wp_t = recording.waypoint_t_s
    # the interval (k, k + 1) holding each time; a time on the last waypoint is in the last interval
    k = np.clip(np.searchsorted(wp_t, t_s, side="right") - 1, 0, max(wp_t.size - 2, 0))
    after = np.minimum(k + 1, wp_t.size - 1)
    return np.where(wp_floor[k] == wp_floor[after], wp_floor[k], -1)


def load_building_radio_map(path, floor_names: Sequence[str]) -> RadioMap:
    """A building's radio map from ``path``, refused (``MapfilterError`` naming the file) when it
    has no floor labels or its floors are not ``floor_names``, in that order."""
    radio_map = RadioMap.load(path)
    check_building_radio_map(radio_map, floor_names, path)
    return radio_map


def check_building_radio_map(radio_map: RadioMap, floor_names: Sequence[str], path=None) -> None:
    """Refuse (``MapfilterError``, naming ``path`` if given) a radio map without floor labels or
    whose floors are not ``floor_names``, in that order."""
    if not radio_map.has_floors:
        raise MapfilterError("not a building's radio map (no floor labels): build it with mapfilter radiomap "
                             "build BUILDING.yaml LOGS...", path)
    if list(radio_map.floor_names) != list(floor_names):
        raise MapfilterError(f"the radio map's floors ({', '.join(radio_map.floor_names)}) are not the "
                             f"building's ({', '.join(floor_names)})", path)


def floor_vote_log_likelihood(radio_map: RadioMap, scan_rssi_dbm: np.ndarray, k: int = DEFAULT_VOTE_K,
                              pseudo_count: float = DEFAULT_VOTE_PSEUDO_COUNT,
                              min_shared_aps: int = 3,
                              distances: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(S, F) log-likelihood of each floor for each scan (an (S, K) matrix over the map's APs).

    The k nearest reference points (signal distance, p = 2, missing AP = -100 dBm, at least
    ``min_shared_aps`` shared APs) vote for their floors with weight 1 each; the likelihood of
    floor f is ``(votes_f + pseudo_count) / (k + F * pseudo_count)``. A scan with no candidate
    says nothing (a row of equal values). ``distances``: the scans' ``radiomap.plain_signal_distances``
    if the caller has them already.
    """
    if not radio_map.has_floors:
        raise MapfilterError("the radio map has no floor labels: build it from a building (mapfilter radiomap "
                             "build BUILDING.yaml LOGS...)")
    n_floors = len(radio_map.floor_names)
    scans = np.ascontiguousarray(scan_rssi_dbm, dtype=np.float64)
    out = np.full((scans.shape[0], n_floors), -math.log(n_floors))
    if scans.shape[0] == 0 or len(radio_map) == 0:
        return out
    dist, shared = distances if distances is not None else _distances_to_references(radio_map, scans, 2.0, -100.0)
    dist = np.where(shared >= min_shared_aps, dist, np.inf)
    kk = min(k, dist.shape[1])
    nearest = np.argpartition(dist, kk - 1, axis=1)[:, :kk]
    for s in range(scans.shape[0]):
        ok = np.isfinite(dist[s, nearest[s]])
        if not ok.any():
            continue
        votes = np.bincount(radio_map.floor[nearest[s][ok]], minlength=n_floors).astype(np.float64)
        out[s] = np.log(votes + pseudo_count) - math.log(votes.sum() + n_floors * pseudo_count)
    return out


@dataclasses.dataclass
class FloorPath:
    """What the HMM says about a walk's floors, one row per scan."""

    t_s: np.ndarray  # (S,) scan times
    forward: np.ndarray  # (S, F) P(floor | scans so far): causal
    path: np.ndarray  # (S,) int64 Viterbi floor sequence: the whole walk

    def causal_floor(self) -> np.ndarray:
        """(S,) the most probable floor given the scans so far."""
        return np.argmax(self.forward, axis=1)


def floor_hmm(log_likelihood: np.ndarray, t_s: np.ndarray,
              change_rate_per_s: float = DEFAULT_FLOOR_CHANGE_RATE_PER_S,
              prior: np.ndarray | None = None) -> FloorPath:
    """Forward filter and Viterbi path of a floor HMM over per-scan floor log-likelihoods.

    Between scans ``dt`` seconds apart, the walker leaves the floor with probability
    ``1 - exp(-rate dt)``, to any other floor alike (without connectors and elevations every
    floor is as reachable; a building with stairs only between neighbours could weigh them).
    """
    ll = np.asarray(log_likelihood, dtype=np.float64)
    times = np.asarray(t_s, dtype=np.float64)
    n_scans, n_floors = ll.shape
    if n_scans == 0:
        return FloorPath(times, np.zeros((0, n_floors)), np.zeros(0, np.int64))
    log_prior = np.log(prior) if prior is not None else np.full(n_floors, -math.log(n_floors))
    forward = np.empty_like(ll)
    delta = np.empty_like(ll)
    back = np.zeros((n_scans, n_floors), dtype=np.int64)
    log_alpha = log_prior + ll[0]
    delta[0] = log_alpha
    forward[0] = _normalised(log_alpha)
    for s in range(1, n_scans):
        log_trans = _log_transition(n_floors, max(times[s] - times[s - 1], 0.0), change_rate_per_s)
        log_alpha = _logsumexp_rows(log_alpha[:, None] + log_trans) + ll[s]
        forward[s] = _normalised(log_alpha)
        log_alpha = np.log(np.maximum(forward[s], 1e-300))  # keep it from drifting to -inf
        scores = delta[s - 1][:, None] + log_trans
        back[s] = np.argmax(scores, axis=0)
        delta[s] = scores[back[s], np.arange(n_floors)] + ll[s]
    path = np.empty(n_scans, dtype=np.int64)
    path[-1] = int(np.argmax(delta[-1]))
    for s in range(n_scans - 1, 0, -1):
        path[s - 1] = back[s, path[s]]
    return FloorPath(times, forward, path)


def _log_transition(n_floors: int, dt_s: float, rate_per_s: float) -> np.ndarray:
    if n_floors == 1:
        return np.zeros((1, 1))
    leave = -math.expm1(-rate_per_s * dt_s)
    leave = min(max(leave, 1e-12), 1.0 - 1e-12)
    out = np.full((n_floors, n_floors), math.log(leave / (n_floors - 1)))
    np.fill_diagonal(out, math.log1p(-leave))
    return out


def _logsumexp_rows(a: np.ndarray) -> np.ndarray:
    m = a.max(axis=0)
    return m + np.log(np.exp(a - m).sum(axis=0))


def _normalised(log_p: np.ndarray) -> np.ndarray:
    p = np.exp(log_p - log_p.max())
    return p / p.sum()


def walk_floor(path: FloorPath) -> int:
    """The floor a walk spent most scans on (Viterbi path), for walks that keep one floor."""
    return int(np.bincount(path.path).argmax())
