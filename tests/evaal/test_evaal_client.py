"""The EvaalAPI client against servers that break the protocol (tools/bad_evaal_server.py, in a
thread on 127.0.0.1): each is refused in one printable line, and the client stops asking. The
official server: tests/evaal/test_evaal_server.py."""

from __future__ import annotations

import sys

import pytest

from mapfilter.errors import MapfilterError
from mapfilter.evaal import client as evaal_client
from mapfilter.evaal.client import MAX_SILENT_S, MAX_TOO_FAST, EvaalClient, run_offline, run_online
from tests.conftest import REPO
from tests.evaal.test_evaal import _georeferenced_office

sys.path.insert(0, str(REPO / "tools"))
from bad_evaal_server import ESCAPES, BadServer  # noqa: E402


def _tracker(tmp_path, smooth: bool = False):
    from mapfilter.config import TrackingConfig
    from mapfilter.maps.building import Building
    from mapfilter.pipeline.tracker import Tracker, TrackingInputs

    from mapfilter.sensors.radiomap import RadioMap

    building = Building.load(_georeferenced_office(tmp_path))
    radio_map = RadioMap.load(REPO / "maps" / "office_radiomap.npz")
    return Tracker(building, TrackingInputs(radio_map),
                   config=TrackingConfig().override({"filter.n_particles": 200, "smooth": smooth}))


def _one_printable_line(message: str) -> None:
    assert message.isprintable(), repr(message)  # no escape sequence, raw byte or line break


@pytest.mark.parametrize("kind", ["drip-status", "drip-body"])
def test_an_answer_dripped_a_byte_at_a_time_ends_at_the_deadline(kind):
    """One deadline per request, the answer's last byte included: the dripped answer (a byte every
    0.3 s, 20 s in all) is given up at 0.5 s, and with no time to retry that is the refusal."""
    with BadServer(kind, drip_s=0.3) as server:
        client = EvaalClient(server.url, "t", timeout_s=0.5, retry_s=0.0)
        with pytest.raises(MapfilterError, match=r"no answer from .*/t/state \(no whole answer within 0.5 s\)") as error:
            client.state()
        assert server.dripped < 30  # the client left long before the answer's end (its bytes: 40 or more)
    _one_printable_line(str(error.value))


def test_an_answer_cut_short_of_its_length_is_no_answer():
    with BadServer("short-state") as server:
        with pytest.raises(MapfilterError, match=r"cut short \(990 bytes missing\)"):
            EvaalClient(server.url, "t", timeout_s=5.0, retry_s=0.0).state()


@pytest.mark.parametrize("kind", ["huge-state", "bomb-state"])
def test_a_state_answer_over_the_bound_is_refused(kind, monkeypatch):
    """4 MiB of text, raw or as a gzip of 4 KiB: refused at the bound (1 MiB here), counted
    after decompression, and not sent again."""
    monkeypatch.setattr(evaal_client, "MAX_STATE_BYTES", 1 << 20)
    with BadServer(kind, huge_bytes=4 << 20) as server:
        with pytest.raises(MapfilterError, match="larger than 1 MiB") as error:
            EvaalClient(server.url, "t", timeout_s=5.0, retry_s=5.0).state()
        assert server.requests == ["state"]
    _one_printable_line(str(error.value))


@pytest.mark.parametrize("kind", ["huge-nextdata", "bomb-nextdata", "huge-offline", "bomb-offline"])
def test_a_batch_or_a_log_over_the_bound_is_refused(kind, monkeypatch, tmp_path):
    monkeypatch.setattr(evaal_client, "MAX_LOG_BYTES", 1 << 20)  # the whole log of an offline trial
    monkeypatch.setattr(evaal_client, "MAX_BATCH_BYTES", 1 << 20)  # an online batch
    offline = kind.endswith("offline")
    with BadServer(kind, huge_bytes=4 << 20) as server:
        client = EvaalClient(server.url, "t", timeout_s=5.0, retry_s=5.0)
        with pytest.raises(MapfilterError, match="/t/nextdata: the server's answer is larger than 1 MiB"):
            (run_offline if offline else run_online)(client, _tracker(tmp_path, smooth=offline))
        assert server.requests == ["state", "nextdata"]


def test_too_fast_forever_is_refused_after_a_few_tries(tmp_path):
    with BadServer("too-fast") as server:
        pauses = []
        client = EvaalClient(server.url, "t", timeout_s=5.0, sleep=pauses.append)
        with pytest.raises(MapfilterError, match=f"refused {MAX_TOO_FAST} requests in a row as faster than real "
                                                 r"time \(423\), before it took any"):
            run_online(client, _tracker(tmp_path))
        assert server.requests.count("nextdata") == MAX_TOO_FAST
        assert pauses == [0.02 * 2 ** k for k in range(MAX_TOO_FAST - 1)]  # doubling: never a spin


@pytest.mark.parametrize("kind", ["endless-empty", "endless-repeat"])
def test_a_trial_whose_log_has_ended_but_goes_on_is_refused(kind, tmp_path):
    """The server sends no line of the log's next window (nothing, or the first batch again) and
    never ends the trial: refused once MAX_SILENT_S of trial time passed so."""
    with BadServer(kind) as server:
        with pytest.raises(MapfilterError, match="sent no line of the log for .* s of trial time"):
            run_online(EvaalClient(server.url, "t", timeout_s=5.0), _tracker(tmp_path))
        n = server.requests.count("nextdata")
    assert MAX_SILENT_S / 0.5 < n <= MAX_SILENT_S / 0.5 + 5


def test_a_trial_that_runs_past_its_slack_is_refused(tmp_path):
    """An endless log whose server never times the trial out, with a client that sends a batch
    every 3 s (V h is 1.5 s): once this client's count of the slack (S = 15 s) is 5 s below zero,
    at the 15th batch, it stops."""
    with BadServer("endless-log") as server:
        def clock() -> float:  # the wall clock: 3 s a batch
            return 3.0 * server.requests.count("nextdata")

        with pytest.raises(MapfilterError, match="ran 6.0 s past its slack"):
            run_online(EvaalClient(server.url, "t", timeout_s=5.0), _tracker(tmp_path), clock=clock)
        assert server.requests.count("nextdata") == 15  # 15 + 14 (1.5 - 3) = -6 < -5


def test_a_trial_longer_than_any_walk_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(evaal_client, "MAX_TRIAL_S", 5.0)
    with BadServer("endless-log") as server:
        with pytest.raises(MapfilterError, match="goes on past .* h of trial time"):
            run_online(EvaalClient(server.url, "t", timeout_s=5.0), _tracker(tmp_path))
        assert server.requests.count("nextdata") == 10


def test_a_servers_escape_sequences_are_shown_escaped(tmp_path, capsys):
    """The command's error line holds the server's text with every control character escaped."""
    from mapfilter.cli import main

    with BadServer("escape") as server:
        code = main(["evaal", server.url, "t", str(_georeferenced_office(tmp_path)), "--radiomap",
                     str(REPO / "maps" / "office_radiomap.npz"), "--out", str(tmp_path / "e.csv"), "--timeout", "5",
                     "--retry", "0"])
    err = capsys.readouterr().err
    assert code == 1 and err.endswith("\n") and err.count("\n") == 1, err
    _one_printable_line(err[:-1])
    assert "the server answered 500 to state: \\x1b[2J\\x1b[31mgotcha\\x07 second line" in err
    assert ESCAPES[:4] not in err.encode("utf-8", "surrogateescape")
    assert not (tmp_path / "e.csv").exists()


def test_enter_trial_has_the_same_bounds(tmp_path):
    """mf.enter_trial goes through the same client: a dripped answer ends at its deadline."""
    import mapfilter as mf

    with BadServer("drip-body", drip_s=0.3) as server:
        with pytest.raises(MapfilterError, match="no whole answer within 0.5 s"):
            mf.enter_trial(server.url, "t", _georeferenced_office(tmp_path),
                           radio_map=REPO / "maps" / "office_radiomap.npz", timeout_s=0.5, retry_s=0.0)


class _Answer:
    """What ``_read_answer`` reads of an HTTP response: its headers, its body in pieces, and the
    bytes its Content-Length still promises."""

    def __init__(self, body: bytes, headers: dict[str, str], missing: int = 0) -> None:
        self.body, self.headers, self.length = body, headers, missing

    def getheader(self, name: str):
        return self.headers.get(name)

    def read(self, n: int) -> bytes:
        piece, self.body = self.body[:n], self.body[n:]
        return piece


def test_gzip_answers_of_several_members_are_read_whole_and_cut_ones_are_dropped():
    import gzip

    from mapfilter.evaal.client import _Dropped, _read_answer

    two = gzip.compress(b"first line\n") + gzip.compress(b"second line\n")
    assert _read_answer(_Answer(two, {"Content-Encoding": "gzip"}), 1 << 20, "u") == "first line\nsecond line\n"
    with pytest.raises(_Dropped, match="gzip answer was cut short"):
        _read_answer(_Answer(two[:-12], {"Content-Encoding": "gzip"}), 1 << 20, "u")
    with pytest.raises(_Dropped, match=r"cut short \(5 bytes missing\)"):
        _read_answer(_Answer(b"abc", {}, missing=5), 1 << 20, "u")
    with pytest.raises(MapfilterError, match="larger than 1 MiB"):  # declared: refused before any byte is read
        _read_answer(_Answer(b"", {"Content-Length": str(2 << 20)}), 1 << 20, "u")
    with pytest.raises(MapfilterError, match="encoding 'br'"):
        _read_answer(_Answer(b"x", {"Content-Encoding": "br"}), 1 << 20, "u")
