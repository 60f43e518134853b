"""The viewer under abuse and load: malformed websocket messages (integers beyond the floats'
range, deep nesting, wrong types, NaN and Infinity, unknown keys, binary frames, sizes) are
answered with one-line notes, values clamped, the socket kept and nothing on stderr; idle,
half-open and slowloris connections are cut after the settings' times; at the file descriptor
limit (lowered in a child process) new connections are refused with 503 and one log line per
interval while the open page keeps its frames, and served again once descriptors free up;
bad HTTP requests are logged at most once per interval; a page that converges leaves another
page's preview frames about as fast as without it.

The viewers run on 127.0.0.1 (a free port) from a thread of their own (the fixtures of
tests/test_viewer.py), or as `wavlight view` in a child process, and are always stopped.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import functools
import json
import os
import re
import signal
import socket
import statistics
import struct
import subprocess
import sys
import time
import urllib.error
import urllib.request

import numpy as np
import pytest

pytest.importorskip("aiohttp")

import aiohttp
import test_viewer
from repo import REPO

import wavlight
from wavlight.relight import viewer as viewer_module
from wavlight.relight.progressive import PassSchedule
from wavlight.relight.viewer import EXPOSURE_RANGE, Limits, ObjectLimits, Viewer, ViewLimits, sanitise

#: the fixtures of tests/test_viewer.py: its small bake, loaded, a viewer of it (a fake estimator),
#: headless chromium and its pages
bake_file, transfer, serve = test_viewer.bake_file, test_viewer.transfer, test_viewer.serve
browser, page = test_viewer.browser, test_viewer.page

#: a shipped scene (Spot on a floor under the rooitou sun): its unbiased frame is slow enough
SCENE = str(REPO / "scenes" / "spot_ggx.toml")


# ----------------------------------------------------------------------------- helpers
def in_a_thread(coroutine_function, seconds=180):
    """asyncio.run(coroutine_function()) in a thread of its own (a browser test's playwright may
    keep an event loop in this one)."""
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, coroutine_function()).result(seconds)


def wait_until(predicate, seconds=10.0):
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return predicate()


async def next_frame(ws, timeout=30.0):
    """(header, the text messages before it) of the next frame, acknowledged."""
    texts = []
    while True:
        msg = await asyncio.wait_for(ws.receive(), timeout)
        if msg.type == aiohttp.WSMsgType.TEXT:
            texts.append(json.loads(msg.data))
            continue
        assert msg.type == aiohttp.WSMsgType.BINARY, msg
        n = struct.unpack("<I", msg.data[:4])[0]
        header = json.loads(msg.data[4:4 + n])
        await ws.send_json({"type": "drawn", "seq": header["seq"]})
        return header, texts


async def next_text(ws, timeout=10.0) -> dict:
    msg = await asyncio.wait_for(ws.receive(), timeout)
    assert msg.type == aiohttp.WSMsgType.TEXT, msg
    return json.loads(msg.data)


def closed_by_peer(sock, seconds) -> float | None:
    """Seconds until the peer closed (EOF or reset) ``sock``, reading whatever it sends; None if it
    stayed open for ``seconds``."""
    t0 = time.monotonic()
    sock.settimeout(0.2)
    while time.monotonic() - t0 < seconds:
        try:
            if sock.recv(65536) == b"":
                return time.monotonic() - t0
        except TimeoutError:
            continue
        except OSError:   # reset
            return time.monotonic() - t0
    return None


def handshake(port, token) -> socket.socket:
    """A websocket opened by hand (raw socket, with the viewer's ``token``) after its 101."""
    s = socket.create_connection(("127.0.0.1", port), timeout=10)
    s.sendall(f"GET /ws?token={token} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
              "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n".encode())
    assert s.recv(4096).startswith(b"HTTP/1.1 101")
    return s


def stderr_lines(capfd) -> list[str]:
    return [line for line in capfd.readouterr().err.splitlines() if line.strip()]


# ----------------------------------------------------------------------------- item: malformed messages
LIMITS = Limits(maps=2, max_terms=1024, rotate_y=0.0, terms=256)
HUGE = 10 ** 400


def test_sanitise_clamps_integers_beyond_the_floats_range():
    state, notes = sanitise({"rotate_y": HUGE, "exposure": HUGE, "terms": HUGE, "env": HUGE}, LIMITS)
    assert state["rotate_y"] == float(HUGE % 360)           # wrapped exactly
    assert state["exposure"] == EXPOSURE_RANGE[1] and state["terms"] == LIMITS.max_terms and state["env"] == 0
    assert len(notes) == 3 and all("\n" not in n and len(n) < 200 for n in notes)
    state, notes = sanitise({"rotate_y": -HUGE, "exposure": -HUGE, "terms": -HUGE, "env": -HUGE}, LIMITS)
    assert state["rotate_y"] == float(-HUGE % 360) and state["exposure"] == EXPOSURE_RANGE[0]
    assert state["terms"] == 1 and state["env"] == 0 and len(notes) == 3
    obj = ObjectLimits(translate=(0.0, 0.6, 0.0), lo=(-3.7, -0.1, -3.7), hi=(3.7, 1.3, 3.7), step=0.01,
                       rotate_y=0.0)
    state, notes = sanitise({"translate": [HUGE, -HUGE, 0], "rotate_y": HUGE, "exposure": -HUGE}, obj)
    assert state["translate"] == [3.7, -0.1, 0.0] and state["rotate_y"] == float(HUGE % 360)
    assert state["exposure"] == EXPOSURE_RANGE[0] and len(notes) == 3
    view = ViewLimits(azimuth=10.0, elevation=5.0, distance=4.0, distance_lo=0.2, distance_hi=80.0)
    state, notes = sanitise({"azimuth": -HUGE, "elevation": HUGE, "distance": -HUGE}, view)
    assert state["azimuth"] == float(-HUGE % 360) and state["elevation"] == viewer_module.ELEVATION_LIMIT
    assert state["distance"] == 0.2 and len(notes) == 2


def test_read_message_bounds_size_and_depth_before_parsing():
    read = viewer_module.read_message
    deep = "[" * 20000 + "]" * 20000
    for text, why in ((deep, "nested 20000 deep"), ('{"rotate_y": ' + "[" * 5000 + "]" * 5000 + "}", "nested"),
                      ('{"terms": ' + "9" * 5000 + "}", "5000 digits"),
                      (" " * (viewer_module.MAX_MESSAGE_BYTES + 1), "bytes"), ("", "not JSON"), ("[1, 2]", "object"),
                      ('"state"', "object"), ('{"a": 1', "not JSON")):
        data, note = read(text)
        assert data is None and why in note and "\n" not in note and len(note) < 300, (text[:40], note)
    # brackets inside strings are not nesting; NaN and Infinity are read (the state notes them)
    data, note = read('{"type": "state", "x": "' + "[" * 100 + '", "exposure": NaN, "rotate_y": -Infinity}')
    assert note is None and data["x"] == "[" * 100 and np.isnan(data["exposure"]) and data["rotate_y"] == -np.inf
    assert viewer_module.nesting_depth('{"a": [[1], [2]]}') == 3
    assert viewer_module.nesting_depth('{"a": [[1], {"b": [2]}]}') == 4


def test_malformed_messages_get_one_line_notes_and_keep_the_socket(serve, capfd):
    v = serve()
    max_terms, rot = v.limits.max_terms, v.limits.rotate_y

    # (message, what it is: a state drawn after its notes / an error note / nothing, what a note says)
    cases = [
        (f'{{"type": "state", "rotate_y": {HUGE}}}', "state", None),
        (f'{{"type": "state", "exposure": {HUGE}}}', "state", "outside"),
        (f'{{"type": "state", "exposure": -{HUGE}}}', "state", "outside"),
        (f'{{"type": "state", "terms": {HUGE}}}', "state", "outside"),
        (f'{{"type": "state", "terms": -{HUGE}}}', "state", "outside"),
        (f'{{"type": "state", "env": {HUGE}}}', "state", "not one of the maps"),
        (f'{{"type": "state", "terms": {"9" * 5000}}}', "error", "digits"),
        ("[" * 20000 + "]" * 20000, "error", "nested"),
        ('{"type": "state", "rotate_y": ' + "[" * 20000 + "]" * 20000 + "}", "error", "nested"),
        ('{"type": "state", "rotate_y": ' + "[" * 10 + "]" * 10 + "}", "state", "not a number"),
        ('{"type": "state", "exposure": NaN}', "state", "not finite"),
        ('{"type": "state", "exposure": Infinity}', "state", "not finite"),
        ('{"type": "state", "rotate_y": -Infinity}', "state", "not finite"),
        ('{"type": "state", "rotate_y": {"a": 1}, "terms": true, "env": null, "exposure": "x"}', "state",
         "not a number"),
        ('{"type": 5}', "error", "unknown message type"),
        ('{"type": "drawn", "seq": "1"}', "error", "not an integer"),
        (f'{{"type": "drawn", "seq": {HUGE}}}', "nothing", None),   # a frame never sent: ignored
        ('{"type": "state", "rotate_y": 10, "launch": 1, "x": [1]}', "state", "unknown keys"),
        (json.dumps({"type": "state", **{f"k{i}": i for i in range(4000)}}), "state", "unknown keys"),
        ("x" * (viewer_module.MAX_MESSAGE_BYTES + 1), "error", "bytes"),
        ("", "error", "not JSON"),
        ("\ud7ff\u0000", "error", "not JSON"),
        ('"state"', "error", "JSON object"),
    ]

    async def talk():
        async with aiohttp.ClientSession() as client, client.ws_connect(v.socket_url) as ws:
            drawn = {}
            for i, (text, kind, says) in enumerate(cases):
                # a good state first (another picture than the case's), then the case
                await ws.send_json({"type": "state", "rotate_y": i + 0.5, "terms": 64})
                header, _ = await next_frame(ws)
                assert header["state"]["rotate_y"] == i + 0.5
                await ws.send_str(text)
                if kind == "state":
                    header, texts = await next_frame(ws)
                    drawn[i] = header["state"]
                elif kind == "error":
                    texts = [await next_text(ws)]
                else:
                    texts = []
                lines = [n for t in texts for n in (t.get("notes") or [t.get("message")])]
                assert all(isinstance(n, str) and "\n" not in n and len(n) < 300 for n in lines), (text[:40], lines)
                if says is not None:
                    assert any(says in n for n in lines), (text[:40], lines)
                if kind == "error":
                    assert texts[0]["type"] == "error"
            await ws.send_bytes(b"\x00\x01")
            assert (await next_text(ws))["type"] == "error"
            await ws.send_json({"type": "state", "rotate_y": 77})
            assert (await next_frame(ws))[0]["state"]["rotate_y"] == 77
            return drawn

    drawn = in_a_thread(talk)
    assert drawn[0]["rotate_y"] == float(HUGE % 360)
    assert drawn[1]["exposure"] == EXPOSURE_RANGE[1] and drawn[2]["exposure"] == EXPOSURE_RANGE[0]
    assert drawn[3]["terms"] == max_terms and drawn[4]["terms"] == 1 and drawn[5]["env"] == 0
    assert drawn[10]["exposure"] == 0.0 and drawn[12]["rotate_y"] == rot and drawn[17]["rotate_y"] == 10
    assert wait_until(lambda: v.clients == 0 and v.running_tasks == 0)
    assert stderr_lines(capfd) == []     # bad input is the page's business: nothing on stderr


# ----------------------------------------------------------------------------- item: connection timeouts
@pytest.fixture
def short_timeouts(monkeypatch):
    """The connection settings shortened (the viewer reads them as it serves)."""
    from wavlight.relight import serving

    monkeypatch.setattr(serving, "HTTP_IDLE_SECONDS", 1.0)
    monkeypatch.setattr(serving, "WS_HEARTBEAT_SECONDS", 1.0)
    monkeypatch.setattr(serving, "WS_IDLE_SECONDS", 2.0)
    return serving


def test_idle_half_open_and_slowloris_connections_are_cut(serve, short_timeouts, capfd):
    v = serve()
    idle = short_timeouts.HTTP_IDLE_SECONDS
    bound = 10 * idle + 5.0                           # generous: the setting's time, not this machine's
    host = f"Host: 127.0.0.1:{v.port}\r\n"
    with socket.create_connection(("127.0.0.1", v.port)) as silent, \
            socket.create_connection(("127.0.0.1", v.port)) as partial, \
            socket.create_connection(("127.0.0.1", v.port)) as kept:
        partial.sendall(b"GET / HT")
        kept.sendall(f"GET /?token={v.token} HTTP/1.1\r\n{host}\r\n".encode())
        kept.settimeout(10)
        assert kept.recv(65536).startswith(b"HTTP/1.1 200")
        t0 = time.monotonic()
        for s in (silent, partial, kept):
            seconds = closed_by_peer(s, bound)
            assert seconds is not None, "a connection was never closed"
        assert time.monotonic() - t0 >= 0.8 * idle     # not before the setting's time
    # slowloris: a header byte every tenth of a second keeps no connection alive past the setting
    with socket.create_connection(("127.0.0.1", v.port)) as slow:
        slow.sendall(f"GET / HTTP/1.1\r\n{host}".encode())
        t0, cut = time.monotonic(), None
        while time.monotonic() - t0 < bound:
            try:
                slow.sendall(b"X")
            except OSError:
                cut = time.monotonic() - t0
                break
            slow.settimeout(0.1)
            try:
                if slow.recv(4096) == b"":
                    cut = time.monotonic() - t0
                    break
            except TimeoutError:
                pass
            except OSError:
                cut = time.monotonic() - t0
                break
        assert cut is not None and cut >= 0.8 * idle
    # the server still serves
    with urllib.request.urlopen(v.url, timeout=10) as r:
        assert r.status == 200
    assert stderr_lines(capfd) == []


@pytest.mark.slow
def test_half_open_and_idle_websockets_are_closed(serve, short_timeouts, capfd):
    v = serve()
    ws_idle = short_timeouts.WS_IDLE_SECONDS
    beat = short_timeouts.WS_HEARTBEAT_SECONDS
    # half-open: the peer answers no ping (nor reads anything)
    with handshake(v.port, v.token):
        assert wait_until(lambda: v.clients == 1)
        t0 = time.monotonic()
        assert wait_until(lambda: v.clients == 0, 10 * beat + 5.0)
        assert time.monotonic() - t0 >= 0.8 * beat

    async def talk():
        async with aiohttp.ClientSession() as client:
            # idle: pongs come back (aiohttp answers pings) but the page sends nothing
            async with client.ws_connect(v.socket_url) as ws:
                await ws.send_json({"type": "state", "rotate_y": 5})
                await next_frame(ws)
                t0 = time.monotonic()
                note = await next_text(ws, 10 * ws_idle + 5.0)
                msg = await ws.receive(timeout=10)
                idle_after = time.monotonic() - t0
                assert note["type"] == "error" and "no message from this page" in note["message"]
                assert msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.CLOSING)
                assert ws.close_code == short_timeouts.IDLE_CLOSE_CODE
            # a page that keeps sending is kept for longer than the idle time
            async with client.ws_connect(v.socket_url) as ws:
                t0 = time.monotonic()
                i = 0
                while time.monotonic() - t0 < 2 * ws_idle:
                    await ws.send_json({"type": "state", "rotate_y": i})
                    await next_frame(ws)
                    await asyncio.sleep(ws_idle / 8)
                    i += 1
                assert not ws.closed
        return idle_after

    idle_after = in_a_thread(talk)
    assert idle_after >= 0.8 * ws_idle
    assert wait_until(lambda: v.clients == 0 and v.running_tasks == 0)
    assert stderr_lines(capfd) == []


@pytest.mark.slow
def test_browser_page_closed_for_idleness_connects_again_when_a_control_moves(serve, short_timeouts, page):
    v = serve()
    pg = page()
    pg.goto(v.url + "&rotate_y=30")
    pg.wait_for_function("() => window.viewer && window.viewer.frames >= 1")
    # nothing moves: the viewer closes the socket, the page says so and does not retry by itself
    pg.wait_for_function("() => document.getElementById('status').textContent.startsWith('idle')",
                         timeout=int(1000 * (10 * short_timeouts.WS_IDLE_SECONDS + 5)))
    assert wait_until(lambda: v.clients == 0)
    time.sleep(short_timeouts.WS_IDLE_SECONDS)
    assert v.clients == 0
    frames = pg.evaluate("viewer.frames")
    pg.evaluate("""() => { const e = document.getElementById('rotate_y'); e.value = 120;
        e.dispatchEvent(new Event('input', {bubbles: true})); e.dispatchEvent(new Event('change', {bubbles: true})); }""")
    pg.wait_for_function(f"() => viewer.frames > {frames} && viewer.last.state.rotate_y === 120")
    assert v.clients == 1 and pg.text_content("#status") == ""


def test_bad_http_requests_are_answered_and_logged_at_most_once_per_interval(serve, capfd):
    from wavlight.relight import serving

    v = serve()
    host = f"Host: 127.0.0.1:{v.port}\r\n"
    answers = []
    t0 = time.monotonic()
    for i in range(20):   # a header name with a space: 400 (aiohttp logs each)
        with socket.create_connection(("127.0.0.1", v.port), timeout=10) as s:
            s.sendall(f"GET / HTTP/1.1\r\n{host}Bad Header {i}: x\r\n\r\n".encode())
            answers.append(s.recv(64))
    for method in ("POST", "PUT", "DELETE", "PATCH"):
        req = urllib.request.Request(v.url, method=method, data=b"x")
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(req, timeout=10)
        assert e.value.code == 405
    elapsed = time.monotonic() - t0
    assert all(re.match(rb"HTTP/1\.[01] 400 ", a) for a in answers), answers[:2]
    lines = stderr_lines(capfd)
    assert len(lines) <= 1 + elapsed // serving.LOG_INTERVAL_SECONDS, lines
    assert all("Traceback" not in line for line in lines)


# ----------------------------------------------------------------------------- item: the descriptor limit
CHILD = """
import sys
from wavlight.relight import serving
serving.HTTP_IDLE_SECONDS = 300.0     # the connections held by the test are not cut while it runs
from wavlight.cli.main import main
main(["view", sys.argv[1], "--no-browser"])
"""


def open_descriptors(pid) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


@pytest.mark.slow
@pytest.mark.skipif(not os.path.isdir("/proc/self/fd") or not hasattr(__import__("resource"), "prlimit"),
                    reason="needs /proc and prlimit (Linux)")
def test_at_the_descriptor_limit_new_connections_are_refused_and_open_pages_kept(bake_file):
    import resource

    from wavlight.relight import serving

    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(bake_file[0])], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    lines: list[str] = []
    held: list[socket.socket] = []
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("http://127.0.0.1:"), url
        port = int(url.split("//", 1)[1].split("/", 1)[0].rsplit(":", 1)[1])
        reader = concurrent.futures.ThreadPoolExecutor(1)
        reader.submit(lambda: [lines.append(line) for line in proc.stderr])

        async def talk():
            async with aiohttp.ClientSession() as client, client.ws_connect(url.replace("/?token=", "/ws?token=")) as page:
                await page.send_json({"type": "state", "rotate_y": 10})
                await next_frame(page)                       # the page is open and drawn
                # and has converged once (the converge thread, prepared when the page opened, has
                # its bake and kernels), then released
                await page.send_json({"type": "state", "rotate_y": 10, "converge": True})
                while (await next_frame(page, 120))[0]["converge"] is None:
                    pass
                await page.send_json({"type": "state", "rotate_y": 10, "converge": False})
                while (await next_frame(page, 120))[0]["converge"] is not None:
                    pass
                # the limit: what the viewer has open now, and a few more
                spare = 12
                resource.prlimit(proc.pid, resource.RLIMIT_NOFILE,
                                 (open_descriptors(proc.pid) + spare, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))
                t0 = time.monotonic()
                for _ in range(spare + 40):                  # idle connections, until none is accepted
                    held.append(socket.create_connection(("127.0.0.1", port), timeout=10))
                await asyncio.sleep(1.0)
                refused = 0
                for s in held:
                    s.settimeout(0.05)
                    try:
                        data = s.recv(4096)
                    except TimeoutError:
                        continue                              # accepted, idle
                    except OSError:
                        data = b""
                    refused += 1
                    assert data == b"" or data.startswith(b"HTTP/1.1 503"), data
                assert refused >= 40 - 2, refused            # answered at once, not left in the queue
                # the open page keeps its frames
                await page.send_json({"type": "state", "rotate_y": 20})
                header, _ = await next_frame(page)
                assert header["state"]["rotate_y"] == 20
                at_limit = time.monotonic() - t0
                # descriptors free up: served again
                for s in held:
                    s.close()
                held.clear()
                served = None
                deadline = time.monotonic() + 20
                while served is None and time.monotonic() < deadline:
                    try:
                        async with client.get(url, timeout=aiohttp.ClientTimeout(total=5)) as r:
                            served = r.status if r.status == 200 else None
                    except aiohttp.ClientError:
                        pass
                    if served is None:
                        await asyncio.sleep(0.2)
                assert served == 200
                return at_limit

        at_limit = in_a_thread(talk)
        proc.send_signal(signal.SIGINT)
        proc.wait(30)
        reader.shutdown(wait=True)
    finally:
        for s in held:
            s.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, lines
    refusals = [line for line in lines if "out of file descriptors" in line]
    assert 1 <= len(refusals) <= 1 + at_limit // serving.LOG_INTERVAL_SECONDS, lines[:5]
    assert len(lines) <= len(refusals) + 1 and not any("Traceback" in line for line in lines), lines[:5]


# ----------------------------------------------------------------------------- item: converge and other pages
@pytest.fixture(scope="module")
def converge_bake(tmp_path_factory, device):
    """A bake (128 x 128 pixels) whose unbiased frame takes a while: a call of the estimator is
    much longer than a preview frame."""
    path = tmp_path_factory.mktemp("viewer-load") / "spot.wlt"
    wavlight.bake(SCENE, output=str(path), width=128, height=128, spp=2, levels=5, terms=256,
                  priority="transfer").close()
    t = wavlight.Transfer.load(path)
    yield t
    t.close()


#: a preview frame while another page converges takes at most this many times its median unloaded
FACTOR = 8.0


@pytest.mark.slow
def test_a_page_converging_leaves_another_pages_previews_responsive(converge_bake, capfd, monkeypatch):
    # passes of 16 spp from the first: each holds a thread much longer than a preview on any device
    # (the default schedule's first passes of 2 spp may be as short as a few previews)
    monkeypatch.setattr("wavlight.relight.viewer.PassSchedule", functools.partial(PassSchedule, first=16))
    v = Viewer(converge_bake)                 # the real estimator
    v.start_background(0)

    async def preview(ws, i):
        t0 = time.perf_counter()
        await ws.send_json({"type": "state", "rotate_y": 3 * i, "preview": True})
        header, _ = await next_frame(ws)
        assert header["preview"] is True and header["state"]["rotate_y"] == 3 * i
        return time.perf_counter() - t0

    async def converging(ws, reports):
        while True:
            header, _ = await next_frame(ws, 120)
            if header["converge"] is not None:
                reports.append(header["converge"])

    async def talk():
        async with aiohttp.ClientSession() as client, client.ws_connect(v.socket_url) as b:
            for i in range(5):                                  # warm: kernels, the map's projector
                await preview(b, i)
            unloaded = [await preview(b, i) for i in range(5, 25)]
            async with client.ws_connect(v.socket_url) as a:
                await a.send_json({"type": "state", "rotate_y": 200, "converge": True})
                reports: list = []
                task = asyncio.ensure_future(converging(a, reports))
                while not reports:                              # the converge thread's bake is loaded
                    await asyncio.sleep(0.05)
                loaded = [await preview(b, i) for i in range(25, 45)]
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
            return unloaded, loaded, reports

    try:
        unloaded, loaded, reports = in_a_thread(talk)
    finally:
        v.stop_background()
    base = statistics.median(unloaded)
    calls = [r["pass_seconds"] for r in reports]
    # the premise: a pass holds a thread longer than twice the bound (a preview waiting for the
    # rest of one, half of it on average, fails)
    assert min(calls) > 2 * FACTOR * base, (calls, base)
    assert statistics.median(loaded) <= FACTOR * base, (sorted(loaded), base, calls)
    assert max(loaded) < min(calls), (sorted(loaded), calls)   # no preview waited for a whole call
    assert v.clients == 0 and v.running_tasks == 0
    assert stderr_lines(capfd) == []
