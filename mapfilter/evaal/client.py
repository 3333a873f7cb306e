"""The EvaalAPI client: a trial entered online or offline with a ``Tracker``
(``protocol.py``: the messages).

What an online estimate is. With the request for trial time T the client sends the latest row its
tracker has given after every line before T (the lines of ``[T - h, T)`` came with the previous
request). The tracker gives a row once the records it depends on are complete: a WiFi scan waits
for a record of a later time, the merged sensors wait for each other (a barometer sample every
0.1-0.17 s), an IMU sample's time is its sensor time (a few ms from its AppTimestamp). So a row
stamped just before T can come only with the next batch, and the estimate for T is then the row
before it: what a live system would have shown (on the IPIN 2023 logs a row is sent 0.3-0.5 s after
its stamp, median, at most 0.65 s). :func:`replay_online` is that client over a log file (the same
batches, no server): the estimates ``mapfilter evaal`` would send, to the bit. The ``POSI`` rows the
server may send are ground truth: the tracker does not read them, the offline estimates take their
times. The offline estimates are the whole-walk track at every 0.5 s of the log's clock from its
first line and at its ``POSI`` times, interpolated.

Connections. Every request has one deadline, from the connection to the answer's last byte (a
server that drips its answer a byte at a time cannot hold it longer), and an answer is read to at
most a bound, counted after decompression (``MAX_STATE_BYTES``, ``MAX_BATCH_BYTES``,
``MAX_LOG_BYTES``). A request
whose connection dropped or ran out of time is sent again with the same ``label`` (evaalapi.py
answers a repeated label with the data it sent for it, so no batch is lost or read twice;
evaalapi.md does not list the parameter, and a server that refuses it is asked without), after
asking the trial's ``state`` where it stands, for up to ``retry_s``.

A server that does not keep the protocol is refused in one line, its own text shown printable
(escape sequences and raw bytes as ``\\xNN``): an answer over the bound; ``MAX_TOO_FAST``
refusals in a row as faster than real time (423) although each request waited ``h``; an online
trial that goes on without sending the log's next lines for ``MAX_SILENT_S`` of trial time, that
runs past its slack by ``SLACK_MARGIN_S`` (the server must end a trial once its wall clock passes
V times the trial time plus the slack), or past ``MAX_TRIAL_S`` of trial time.
"""

from __future__ import annotations

import contextlib
import dataclasses
import http.client
import math
import re
import secrets
import socket
import ssl
import threading
import time
import urllib.parse
import zlib
from collections.abc import Callable

import numpy as np

from mapfilter.errors import MapfilterError
from mapfilter.evaal.protocol import (DEFAULT_HORIZON_S, Estimates, TrialRun, TrialState, competition_times,
                                      floor_number, format_position, log_clock_offset_s, log_clock_s,
                                      offline_estimates, parse_position, served_time_s)
from mapfilter.io.tracks import Track, with_latlon
from mapfilter.pipeline.tracker import TrackResult, Tracker
from mapfilter.sensors.logs import LogStream
from mapfilter.sensors.recording import concatenate

# a scoring trial with V > 2 refuses a request less than h after the previous one (423): the
# client then waits this much beyond h (the server's clock reads the request a little later)
_PACE_MARGIN_S = 0.02
MAX_TOO_FAST = 8  # 423s in a row, each sent h after the previous request taken (pauses doubling from 0.02 s)
MAX_STATE_BYTES = 1 << 20  # a state line, a POST's answer: a few hundred bytes
# a log or a batch of it, decompressed: the IPIN 2023 logs are 16 kB/s (3.7 MB for 4 min), so a
# whole log of 256 MiB is over four hours, and a batch (h at most 10 s) of 16 MiB a hundred times
# denser than theirs
MAX_LOG_BYTES = 256 << 20
MAX_BATCH_BYTES = 16 << 20
MAX_SILENT_S = 10.0  # trial time with no line of the log (the IPIN 2023 logs never pause for 0.2 s)
SLACK_MARGIN_S = 5.0  # beyond its slack: the server would have ended the trial (its clock reads ours +- latency)
MAX_TRIAL_S = 6 * 3600.0  # an online trial is one walk
_READ_BYTES = 1 << 16


# ---- HTTP ------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Reply:
    """One answer of the server."""

    status: int
    text: str


class _Dropped(Exception):
    """The connection dropped, timed out or was refused before an answer came."""


class EvaalClient:
    """The EvaalAPI commands of one trial over HTTP (standard library only).

    ``server_url``: the API's root, e.g. ``https://evaal.aaloa.org/evaalapi/``; ``trial``: the
    trial's name. Every request must be answered, to its last byte, within ``timeout_s``; a dropped
    connection or a late answer is retried for up to ``retry_s`` seconds (:meth:`call`),
    ``on_retry`` told each time.
    """

    def __init__(self, server_url: str, trial: str, timeout_s: float = 10.0, retry_s: float = 30.0,
                 on_retry: Callable[[str], None] | None = None,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        parts = urllib.parse.urlsplit(server_url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise MapfilterError(f"the server URL must be http://HOST[:PORT]/PATH or https://..., got {server_url!r}")
        try:
            parts.port  # noqa: B018 - a port that is no number is refused here
        except ValueError:
            raise MapfilterError(f"the server URL has a port that is not a number: {server_url!r}") from None
        if not trial or not re.fullmatch(r"[A-Za-z0-9_.~-]+", trial):
            raise MapfilterError(f"a trial name is letters, digits and _.~- only, got {trial!r}")
        if not (timeout_s > 0 and math.isfinite(timeout_s)) or not (retry_s >= 0 and math.isfinite(retry_s)):
            raise ValueError("timeout_s must be > 0 and retry_s >= 0")
        self.trial = trial
        self.url = server_url.rstrip("/") + "/" + trial
        self._parts = urllib.parse.urlsplit(self.url)
        self.timeout_s = timeout_s
        self.retry_s = retry_s
        self.on_retry = on_retry
        self.sleep = sleep
        self.dropped = 0  # requests sent again after a dropped connection

    def request(self, command: str, query: dict[str, str] | None = None, body: bytes | None = None,
                max_bytes: int | None = None) -> Reply:
        """One request: ``GET TRIAL/command?query`` (``POST`` with ``body``), answered within
        ``timeout_s`` (connection, status, headers, body); raises ``_Dropped`` when no whole answer
        came in time, ``MapfilterError`` for an answer of more than ``max_bytes`` (decompressed;
        default ``MAX_STATE_BYTES``)."""
        max_bytes = MAX_STATE_BYTES if max_bytes is None else max_bytes
        path = f"{self._parts.path}/{command}" + (f"?{urllib.parse.urlencode(query)}" if query else "")
        headers = {"Accept-Encoding": "gzip", "Connection": "close"}  # the server compresses text when asked
        if body is not None:
            headers["Content-Type"] = "text/csv; charset=us-ascii"  # the only type POST estimates takes
        deadline = time.monotonic() + self.timeout_s
        expired = threading.Event()
        if self._parts.scheme == "https":
            connection = http.client.HTTPSConnection(self._parts.hostname, self._parts.port, timeout=self.timeout_s,
                                                     context=ssl.create_default_context())
        else:
            connection = http.client.HTTPConnection(self._parts.hostname, self._parts.port, timeout=self.timeout_s)

        watchdog = None
        try:
            connection.connect()
            # the connection's own socket: once the status line says the server will close,
            # http.client lets go of it (connection.sock is None) while the answer is read through it
            sock = connection.sock

            def cut() -> None:  # the deadline passed: whatever read is waiting ends now
                expired.set()
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)

            watchdog = threading.Timer(max(deadline - time.monotonic(), 0.0), cut)
            watchdog.daemon = True
            watchdog.start()
            connection.request("POST" if body is not None else "GET", path, body=body, headers=headers)
            response = connection.getresponse()
            text = _read_answer(response, max_bytes, f"{self.url}/{command}")
            if expired.is_set():
                raise _Dropped(f"no whole answer within {self.timeout_s:g} s")
            return Reply(response.status, text)
        except (_Dropped, OSError, http.client.HTTPException, EOFError, ValueError) as exc:
            if expired.is_set() or isinstance(exc, TimeoutError):
                raise _Dropped(f"no whole answer within {self.timeout_s:g} s") from None
            if isinstance(exc, _Dropped):
                raise
            raise _Dropped(_short(f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__)) from None
        finally:
            if watchdog is not None:
                watchdog.cancel()
            connection.close()

    def call(self, command: str, query: dict[str, str] | None = None, body: bytes | None = None,
             before_retry: Callable[[], Reply | None] | None = None, max_bytes: int | None = None) -> Reply:
        """:meth:`request`, sent again while the connection drops (for up to ``retry_s``, pausing
        0.2 s, then twice as long each time up to 2 s). ``before_retry`` runs before each new try
        and may return the answer instead (e.g. the trial finished meanwhile)."""
        deadline = time.monotonic() + self.retry_s
        pause_s = 0.2
        while True:
            try:
                return self.request(command, query, body, max_bytes)
            except _Dropped as exc:
                if time.monotonic() + pause_s > deadline:
                    raise MapfilterError(f"no answer from {self.url}/{command} ({exc}) for {self.retry_s:g} s: the "
                                         "server is down, unreachable or too slow; run the command again to "
                                         "continue (the trial's state says where it stands)") from None
                self.dropped += 1
                if self.on_retry is not None:
                    self.on_retry(f"{command}: {exc}; trying again in {pause_s:.1f} s")
                self.sleep(pause_s)
                pause_s = min(2 * pause_s, 2.0)
                if before_retry is not None:
                    answer = before_retry()
                    if answer is not None:
                        return answer

    def state(self) -> TrialState:
        """The trial's state (``GET TRIAL/state``)."""
        reply = self.call("state")
        _check_found(reply, self.trial)
        if reply.status != 200:
            raise MapfilterError(f"trial {self.trial}: the server answered {reply.status} to state: "
                                 f"{_short(reply.text)}")
        return TrialState.parse(reply.text)

    def reload(self) -> TrialState:
        """Put a test trial back to its start (``GET TRIAL/reload``; a scoring trial refuses: 422)."""
        reply = self.call("reload")
        _check_found(reply, self.trial)
        if reply.status != 200:
            raise MapfilterError(f"trial {self.trial} cannot be reloaded ({reply.status}: {_short(reply.text)}): only "
                                 "test trials can")
        return TrialState.parse(reply.text)

    def estimates(self) -> Reply:
        """The estimates the server holds (``GET TRIAL/estimates``: ``pts,c,h,s,pos`` lines)."""
        return self.call("estimates", max_bytes=MAX_LOG_BYTES)


def _read_answer(response: http.client.HTTPResponse, max_bytes: int, where: str) -> str:
    """The body of ``response`` as text, gunzipped when it says so, refused beyond ``max_bytes``
    (raw or decompressed: a gzip bomb stops at the bound); ``_Dropped`` when it was cut short."""
    encoding = (response.getheader("Content-Encoding") or "identity").strip().lower()
    if encoding not in ("identity", "gzip"):
        raise MapfilterError(f"{where}: the server answered in the encoding {_printable(encoding[:40])!r}, which "
                             "this client did not ask for")
    declared = response.getheader("Content-Length")
    if declared is not None and declared.strip().isdigit() and int(declared) > max_bytes:
        raise _too_large(where, max_bytes)
    gunzip = zlib.decompressobj(16 + zlib.MAX_WBITS) if encoding == "gzip" else None
    blocks: list[bytes] = []
    size = raw = 0
    while True:
        block = response.read(_READ_BYTES)
        if not block:
            break
        raw += len(block)
        if raw > max_bytes:
            raise _too_large(where, max_bytes)
        if gunzip is None:
            size += len(block)
            blocks.append(block)
        else:
            try:
                while block:
                    out = gunzip.decompress(block, max_bytes - size + 1)
                    size += len(out)
                    blocks.append(out)
                    if size > max_bytes:
                        break
                    if gunzip.eof:  # a member ended: another may follow (RFC 1952)
                        block = gunzip.unused_data
                        if block:
                            gunzip = zlib.decompressobj(16 + zlib.MAX_WBITS)
                    else:
                        block = gunzip.unconsumed_tail
            except zlib.error:
                raise MapfilterError(f"{where}: the server's gzip answer is not gzip") from None
        if size > max_bytes:
            raise _too_large(where, max_bytes)
    if response.length:  # fewer bytes than its Content-Length said
        raise _Dropped(f"the answer was cut short ({response.length} bytes missing)")
    if gunzip is not None and raw and not gunzip.eof:
        raise _Dropped("the gzip answer was cut short")
    return b"".join(blocks).decode("utf-8", errors="replace")


def _too_large(where: str, max_bytes: int) -> MapfilterError:
    return MapfilterError(f"{where}: the server's answer is larger than {max_bytes >> 20} MiB (decompressed): not an "
                          "EvaalAPI answer this client takes")


def _printable(text: str) -> str:
    """``text`` with every character that is not printable (escape sequences, raw bytes, line
    breaks) as ``\\xNN``: a server's text can never move the cursor or recolour a terminal."""
    return "".join(c if c.isprintable() else f"\\x{ord(c):02x}" if ord(c) < 256 else f"\\u{ord(c):04x}"
                   for c in text)


def _short(text: str) -> str:
    """A server's text for one line of ours: whitespace runs as one space, printable, at most 200
    characters."""
    text = _printable(" ".join(text.split()))
    return text if len(text) <= 200 else text[:200] + "..."


def _check_found(reply: Reply, trial: str) -> None:
    if reply.status == 404:
        raise MapfilterError(f"the server has no trial {trial!r} (404): check the trial name and the server URL "
                             "(it ends in /evaalapi/)")


class OnlineTracker:
    """The tracker fed the batches of an online trial; the position of its latest row."""

    def __init__(self, tracker: Tracker, name: str) -> None:
        self.tracker = tracker
        self.building = tracker.building
        self.stream = LogStream(name)
        self.position: tuple[float, float, int] | None = None
        self.rows = 0

    def feed(self, text: str) -> None:
        chunk = self.stream.feed_text(text)
        self._rows(self.tracker.feed(chunk))

    def close(self) -> TrackResult | None:
        chunk = self.stream.close() if self.stream.format is not None else None
        if chunk is not None:
            self._rows(self.tracker.feed(chunk))
        self.tracker.close()
        return self.tracker.result() if self.rows else None

    def _rows(self, rows: Track) -> None:
        if len(rows):
            self.rows += len(rows)
            last = rows.rows(slice(len(rows) - 1, len(rows)))
            (lat, lon), = with_latlon(last, self.building).latlon_deg
            floor = floor_number(last.floor[0] if last.floor is not None else self.building.floors[0].name)
            self.position = (float(lon), float(lat), floor)


def run_online(client: EvaalClient, tracker: Tracker, horizon_s: float = DEFAULT_HORIZON_S, *,
               progress: Callable[[str], None] | None = None, progress_every_s: float = 30.0,
               clock: Callable[[], float] = time.time) -> TrialRun:
    """Enter an online trial with ``tracker`` (fresh, its building georeferenced): reads the
    trial's state, then asks for the next ``horizon_s`` of lines until the trial ends, sending with
    each request the latest row's position (before the first row: the position the server holds).

    A trial another run started is continued from its trial time with this fresh tracker. A request
    refused as faster than real time (423) is sent again ``h`` after the previous one, and from
    then on every request waits for that. ``progress`` gets a line every ``progress_every_s`` of
    trial time (the trial time, the requests, the slack as this client counts it). Returns the
    run, also when it timed out (``TrialRun.timed_out``); ``MapfilterError`` for an offline or
    finished trial, a refused request (422), a lost server, or a server that breaks the protocol
    (the module's docstring: 423 without end, no end to the trial, an answer too large).
    """
    if not (horizon_s > 0 and math.isfinite(horizon_s)):
        raise MapfilterError(f"the horizon must be a positive number of seconds, got {horizon_s}")
    state = client.state()
    name = f"trial {client.trial}"
    if state.offline:
        raise MapfilterError(f"{name} is an offline trial: enter it with --offline")
    if state.finished:
        raise MapfilterError(f"{name} has finished{' by a timeout' if state.timed_out else ''}: a test trial can be "
                             "reloaded (--reload)")
    run = _OnlineRun(client, tracker, state, name, horizon_s, progress, progress_every_s, clock)
    while run.next_request():
        pass
    return run.finish()


class _OnlineRun:
    """One online trial as it goes: the requests sent, the positions given, the pace the server
    asks for and the slack as this client counts it."""

    def __init__(self, client: EvaalClient, tracker: Tracker, state: TrialState, name: str, horizon_s: float,
                 progress: Callable[[str], None] | None, progress_every_s: float, clock: Callable[[], float]):
        self.client, self.state, self.name, self.horizon_s = client, state, name, horizon_s
        self.progress, self.progress_every_s, self.clock = progress, progress_every_s, clock
        self.held = parse_position(state.position, f"{name}: the server's position")
        self.resumed = state.started
        self.online = OnlineTracker(tracker, name)
        self.trial_s: float | None = state.trial_s if self.resumed else None
        self.sent: list[tuple[float, float, float, int]] = []
        self.given: list[int] = []
        self.busy: list[float] = []
        self.answered_s: float | None = None  # when the previous batch came
        self.labels = secrets.token_hex(4)  # this run's own request labels
        self.use_labels = True
        self.slowdown, self.slack_max_s = state.slowdown, state.slack_s
        self.slack_s, self.lowest_s = self.slack_max_s, math.inf
        self.previous_s: float | None = None  # wall clock of the previous request the server took
        self.previous_h = 0.0
        self.paced = False
        self.too_fast = self.requests = 0
        self.next_report_s = -math.inf
        self.started_s = clock()
        self.final: TrialState | None = None
        self.reply_text = ""
        self.too_fast_in_row = 0
        self.silent_s = 0.0  # trial time since a batch last held a line of its window

    def next_request(self) -> bool:
        """Ask for the next batch with the latest position and take the answer; False once the
        trial has ended."""
        position = self.held if self.online.position is None else self.online.position
        reply, sent_s = self.send(position)
        if reply.status == 423:  # faster than real time: from now on, wait h after the previous one
            self.refused_as_too_fast(reply)
            return True
        self.too_fast_in_row = 0
        if reply.status == 422 and self.use_labels and "label" in reply.text:
            self.use_labels = False  # a server without retry labels
            return True
        _check_found(reply, self.client.trial)
        if reply.status == 405:
            self.ended(reply, position)
            return False
        if reply.status == 422:
            raise MapfilterError(f"{self.name}: the server refused the request (422): {_short(reply.text)}")
        if reply.status != 200:
            raise MapfilterError(f"{self.name}: the server answered {reply.status}: {_short(reply.text)}")
        self.take_batch(reply, sent_s, position)
        return True

    def send(self, position: tuple[float, float, int]) -> tuple[Reply, float]:
        """``nextdata`` with ``position`` (once the pace allows); the answer and when it was sent."""
        query = {"horizon": f"{self.horizon_s:g}", "position": format_position(*position)}
        if self.use_labels:
            query["label"] = f"{self.labels}-{self.requests}"
        if self.answered_s is not None:
            self.busy.append(self.clock() - self.answered_s)
            self.answered_s = None
        if self.paced and self.previous_s is not None:
            wait_s = self.previous_s + self.previous_h + _PACE_MARGIN_S - self.clock()
            if wait_s > 0:
                self.client.sleep(wait_s)
        sent_s = self.clock()
        reply = self.client.call("nextdata", query,
                                 before_retry=_where_it_stands(self.client, self.trial_s, self.horizon_s),
                                 max_bytes=MAX_BATCH_BYTES)
        return reply, sent_s

    def refused_as_too_fast(self, reply: Reply) -> None:
        self.too_fast += 1
        self.too_fast_in_row += 1
        if self.too_fast_in_row >= MAX_TOO_FAST:
            waited = (f"although each came {self.previous_h:g} s after the one it took" if self.previous_s is not None
                      else "before it took any")
            raise MapfilterError(f"{self.name}: the server refused {self.too_fast_in_row} requests in a row as faster "
                                 f"than real time (423), {waited}: it does not keep the protocol "
                                 f"({_short(reply.text)})")
        self.paced = True
        # the server's clock read the previous one later than ours: never spin
        self.client.sleep(_PACE_MARGIN_S * 2 ** (self.too_fast_in_row - 1))

    def ended(self, reply: Reply, position: tuple[float, float, int]) -> None:
        self.final = TrialState.parse(reply.text)
        self.reply_text = _short(reply.text)
        if not self.final.timed_out and self.trial_s is not None:
            self.sent.append((self.trial_s, *position))  # the server keeps the position of the request that ended it
            self.given.append(self.online.rows)
            self.requests += 1

    def take_batch(self, reply: Reply, sent_s: float, position: tuple[float, float, int]) -> None:
        """A batch taken: count the slack, note the position sent, check the trial goes on, track."""
        self.requests += 1
        if self.previous_s is not None:
            self.slack_s = min(self.slack_max_s, self.slack_s + self.slowdown * self.previous_h
                               - (sent_s - self.previous_s))
        self.lowest_s = min(self.lowest_s, self.slack_s)
        self.previous_s, self.previous_h = sent_s, self.horizon_s
        if self.trial_s is None:  # the first request: the server keeps its initial position at the first line
            self.trial_s = served_time_s(reply.text)
            if self.trial_s is None:
                raise MapfilterError(f"{self.name}: the first batch of the log has no line with a time")
            self.sent.append((self.trial_s, *self.held))
        else:
            self.sent.append((self.trial_s, *position))
        self.given.append(self.online.rows)
        self.silent_s = 0.0 if _holds_window(reply.text, self.trial_s, self.horizon_s) else \
            self.silent_s + self.horizon_s
        self.trial_s += self.horizon_s  # as the server counts it
        _check_trial_goes_on(self.name, self.trial_s, self.silent_s, self.slack_s)
        self.answered_s = self.clock()
        self.online.feed(reply.text)
        if self.progress is not None and self.trial_s >= self.next_report_s:
            self.progress(f"trial time {self.trial_s:.1f} s: {self.requests} requests, {self.online.rows} tracker "
                          f"rows, slack {self.slack_s:.1f} s (lowest {self.lowest_s:.1f} s)")
            self.next_report_s = self.trial_s + self.progress_every_s

    def finish(self) -> TrialRun:
        """The tracker closed and the run, with the slack as the server counted it where it says."""
        result = self.online.close()
        wall_s = self.clock() - self.started_s
        slack_left_s, lowest = _server_slack(self.client)
        lowest_s = self.lowest_s if math.isfinite(self.lowest_s) else None
        return TrialRun(self.client.trial, False, Estimates.of_rows(self.sent), self.requests, self.reply_text,
                        self.final, wall_s, slack_left_s if slack_left_s is not None else self.slack_s,
                        lowest if lowest is not None else lowest_s, self.too_fast, self.client.dropped,
                        self.state.trial_s if self.resumed else None, result, np.array(self.given),
                        np.array(self.busy))


def _holds_window(text: str, start_s: float, horizon_s: float) -> bool:
    """A batch holds a line of its window ``[start_s, start_s + h)`` (the server's times: a line's
    first number; 1 s either side, as times are kept to the ms)."""
    for line in text.splitlines():
        time_s = served_time_s(line)
        if time_s is not None and start_s - 1.0 <= time_s < start_s + horizon_s + 1.0:
            return True
    return False


def _check_trial_goes_on(name: str, trial_s: float, silent_s: float, slack_s: float) -> None:
    """Refuse a trial the server should have ended: no line of the log for ``MAX_SILENT_S`` of
    trial time (the log has ended), past its slack (it timed out), past ``MAX_TRIAL_S``."""
    if silent_s > MAX_SILENT_S:
        raise MapfilterError(f"{name}: the server sent no line of the log for {silent_s:g} s of trial time (at "
                             f"{trial_s:.1f} s) and does not end the trial: it does not keep the protocol")
    if slack_s < -SLACK_MARGIN_S:
        raise MapfilterError(f"{name}: the trial ran {-slack_s:.1f} s past its slack (V times the trial time plus S) "
                             "and the server does not end it: it does not keep the protocol")
    if trial_s > MAX_TRIAL_S:
        raise MapfilterError(f"{name}: the trial goes on past {MAX_TRIAL_S / 3600:g} h of trial time: no walk is "
                             "that long")


def _where_it_stands(client: EvaalClient, trial_s: float | None, horizon_s: float) -> Callable[[], Reply | None]:
    """Before a ``nextdata`` is sent again: the trial's state. Finished: that is the answer (as the
    405 it would give). Still at ``trial_s`` (not taken) or one horizon on (taken: the repeated
    label gets the same lines back): send it again. Anywhere else: another client moved it."""
    def check() -> Reply | None:
        try:
            reply = client.request("state")
        except _Dropped:
            return None  # still down: the retry loop goes on
        if reply.status != 200:
            return None
        state = TrialState.parse(reply.text)
        if state.finished:
            return Reply(405, reply.text)
        if trial_s is not None and state.started and not any(
                abs(state.trial_s - t) < 1e-3 for t in (trial_s, trial_s + horizon_s)):
            raise MapfilterError(f"trial {client.trial} moved to trial time {state.trial_s:.3f} s while this client "
                                 f"was at {trial_s:.3f} s: is another client using it?")
        return None
    return check


def _server_slack(client: EvaalClient) -> tuple[float | None, float | None]:
    """(the slack at the last request, the lowest) from the server's own list of estimates."""
    try:
        reply = client.request("estimates", max_bytes=MAX_LOG_BYTES)
    except _Dropped:
        return None, None
    if reply.status != 200:
        return None, None
    slack = []
    for line in reply.text.splitlines()[2:]:  # the header, then the initial position (s = S)
        fields = line.split(",")
        try:
            slack.append(float(fields[3]))
        except (IndexError, ValueError):
            continue
    return (slack[-1], min(slack)) if slack else (None, None)


def run_offline(client: EvaalClient, tracker: Tracker, *, progress: Callable[[str], None] | None = None,
                clock: Callable[[], float] = time.time) -> TrialRun:
    """Enter an offline trial with ``tracker`` (fresh, with ``config.smooth``): the whole log
    (``nextdata?offline``), the whole-walk track, then its estimates (:func:`competition_times`)
    posted in one go. Returns the run (the POST's answer in ``reply``; a timeout in
    ``timed_out``); ``MapfilterError`` for an online, started or finished trial."""
    name = f"trial {client.trial}"
    state = client.state()
    if not state.offline:
        raise MapfilterError(f"{name} is an online trial: enter it without --offline")
    if state.finished:
        raise MapfilterError(f"{name} has finished: a test trial can be reloaded (--reload)")
    if state.started:
        raise MapfilterError(f"{name} has started: an offline trial sends its log once; a test trial can be "
                             "reloaded (--reload)")
    if not tracker.config.smooth:
        raise ValueError("an offline trial posts the whole-walk track: give the tracker config.smooth")
    started_s = clock()

    def data_lost() -> Reply | None:
        state_now = client.state()
        if state_now.started or state_now.finished:
            raise MapfilterError(f"{name}: the connection dropped while the server sent the log, and an offline "
                                 "trial sends it once: a test trial can be reloaded (--reload)")
        return None

    reply = client.call("nextdata", {"offline": ""}, before_retry=data_lost, max_bytes=MAX_LOG_BYTES)
    _check_found(reply, client.trial)
    if reply.status != 200:
        raise MapfilterError(f"{name}: the server answered {reply.status} to nextdata?offline: {_short(reply.text)}")
    if progress is not None:
        progress(f"the log: {reply.text.count(chr(10))} lines in {clock() - started_s:.1f} s; tracking (the server "
                 f"takes the estimates for {state.slack_s:g} s)")
    estimates, result = offline_run(tracker, reply.text, name)
    taken_s = clock() - started_s
    if progress is not None:
        progress(f"{len(estimates)} estimates after {taken_s:.1f} s: posting")

    def posted_meanwhile() -> Reply | None:
        # the answer was lost with the connection: the state says whether the estimates were taken
        state_now = client.state()
        if not state_now.finished:
            return None
        return Reply(405 if state_now.timed_out else 201, "the server took the estimates (its answer was lost)")

    post = client.call("estimates", body="".join(line + "\n" for line in estimates.lines()).encode("ascii"),
                       before_retry=posted_meanwhile)
    final = client.state()
    if post.status not in (201, 409, 405):
        raise MapfilterError(f"{name}: the server answered {post.status} to the estimates: {_short(post.text)}")
    return TrialRun(client.trial, True, estimates, 1, _short(post.text), final, clock() - started_s,
                    state.slack_s - taken_s, None, dropped=client.dropped, result=result)


def offline_run(tracker: Tracker, text: str, name: str) -> tuple[Estimates, TrackResult]:
    """The whole log's text through ``tracker`` (with smoothing): the offline estimates at the
    competition's times (:func:`competition_times`) and the run."""
    stream = LogStream(name)
    recording = concatenate([stream.feed_text(text), stream.close()])
    first_s = served_time_s(text)
    last_s = next((t for t in map(served_time_s, reversed(text.splitlines())) if t is not None), None)
    if first_s is None or last_s is None:
        raise MapfilterError(f"{name}: the log has no line with a time")
    tracker.feed(recording)
    tracker.close()
    result = tracker.result()
    times = competition_times(first_s, last_s, log_clock_s(recording.waypoint_t_s, recording))
    return offline_estimates(result.offline, tracker.building, times, log_clock_offset_s(recording)), result
