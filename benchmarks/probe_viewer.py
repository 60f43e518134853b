"""A probe of `wavlight view` under abuse and load: malformed websocket messages, bad HTTP
requests, idle and half-open connections, many websockets, pages converging beside a page that
previews, and the file descriptor limit. Each case runs against the real command in a child
process (a 128 x 128 bake of the bunny, cached in /tmp/wavlight-probe-viewer) and fails when the
viewer answers it wrongly for its class, writes a traceback or more than one line on stderr for
it, or stops serving pages after it.

Classes and what passes:

- websocket messages (huge numbers, deep nesting, wrong types, NaN/Infinity, unknown keys,
  binary, oversized): a one-line note (a huge angle may be answered by its frame: it wraps) and
  the socket kept (a good state then gets its frame); a message over the protocol's limit or
  text that is not UTF-8: closed with the websocket protocol's code (1009, 1007);
- HTTP (bad methods, huge headers and URLs, a flood of bad requests, Host and Origin): a 4xx
  answer (403 for another site or a request without the run's token: the page, its socket, an
  upload), at most one log line (for a flood: at most one per interval);
- idle connections (sending nothing, a partial request line, a slowloris, an idle keep-alive, a
  half-open websocket, a websocket that answers pings but sends nothing, one that reads nothing):
  closed within a minute (the child's settings shortened where the tree has them);
- many websockets opened and closed (cleanly and by reset) while a page draws: every handshake
  answered and the page's frames kept;
- converge load: a page's preview frames while 1, 5 or 20 other pages converge within 8 times
  their median without them;
- the descriptor limit (lowered with prlimit once the page is open): new connections refused at
  once, at most two lines on stderr, the open page's frames kept, served again once they close.

    python benchmarks/probe_viewer.py [--tree DIR] [--classes NAME,...] [-o FILE]
    python benchmarks/probe_viewer.py --tree /tmp/wl-baseline -o /tmp/probe-viewer-baseline.json
    python benchmarks/probe_viewer.py --compare /tmp/probe-viewer-baseline.json

``--tree DIR`` runs the children with PYTHONPATH=DIR (another copy of the package: a baseline).
Writes benchmarks/results/probe-viewer.json (``-o -``: stdout only): a row per case and a table
per class (cases, failed; with --compare, failed in the baseline too).
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import signal
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse

import aiohttp

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
CACHE = os.path.join(tempfile.gettempdir(), "wavlight-probe-viewer")
HUGE = 10 ** 400

CHILD = r"""
import os, sys
try:   # the connection settings, where this copy of the package has them
    from wavlight.relight import serving
    for name in ("HTTP_IDLE_SECONDS", "WS_HEARTBEAT_SECONDS", "WS_IDLE_SECONDS"):
        if os.environ.get("PROBE_" + name):
            setattr(serving, name, float(os.environ["PROBE_" + name]))
except ImportError:
    pass
from wavlight.cli.main import main
main(["view", sys.argv[1], "--no-browser"])
"""


def bake_file() -> str:
    path = os.path.join(CACHE, "bunny128.wlt")
    if not os.path.exists(path):
        os.makedirs(CACHE, exist_ok=True)
        code = ("import sys, wavlight; wavlight.bake(sys.argv[1], output=sys.argv[2], width=128, height=128, spp=2, "
                "levels=5, terms=256, priority='transfer').close()")
        subprocess.run([sys.executable, "-c", code, os.path.join(HERE, "scenes", "bunny_ggx.toml"), path], check=True,
                       cwd=ROOT)
    return path


class Child:
    """`wavlight view BAKE` in a child process; its stderr lines with their times."""

    def __init__(self, bake, tree=None, settings=None):
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        if tree:
            env["PYTHONPATH"] = tree
        for name, value in (settings or {}).items():
            env["PROBE_" + name] = str(value)
        self.proc = subprocess.Popen([sys.executable, "-c", CHILD, bake], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, env=env, cwd=tempfile.gettempdir())
        self.url = self.proc.stdout.readline().strip()
        if not self.url.startswith("http://"):
            raise RuntimeError(f"the viewer did not start: {self.proc.stderr.read()[-500:]}")
        parts = urllib.parse.urlsplit(self.url)
        #: the page's query (its token, where the viewer has one): every request carries it
        self.port, self.query = parts.port, parts.query
        self.ws_url = f"http://127.0.0.1:{self.port}/ws" + (f"?{self.query}" if self.query else "")
        self.lines: list = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stderr:
            self.lines.append((time.monotonic(), line.rstrip("\n")))

    def since(self, t0):
        return [line for t, line in self.lines if t >= t0]

    def stop(self):
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        return self.proc.returncode


# ----------------------------------------------------------------------------- helpers
async def served(url, timeout=10.0) -> bool:
    try:
        async with aiohttp.ClientSession() as s, s.get(url, timeout=aiohttp.ClientTimeout(total=timeout)) as r:
            return r.status == 200
    except (TimeoutError, aiohttp.ClientError):
        return False


async def frame(ws, timeout=30.0):
    """The next frame's header (acknowledged), skipping text; None when the socket closed."""
    while True:
        msg = await ws.receive(timeout=timeout)
        if msg.type == aiohttp.WSMsgType.TEXT:
            continue
        if msg.type != aiohttp.WSMsgType.BINARY:
            return None
        n = struct.unpack("<I", msg.data[:4])[0]
        header = json.loads(msg.data[4:4 + n])
        await ws.send_json({"type": "drawn", "seq": header["seq"]})
        return header


def one_line_answer(msg) -> str | None:
    """Why a reply is not a one-line answer (None when it is)."""
    if msg.type == aiohttp.WSMsgType.BINARY:
        return None
    if msg.type != aiohttp.WSMsgType.TEXT:
        return f"closed ({msg.type.name} {msg.data})"
    data = json.loads(msg.data)
    lines = data.get("notes") or [data.get("message")]
    if not all(isinstance(n, str) and "\n" not in n and len(n) < 400 for n in lines):
        return f"not one line: {str(lines)[:80]}"
    return None


async def raw_request(port, data: bytes, read=True, timeout=10.0) -> bytes:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(data)
        await writer.drain()
        return await asyncio.wait_for(reader.read(65536), timeout) if read else b""
    except (TimeoutError, ConnectionError) as e:
        return f"<{type(e).__name__}>".encode()
    finally:
        writer.close()


def masked(opcode: int, payload: bytes) -> bytes:
    mask = b"\x01\x02\x03\x04"
    n = len(payload)
    head = bytes([0x80 | opcode])
    head += bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + struct.pack(">H", n) if n < 65536 else \
        bytes([0x80 | 127]) + struct.pack(">Q", n)
    return head + mask + bytes(c ^ mask[i % 4] for i, c in enumerate(payload))


def upgrade(port, query="") -> bytes:
    return (f"GET /ws{'?' + query if query else ''} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n").encode()


async def closed_within(reader, seconds) -> float | None:
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < seconds:
            data = await asyncio.wait_for(reader.read(65536), seconds)
            if not data:
                return time.monotonic() - t0
    except ConnectionError:
        return time.monotonic() - t0
    except TimeoutError:
        return None
    return None


# ----------------------------------------------------------------------------- the classes
def message_cases():
    """(class, case, text or bytes, expected): 'note' a one-line note first, 'answer' a note or a frame
    (an angle wraps without one), 'kept' nothing but the socket kept, 'protocol' closed with the
    websocket protocol's code."""
    cases = []
    for key in ("rotate_y", "exposure", "terms", "env"):
        for sign in ("", "-"):
            cases.append(("websocket: huge numbers", f"{key}={sign}10^400", f'{{"type":"state","{key}":{sign}{HUGE}}}',
                          "answer" if key == "rotate_y" else "note"))
    cases += [("websocket: huge numbers", "terms=5000 digits", '{"type":"state","terms":' + "9" * 5000 + "}", "note"),
              ("websocket: huge numbers", "exposure=1e400", '{"type":"state","exposure":1e400}', "note"),
              ("websocket: huge numbers", "drawn seq=10^400", f'{{"type":"drawn","seq":{HUGE}}}', "kept")]
    cases += [("websocket: deep nesting", "20000 [", "[" * 20000 + "]" * 20000, "note"),
              ("websocket: deep nesting", '20000 {"a":', '{"a":' * 20000 + "1" + "}" * 20000, "note"),
              ("websocket: deep nesting", "rotate_y nested 20000", '{"type":"state","rotate_y":' + "[" * 20000 +
               "]" * 20000 + "}", "note"),
              ("websocket: deep nesting", "rotate_y nested 100", '{"type":"state","rotate_y":' + "[" * 100 + "]" * 100 +
               "}", "note"),
              ("websocket: deep nesting", "10000 [ unclosed", "[" * 10000, "note")]
    for key in ("rotate_y", "exposure", "terms", "env", "encoding", "translate"):
        for value in ("[1,2]", '{"a":1}', "true", "null", '"abc"'):
            cases.append(("websocket: wrong types", f"{key}={value}", f'{{"type":"state","{key}":{value}}}', "note"))
    cases += [("websocket: wrong types", "type=5", '{"type":5}', "note"),
              ("websocket: wrong types", "type=[]", '{"type":[]}', "note"),
              ("websocket: wrong types", "seq='x'", '{"type":"drawn","seq":"x"}', "note"),
              ("websocket: wrong types", "a JSON string", '"state"', "note"),
              ("websocket: wrong types", "a JSON number", "42", "note")]
    for key, lit in (("exposure", "NaN"), ("rotate_y", "Infinity"), ("terms", "-Infinity"), ("env", "NaN")):
        cases.append(("websocket: NaN/Infinity", f"{key}={lit}", f'{{"type":"state","{key}":{lit}}}', "note"))
    cases += [("websocket: unknown keys", "one unknown key", '{"type":"state","launch":1}', "note"),
              ("websocket: unknown keys", "4000 unknown keys",
               json.dumps({"type": "state", **{f"k{i}": i for i in range(4000)}}), "note"),
              ("websocket: unknown keys", "unknown type", '{"type":"launch"}', "note")]
    cases += [("websocket: binary frames", "2 bytes", b"\x00\x01", "note"),
              ("websocket: binary frames", "100 kB", bytes(100_000), "note")]
    cases += [("websocket: oversized", "64 KiB + 1", " " * (65536 + 1), "note"),
              ("websocket: oversized", "512 KiB", " " * (512 << 10), "note"),
              ("websocket: oversized", "1 MiB + 1 (protocol limit)", " " * ((1 << 20) + 1), "protocol"),
              ("websocket: oversized", "8 MiB (protocol limit)", " " * (8 << 20), "protocol")]
    cases += [("websocket: other", "empty text", "", "note"),
              ("websocket: other", "not JSON", "hello", "note"),
              ("websocket: other", "NUL and control characters", '{"type":"state","env":"\\u0000\\u0007"}', "note")]
    return cases


async def probe_messages(child, rows):
    async with aiohttp.ClientSession() as client:
        for cls, case, payload, expected in message_cases():
            t0 = time.monotonic()
            why = None
            try:
                ws = await client.ws_connect(child.ws_url, max_msg_size=0)
                await ws.send_json({"type": "state", "rotate_y": 1})
                await frame(ws)
                if isinstance(payload, bytes):
                    await ws.send_bytes(payload)
                else:
                    await ws.send_str(payload)
                if expected == "protocol":
                    msg = await ws.receive(timeout=15)
                    if msg.type not in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED):
                        why = f"not closed: {msg.type.name}"
                    elif ws.close_code not in (1009, 1007):
                        why = f"closed with {ws.close_code}"
                else:
                    if expected in ("answer", "note"):
                        msg = await ws.receive(timeout=15)
                        why = one_line_answer(msg)
                        if why is None and expected == "note" and msg.type != aiohttp.WSMsgType.TEXT:
                            why = "no note (a frame only)"
                    if why is None:   # kept: a good state gets its frame
                        await ws.send_json({"type": "state", "rotate_y": 2})
                        if await frame(ws, 15) is None:
                            why = "the socket was closed"
                await ws.close()
            except (TimeoutError, aiohttp.ClientError, ConnectionError) as e:
                # (a message over the protocol's limit: the viewer may close while it is still being sent)
                why = None if expected == "protocol" and isinstance(e, ConnectionError) else f"{type(e).__name__} {e}"[:100]
            rows.append(await verdict(child, cls, case, t0, why))
    # text that is not UTF-8 (a raw frame: clients refuse to send it)
    for case, payload in (("invalid byte", b"\xff\xfe"), ("encoded surrogate", b'{"a":"\xed\xa0\x80"}')):
        t0 = time.monotonic()
        reader, writer = await asyncio.open_connection("127.0.0.1", child.port)
        writer.write(upgrade(child.port, child.query))
        await reader.readuntil(b"\r\n\r\n")
        writer.write(masked(1, payload))
        await writer.drain()
        try:
            data = await asyncio.wait_for(reader.read(4096), 10)
            code = struct.unpack(">H", data[2:4])[0] if len(data) >= 4 and data[0] & 0x0F == 8 else None
            why = None if code == 1007 else f"answered {data[:20]!r}"
        except (TimeoutError, ConnectionError) as e:
            why = type(e).__name__
        writer.close()
        rows.append(await verdict(child, "websocket: non-UTF-8 text", case, t0, why))


async def verdict(child, cls, case, t0, why, lines_allowed=1, serving=True):
    await asyncio.sleep(0.05)
    lines = child.since(t0)
    if why is None and any("Traceback" in line for line in lines):
        why = "a traceback"
    if why is None and len(lines) > lines_allowed:
        why = f"{len(lines)} stderr lines: {lines[0][:80]}"
    if why is None and serving and not await served(child.url):
        why = "the viewer stopped serving"
    row = {"class": cls, "case": case, "failed": why is not None, "why": why, "stderr_lines": len(lines)}
    print(json.dumps(row), flush=True)
    return row


async def probe_http(child, rows):
    port, host = child.port, f"127.0.0.1:{child.port}"

    def status_of(answer: bytes):
        m = re.match(rb"HTTP/1\.[01] (\d{3}) ", answer)
        return int(m.group(1)) if m else None

    cases = [("HTTP: bad methods", m, f"{m} / HTTP/1.1\r\nHost: {host}\r\nContent-Length: 0\r\n\r\n".encode())
             for m in ("POST", "PUT", "DELETE", "PATCH", "TRACE", "FOO")]
    cases += [("HTTP: bad methods", "POST /ws", f"POST /ws HTTP/1.1\r\nHost: {host}\r\nContent-Length: 0\r\n\r\n".encode()),
              ("HTTP: bad methods", "CONNECT", f"CONNECT {host} HTTP/1.1\r\nHost: {host}\r\n\r\n".encode()),
              ("HTTP: bad methods", "OPTIONS *", f"OPTIONS * HTTP/1.1\r\nHost: {host}\r\n\r\n".encode())]
    cases += [("HTTP: huge headers", "a 20 kB header", f"GET / HTTP/1.1\r\nHost: {host}\r\nX: {'a' * 20000}\r\n\r\n".encode()),
              ("HTTP: huge headers", "300 headers", (f"GET / HTTP/1.1\r\nHost: {host}\r\n" +
                                                    "".join(f"X-{i}: y\r\n" for i in range(300)) + "\r\n").encode()),
              ("HTTP: huge headers", "a 100 kB URL", f"GET /?{'a' * 100000} HTTP/1.1\r\nHost: {host}\r\n\r\n".encode()),
              ("HTTP: huge headers", "a bad header name", f"GET / HTTP/1.1\r\nHost: {host}\r\nBad Name: x\r\n\r\n".encode()),
              ("HTTP: huge headers", "TLS hello", b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03" + bytes(64)),
              ("HTTP: huge headers", "chunked and length", (f"GET / HTTP/1.1\r\nHost: {host}\r\nContent-Length: 5\r\n"
                                                            "Transfer-Encoding: chunked\r\n\r\n0\r\n\r\n").encode())]
    cases += [("HTTP: Host and Origin", "Host evil.example", b"GET / HTTP/1.1\r\nHost: evil.example\r\n\r\n"),
              ("HTTP: Host and Origin", "Host another port", b"GET / HTTP/1.1\r\nHost: 127.0.0.1:1\r\n\r\n"),
              ("HTTP: Host and Origin", "no Host (HTTP/1.0)", b"GET / HTTP/1.0\r\n\r\n"),
              ("HTTP: Host and Origin", "ws Origin evil", upgrade(port, child.query).replace(
                  b"\r\n\r\n", b"\r\nOrigin: http://evil.example\r\n\r\n")),
              ("HTTP: Host and Origin", "ws Origin null", upgrade(port, child.query).replace(b"\r\n\r\n", b"\r\nOrigin: null\r\n\r\n")),
              ("HTTP: Host and Origin", "ws Origin https", upgrade(port, child.query).replace(
                  b"\r\n\r\n", f"\r\nOrigin: https://{host}\r\n\r\n".encode())),
              ("HTTP: Host and Origin", "the page without the token", f"GET / HTTP/1.1\r\nHost: {host}\r\n\r\n".encode()),
              ("HTTP: Host and Origin", "ws without the token", upgrade(port)),
              ("HTTP: Host and Origin", "upload without the token", (f"POST /upload?name=a.exr HTTP/1.1\r\nHost: {host}\r\n"
                                                                     "Content-Length: 1\r\n\r\nx").encode())]
    for cls, case, data in cases:
        t0 = time.monotonic()
        answer = await raw_request(port, data)
        status = status_of(answer)
        if cls == "HTTP: Host and Origin":
            why = None if status == 403 else f"answered {answer[:30]!r}"
        else:
            why = None if (status is not None and 400 <= status < 500) or answer in (b"", b"<ConnectionResetError>") \
                else f"answered {answer[:30]!r}"
        rows.append(await verdict(child, cls, case, t0, why))
    # a flood of bad requests: at most a line per interval
    t0 = time.monotonic()
    for i in range(50):
        await raw_request(port, f"GET / HTTP/1.1\r\nHost: {host}\r\nBad Name {i}: x\r\n\r\n".encode())
    rows.append(await verdict(child, "HTTP: huge headers", "50 bad requests in a row (log flood)", t0, None,
                              lines_allowed=2))


async def probe_idle(child, rows, limit=60.0):
    port, host = child.port, f"127.0.0.1:{child.port}"
    opened = []

    async def open_with(data: bytes, ws=False):
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        if data:
            writer.write(data)
            await writer.drain()
        if ws:
            await reader.readuntil(b"\r\n\r\n")
        opened.append(writer)
        return reader, writer

    t0 = time.monotonic()
    watched = {"sends nothing": (await open_with(b""))[0],
               "partial request line": (await open_with(b"GET / HT"))[0]}
    r, w = await open_with(f"GET /?{child.query} HTTP/1.1\r\nHost: {host}\r\n\r\n".encode())
    await r.read(65536)
    watched["idle keep-alive"] = r
    r, w = await open_with(upgrade(port, child.query), ws=True)      # never reads again: no pong
    watched["half-open websocket (no pong)"] = r
    r, w = await open_with(upgrade(port, child.query), ws=True)      # asks for frames, never reads them
    for i in range(200):
        w.write(masked(1, json.dumps({"type": "state", "rotate_y": i, "encoding": "raw"}).encode()))
    watched["websocket that reads nothing"] = r
    slow_r, slow_w = await open_with(f"GET / HTTP/1.1\r\nHost: {host}\r\n".encode())
    watched["slowloris (a byte every 0.5 s)"] = slow_r

    async def trickle():
        try:
            while True:
                slow_w.write(b"X")
                await slow_w.drain()
                await asyncio.sleep(0.5)
        except (ConnectionError, RuntimeError):
            return

    trickling = asyncio.ensure_future(trickle())

    async def pongs_only():   # answers pings (aiohttp does) and sends nothing
        async with aiohttp.ClientSession() as s, s.ws_connect(child.ws_url) as ws:
            t = time.monotonic()
            msg = await ws.receive(timeout=limit)
            while msg.type in (aiohttp.WSMsgType.TEXT, aiohttp.WSMsgType.BINARY):
                msg = await ws.receive(timeout=limit)
            return time.monotonic() - t

    async def watch(name, reader):
        if name == "websocket that reads nothing":   # read only once the viewer had time to give up on it
            await asyncio.sleep(limit / 2)
            return name, await closed_within(reader, limit / 2)
        return name, await closed_within(reader, limit)

    results = await asyncio.gather(*(watch(n, r) for n, r in watched.items()),
                                   asyncio.wait_for(pongs_only(), limit + 5), return_exceptions=True)
    trickling.cancel()
    for item in results[:-1]:
        name, seconds = item if not isinstance(item, BaseException) else ("?", None)
        rows.append(await verdict(child, "idle connections", name, t0,
                                  None if seconds is not None else f"still open after {limit:g} s"))
    pong = results[-1]
    rows.append(await verdict(child, "idle connections", "websocket answering pings, sending nothing", t0,
                              None if not isinstance(pong, BaseException) else f"still open after {limit:g} s"))
    for w in opened:
        w.close()


async def probe_many_websockets(child, rows):
    async with aiohttp.ClientSession() as client, client.ws_connect(child.ws_url) as page:
        await page.send_json({"type": "state", "rotate_y": 1})
        await frame(page)
        for case, abrupt in (("300 opened and closed, 50 at a time", False),
                             ("300 opened and reset, 50 at a time", True)):
            t0 = time.monotonic()
            failures = 0

            async def one(i, abrupt=abrupt):
                nonlocal failures
                try:
                    if abrupt:
                        reader, writer = await asyncio.open_connection("127.0.0.1", child.port)
                        writer.write(upgrade(child.port, child.query) + masked(1, b'{"type":"state","rotate_y":%d}' % i))
                        await writer.drain()
                        await reader.readuntil(b"\r\n\r\n")
                        writer.transport.abort()
                    else:
                        ws = await client.ws_connect(child.ws_url)
                        await ws.send_json({"type": "state", "rotate_y": i})
                        await ws.close()
                except (aiohttp.ClientError, ConnectionError, asyncio.IncompleteReadError):
                    failures += 1

            for start in range(0, 300, 50):
                await asyncio.gather(*(one(i) for i in range(start, start + 50)))
            await page.send_json({"type": "state", "rotate_y": 7 + abrupt})
            header = await frame(page, 30)
            why = f"{failures} handshakes failed" if failures else None
            if why is None and (header is None or header["state"]["rotate_y"] != 7 + abrupt):
                why = "the open page lost its frames"
            rows.append(await verdict(child, "many websockets", case, t0, why, lines_allowed=0))


async def probe_converge(child, rows, factor=8.0):
    async with aiohttp.ClientSession() as client, client.ws_connect(child.ws_url) as b:
        async def preview(i):
            t = time.perf_counter()
            await b.send_json({"type": "state", "rotate_y": 3 * i, "preview": True})
            header = await frame(b, 120)
            assert header is not None
            return time.perf_counter() - t

        i = 0
        for _ in range(5):
            await preview(i)
            i += 1
        for n in (1, 5, 20):
            await asyncio.sleep(3.0)                     # the calls of the pages closed before end
            t0 = time.monotonic()
            unloaded = []
            for _ in range(15):
                unloaded.append(await preview(i))
                i += 1
            pages = [await client.ws_connect(child.ws_url) for _ in range(n)]
            reports = []

            async def converging(ws, k, reports=reports):
                await ws.send_json({"type": "state", "rotate_y": 100 + k, "converge": True})
                while True:
                    header = await frame(ws, 300)
                    if header is None:
                        return
                    if header["converge"] is not None:
                        reports.append(header["converge"])

            tasks = [asyncio.ensure_future(converging(ws, k)) for k, ws in enumerate(pages)]
            await asyncio.sleep(2.0)
            loaded = []
            budget = time.monotonic() + 45.0             # (previews that wait for whole calls: a few)
            while len(loaded) < 15 and time.monotonic() < budget:
                loaded.append(await preview(i))
                i += 1
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            for ws in pages:
                await ws.close()
            base, under = statistics.median(unloaded), statistics.median(loaded)
            why = None if under <= factor * base else f"median {1e3 * under:.0f} ms against {1e3 * base:.1f} ms"
            row = await verdict(child, "converge load", f"previews while {n} pages converge", t0, why)
            row.update(unloaded_ms=round(1e3 * base, 2), loaded_ms=round(1e3 * under, 2),
                       loaded_max_ms=round(1e3 * max(loaded), 2), converge_rounds=len(reports))
            rows.append(row)


async def probe_descriptors(bake, tree, rows):
    import resource

    child = Child(bake, tree, {"HTTP_IDLE_SECONDS": 300})
    held = []
    try:
        async with aiohttp.ClientSession() as client, client.ws_connect(child.ws_url) as page:
            await page.send_json({"type": "state", "rotate_y": 1})
            await frame(page)
            fds = len(os.listdir(f"/proc/{child.proc.pid}/fd"))
            resource.prlimit(child.proc.pid, resource.RLIMIT_NOFILE,
                             (fds + 16, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))
            t0 = time.monotonic()
            unanswered = 0   # connections the kernel did not even complete (the viewer's queue full)
            for _ in range(200):
                try:
                    held.append(await asyncio.wait_for(asyncio.open_connection("127.0.0.1", child.port), 3.0))
                except (TimeoutError, OSError):
                    unanswered += 1
                    if unanswered >= 5:
                        break
            await asyncio.sleep(3.0)
            refused = 0
            for reader, _ in held:
                try:
                    data = await asyncio.wait_for(reader.read(4096), 0.05)
                except TimeoutError:
                    continue
                except ConnectionError:
                    data = b""
                refused += data == b"" or data.startswith(b"HTTP/1.1 503")
            lines = child.since(t0)
            rows.append(await verdict(child, "descriptor limit", "200 connections: refused at once", t0,
                                      None if refused >= 150 else f"{refused} of 200 answered", lines_allowed=10 ** 9,
                                      serving=False))   # (it refuses while they are held: its point)
            rows[-1]["stderr_lines"] = len(lines)
            row = {"class": "descriptor limit", "case": "stderr lines in 3 s at the limit",
                   "failed": len(lines) > 2, "why": None if len(lines) <= 2 else f"{len(lines)} lines: {lines[0][:80]}",
                   "stderr_lines": len(lines)}
            print(json.dumps(row), flush=True)
            rows.append(row)
            await page.send_json({"type": "state", "rotate_y": 2})
            try:
                header = await frame(page, 20)
            except TimeoutError:
                header = None
            row = {"class": "descriptor limit", "case": "the open page keeps its frames",
                   "failed": header is None, "why": None if header else "no frame in 20 s"}
            print(json.dumps(row), flush=True)
            rows.append(row)
            for _, writer in held:
                writer.close()
            held.clear()
            ok = False
            deadline = time.monotonic() + 20
            while not ok and time.monotonic() < deadline:
                ok = await served(child.url, 5)
                if not ok:
                    await asyncio.sleep(0.5)
            row = {"class": "descriptor limit", "case": "served again once they close", "failed": not ok,
                   "why": None if ok else "not served within 20 s"}
            print(json.dumps(row), flush=True)
            rows.append(row)
    finally:
        for _, writer in held:
            writer.close()
        child.stop()


CLASSES = ("messages", "http", "idle", "many", "converge", "descriptors")


async def run(bake, tree, classes):
    rows = []
    if {"messages", "http", "many", "converge"} & set(classes):
        child = Child(bake, tree)
        try:
            if "messages" in classes:
                await probe_messages(child, rows)
            if "http" in classes:
                await probe_http(child, rows)
            if "many" in classes:
                await probe_many_websockets(child, rows)
            if "converge" in classes:
                await probe_converge(child, rows)
        finally:
            code = child.stop()
            rows.append({"class": "stop", "case": "SIGINT ends it with exit 0", "failed": code != 0,
                         "why": None if code == 0 else f"exit {code}"})
            print(json.dumps(rows[-1]), flush=True)
    if "idle" in classes:
        child = Child(bake, tree, {"HTTP_IDLE_SECONDS": 2, "WS_HEARTBEAT_SECONDS": 2, "WS_IDLE_SECONDS": 4})
        try:
            await probe_idle(child, rows)
        finally:
            child.stop()
    if "descriptors" in classes:
        await probe_descriptors(bake, tree, rows)
    return rows


def table(rows, compared=None):
    """Per class: cases, failed (and failed in the compared rows)."""
    out = {}
    for r in rows:
        t = out.setdefault(r["class"], {"cases": 0, "failed": 0})
        t["cases"] += 1
        t["failed"] += bool(r["failed"])
    if compared:
        for r in compared:
            t = out.setdefault(r["class"], {"cases": 0, "failed": 0})
            t["failed_compared"] = t.get("failed_compared", 0) + bool(r["failed"])
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", default=None, help="run the children with PYTHONPATH=DIR (another copy of the package)")
    ap.add_argument("--classes", default=",".join(CLASSES), help=f"some of {','.join(CLASSES)}")
    ap.add_argument("--compare", default=None, help="a JSON file of this probe (a baseline) to set beside")
    ap.add_argument("-o", "--output", default=os.path.join(HERE, "results", "probe-viewer.json"))
    args = ap.parse_args()
    classes = [c for c in args.classes.split(",") if c]
    rows = asyncio.run(run(bake_file(), args.tree, classes))
    compared = None
    if args.compare:
        with open(args.compare) as fh:
            compared = json.load(fh)["rows"]
    data = {"tree": args.tree or "this checkout", "rows": rows, "table": table(rows, compared)}
    if compared is not None:
        data["compared"] = compared
    text = json.dumps(data, indent=1)
    if args.output == "-":
        print(text)
    else:
        with open(args.output, "w") as fh:
            fh.write(text + "\n")
    for cls, t in data["table"].items():
        extra = f", baseline failed {t['failed_compared']}" if "failed_compared" in t else ""
        print(f"{cls}: {t['cases']} cases, {t['failed']} failed{extra}")


if __name__ == "__main__":
    main()
