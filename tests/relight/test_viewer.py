"""The interactive viewer (wavlight view): the state from the URL sanitised, frames over
the websocket, the page in a real browser (Debian's chromium driven headless by playwright:
moving a slider changes the picture, the page reports its frame rate), two pages at once, a
page closed while frames stream, the converge control, and the command line; and the same for a
bake that varies one object (a tilted card over a floor under a small sun): its translation and
rotation sliders, its state in the URL, its frames and converge by the moving-object estimator,
and its bad parameters; and for a bake that varies the view (a ball on a floor): the orbit of the
camera by a drag on the picture, the wheel and the sliders (smaller frames while dragging), its
state in the URL, its frames against ViewFrames.frame, converge by ViewFrames.converge, its bad
parameters and the command line.

The server runs on 127.0.0.1 (a free port) in a thread of its own, started by a fixture and
always stopped. The browser tests are skipped only where playwright or chromium is missing.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import itertools
import json
import os
import re
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("aiohttp")

import aiohttp  # noqa: E402
from click.testing import CliRunner  # noqa: E402
from scenes_util import over_floor, toml_text, write_sun_sky  # noqa: E402

import wavlight  # noqa: E402
from wavlight.cli.main import main  # noqa: E402
from wavlight.imageio import srgb_encode  # noqa: E402
from wavlight.relight import viewer as viewer_module  # noqa: E402
from wavlight.relight.settings import VIEWER  # noqa: E402
from wavlight.relight.viewer import (EXPOSURE_RANGE, Limits, ObjectLimits, Viewer, ViewLimits, sanitise,  # noqa: E402
                                     tone_map)
from wavlight.scene import rotation  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
#: `wavlight view ...` in a fresh interpreter
WAVLIGHT = [sys.executable, "-m", "wavlight.cli.main"]
SCENE = ROOT / "scenes" / "spot_ggx.toml"
LEVELS = 5                      # 32 x 32 texels: K up to 1024
TIMEOUT_MS = 15000


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def bake_file(tmp_path_factory, device):
    """A tiny bake (32 x 32 pixels) of Spot, and a second map (a gradient, 32 x 16)."""
    folder = tmp_path_factory.mktemp("viewer")
    path = folder / "spot.wlt"
    wavlight.bake(str(SCENE), output=str(path), width=32, height=32, spp=2, levels=LEVELS, terms=256,
                  priority="transfer").close()
    sky = np.zeros((16, 32, 3), np.float32)
    sky[..., 0] = np.linspace(0.2, 2.0, 32)[None, :]
    sky[..., 1] = np.linspace(1.5, 0.1, 16)[:, None]
    sky[..., 2] = 0.7
    wavlight.save_image(str(folder / "gradient.exr"), sky)
    return path, folder / "gradient.exr"


def _loaded(path):
    """A fixture's body: the bake file at ``path`` loaded, closed after its tests."""
    t = wavlight.Transfer.load(path)
    yield t
    t.close()


@pytest.fixture(scope="module")
def transfer(bake_file):
    yield from _loaded(bake_file[0])


class FakeConverge:
    """A stand-in estimator with the converge signature: the K-term frame plus seeded noise of
    standard error 5% / sqrt(spp); records its calls."""

    def __init__(self, delay=0.0):
        self.calls, self.delay = [], delay

    def __call__(self, transfer, scene=None, env=None, rotate_y=None, scale=1.0, spp=4, seed=0, progress=None):
        self.calls.append({"rotate_y": rotate_y, "spp": spp, "seed": seed})
        if self.delay:
            time.sleep(self.delay)
        image = transfer.frame(env, rotate_y, scale)
        err = np.full(image.shape, 0.05 * float(image.mean()) / np.sqrt(spp), np.float32)
        noise = np.random.default_rng(seed).standard_normal(image.shape).astype(np.float32)
        return np.maximum(image + noise * err, 0.0), err


def _serving(transfer, defaults=dict):
    """A fixture's body: start(**viewer options) -> a running Viewer of ``transfer`` (its URL:
    viewer.url; ``defaults()`` gives the options not passed), all stopped after the test, each
    with no client and no task left."""
    started = []

    def start(**options):
        v = Viewer(transfer, **{**defaults(), **options})
        v.start_background(0)
        started.append(v)
        return v

    yield start
    for v in started:
        v.stop_background()
        assert v.clients == 0 and v.running_tasks == 0


@pytest.fixture
def serve(transfer, bake_file):
    """serve(**viewer options) -> a running Viewer, stopped after the test."""
    yield from _serving(transfer, lambda: {"maps": [str(bake_file[1])], "converge": FakeConverge()})


def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


@pytest.fixture(scope="module")
def browser():
    sync_api = pytest.importorskip("playwright.sync_api")
    path = _chromium()
    if path is None:
        pytest.skip("no chromium installed")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=path, headless=True, args=["--no-sandbox"])
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def page(browser):
    """A fresh page (a context of its own: another browser), closed after the test."""
    pages = []

    def new():
        context = browser.new_context()
        pg = context.new_page()
        pg.set_default_timeout(TIMEOUT_MS)
        pages.append(context)
        return pg

    yield new
    for context in pages:
        context.close()


def _pixel_sum(pg) -> float:
    return pg.evaluate("""() => { const c = document.getElementById('frame');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let s = 0; for (let i = 0; i < d.length; i += 4) s += d[i] + d[i + 1] + d[i + 2]; return s; }""")


def _set(pg, control, value):
    """Set a control and dispatch what a user's change dispatches (input, then change)."""
    pg.evaluate("""([id, v]) => { const e = document.getElementById(id); e.value = v;
        e.dispatchEvent(new Event('input', {bubbles: true})); e.dispatchEvent(new Event('change', {bubbles: true})); }""",
                [control, value])


def _frames(pg, at_least):
    pg.wait_for_function(f"() => window.viewer && window.viewer.frames >= {at_least}")


def _opened(serve, page, query="", **options):
    """A viewer started by ``serve`` (with ``options``) and a page at its URL + ``query``, after
    the page's first frame."""
    v = serve(**options)
    pg = page()
    pg.goto(v.url + query.replace("?", "&", 1))
    _frames(pg, 1)
    return v, pg


def _start_converge(pg, passes=2):
    """Press converge and wait for ``passes`` passes of refinement."""
    assert not pg.is_disabled("#converge")
    pg.click("#converge")
    pg.wait_for_function(f"() => viewer.last.converge && viewer.last.converge.passes >= {passes}")
    assert "spp" in pg.text_content("#converge_info")


#: the page's converge line: "converge: N spp, relative error X% (...)"
CONVERGE_TEXT = re.compile(r"converge: (\d+) spp, relative error ([0-9.]+)%")



def _wait(predicate, seconds=10.0):
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return predicate()


# ----------------------------------------------------------------------------- no browser
LIMITS = Limits(maps=2, max_terms=1024, rotate_y=0.0, terms=256)


def test_sanitise_replaces_and_clamps_with_one_line_notes():
    state, notes = sanitise({"rotate_y": "abc", "terms": "-5", "env": "99", "exposure": "inf"}, LIMITS)
    assert state == {"rotate_y": 0.0, "exposure": 0.0, "tonemap": "clamp", "terms": 1, "env": 0, "encoding": "jpeg",
                     "show_background": True, "preview": False, "converge": False}
    assert len(notes) == 4 and all("\n" not in n for n in notes)
    assert any("rotate_y='abc' is not a number" in n for n in notes)
    assert any("exposure='inf' is not finite" in n for n in notes)
    state, notes = sanitise({"rotate_y": "-30", "terms": "1e9", "exposure": "100", "env": "1",
                             "encoding": "gif", "converge": "1", "other": "x"}, LIMITS)
    assert (state["rotate_y"], state["terms"], state["exposure"], state["env"]) == (330.0, 1024, EXPOSURE_RANGE[1], 1)
    assert state["encoding"] == "jpeg" and state["converge"] is False   # no estimator in these limits
    assert len(notes) == 3
    state, notes = sanitise({"rotate_y": 400, "terms": 64.4, "env": 1.5, "exposure": "nan"}, LIMITS)
    assert (state["rotate_y"], state["terms"], state["env"], state["exposure"]) == (40.0, 64, 0, 0.0)
    state, _ = sanitise({"rotate_y": [1, 2], "terms": True, "exposure": "9" * 500, "env": None}, LIMITS)
    assert (state["rotate_y"], state["terms"], state["exposure"], state["env"]) == (0.0, 256, 0.0, 0)
    state, notes = sanitise({}, LIMITS)
    assert notes == [] and state["terms"] == 256
    on, _ = sanitise({"converge": True, "preview": True}, Limits(2, 1024, 0.0, 256, converge=True))
    assert on["converge"] is True and on["preview"] is True
    # the background: shown unless given as false; anything else shown, with a note
    for raw, shown_ in ((False, False), ("0", False), ("false", False), (True, True), ("1", True)):
        state, notes = sanitise({"show_background": raw}, LIMITS)
        assert state["show_background"] is shown_ and notes == []
    state, notes = sanitise({"show_background": "maybe"}, LIMITS)
    assert state["show_background"] is True and len(notes) == 1 and "show_background='maybe'" in notes[0]


def test_tone_map_is_srgb_of_exposure_times_linear():
    rng = np.random.default_rng(1)
    image = rng.exponential(0.3, (17, 23, 3)).astype(np.float32)
    image[0, 0] = [np.nan, np.inf, -1.0]
    for exposure in (-1.5, 0.0, 0.7):
        want = np.round(srgb_encode(np.nan_to_num(image * 2.0 ** exposure, nan=0.0, posinf=1.0)) * 255)
        got = tone_map(image, exposure)
        assert got.dtype == np.uint8 and got.shape == image.shape
        assert np.abs(got.astype(int) - want).max() <= 1
    assert list(tone_map(image, 0.0)[0, 0]) == [0, 255, 0]
    rgba = tone_map(image, 0.0, alpha=True)
    assert rgba.shape == (17, 23, 4) and (rgba[..., 3] == 255).all()
    assert (rgba[..., :3] == tone_map(image, 0.0)).all()


def test_sanitise_keeps_a_known_tone_curve_and_replaces_others_with_a_note():
    for limits in (LIMITS, ObjectLimits((0.0, 0.0, 0.0), (-1.0,) * 3, (1.0,) * 3, 0.1, 0.0, False),
                   ViewLimits(0.0, 10.0, 3.0, 0.5, 9.0, False)):
        state, notes = sanitise({"tonemap": "aces"}, limits)
        assert state["tonemap"] == "aces" and notes == []
        assert sanitise({}, limits)[0]["tonemap"] == "clamp"
        state, notes = sanitise({"tonemap": "filmic<script>"}, limits)
        assert state["tonemap"] == "clamp" and len(notes) == 1 and "tonemap=" in notes[0] and "\n" not in notes[0]


def test_tone_map_with_a_curve_is_srgb_of_the_curve():
    """The viewer's frames: srgb(curve(x 2^EV)) with the curve of wavlight.display (written out
    here from Narkowicz's published constants), within one 8-bit level."""
    rng = np.random.default_rng(2)
    image = rng.exponential(0.8, (13, 19, 3)).astype(np.float32)
    for exposure in (-1.0, 0.0, 2.5):
        x = image.astype(np.float64) * 2.0 ** exposure
        curve = np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)
        want = np.round(srgb_encode(curve) * 255)
        got = tone_map(image, exposure, tonemap="aces")
        assert got.dtype == np.uint8 and np.abs(got.astype(int) - want).max() <= 1
    assert (tone_map(image, 0.0, tonemap="clamp") == tone_map(image, 0.0)).all()


def _config(html: str) -> dict:
    return json.loads(re.search(r'<script id="config" type="application/json">(.*?)</script>', html,
                                re.DOTALL).group(1))


def _get(url, headers=None):
    req = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode()


def _split(data: bytes):
    n = struct.unpack("<I", data[:4])[0]
    return json.loads(data[4:4 + n]), data[4 + n:]


async def _next_frame(ws, timeout=10.0, ack=True):
    """The next frame message (header, payload); text messages before it are returned in a list too."""
    texts = []
    while True:
        msg = await asyncio.wait_for(ws.receive(), timeout)
        if msg.type == aiohttp.WSMsgType.TEXT:
            texts.append(json.loads(msg.data))
            continue
        assert msg.type == aiohttp.WSMsgType.BINARY, msg
        header, payload = _split(msg.data)
        if ack:
            await ws.send_json({"type": "drawn", "seq": header["seq"]})
        return header, payload, texts


def test_page_and_socket_sanitise_bad_input(serve, transfer):
    v = serve()
    status, html = _get(v.url + "&rotate_y=abc&terms=-5&env=99&exposure=inf&encoding=gif")
    assert status == 200
    config = _config(html)
    assert {k: config["state"][k] for k in ("rotate_y", "terms", "env", "exposure", "encoding")} == \
        {"rotate_y": transfer.scene_rotate_y % 360, "terms": 1, "env": 0, "exposure": 0.0, "encoding": "jpeg"}
    assert len(config["notes"]) == 5
    assert config["maps"] == ["the baked map", "gradient.exr"] and config["max_terms"] == 4 ** LEVELS
    assert not re.search(r'<(script|link)[^>]+(src|href)="(https?:)?//', html)
    assert _get(v.address + "nothing-here?token=" + v.token)[0] == 404
    status, text = _get(v.url, {"Host": "example.com"})
    assert status == 403 and text.count("\n") == 1

    async def talk():
        async with aiohttp.ClientSession() as client:
            with pytest.raises(aiohttp.WSServerHandshakeError):
                await client.ws_connect(v.socket_url, headers={"Origin": "http://example.com"})
            async with client.ws_connect(v.socket_url) as ws:
                for bad in ("not json", "[1, 2]", json.dumps({"type": "launch"})):
                    await ws.send_str(bad)
                    reply = json.loads((await ws.receive(timeout=10)).data)
                    assert reply["type"] == "error" and "\n" not in reply["message"]
                await ws.send_bytes(b"\x00\x01")
                assert json.loads((await ws.receive(timeout=10)).data)["type"] == "error"
                await ws.send_json({"type": "state", "rotate_y": "abc", "terms": -5, "env": 99, "exposure": 1e999})
                header, payload, texts = await _next_frame(ws)
                assert texts and texts[0]["type"] == "state" and len(texts[0]["notes"]) == 4
                assert header["state"] == {"rotate_y": transfer.scene_rotate_y % 360, "exposure": 0.0,
                                           "tonemap": "clamp", "terms": 1,
                                           "env": 0, "show_background": True}
                assert payload[:2] == b"\xff\xd8" and header["encoding"] == "jpeg"   # a JPEG
                await ws.send_json({"type": "state", "rotate_y": 90, "terms": 64, "env": 1, "encoding": "raw"})
                header, payload, _ = await _next_frame(ws)
                assert header["encoding"] == "raw" and len(payload) == transfer.width * transfer.height * 4
                assert header["state"]["env"] == 1 and header["terms_used"] <= 64
                await ws.send_json({"type": "state", "rotate_y": 90, "terms": 64, "env": 1, "encoding": "raw",
                                    "exposure": 2})   # exposure alone: the same frame, tone mapped again
                header2, payload2, _ = await _next_frame(ws)
                assert header2["state"]["exposure"] == 2 and payload2 != payload
                await ws.send_str("x" * (viewer_module.MAX_MESSAGE_BYTES + 10))   # too large: a note
                reply = json.loads((await ws.receive(timeout=10)).data)
                assert reply["type"] == "error" and str(viewer_module.MAX_MESSAGE_BYTES) in reply["message"]
                await ws.send_str("x" * (viewer_module.MESSAGE_CLOSE_BYTES + 10))   # too large to read: closed
                msg = await ws.receive(timeout=10)
                assert msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.CLOSING)
                assert ws.close_code == aiohttp.WSCloseCode.MESSAGE_TOO_BIG

    asyncio.run(talk())
    assert _wait(lambda: v.clients == 0 and v.running_tasks == 0)


def _drop_mid_frame(port, token, state):
    """A websocket opened by hand, sent one state, then its TCP connection reset without a
    closing handshake while the frame is computed."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(f"GET /ws?token={token} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                  "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n".encode())
        assert s.recv(4096).startswith(b"HTTP/1.1 101")
        body, mask = json.dumps(state).encode(), b"\x01\x02\x03\x04"
        s.sendall(bytes([0x81, 0x80 | len(body)]) + mask + bytes(c ^ mask[i % 4] for i, c in enumerate(body)))
        time.sleep(0.1)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))   # close: a reset


def test_sockets_closed_mid_frame_leave_the_server_serving(serve, capfd):
    v = serve()
    plain = v.frame
    v.frame = lambda state, terms: (time.sleep(0.3), plain(state, terms))[1]   # a slow frame

    async def talk():
        async with aiohttp.ClientSession() as client:
            for i in range(3):   # closed while its frame is computed
                ws = await client.ws_connect(v.socket_url)
                await ws.send_json({"type": "state", "rotate_y": 10 * i})
                await asyncio.sleep(0.1)
                await ws.close()
            _drop_mid_frame(v.port, v.token, {"type": "state", "rotate_y": 77})
            async with client.ws_connect(v.socket_url) as ws:
                await ws.send_json({"type": "state", "rotate_y": 5})
                header, _, _ = await _next_frame(ws)
                assert header["state"]["rotate_y"] == 5

    asyncio.run(talk())
    assert _wait(lambda: v.clients == 0 and v.running_tasks == 0)
    err = capfd.readouterr().err
    assert "Traceback" not in err and "Error handling request" not in err


def test_converge_of_a_bake_made_without_an_output_file(bake_file, tmp_path):
    """A Transfer baked without an output (its temporary file removed once read) and a bake
    file written over after it was loaded: the converge thread works on the loaded bake,
    not on what is at its path."""
    baked = wavlight.bake(str(SCENE), width=16, height=16, spp=2, levels=3, terms=32)
    assert not os.path.exists(baked.path)
    image, _ = Viewer(baked).converge_call({"rotate_y": 30.0, "env": 0}, 2, 0)
    assert image.shape == (16, 16, 3) and np.isfinite(image).all() and image.max() > 0
    copy = tmp_path / "spot.wlt"
    shutil.copyfile(bake_file[0], copy)
    loaded = wavlight.Transfer.load(copy)
    copy.write_bytes(b"written over")
    image, _ = Viewer(loaded).converge_call({"rotate_y": 30.0, "env": 0}, 2, 0)
    assert image.shape == (loaded.height, loaded.width, 3) and np.isfinite(image).all()


def _doubling(spps):
    """Calls start at 2 spp and double (while they are short) or stay."""
    assert spps[0] == 2 and all(b in (a, 2 * a) for a, b in itertools.pairwise(spps)), spps


def test_converge_streams_the_spp_weighted_mean_and_stops_when_the_lighting_changes(serve, transfer):
    values = {}

    def constant(transfer, scene=None, env=None, rotate_y=None, scale=1.0, spp=4, seed=0):
        values[seed] = (spp, 0.01 * (seed + 1), rotate_y)
        shape = (transfer.height, transfer.width, 3)
        return np.full(shape, 0.01 * (seed + 1), np.float32), np.full(shape, 0.002, np.float32)

    v = serve(converge=constant)

    async def talk():
        async with aiohttp.ClientSession() as client:
            async with client.ws_connect(v.socket_url) as ws:
                await ws.send_json({"type": "state", "rotate_y": 45, "converge": True, "encoding": "raw"})
                headers = []
                while len(headers) < 4:   # (the relit frame of the state first, then the passes)
                    header, payload, _ = await _next_frame(ws)
                    if header["converge"] is not None or headers:
                        headers.append((header, payload))
                await ws.send_json({"type": "state", "rotate_y": 50, "converge": False, "encoding": "raw"})
                while True:
                    header, _, _ = await _next_frame(ws)
                    if header["converge"] is None:
                        break
                return headers, header

    headers, after = asyncio.run(talk())
    for header, payload in headers:
        c = header["converge"]
        seeds = range(c["passes"])
        spp = np.array([values[s][0] for s in seeds], float)
        means = np.array([values[s][1] for s in seeds])
        n = spp.sum()
        mean = float(np.sum(spp * means) / n)
        assert c["spp"] == n
        # the samples of all passes pooled: their sum of squares less n mean^2, over (n - 1) n
        squares = np.sum((spp - 1) * spp * 0.002 ** 2 + spp * means ** 2)
        pooled = np.sqrt((squares - n * mean ** 2) / (n - 1) / n)
        assert c["relative_error"] == pytest.approx(pooled / mean, rel=1e-4)
        want = round(float(srgb_encode(np.float32(mean))) * 255)
        got = np.frombuffer(payload, np.uint8).reshape(transfer.height, transfer.width, 4)[..., :3]
        assert np.abs(got.astype(int) - want).max() <= 1
    _doubling([values[s][0] for s in sorted(values)])
    assert all(values[s][2] == 45 for s in values)
    assert after["state"]["rotate_y"] == 50
    n = len(values)
    time.sleep(0.3)
    assert len(values) == n          # no call after the lighting changed


# ----------------------------------------------------------------------------- in the browser
def test_browser_shows_url_state_and_a_slider_changes_the_picture(serve, page):
    v, pg = _opened(serve, page, "?rotate_y=30&terms=64")
    assert pg.text_content("#rotate_y_value") == "30°" and pg.input_value("#rotate_y") == "30"
    assert pg.text_content("#terms_value") == "64"
    assert pg.input_value("#env") == "0"
    assert "rotate_y=30" in pg.url and "terms=64" in pg.url
    first = _pixel_sum(pg)
    assert first > 0
    _set(pg, "rotate_y", "150")
    pg.wait_for_function("() => viewer.last && viewer.last.state.rotate_y === 150")
    assert _pixel_sum(pg) != first
    assert "rotate_y=150" in pg.url
    pg.wait_for_function("() => parseFloat(document.getElementById('fps').textContent) > 0")
    assert float(pg.text_content("#fps")) > 0
    # the exposure slider is in stops, the map a choice; both reach the frame and the URL
    _set(pg, "exposure", "1.5")
    pg.wait_for_function("() => viewer.last.state.exposure === 1.5")
    assert "+1.5 EV" in pg.text_content("#exposure_value") and "exposure=1.5" in pg.url
    _set(pg, "env", "1")
    pg.wait_for_function("() => viewer.last.state.env === 1")
    assert "env=1" in pg.url
    assert pg.evaluate("viewer.errors") == 0


def test_browser_tone_curve_from_the_url_and_the_choice(serve, page, bake_file):
    """The tone curve is in the URL where it is not clamp, the choice shows it, and the picture
    drawn is the frame through that curve (raw frames: the canvas holds the bytes sent)."""
    v, pg = _opened(serve, page, "?rotate_y=30&terms=64&encoding=raw&tonemap=aces")
    assert pg.input_value("#tonemap") == "aces"
    assert pg.evaluate("viewer.last.state.tonemap") == "aces" and "tonemap=aces" in pg.url
    assert pg.evaluate("Array.from(document.getElementById('tonemap').options).map(o => o.value)") == \
        ["clamp", "aces"]
    state, _ = sanitise({"rotate_y": "30", "terms": "64"}, v.limits)
    other = wavlight.Transfer.load(bake_file[0])   # the frame the viewer computes, computed here
    try:
        image, _ = other.frame_timed(None, 30.0, 1.0, v.detail(state), background=v.background)
    finally:
        other.close()

    def canvas():
        data = pg.evaluate("""() => { const c = document.getElementById('frame');
            return Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data); }""")
        return np.array(data, np.uint8).reshape(image.shape[0], image.shape[1], 4)

    assert (canvas() == tone_map(image, 0.0, alpha=True, tonemap="aces")).all()
    _set(pg, "tonemap", "clamp")
    pg.wait_for_function("() => viewer.last.state.tonemap === 'clamp'")
    pg.wait_for_function("() => !location.search.includes('tonemap')")
    assert (canvas() == tone_map(image, 0.0, alpha=True)).all()
    _set(pg, "tonemap", "aces")
    pg.wait_for_function("() => viewer.last.state.tonemap === 'aces' && location.search.includes('tonemap=aces')")
    assert pg.evaluate("viewer.errors") == 0


def test_browser_drag_previews_fewer_terms_and_sharpens_on_release(serve, page):
    v, pg = _opened(serve, page, "?terms=256")
    box = pg.locator("#rotate_y").bounding_box()
    y = box["y"] + box["height"] / 2
    pg.mouse.move(box["x"] + 5, y)
    pg.mouse.down()
    for i in range(1, 15):
        pg.mouse.move(box["x"] + 5 + i * (box["width"] - 10) / 15, y)
        time.sleep(0.02)
    pg.wait_for_function("() => viewer.last.preview === true")
    assert pg.evaluate("viewer.last.terms_used") <= 64
    pg.mouse.up()
    pg.wait_for_function("() => viewer.last.preview === false && viewer.last.state.rotate_y === viewer.state.rotate_y")
    assert pg.evaluate("viewer.last.terms_used") > 64


def test_browser_bad_url_parameters_show_the_values_used(serve, page, transfer):
    v, pg = _opened(serve, page, "?rotate_y=abc&terms=-5&env=99&exposure=inf")
    rot = transfer.scene_rotate_y % 360
    assert pg.text_content("#rotate_y_value") == f"{rot:g}°"
    assert pg.text_content("#terms_value") == "1"
    assert pg.input_value("#env") == "0"
    assert pg.text_content("#exposure_value").startswith("0 EV")
    assert pg.evaluate("location.search") == f"?token={v.token}&rotate_y={rot:g}&exposure=0&terms=1&env=0"
    notes = pg.text_content("#notes").splitlines()
    assert len(notes) == 4 and any("rotate_y='abc'" in n for n in notes)
    assert pg.evaluate("viewer.errors") == 0 and pg.text_content("#status") == ""


def test_browser_two_pages_at_once_both_get_frames(serve, page):
    v = serve()
    a, b = page(), page()
    a.goto(v.url + "&rotate_y=10")
    b.goto(v.url + "&rotate_y=200&env=1")
    _frames(a, 1)
    _frames(b, 1)
    assert _wait(lambda: v.clients == 2)
    for i in range(3):
        _set(a, "rotate_y", str(20 + 10 * i))
        _set(b, "rotate_y", str(220 + 10 * i))
    a.wait_for_function("() => viewer.last.state.rotate_y === 40")
    b.wait_for_function("() => viewer.last.state.rotate_y === 240 && viewer.last.state.env === 1")


def test_browser_page_closed_mid_stream_leaves_the_server_serving(serve, page, capfd):
    v = serve()
    a = page()
    a.goto(v.url)
    _frames(a, 1)
    # the page changes the rotation on a timer: frames stream until it closes
    a.evaluate("""() => { let r = 0; setInterval(() => { const e = document.getElementById('rotate_y');
        r = (r + 7) % 360; e.value = r; e.dispatchEvent(new Event('input')); }, 5); }""")
    _frames(a, 5)
    a.close()
    assert _wait(lambda: v.clients == 0 and v.running_tasks == 0)
    b = page()
    b.goto(v.url + "&rotate_y=33")
    _frames(b, 1)
    assert b.evaluate("viewer.last.state.rotate_y") == 33
    err = capfd.readouterr().err
    assert "Traceback" not in err and "Error handling request" not in err


def test_browser_converge_shows_spp_growing_error_falling_and_restarts_when_a_slider_moves(serve, page):
    fake = FakeConverge(delay=0.02)
    v, pg = _opened(serve, page, "?rotate_y=60", converge=fake)
    _start_converge(pg, 5)
    _doubling([c["spp"] for c in fake.calls])
    assert len({c["seed"] for c in fake.calls}) == len(fake.calls)
    shown = pg.evaluate("viewer.converged")          # [spp, relative error, time] of each pass drawn
    spp, error = [s[0] for s in shown], [s[1] for s in shown]
    assert spp == sorted(set(spp)) and len(spp) >= 5
    # the fake's error is 5% / sqrt(spp) a pass: the pooled error falls as 1 / sqrt(spp) (its
    # estimate from thousands of pixels: within a few percent)
    assert error[-1] < error[0] * np.sqrt(spp[0] / spp[-1]) * 1.3 and error[-1] < error[0] / 2
    text, last = pg.evaluate("[document.getElementById('converge_info').textContent, viewer.last.converge.spp]")
    m = CONVERGE_TEXT.search(text)         # (read at once with the last header: passes keep coming)
    assert m and int(m.group(1)) == last and float(m.group(2)) > 0
    # a change of state: the preview of the new state, then passes again from the first
    _set(pg, "rotate_y", "90")
    pg.wait_for_function("() => viewer.last.state.rotate_y === 90 && viewer.last.converge !== null"
                         " && viewer.converged.length >= 2")
    assert pg.get_attribute("#converge", "aria-pressed") == "true"
    assert pg.evaluate("viewer.restarts") >= 1 and pg.evaluate("viewer.converged[0][0]") == 2
    again = [c for c in fake.calls if c["rotate_y"] == 90]
    assert again and again[0]["seed"] == 0 and again[0]["spp"] == 2
    # released: no more passes
    pg.click("#converge")
    pg.wait_for_function("() => viewer.last.converge === null")
    assert pg.get_attribute("#converge", "aria-pressed") == "false"
    n = len(fake.calls)
    time.sleep(0.3)
    assert len(fake.calls) <= n + 1 and {c["rotate_y"] for c in fake.calls} == {60, 90}


def test_browser_converge_disabled_without_the_estimator(serve, page):
    v, pg = _opened(serve, page, "?converge=1", converge=None)
    assert pg.is_disabled("#converge")
    assert "converge" in pg.get_attribute("#converge", "title")
    assert pg.evaluate("viewer.last.converge") is None


# ----------------------------------------------------------------------------- the command
def _run_view_command(args, query):
    """``wavlight view ARGS --no-browser`` in a child process: its URL is the one line it prints;
    the page at URL + ``query`` is fetched, then SIGINT stops it, which must end it with exit 0,
    nothing more on stdout and no traceback. Returns the page's config."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(WAVLIGHT + ["view", *map(str, args), "--no-browser"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    try:
        line = proc.stdout.readline()
        assert re.fullmatch(r"http://127\.0\.0\.1:\d+/\?token=[\w-]+\n", line), line
        status, html = _get(line.strip() + query.replace("?", "&", 1))
        assert status == 200
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert "Traceback" not in err and out == ""
    return _config(html)


def test_view_command_prints_the_url_serves_and_stops_on_sigint(bake_file):
    config = _run_view_command([bake_file[0], "--env", bake_file[1]], "?env=1")
    assert config["state"]["env"] == 1


def test_view_command_errors_are_one_line(bake_file, tmp_path):
    runner = CliRunner()
    for args in ([str(tmp_path / "missing.wlt"), "--no-browser"],
                 [str(bake_file[0]), "--no-browser", "--env", str(tmp_path / "missing.hdr")],
                 [str(bake_file[0]), "--no-browser", "--port", "70000"]):
        result = runner.invoke(main, ["view", *args])
        assert result.exit_code == 2, result.output
        assert result.output.count("\n") <= 2 and "Traceback" not in result.output
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        # (in a thread of its own: the browser tests' playwright keeps an event loop in this one)
        with concurrent.futures.ThreadPoolExecutor(1) as pool:
            result = pool.submit(runner.invoke, main, ["view", str(bake_file[0]), "--no-browser", "--port",
                                                       str(port)]).result(60)
    assert result.exit_code == 2 and "cannot listen" in result.output and result.output.count("\n") == 1


# ----------------------------------------------------------------------------- a bake that varies an object
#: the card's own rotation (about +X), which the viewer's rotation about +Y is composed with
CARD_ROTATE = [1.0, 0.0, 0.0, 60.0]


def card_scene():
    """A ggx card (1.2 x 0.6, tilted 60 degrees about +X) over a lambert floor, 48 x 32 pixels."""
    return over_floor({"shape": "quad", "name": "card", "size": [1.2, 0.6], "rotate": CARD_ROTATE,
                       "translate": [0.0, 0.6, 0.0]}, width=48, height=32)


@pytest.fixture(scope="module")
def object_bake(tmp_path_factory, device):
    """A tiny bake (48 x 32 pixels) with vary="object" of the card, from a scene file on disk."""
    folder = tmp_path_factory.mktemp("viewer-object")
    write_sun_sky(folder)                                  # a small sun: hard shadows
    (folder / "scene.toml").write_text(toml_text(card_scene()))
    path = folder / "card.wlt"
    wavlight.bake(str(folder / "scene.toml"), output=str(path), spp=2, levels=4, terms=64, priority="area",
                  vary="object", object="card", static_spp=32).close()
    return path, folder / "scene.toml"


@pytest.fixture(scope="module")
def object_transfer(object_bake):
    yield from _loaded(object_bake[0])


@pytest.fixture
def serve_object(object_transfer):
    """serve_object(**viewer options) -> a running Viewer of the object bake, stopped after the test."""
    yield from _serving(object_transfer)


def _object_limits(v):
    lim = v.limits
    assert isinstance(lim, ObjectLimits)
    return lim


def test_object_sanitise_and_the_factors_each_bake_holds_fixed():
    lim = ObjectLimits(translate=(0.0, 0.6, 0.0), lo=(-3.7, -0.1, -3.7), hi=(3.7, 1.3, 3.7), step=0.01,
                       rotate_y=0.0, converge=True)
    state, notes = sanitise({"translate": "0.3,0,0.2", "rotate_y": "405", "exposure": "0.5"}, lim)
    assert state == {"translate": [0.3, 0.0, 0.2], "rotate_y": 45.0, "exposure": 0.5,
                     "tonemap": "clamp", "encoding": "jpeg",
                     "preview": False, "converge": False} and notes == []
    for bad, why in (("1,nan,2", "finite"), ("1,inf,2", "finite"), ("1,2", "three numbers"), ("1,2,3,4", "three"),
                     ("a,b,c", "numbers"), ([1, 2], "three"), ([1, True, 2], "numbers"), (5, "three"),
                     ("9" * 300, "three")):
        state, notes = sanitise({"translate": bad}, lim)
        assert state["translate"] == [0.0, 0.6, 0.0], bad
        assert len(notes) == 1 and why in notes[0] and "\n" not in notes[0], (bad, notes)
    state, notes = sanitise({"translate": [100, -100, 0.25]}, lim)
    assert state["translate"] == [3.7, -0.1, 0.25] and len(notes) == 2
    assert any("translate x=100 is outside [-3.7, 3.7]" in n for n in notes)
    state, notes = sanitise({"env": "1", "terms": "64", "rotate_y": "abc", "converge": "1"}, lim)
    assert "env" not in state and "terms" not in state and state["rotate_y"] == 0.0 and state["converge"] is True
    assert len(notes) == 3 and sum("does not apply: this bake varies an object" in n for n in notes) == 2
    # the factor a lighting bake holds fixed: the same rule
    state, notes = sanitise({"translate": "0.3,0,0.2", "rotate_y": "10"}, LIMITS)
    assert "translate" not in state and state["rotate_y"] == 10.0
    assert len(notes) == 1 and "does not apply: this bake varies the lighting" in notes[0]


def test_object_limits_and_placement_come_from_the_scene(serve_object, object_transfer):
    v = serve_object()
    lim = _object_limits(v)
    assert lim.translate == (0.0, 0.6, 0.0) and lim.rotate_y == 0.0
    scene = v.frames.mover.scene
    used = scene.vertices[np.unique(scene.faces)]
    lo, hi = np.array(lim.lo), np.array(lim.hi)
    # every translation that keeps the card's bounding sphere's centre in the scene's bounds is in range
    center, radius = v.frames.mover.center, v.frames.mover.radius
    assert np.all(lo <= used.min(0) - center - radius + 1e-9) and np.all(hi >= used.max(0) - center + radius - 1e-9)
    assert np.all(lo <= lim.translate) and np.all(np.array(lim.translate) <= hi)
    assert np.all(hi - lo <= (used.max(0) - used.min(0)) + 2 * radius + 2 * lim.step + 1e-9)
    # the slider's rotation about +Y after the card's own rotation about +X
    for degrees in (0.0, 45.0, 180.0, 300.0):
        t, r = v.frames.placement({"translate": [0.1, 0.6, -0.2], "rotate_y": degrees})
        assert t == [0.1, 0.6, -0.2]
        want = rotation([0.0, 1.0, 0.0, degrees]) @ rotation(CARD_ROTATE)
        assert np.allclose(rotation(r), want, atol=1e-9), degrees


def test_object_page_and_socket_frames_are_the_moving_estimators(serve_object, object_transfer):
    v = serve_object()
    lim = _object_limits(v)
    status, html = _get(v.url + "&translate=0.3,0,0.2&rotate_y=45&exposure=0.5")
    config = _config(html)
    assert status == 200 and config["vary"] == "object" and config["object"] == "card"
    assert config["state"]["translate"] == [0.3, 0.0, 0.2] and config["state"]["rotate_y"] == 45.0
    assert config["notes"] == [] and "maps" not in config and "max_terms" not in config
    assert config["translate_min"] == list(lim.lo) and config["translate_max"] == list(lim.hi)
    status, html = _get(v.url + "&translate=1,nan,2&rotate_y=inf&env=1&terms=5")
    config = _config(html)
    assert config["state"]["translate"] == list(lim.translate) and config["state"]["rotate_y"] == lim.rotate_y
    assert len(config["notes"]) == 4 and all("\n" not in n for n in config["notes"])
    mover = MovingObjectOf(object_transfer, v)

    def expected(translate, rotate_y, spp, exposure=0.0):
        t, r = v.frames.placement({"translate": translate, "rotate_y": rotate_y})
        return tone_map(mover.frame(t, r, spp=spp, seed=0).image, exposure, alpha=True)

    def picture(payload):
        return np.frombuffer(payload, np.uint8).reshape(object_transfer.height, object_transfer.width, 4)

    async def talk():
        async with aiohttp.ClientSession() as client:
            async with client.ws_connect(v.socket_url) as ws:
                await ws.send_json({"type": "state", "translate": [0.3, 0.6, 0.2], "rotate_y": 45, "exposure": 0.5,
                                    "encoding": "raw"})
                header, payload, texts = await _next_frame(ws)
                assert texts == []
                assert header["state"] == {"translate": [0.3, 0.6, 0.2], "rotate_y": 45.0, "exposure": 0.5,
                                           "tonemap": "clamp"}
                assert header["spp"] == viewer_module.OBJECT_FRAME_SPP and header["preview"] is False
                want = expected([0.3, 0.6, 0.2], 45.0, viewer_module.OBJECT_FRAME_SPP, 0.5)
                assert np.abs(picture(payload).astype(int) - want).max() <= 1
                first = picture(payload).copy()
                # the same place while a slider is dragged: the preview's samples
                await ws.send_json({"type": "state", "translate": [0.3, 0.6, 0.2], "rotate_y": 45, "exposure": 0.5,
                                    "encoding": "raw", "preview": True})
                header, payload, _ = await _next_frame(ws)
                assert header["preview"] is True and header["spp"] == viewer_module.OBJECT_PREVIEW_SPP
                # another place, another picture; a rotation alone turns the card
                await ws.send_json({"type": "state", "translate": [-1.0, 0.6, 0.2], "rotate_y": 45,
                                    "exposure": 0.5, "encoding": "raw"})
                header, payload, _ = await _next_frame(ws)
                moved = picture(payload)
                assert header["state"]["translate"] == [-1.0, 0.6, 0.2] and np.any(moved != first)
                await ws.send_json({"type": "state", "translate": [0.3, 0.6, 0.2], "rotate_y": 135,
                                    "exposure": 0.5, "encoding": "raw"})
                header, payload, _ = await _next_frame(ws)
                assert header["state"]["rotate_y"] == 135.0 and np.any(picture(payload) != first)
                # the lighting's parameters and bad values: notes, then the frame of the values used
                await ws.send_json({"type": "state", "translate": [0.3, "x", 0.2], "rotate_y": 45, "env": 1,
                                    "terms": 4, "exposure": 0.5, "encoding": "raw"})
                header, payload, texts = await _next_frame(ws)
                assert texts and texts[0]["type"] == "state" and len(texts[0]["notes"]) == 3
                assert header["state"]["translate"] == list(lim.translate)
                # converge: the moving estimator at this place, seeds 0, 1, ..., weighted by spp
                await ws.send_json({"type": "state", "translate": [0.3, 0.6, 0.2], "rotate_y": 45, "exposure": 0.5,
                                    "encoding": "raw", "converge": True})
                reports = []
                while len(reports) < 3:
                    header, payload, _ = await _next_frame(ws)
                    if header["converge"] is not None:
                        reports.append((header["converge"], picture(payload).copy()))
                c, pic = reports[0]
                assert c["spp"] == c["pass_spp"] == 2 and c["passes"] == 1
                assert np.abs(pic.astype(int) - expected([0.3, 0.6, 0.2], 45.0, 2, 0.5)).max() <= 1
                _doubling([r[0]["pass_spp"] for r in reports])
                assert [r[0]["spp"] for r in reports] == list(np.cumsum([r[0]["pass_spp"] for r in reports]))
                await ws.send_json({"type": "state", "translate": [0.5, 0.6, 0.2], "rotate_y": 45, "exposure": 0.5,
                                    "encoding": "raw", "converge": False})
                while True:
                    header, _, _ = await _next_frame(ws)
                    if header["converge"] is None:
                        break
                assert header["state"]["translate"] == [0.5, 0.6, 0.2]

    _in_a_thread(talk)
    assert _wait(lambda: v.clients == 0 and v.running_tasks == 0)


def _in_a_thread(coroutine_function, seconds=120):
    """asyncio.run(coroutine_function()) in a thread of its own (the browser tests' playwright
    keeps an event loop in this one)."""
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, coroutine_function()).result(seconds)


def MovingObjectOf(transfer, v):
    """A moving object of its own for the same bake and scene as the viewer's (expected frames)."""
    from wavlight.relight.moving import MovingObject

    return MovingObject(transfer, v.frames.mover.scene)


def test_object_viewer_refuses_maps_and_the_command_line_errors_are_one_line(object_transfer, object_bake, tmp_path):
    with pytest.raises(wavlight.WavlightError, match="varies an object"):
        Viewer(object_transfer, maps=[str(object_bake[1].parent / "sky.exr")])
    runner = CliRunner()
    for args, words in (([str(object_bake[0]), "--no-browser", "--env", str(object_bake[1].parent / "sky.exr")],
                         "--env does not apply"),
                        ([str(object_bake[0]), "--no-browser", "--scene", str(tmp_path / "missing.toml")],
                         "missing.toml")):
        result = runner.invoke(main, ["view", *args])
        assert result.exit_code == 2 and words in result.output, result.output
        assert result.output.count("\n") == 1 and "Traceback" not in result.output


def test_browser_object_sliders_url_and_frame_rate(serve_object, page):
    v, pg = _opened(serve_object, page, "?translate=0.3,0,0.2&rotate_y=45&exposure=0.5")
    assert pg.is_hidden("#terms") and pg.is_hidden("#env") and pg.is_visible("#translate_x")
    assert [pg.input_value(f"#translate_{a}") for a in "xyz"] == ["0.3", "0", "0.2"]
    assert pg.text_content("#rotate_y_value") == "45°" and pg.input_value("#rotate_y") == "45"
    assert "object rotation" in pg.text_content("label[for=rotate_y]")
    assert pg.evaluate("location.search") == "?token=" + v.token + "&translate=0.3,0,0.2&rotate_y=45&exposure=0.5"
    assert pg.evaluate("viewer.last.state") == {"translate": [0.3, 0, 0.2], "rotate_y": 45, "exposure": 0.5,
                                                "tonemap": "clamp"}
    first = _pixel_sum(pg)
    assert first > 0
    _set(pg, "translate_x", "-1")
    pg.wait_for_function("() => viewer.last.state.translate[0] === -1")
    moved = _pixel_sum(pg)
    assert moved != first
    assert "translate=-1,0,0.2" in pg.url and pg.text_content("#translate_x_value") == "-1"
    _set(pg, "rotate_y", "120")
    pg.wait_for_function("() => viewer.last.state.rotate_y === 120 && !viewer.last.preview")
    assert _pixel_sum(pg) != moved
    pg.wait_for_function("() => parseFloat(document.getElementById('fps').textContent) > 0")
    assert float(pg.text_content("#fps")) > 0
    assert "spp" in pg.text_content("#info")
    # the URL restores the state it carries
    shared = pg.url
    assert "translate=-1,0,0.2" in shared and "rotate_y=120" in shared and "exposure=0.5" in shared
    other = page()
    other.goto(shared)
    _frames(other, 1)
    assert other.evaluate("viewer.last.state") == pg.evaluate("viewer.last.state")
    assert [other.input_value(f"#translate_{a}") for a in "xyz"] == ["-1", "0", "0.2"]
    assert other.input_value("#rotate_y") == "120"
    assert _pixel_sum(other) == _pixel_sum(pg)     # the same frame (seed 0) at the same place
    assert pg.evaluate("viewer.errors") == 0 and other.evaluate("viewer.errors") == 0


def test_browser_object_bad_parameters_show_the_values_used(serve_object, page):
    v = serve_object()
    lim = _object_limits(v)
    pg = page()
    pg.goto(v.url + "&translate=1,nan&rotate_y=abc&exposure=inf&env=1&terms=5")
    _frames(pg, 1)
    default = ",".join(f"{x:g}" for x in lim.translate)
    assert pg.evaluate("location.search") == f"?token={v.token}&translate={default}&rotate_y={lim.rotate_y:g}&exposure=0"
    notes = pg.text_content("#notes").splitlines()
    assert len(notes) == 5 and any("translate='1,nan'" in n for n in notes)
    assert sum("does not apply" in n for n in notes) == 2
    pg.goto(v.url + "&translate=99,0.6,-99")
    _frames(pg, 1)
    assert pg.evaluate("viewer.last.state.translate") == [lim.hi[0], 0.6, lim.lo[2]]
    assert len(pg.text_content("#notes").splitlines()) == 2
    assert pg.evaluate("viewer.errors") == 0 and pg.text_content("#status") == ""


def test_browser_object_converge_refines_and_restarts_when_the_object_moves(serve_object, page):
    v, pg = _opened(serve_object, page, "?translate=0.3,0.6,0.2")
    _start_converge(pg)
    _set(pg, "translate_z", "-0.5")
    pg.wait_for_function("() => viewer.last.converge !== null && viewer.last.state.translate[2] === -0.5"
                         " && viewer.restarts >= 1")
    assert pg.get_attribute("#converge", "aria-pressed") == "true"
    pg.click("#converge")
    pg.wait_for_function("() => viewer.last.converge === null")
    assert pg.get_attribute("#converge", "aria-pressed") == "false"


# ----------------------------------------------------------------------------- a bake that varies the view
#: the view scene's camera: azimuth 0 (on +Z of the target), elevation atan(1 / 3.5), distance sqrt(13.25)
VIEW_EYE, VIEW_TARGET = [0.0, 1.5, 3.5], [0.0, 0.5, 0.0]
VIEW_SIZE = (96, 64)
#: the most pixels of a view bake's frame while dragging, in these tests: 48 x 32
VIEW_PREVIEW_PIXELS = 48 * 32


def view_scene():
    """A ggx ball on a lambert floor under a sky with a small sun, 96 x 64 pixels."""
    d = over_floor({"shape": "sphere", "center": [0.0, 0.6, 0.0], "radius": 0.6, "subdivisions": 2},
                   width=VIEW_SIZE[0], height=VIEW_SIZE[1], target=VIEW_TARGET, rotate_y=20.0, material="ball")
    d["camera"]["eye"] = list(VIEW_EYE)
    return d


@pytest.fixture(scope="module")
def view_bake(tmp_path_factory, device):
    """A tiny bake with vary="view" (8 x 8 texels, about 1300 cache points) of the ball, from a scene
    made with load_dict (so the bake names no scene file); the same scene as a file beside it."""
    folder = tmp_path_factory.mktemp("viewer-view")
    write_sun_sky(folder)
    (folder / "scene.toml").write_text(toml_text(view_scene()))
    scene = wavlight.load_dict(view_scene(), base_dir=str(folder))
    path = folder / "ball.wlt"
    wavlight.bake(scene, output=str(path), vary="view", levels=3, density=30).close()
    return path, scene, folder / "scene.toml"


@pytest.fixture(scope="module")
def view_transfer(view_bake):
    yield from _loaded(view_bake[0])


@pytest.fixture
def serve_view(view_transfer, view_bake):
    """serve_view(**viewer options) -> a running Viewer of the view bake, stopped after the test."""
    yield from _serving(view_transfer, lambda: {"scene": view_bake[1], "preview_pixels": VIEW_PREVIEW_PIXELS})


def _orbit(azimuth, elevation, distance, target=VIEW_TARGET):
    """The eye of an orbit about +Y (azimuth 0 on +Z, 90 on +X), from the definition."""
    a, e = np.radians(azimuth), np.radians(elevation)
    return np.asarray(target) + distance * np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])


VIEW_LIMITS = ViewLimits(azimuth=0.0, elevation=15.945, distance=3.64, distance_lo=0.182, distance_hi=72.8,
                         converge=True)


def test_view_sanitise_orbit_and_the_factors_a_view_bake_holds_fixed():
    lim = VIEW_LIMITS
    state, notes = sanitise({"azimuth": "30", "elevation": "15", "distance": "4.2", "exposure": "0.5"}, lim)
    assert state == {"azimuth": 30.0, "elevation": 15.0, "distance": 4.2, "exposure": 0.5,
                     "tonemap": "clamp", "show_background": True, "encoding": "jpeg",
                     "preview": False, "converge": False} and notes == []
    state, notes = sanitise({"show_background": "0"}, lim)   # a view bake's frames hide it too
    assert state["show_background"] is False and notes == []
    state, notes = sanitise({}, lim)
    assert (state["azimuth"], state["elevation"], state["distance"]) == (0.0, 15.945, 3.64) and notes == []
    state, notes = sanitise({"azimuth": "-30", "elevation": "95", "distance": "0"}, lim)
    assert (state["azimuth"], state["elevation"], state["distance"]) == (330.0, 89.0, 0.182)
    assert len(notes) == 2 and all("\n" not in n for n in notes)
    assert any("elevation=95 is outside [-89, 89]: using 89" in n for n in notes)
    assert any("distance=0 is outside [0.182, 72.8]: using 0.182" in n for n in notes)
    state, notes = sanitise({"azimuth": "inf", "elevation": "nan", "distance": "-1e999", "exposure": "x"}, lim)
    assert (state["azimuth"], state["elevation"], state["distance"], state["exposure"]) == (0.0, 15.945, 3.64, 0.0)
    assert len(notes) == 4 and sum("not finite" in n for n in notes) == 3
    state, notes = sanitise({"elevation": -89.5, "distance": 1e6, "azimuth": 725.25}, lim)
    assert (state["azimuth"], state["elevation"], state["distance"]) == (5.25, -89.0, 72.8) and len(notes) == 2
    state, _ = sanitise({"distance": 4.123456}, lim)
    assert state["distance"] == 4.123                                  # 4 significant digits, as the page
    # the factors a view bake holds fixed: noted and ignored
    state, notes = sanitise({"rotate_y": "10", "env": "1", "terms": "64", "translate": "0,0,0", "azimuth": 10}, lim)
    assert set(state) == {"azimuth", "elevation", "distance", "exposure", "tonemap", "show_background", "encoding",
                          "preview", "converge"}
    assert len(notes) == 4 and all("does not apply: this bake varies the view" in n for n in notes)
    # and the camera on the other bakes
    _, notes = sanitise({"azimuth": "10", "distance": "2"}, LIMITS)
    assert len(notes) == 2 and all("does not apply: this bake varies the lighting" in n for n in notes)
    # the orbit: its eye from the definition (up +Y), and back
    for az, el, d in ((0.0, 0.0, 1.0), (30.0, 15.0, 4.2), (250.0, -60.0, 0.5), (359.0, 89.0, 10.0)):
        eye = viewer_module.orbit_eye(VIEW_TARGET, [0, 1, 0], az, el, d)
        assert np.allclose(eye, _orbit(az, el, d), atol=1e-12)
        assert np.allclose(viewer_module.orbit_angles(eye, VIEW_TARGET, [0, 1, 0]), (az, el, d), atol=1e-9)
    # another up: the elevation is measured from the plane normal to it
    eye = viewer_module.orbit_eye([0, 0, 0], [0, 0, 1], 40.0, 89.0, 2.0)
    assert eye[2] == pytest.approx(2.0 * np.sin(np.radians(89.0)))
    assert viewer_module.preview_size(512, 512) == (181, 181)
    assert viewer_module.preview_size(96, 64, VIEW_PREVIEW_PIXELS) == (48, 32)
    assert viewer_module.preview_size(32, 24) == (32, 24)


def test_view_limits_are_the_scene_cameras(serve_view, view_transfer):
    v = serve_view()
    lim = v.limits
    assert isinstance(lim, ViewLimits) and lim == VIEW_LIMITS
    state, _ = sanitise({}, lim)
    eye, target, fov = v.frames.camera(state)
    assert np.allclose(eye, VIEW_EYE, atol=1e-3) and np.allclose(target, VIEW_TARGET) and fov == 40.0
    status, html = _get(v.url)
    config = _config(html)
    assert status == 200 and config["vary"] == "view" and config["notes"] == []
    assert {k: config["state"][k] for k in ("azimuth", "elevation", "distance", "exposure")} == \
        {"azimuth": 0.0, "elevation": 15.945, "distance": 3.64, "exposure": 0.0}
    assert (config["width"], config["height"], config["preview_width"], config["preview_height"]) == (96, 64, 48, 32)
    assert "maps" not in config and "max_terms" not in config and "translate_min" not in config


def _view_frames(transfer, scene):
    """The view frames the viewer shows: with its default background."""
    from wavlight.relight.view_frames import ViewFrames

    return ViewFrames(transfer, scene, background=VIEWER["background"].default)


def test_view_socket_hides_the_background_with_frames_without_it(serve_view):
    """A view bake's show_background false: its frames are made with background none (black
    where every ray misses, the surfaces unchanged), the command says --background none, and the
    PNG stays opaque (a view frame keeps no hit share)."""
    v = serve_view()
    assert _config(_get(v.url)[1])["background_toggle"] is True

    def picture(header, payload):
        return np.frombuffer(payload, np.uint8).reshape(header["height"], header["width"], 4).copy()

    async def talk():
        async with aiohttp.ClientSession() as client:
            async with client.ws_connect(v.socket_url) as ws:
                out = {}
                for show in (True, False):
                    await ws.send_json({"type": "state", "azimuth": 30, "elevation": 15, "distance": 4.2,
                                        "encoding": "raw", "show_background": show})
                    header, payload, texts = await _next_frame(ws)
                    assert texts == [] and header["state"]["show_background"] is show
                    await ws.send_json({"type": "png"})
                    png_header, png, _ = await _next_frame(ws, ack=False)
                    assert png_header["type"] == "png"
                    out[show] = (header, picture(header, payload), png)
                return out
    out = _in_a_thread(talk)
    (h1, shown, _), (h0, hidden, png) = out[True], out[False]
    assert "--background none" in h0["command"] and "--background none" not in h1["command"]
    black = (hidden[..., :3] == 0).all(-1)
    assert 0 < black.mean() < 1 and shown[black, :3].any()           # the sky hidden
    assert np.array_equal(hidden[~black], shown[~black])             # the surfaces the same
    from PIL import Image
    import io

    assert Image.open(io.BytesIO(png)).mode == "RGB"


def test_view_socket_frames_are_view_frames_and_bad_parameters_get_notes(serve_view, view_transfer, view_bake):
    v = serve_view()
    # the page's state from the URL: bad values replaced, the fixed factors noted
    status, html = _get(v.url + "&azimuth=abc&elevation=100&distance=-2&exposure=inf&rotate_y=5&env=1&terms=3"
                                "&translate=1,2,3")
    config = _config(html)
    assert {k: config["state"][k] for k in ("azimuth", "elevation", "distance", "exposure")} == \
        {"azimuth": 0.0, "elevation": 89.0, "distance": 0.182, "exposure": 0.0}
    assert len(config["notes"]) == 8 and all("\n" not in n for n in config["notes"])
    assert sum("does not apply" in n for n in config["notes"]) == 4
    cameras = [(30.0, 15.0, 4.2, 0.5), (200.0, 40.0, 3.0, 0.0), (75.5, -5.0, 6.0, -1.0)]
    got = {}

    def picture(header, payload):
        return np.frombuffer(payload, np.uint8).reshape(header["height"], header["width"], 4).copy()

    async def talk():
        async with aiohttp.ClientSession() as client:
            async with client.ws_connect(v.socket_url) as ws:
                for az, el, d, ev in cameras:
                    await ws.send_json({"type": "state", "azimuth": az, "elevation": el, "distance": d,
                                        "exposure": ev, "encoding": "raw"})
                    header, payload, texts = await _next_frame(ws)
                    assert texts == [] and header["preview"] is False
                    assert header["state"] == {"azimuth": az, "elevation": el, "distance": d, "exposure": ev,
                                               "tonemap": "clamp", "show_background": True}
                    got[az, el, d, ev] = picture(header, payload)
                # while dragging: a smaller frame of the same camera
                await ws.send_json({"type": "state", "azimuth": 30, "elevation": 15, "distance": 4.2, "exposure": 0.5,
                                    "encoding": "raw", "preview": True})
                header, payload, _ = await _next_frame(ws)
                assert header["preview"] is True and (header["width"], header["height"]) == (48, 32)
                got["preview"] = picture(header, payload)
                # bad values and the fixed factors: notes first, then the frame of the values used
                await ws.send_json({"type": "state", "azimuth": "x", "elevation": -1e999, "distance": 1e9,
                                    "rotate_y": 3, "terms": 4, "exposure": 0.5, "encoding": "raw"})
                header, payload, texts = await _next_frame(ws)
                assert texts and texts[0]["type"] == "state" and len(texts[0]["notes"]) == 5
                assert header["state"] == {"azimuth": 0.0, "elevation": 15.945, "distance": 72.8, "exposure": 0.5,
                                           "tonemap": "clamp", "show_background": True}
                # converge: ViewFrames.converge at this camera, seeds 0, 1, ..., until the camera moves
                await ws.send_json({"type": "state", "azimuth": 30, "elevation": 15, "distance": 4.2, "exposure": 0.5,
                                    "encoding": "raw", "converge": True})
                reports = []
                while len(reports) < 3:
                    header, payload, _ = await _next_frame(ws)
                    if header["converge"] is not None:
                        reports.append((header["converge"], picture(header, payload)))
                await ws.send_json({"type": "state", "azimuth": 31, "elevation": 15, "distance": 4.2, "exposure": 0.5,
                                    "encoding": "raw", "converge": False})
                while True:
                    header, _, _ = await _next_frame(ws)
                    if header["converge"] is None:
                        break
                assert header["state"]["azimuth"] == 31.0
                return reports

    reports = _in_a_thread(talk)
    assert _wait(lambda: v.clients == 0 and v.running_tasks == 0)
    frames = _view_frames(view_transfer, view_bake[1])
    for (az, el, d, ev), pic in ((k, p) for k, p in got.items() if k != "preview"):
        image, _ = frames.frame(eye=_orbit(az, el, d), target=VIEW_TARGET, fov=40.0, width=96, height=64)
        assert np.abs(pic.astype(int) - tone_map(image, ev, alpha=True)).max() <= 1, (az, el, d)
    image, _ = frames.frame(eye=_orbit(30, 15, 4.2), target=VIEW_TARGET, fov=40.0, width=48, height=32)
    assert np.abs(got["preview"].astype(int) - tone_map(image, 0.5, alpha=True)).max() <= 1
    assert len({p.tobytes() for p in got.values()}) == len(got)          # each camera its own picture
    c, pic = reports[0]
    assert c["spp"] == c["pass_spp"] == 2 and c["passes"] == 1
    result = frames.converge(eye=_orbit(30, 15, 4.2), target=VIEW_TARGET, fov=40.0, width=96, height=64, spp=2, seed=0)
    assert np.abs(pic.astype(int) - tone_map(result.image, 0.5, alpha=True)).max() <= 1
    _doubling([r[0]["pass_spp"] for r in reports])
    assert [r[0]["spp"] for r in reports] == list(np.cumsum([r[0]["pass_spp"] for r in reports]))


def test_view_viewer_refuses_maps_and_the_command_line(view_transfer, view_bake, tmp_path):
    sky = str(view_bake[2].parent / "sky.exr")
    with pytest.raises(wavlight.WavlightError, match="varies the view"):
        Viewer(view_transfer, maps=[sky], scene=view_bake[1])
    runner = CliRunner()
    for args, words in (([str(view_bake[0]), "--no-browser", "--env", sky], "--env does not apply"),
                        ([str(view_bake[0]), "--no-browser"], "pass its scene"),
                        ([str(view_bake[0]), "--no-browser", "--scene", str(tmp_path / "missing.toml")],
                         "missing.toml")):
        result = runner.invoke(main, ["view", *args])
        assert result.exit_code == 2 and words in result.output, result.output
        assert result.output.count("\n") == 1 and "Traceback" not in result.output
    config = _run_view_command([view_bake[0], "--scene", view_bake[2]],
                               "?azimuth=30&elevation=15&distance=4.2&exposure=0.5")
    assert config["vary"] == "view" and config["notes"] == []
    assert config["state"]["azimuth"] == 30.0 and config["state"]["distance"] == 4.2


def _drag(pg, selector, dx, dy, steps=12, pause=0.03):
    """Press on the middle of an element, move by (dx, dy) in steps, and keep holding."""
    box = pg.locator(selector).bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    pg.mouse.move(x, y)
    pg.mouse.down()
    for i in range(1, steps + 1):
        pg.mouse.move(x + dx * i / steps, y + dy * i / steps)
        time.sleep(pause)


def _query(pg) -> dict:
    return dict(urllib.parse.parse_qsl(pg.evaluate("location.search")[1:]))


def test_browser_view_drag_orbits_the_camera_and_the_url_restores_it(serve_view, page):
    v, pg = _opened(serve_view, page, "?azimuth=30&elevation=15&distance=4.2&exposure=0.5")
    assert pg.is_visible("#azimuth") and pg.is_hidden("#rotate_y") and pg.is_hidden("#terms")
    assert pg.evaluate("location.search") == "?token=" + v.token + "&azimuth=30&elevation=15&distance=4.2&exposure=0.5"
    assert pg.evaluate("viewer.last.state") == {"azimuth": 30, "elevation": 15, "distance": 4.2, "exposure": 0.5,
                                                "tonemap": "clamp", "show_background": True}
    assert (pg.input_value("#azimuth"), pg.input_value("#elevation")) == ("30", "15")
    assert pg.text_content("#distance_value") == "4.2" and pg.text_content("#azimuth_value") == "30°"
    assert pg.evaluate("[viewer.last.width, viewer.last.height]") == [96, 64]
    first = _pixel_sum(pg)
    assert first > 0
    # a drag on the picture: smaller frames while it is held, the full frame on release
    _drag(pg, "#frame", -60, 40)
    pg.wait_for_function("() => viewer.last.preview === true")
    assert pg.evaluate("[viewer.last.width, viewer.last.height]") == [48, 32]
    pg.mouse.up()
    pg.wait_for_function("() => viewer.last.preview === false && viewer.last.state.azimuth === viewer.state.azimuth"
                         " && viewer.last.state.elevation === viewer.state.elevation")
    state = pg.evaluate("viewer.last.state")
    assert state["azimuth"] > 30 and state["elevation"] > 15 and state["distance"] == 4.2
    assert pg.evaluate("[viewer.last.width, viewer.last.height]") == [96, 64]
    turned = _pixel_sum(pg)
    assert turned != first
    pg.wait_for_function(f"() => location.search.includes('azimuth={state['azimuth']:g}&')")
    q = _query(pg)
    assert float(q["azimuth"]) == state["azimuth"] and float(q["elevation"]) == state["elevation"]
    assert pg.input_value("#azimuth") == f"{state['azimuth']:g}"
    # the wheel: the distance (and its slider, the URL)
    box = pg.locator("#frame").bounding_box()
    pg.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    pg.mouse.wheel(0, 350)
    pg.wait_for_function("() => viewer.last.state.distance > 4.2 && viewer.last.preview === false")
    distance = pg.evaluate("viewer.last.state.distance")
    assert distance == pytest.approx(4.2 * 2 ** 0.5, rel=2e-3)
    pg.wait_for_function(f"() => location.search.includes('distance={distance:g}')")
    assert pg.text_content("#distance_value") == f"{distance:g}"
    # a slider, the same state
    _set(pg, "elevation", "40")
    pg.wait_for_function("() => viewer.last.state.elevation === 40")
    assert "elevation=40" in pg.url and pg.text_content("#elevation_value") == "40°"
    pg.wait_for_function("() => parseFloat(document.getElementById('fps').textContent) > 0")
    assert float(pg.text_content("#fps")) > 0
    assert "moving camera" in pg.text_content("#info")
    # the URL restores the view
    other = page()
    other.goto(pg.url)
    _frames(other, 1)
    assert other.evaluate("viewer.last.state") == pg.evaluate("viewer.last.state")
    assert other.input_value("#elevation") == "40" and other.input_value("#azimuth") == pg.input_value("#azimuth")
    assert _pixel_sum(other) == _pixel_sum(pg)
    assert pg.evaluate("viewer.errors") == 0 and other.evaluate("viewer.errors") == 0


def test_browser_view_bad_parameters_show_the_values_used(serve_view, page):
    v, pg = _opened(serve_view, page, "?azimuth=-90&elevation=120&distance=nan&exposure=99&rotate_y=4&env=2")
    assert pg.evaluate("location.search") == "?token=" + v.token + "&azimuth=270&elevation=89&distance=3.64&exposure=12"
    assert pg.text_content("#elevation_value") == "89°" and pg.input_value("#elevation") == "89"
    notes = pg.text_content("#notes").splitlines()
    assert len(notes) == 5 and sum("does not apply" in n for n in notes) == 2
    assert any("distance='nan' is not finite" in n for n in notes)
    # a drag upwards never takes the elevation past the limit
    _drag(pg, "#frame", 0, 400, steps=8)
    pg.mouse.up()
    pg.wait_for_function("() => viewer.last.preview === false && viewer.frames >= 2")
    assert pg.evaluate("viewer.last.state.elevation") == 89
    assert pg.evaluate("viewer.errors") == 0 and pg.text_content("#status") == ""


def test_browser_view_converge_refines_and_restarts_when_the_camera_moves(serve_view, page):
    v, pg = _opened(serve_view, page, "?azimuth=30&elevation=15&distance=4.2")
    _start_converge(pg)
    assert pg.evaluate("[viewer.last.width, viewer.last.height]") == [96, 64]
    _drag(pg, "#frame", 30, 0, steps=4)
    pg.mouse.up()
    pg.wait_for_function("() => viewer.last.converge !== null && viewer.last.preview === false"
                         " && viewer.last.state.azimuth === viewer.state.azimuth && viewer.restarts >= 1")
    assert pg.get_attribute("#converge", "aria-pressed") == "true"
    assert pg.evaluate("viewer.last.state.azimuth") < 30
