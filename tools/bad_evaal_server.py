"""An EvaalAPI server that breaks the protocol in one chosen way, on 127.0.0.1: for the client's
tests (tests/evaal/test_evaal_client.py) and tools/hostile_inputs.py. Standard library only.

Each kind misbehaves at one command and answers the others as a test trial would (its state line
online, V = 3, S = 15, or offline, S = 60):

- ``drip-status``: every answer's status line, one byte every ``drip_s``;
- ``drip-body``: the state's headers at once, then its body one byte every ``drip_s``;
- ``huge-state``, ``huge-nextdata``, ``huge-offline``: ``huge_bytes`` of text without a
  Content-Length (the end is the connection's close), for ``state``, online ``nextdata``, or
  ``nextdata?offline``;
- ``bomb-state``, ``bomb-nextdata``, ``bomb-offline``: a gzip answer of ``huge_bytes`` of zeros
  (3 GB gzip to 3 MB);
- ``too-fast``: every ``nextdata`` refused as faster than real time (423);
- ``endless-empty``, ``endless-repeat``, ``endless-log``: an online trial that never ends: every
  ``nextdata`` is 200, with no line, with the first batch again, or with the lines of its window
  of an endless log;
- ``short-state``: the state's answer cut short of its Content-Length;
- ``escape``: the state refused (500) with terminal escape sequences and raw bytes in its text.

    with BadServer("too-fast") as server:
        server.url   # http://127.0.0.1:PORT/evaalapi/ (any trial name)

As a script: ``python tools/bad_evaal_server.py KIND [--port 54322]`` serves until Ctrl-C.
"""

from __future__ import annotations

import argparse
import contextlib
import socketserver
import struct
import sys
import threading
import time
import urllib.parse
import zlib

KINDS = ("drip-status", "drip-body", "huge-state", "huge-nextdata", "huge-offline", "bomb-state", "bomb-nextdata",
         "bomb-offline", "too-fast", "endless-empty", "endless-repeat", "endless-log", "short-state", "escape")
POSITION = "11.110000000,49.460000000,0"  # the georeferenced office of the tests (origin 49.46 N, 11.11 E)
ONLINE_STATE = f"0.000,-1.000,3.000,15.000,0.000,0.000,0.000,{POSITION}"
OFFLINE_STATE = f"0.000,-2.000,0.000,60.000,0.000,0.000,0.000,{POSITION}"
# the first lines of a GetSensorData log, as the server sends them (no header)
BATCH = "".join(f"ACCE;{0.05 + 0.02 * i:.3f};{1000.0 + i:.3f};0.1;9.8;0.2;3\n" for i in range(20))
ESCAPES = b"\x1b[2J\x1b[31mgotcha\x07\r\nsecond line\xff\xfe\x00 end"


def gzip_of_zeros(n_bytes: int) -> bytes:
    """A gzip member of ``n_bytes`` zeros (3 GB in 3 MB): after a full flush the compressor has
    forgotten what came before, so every further MiB of zeros compresses to the same bytes, made
    once; the trailer's CRC-32 is the data's."""
    block = bytes(1 << 20)
    packer = zlib.compressobj(9, zlib.DEFLATED, -zlib.MAX_WBITS)
    n_blocks, rest = divmod(n_bytes, 1 << 20)
    parts = []
    if n_blocks:
        parts.append(packer.compress(block) + packer.flush(zlib.Z_FULL_FLUSH))
    if n_blocks > 1:
        parts.append((packer.compress(block) + packer.flush(zlib.Z_FULL_FLUSH)) * (n_blocks - 1))
    parts.append(packer.compress(bytes(rest)) + packer.flush())
    crc = 0
    for _ in range(n_blocks):
        crc = zlib.crc32(block, crc)
    crc = zlib.crc32(bytes(rest), crc)
    header = b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x02\xff"  # gzip, deflate, no name, no time
    return header + b"".join(parts) + struct.pack("<II", crc, n_bytes & 0xFFFFFFFF)


class _Handler(socketserver.StreamRequestHandler):
    server: _Server

    def handle(self) -> None:
        with contextlib.suppress(OSError):
            while self._one_request():
                pass

    def _one_request(self) -> bool:
        line = self.rfile.readline(65537)
        if not line:
            return False
        headers = {}
        while True:
            header = self.rfile.readline(65537)
            if header in (b"\r\n", b"\n", b""):
                break
            name, _, value = header.decode("latin-1").partition(":")
            headers[name.strip().lower()] = value.strip()
        if int(headers.get("content-length", "0") or 0):
            self.rfile.read(int(headers["content-length"]))
        target = line.split()[1].decode("latin-1") if len(line.split()) > 1 else "/"
        url = urllib.parse.urlsplit(target)
        command = url.path.rstrip("/").rsplit("/", 1)[-1]
        query = urllib.parse.parse_qs(url.query, keep_blank_values=True)
        self.server.requests.append(command)
        self._answer(command, query)
        return False  # one request per connection

    def _answer(self, command: str, query: dict) -> None:
        kind, server = self.server.kind, self.server
        offline = kind.endswith("-offline")
        if kind == "drip-status":
            self._drip(b"HTTP/1.1 200 OK\r\nContent-Length: 5\r\n\r\nhello")
            return
        if command == "state":
            if kind == "drip-body":
                text = ONLINE_STATE.encode()
                self._send_headers(200, {"Content-Length": str(len(text))})
                self._drip(text)
            elif kind == "huge-state":
                self._stream(server.huge_bytes)
            elif kind == "bomb-state":
                self._send(200, server.bomb, {"Content-Encoding": "gzip"})
            elif kind == "escape":
                self._send(500, ESCAPES)
            elif kind == "short-state":
                self._send_headers(200, {"Content-Length": "1000"})
                self.wfile.write(ONLINE_STATE.encode()[:10])
            else:
                self._send(200, (OFFLINE_STATE if offline else ONLINE_STATE).encode())
            return
        if command != "nextdata":
            self._send(200, b"")
            return
        if kind in ("huge-nextdata", "huge-offline"):
            self._stream(server.huge_bytes)
        elif kind in ("bomb-nextdata", "bomb-offline"):
            self._send(200, server.bomb, {"Content-Encoding": "gzip"})
        elif kind == "too-fast":
            self._send(423, b"Too early: the trial runs in real time")
        elif kind == "endless-empty" and server.requests.count("nextdata") > 1:
            self._send(200, b"")
        elif kind == "endless-log":
            horizon_s = float(query.get("horizon", ["0.5"])[0])
            with server.lock:
                start_s = server.trial_s
                server.trial_s += horizon_s
            lines = "".join(f"ACCE;{start_s + horizon_s * i / 10:.3f};{1000.0 + i:.3f};0.1;9.8;0.2;3\n" for i in range(10))
            self._send(200, lines.encode())
        else:  # endless-repeat, and the first batch of every other kind
            self._send(200, BATCH.encode())

    def _send_headers(self, status: int, headers: dict[str, str]) -> None:
        lines = [f"HTTP/1.1 {status} X"] + [f"{k}: {v}" for k, v in {"Connection": "close", **headers}.items()]
        self.wfile.write(("\r\n".join(lines) + "\r\n\r\n").encode("latin-1"))
        self.wfile.flush()

    def _send(self, status: int, body: bytes, headers: dict[str, str] | None = None) -> None:
        self._send_headers(status, {"Content-Length": str(len(body)), **(headers or {})})
        self.wfile.write(body)
        self.wfile.flush()

    def _drip(self, data: bytes) -> None:
        for i in range(len(data)):
            self.wfile.write(data[i:i + 1])
            self.wfile.flush()
            self.server.dripped += 1
            if self.server.stop.wait(self.server.drip_s):
                return
        self.server.completed += 1

    def _stream(self, n_bytes: int) -> None:
        """``n_bytes`` of log-like text, the end marked by closing the connection."""
        self._send_headers(200, {})
        block = (BATCH * (1 + (1 << 16) // len(BATCH))).encode()[:1 << 16]
        sent = 0
        while sent < n_bytes and not self.server.stop.is_set():
            self.wfile.write(block[:n_bytes - sent])
            sent += len(block)
        self.server.completed += sent >= n_bytes


class _Server(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True


class BadServer:
    """A server of one ``kind`` (``KINDS``) on 127.0.0.1 in a thread of this process."""

    def __init__(self, kind: str, port: int = 0, drip_s: float = 1.0, huge_bytes: int = 3 << 30,
                 bomb: bytes | None = None) -> None:
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {', '.join(KINDS)}, not {kind!r}")
        self.server = _Server(("127.0.0.1", port), _Handler)
        self.server.kind, self.server.drip_s, self.server.huge_bytes = kind, drip_s, huge_bytes
        self.server.bomb = bomb if bomb is not None or not kind.startswith("bomb") else gzip_of_zeros(huge_bytes)
        self.server.requests = []  # the commands asked, in order
        self.server.completed = 0  # answers dripped or streamed to their end
        self.server.dripped = 0  # bytes dripped so far
        self.server.stop = threading.Event()
        self.server.lock = threading.Lock()
        self.server.trial_s = 0.05  # endless-log: the start of the next window
        self.thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.server.server_address[1]}/evaalapi/"

    @property
    def requests(self) -> list[str]:
        return self.server.requests

    @property
    def completed(self) -> int:
        return self.server.completed

    @property
    def dripped(self) -> int:
        return self.server.dripped

    def __enter__(self) -> BadServer:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.server.stop.set()
        self.server.shutdown()
        self.server.server_close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("kind", choices=KINDS)
    parser.add_argument("--port", type=int, default=54322)
    args = parser.parse_args(argv)
    with BadServer(args.kind, args.port) as server:
        print(f"serving {args.kind} at {server.url} (Ctrl-C stops it)", file=sys.stderr)
        with contextlib.suppress(KeyboardInterrupt):
            while True:
                time.sleep(3600)
    return 0


if __name__ == "__main__":
    sys.exit(main())
