"""The viewer's tools for a lighting designer, and what keeps other web pages out of it: the run's
token on every route (the page, its websocket, its uploads) beside the Host and Origin checks; a
map sent from the page (checked as any map: a file that is not an image, a map black everywhere,
NaN texels, a name that is not a map's, a path in the name, a size beyond the bound, a bake whose
lighting is fixed), written only in the run's temporary folder, which is gone once the viewer
stops; the PNG of the picture shown; the ``wavlight frame`` command of a state, read back by the
command line's own parser; the background hidden where the camera sees only the map. In the
browser: the file picker and a dropped file, the PNG download, the command's copy button and the
background's checkbox.

The viewers run on 127.0.0.1 (a free port) from a thread of their own (the fixtures of
tests/relight/test_viewer.py) and are always stopped.
"""
from __future__ import annotations

import asyncio
import base64
import dataclasses
import io
import json
import os
import shlex
import struct

import numpy as np
import pytest

pytest.importorskip("aiohttp")

import aiohttp
import test_viewer
from wavlight.cli.relight import frame as frame_command_line

import wavlight
from wavlight.relight import uploads
from wavlight.relight.converge import bake_hits
from wavlight.relight.pictures import tone_map
from wavlight.relight.viewer import Viewer
from wavlight.relight.viewstate import orbit_eye

bake_file, transfer, serve = test_viewer.bake_file, test_viewer.transfer, test_viewer.serve
browser, page = test_viewer.browser, test_viewer.page
object_bake, object_transfer, serve_object = (test_viewer.object_bake, test_viewer.object_transfer,
                                              test_viewer.serve_object)
view_bake, view_transfer, serve_view = test_viewer.view_bake, test_viewer.view_transfer, test_viewer.serve_view
_frames, _set = test_viewer._frames, test_viewer._set


# ----------------------------------------------------------------------------- helpers
def in_a_thread(coroutine_function, seconds=120):
    return test_viewer._in_a_thread(coroutine_function, seconds)


def split(data: bytes):
    n = struct.unpack("<I", data[:4])[0]
    return json.loads(data[4:4 + n]), data[4 + n:]


async def next_binary(ws, timeout=20.0):
    """(header, payload, texts before it) of the next binary message; frames acknowledged."""
    texts = []
    while True:
        msg = await asyncio.wait_for(ws.receive(), timeout)
        if msg.type == aiohttp.WSMsgType.TEXT:
            texts.append(json.loads(msg.data))
            continue
        assert msg.type == aiohttp.WSMsgType.BINARY, msg
        header, payload = split(msg.data)
        if header["type"] == "frame":
            await ws.send_json({"type": "drawn", "seq": header["seq"]})
        return header, payload, texts


async def post(client, v, data, name, token=True, headers=None):
    """(status, JSON or text) of POST /upload?name=... with ``data`` as the body."""
    query = {"name": name, **({"token": v.token} if token is True else {"token": token} if token else {})}
    async with client.post(v.address + "upload", params=query, data=data, headers=headers or {}) as r:
        text = await r.text()
        try:
            return r.status, json.loads(text)
        except ValueError:
            return r.status, text


def exr_bytes(tmp_path, pixels, name="map.exr") -> bytes:
    path = tmp_path / name
    wavlight.save_image(str(path), np.asarray(pixels, np.float32))
    return path.read_bytes()


def pfm_bytes(pixels) -> bytes:
    """A PFM file of (H, W, 3) float32 ``pixels`` written by hand (NaN kept: wavlight's writers refuse it)."""
    pixels = np.asarray(pixels, np.float32)
    h, w = pixels.shape[:2]
    return f"PF\n{w} {h}\n-1.0\n".encode() + pixels[::-1].astype("<f4").tobytes()


def one_line(text) -> bool:
    return isinstance(text, str) and text.strip() != "" and "\n" not in text.strip()


# ----------------------------------------------------------------------------- the token, Host and Origin
def test_every_route_needs_the_token_and_this_host_and_origin(serve):
    v = serve()
    assert v.url == f"{v.address}?token={v.token}" and len(v.token) >= 32
    assert v.token != serve().token                      # a token per run

    async def talk():
        async with aiohttp.ClientSession() as client:
            async with client.get(v.address) as r:           # the address alone: a hint, one line
                text = await r.text()
                assert r.status == 403 and one_line(text) and "URL the viewer printed" in text
            for bad in ("", "x", v.token[:-1], v.token + "x", v.token.upper()):
                async with client.get(v.address, params={"token": bad}) as r:
                    assert r.status == 403, bad
            async with client.get(v.url) as r:
                assert r.status == 200
            for url in (f"{v.address}ws", f"{v.address}ws?token=nope"):
                with pytest.raises(aiohttp.WSServerHandshakeError) as e:
                    await client.ws_connect(url)
                assert e.value.status == 403
            # the right token from another site's page (its Origin) or another name of the server (DNS
            # rebinding: the Host) is refused all the same
            for headers in ({"Origin": "http://evil.example"}, {"Host": "evil.example"},
                            {"Host": f"evil.example:{v.port}"}, {"Origin": "null"}):
                with pytest.raises(aiohttp.WSServerHandshakeError) as e:
                    await client.ws_connect(v.socket_url, headers=headers)
                assert e.value.status == 403, headers
                async with client.get(v.url, headers=headers) as r:
                    assert r.status == 403, headers
                status, _ = await post(client, v, b"x" * 10, "map.exr", headers=headers)
                assert status == 403, headers
            for token in (False, "wrong"):
                status, text = await post(client, v, b"x" * 10, "map.exr", token=token)
                assert status == 403 and one_line(text)
            async with client.ws_connect(v.socket_url, headers={"Origin": f"http://127.0.0.1:{v.port}"}) as ws:
                await ws.send_json({"type": "state"})
                header, _, _ = await next_binary(ws)
                assert header["type"] == "frame"
    in_a_thread(talk)
    assert os.listdir(v.uploads.folder) == [] and v.limits.maps == 2


# ----------------------------------------------------------------------------- uploads
def test_a_map_sent_from_the_page_is_checked_joins_the_list_and_leaves_nothing(serve, bake_file, transfer, tmp_path):
    v = serve(max_upload_bytes=1 << 20)
    folder = v.uploads.folder
    assert os.path.isdir(folder) and os.listdir(folder) == []
    good = bake_file[1].read_bytes()                     # the gradient, also the viewer's map 1
    nan = np.ones((8, 16, 3), np.float32)
    nan[2, 3] = np.nan
    nan[4, 5, 1] = -2.0

    async def talk():
        async with aiohttp.ClientSession() as client:
            # a path in the name is not a path: the server names the file; the page shows the last part
            status, data = await post(client, v, good, "../../../tmp/../evil/gradient.exr")
            assert status == 200 and data["index"] == 2 and data["name"] == "gradient.exr", data
            assert not os.path.exists(os.path.join(folder, "..", "..", "evil"))
            status, data = await post(client, v, good, "C:\\Users\\x\\..\\sky.exr")
            assert status == 200 and data["index"] == 3 and data["name"] == "sky.exr"
            status, data = await post(client, v, pfm_bytes(nan), "nan.pfm")
            assert status == 200 and data["index"] == 4
            assert len(data["notes"]) == 1 and "NaN, Inf or negative" in data["notes"][0] and one_line(data["notes"][0])
            assert folder not in data["notes"][0]
            refused = [
                (b"this is not an image at all", "notes.exr", 400, "notes.exr"),
                (good, "gradient.txt", 415, "not an environment map's file name"),
                (good, "no-extension", 415, "not an environment map's file name"),
                (b"", "empty.exr", 400, "an empty file"),
                (exr_bytes(tmp_path, np.zeros((8, 16, 3))), "black.exr", 400, "black everywhere"),
                (b"\x00" * ((1 << 20) + 1), "big.exr", 413, "at most 1 MiB"),
            ]
            for body, name, code, words in refused:
                status, data = await post(client, v, body, name)
                assert status == code and one_line(data["error"]) and words in data["error"], (name, data)
                assert folder not in data["error"] and v.limits.maps == 5
            # streamed without a declared length: cut at the bound all the same

            async def chunks():
                for _ in range(40):
                    yield b"\x00" * (1 << 15)
            status, data = await post(client, v, chunks(), "streamed.exr")
            assert status == 413 and "at most 1 MiB" in data["error"]
            # the maps sent are chosen as any other: map 2 is the same file as map 1
            async with client.ws_connect(v.socket_url) as ws:
                pictures = []
                for env in (1, 2, 0):
                    await ws.send_json({"type": "state", "env": env, "encoding": "raw"})
                    while True:
                        header, payload, _ = await next_binary(ws)
                        if header["state"]["env"] == env:
                            break
                    pictures.append(payload)
                assert pictures[0] == pictures[1] != pictures[2]
                assert "--env gradient.exr" in header["command"] or env == 0
    in_a_thread(talk)
    assert os.listdir(folder) == []                      # each file removed once read
    assert v.map_files[2:] == ["gradient.exr", "sky.exr", "nan.pfm"]
    v.stop_background()
    assert not os.path.exists(folder)                    # the folder gone with the viewer


def test_a_bake_whose_lighting_is_fixed_refuses_maps_in_one_line(serve_object):
    v = serve_object()

    async def talk():
        async with aiohttp.ClientSession() as client:
            status, data = await post(client, v, b"x" * 100, "map.exr")
            assert status == 409 and one_line(data["error"]) and "another map does not apply" in data["error"]
    in_a_thread(talk)
    assert os.listdir(v.uploads.folder) == []


# ----------------------------------------------------------------------------- the command
def parsed(command: str) -> dict:
    """The settings ``wavlight frame`` reads from ``command`` (click's own parser)."""
    args = shlex.split(command)
    assert args[:2] == ["wavlight", "frame"]
    with frame_command_line.make_context("frame", args[2:]) as ctx:
        return ctx.params


def test_the_command_of_a_lighting_state_is_read_back_by_the_command_line(transfer, bake_file):
    v = Viewer(transfer, maps=[str(bake_file[1])], scene="my scene.toml")
    v.map_files.append("sent from the page.hdr")
    for page, spp in (({"rotate_y": "30.25", "terms": 64, "exposure": "-1.5", "tonemap": "aces"}, None),
                      ({"rotate_y": 359.999, "env": 1, "terms": 3}, None),
                      ({"rotate_y": 12, "env": 2, "exposure": 2}, 64)):
        state, _ = test_viewer.sanitise(page, dataclasses.replace(v.limits, maps=3))
        s = parsed(v.command(state, spp))
        assert s["rotate_y"] == state["rotate_y"] and s["exposure"] == state["exposure"]
        assert s["tonemap"] == state["tonemap"] and s["background"] == v.background
        assert s["env"] == [None, str(bake_file[1]), "sent from the page.hdr"][state["env"]]
        assert s["scene"] == "my scene.toml" and s["output"].endswith(".png")
        if spp is None:
            assert s["terms"] == state["terms"] and s["spp"] is None
        else:
            assert s["terms"] is None and (s["spp"], s["seed"]) == (spp, 0)
        for key in ("translate", "rotate", "eye", "target"):
            assert s[key] is None


def test_the_commands_of_object_and_view_states_are_read_back(serve_object, serve_view):
    v = serve_object()
    state, _ = test_viewer.sanitise({"translate": "0.3,0.1,-0.2", "rotate_y": 45, "exposure": 0.5}, v.limits)
    s = parsed(v.command(state))
    translate, rotate = v.frames.placement(state)
    assert list(s["translate"]) == translate and np.allclose(s["rotate"], rotate, rtol=0, atol=1e-12)
    assert s["spp"] == test_viewer.viewer_module.OBJECT_FRAME_SPP and s["background"] is None
    assert s["exposure"] == 0.5 and s["env"] is None and s["rotate_y"] is None
    w = serve_view()
    state, _ = test_viewer.sanitise({"azimuth": 30, "elevation": 15, "distance": 4.2}, w.limits)
    s = parsed(w.command(state))
    cam = w.frames.views.scene.camera
    assert np.allclose(s["eye"], orbit_eye(cam.target, cam.up, 30, 15, 4.2), rtol=0, atol=1e-12)
    assert s["mode"] == "point" and s["background"] == w.background and s["spp"] is None
    s = parsed(w.command(state, spp=8))
    assert s["spp"] == 8 and s["mode"] is None


# ----------------------------------------------------------------------------- PNG and background
def test_the_png_is_the_picture_shown_and_a_hidden_background_is_transparent(serve, transfer):
    from PIL import Image

    v = serve()
    cover = bake_hits(transfer) / transfer.spp
    assert (cover == 0).any() and (cover > 0).any()     # the bake sees the map somewhere

    async def talk():
        async with aiohttp.ClientSession() as client, client.ws_connect(v.socket_url) as ws:
            await ws.send_json({"type": "png"})             # before any frame: one line
            msg = await ws.receive(timeout=10)
            assert msg.type == aiohttp.WSMsgType.TEXT and json.loads(msg.data)["type"] == "error"
            out = {}
            for show in (True, False):
                await ws.send_json({"type": "state", "rotate_y": 40, "exposure": 0.5, "tonemap": "aces",
                                    "encoding": "raw", "show_background": show})
                while True:
                    header, raw, _ = await next_binary(ws)
                    if header["state"]["show_background"] is show:
                        break
                await ws.send_json({"type": "png"})
                png_header, png, _ = await next_binary(ws)
                assert png_header["type"] == "png" and png_header["width"] == header["width"]
                out[show] = (np.frombuffer(raw, np.uint8).reshape(header["height"], header["width"], 4),
                             Image.open(io.BytesIO(png)))
            return out
    out = in_a_thread(talk)
    linear = transfer.frame(None, 40.0, background=v.background)
    shown = tone_map(linear, 0.5, tonemap="aces")
    raw, png = out[True]
    assert png.format == "PNG" and png.mode == "RGB" and png.size == (transfer.width, transfer.height)
    assert np.abs(np.asarray(png).astype(int) - shown.astype(int)).max() <= 1
    assert np.abs(raw[..., :3].astype(int) - shown.astype(int)).max() <= 1
    # hidden: the frame without background (misses contribute 0), the PNG with straight alpha
    raw, png = out[False]
    rgba = np.asarray(png)
    assert png.mode == "RGBA"
    hidden = transfer.frame(None, 40.0, background="none")
    assert np.abs(raw[..., :3].astype(int) - tone_map(hidden, 0.5, tonemap="aces").astype(int)).max() <= 1
    assert (rgba[cover == 0] == 0).all() and (raw[cover == 0, :3] == 0).all()   # black, and transparent
    hit = cover > 0
    assert np.array_equal(rgba[..., 3][hit], np.round(cover[hit] * 255).astype(np.uint8))
    edge = hit & (cover < 1)   # a silhouette's pixels: the object's colour over its coverage
    assert edge.any()
    own = tone_map((hidden / np.maximum(cover, 1e-9)[..., None]).astype(np.float32), 0.5, tonemap="aces")
    assert np.abs(rgba[edge, :3].astype(int) - own[edge].astype(int)).max() <= 1
    assert (own[edge].astype(int) > tone_map(hidden, 0.5, tonemap="aces")[edge].astype(int)).any()
    assert np.abs(rgba[cover == 1, :3].astype(int) - shown[cover == 1].astype(int)).max() <= 1


# ----------------------------------------------------------------------------- in the browser
def test_browser_opens_maps_from_the_picker_and_a_drop_and_says_why_in_one_line(serve, page, bake_file, tmp_path):
    v = serve(max_upload_bytes=1 << 16)
    pg = page()
    pg.goto(v.url)
    _frames(pg, 1)
    pg.set_input_files("#map_file", str(bake_file[1]))
    pg.wait_for_function("() => viewer.uploads === 1 && viewer.last.state.env === 2")
    assert pg.input_value("#env") == "2" and "env=2" in pg.url and f"token={v.token}" in pg.url
    assert "2: gradient.exr" in pg.text_content("#env")
    pg.wait_for_function("() => document.getElementById('command').value.includes('--env gradient.exr')")
    assert "give its path on your machine" in pg.get_attribute("#command", "title")
    # a file dropped on the page
    data = base64.b64encode(bake_file[1].read_bytes()).decode()
    transfer_handle = pg.evaluate_handle("""(data) => { const dt = new DataTransfer();
        const bytes = Uint8Array.from(atob(data), (c) => c.charCodeAt(0));
        dt.items.add(new File([bytes], 'dropped.exr')); return dt; }""", data)
    pg.dispatch_event("#frame", "drop", {"dataTransfer": transfer_handle})
    pg.wait_for_function("() => viewer.uploads === 2 && viewer.last.state.env === 3")
    assert "3: dropped.exr" in pg.text_content("#env")
    # not an image; too large: one line each, the map shown kept
    (tmp_path / "notes.hdr").write_text("not a map")
    pg.set_input_files("#map_file", str(tmp_path / "notes.hdr"))
    pg.wait_for_function("() => document.getElementById('status').textContent.includes('notes.hdr')")
    big = tmp_path / "big.exr"
    big.write_bytes(b"\x00" * ((1 << 16) + 1))
    pg.set_input_files("#map_file", str(big))
    pg.wait_for_function("() => document.getElementById('status').textContent.includes('big.exr')")
    assert "at most" in pg.text_content("#status") and "\n" not in pg.text_content("#status").strip()
    assert pg.evaluate("viewer.uploads") == 2 and pg.input_value("#env") == "3" and v.limits.maps == 4
    assert os.listdir(v.uploads.folder) == []


def test_browser_saves_the_png_copies_the_command_and_hides_the_background(serve, page, transfer):
    from PIL import Image

    v = serve()
    pg = page()
    pg.context.grant_permissions(["clipboard-read", "clipboard-write"])
    pg.goto(v.url + "&rotate_y=30&encoding=raw")
    _frames(pg, 1)
    with pg.expect_download() as info:
        pg.click("#download")
    picture = Image.open(info.value.path())
    assert picture.format == "PNG" and picture.size == (transfer.width, transfer.height)
    assert info.value.suggested_filename.endswith(".png")
    pg.wait_for_function("() => document.getElementById('command').value.startsWith('wavlight frame ')")
    command = pg.input_value("#command")
    s = parsed(command)
    assert s["rotate_y"] == 30 and s["terms"] == pg.evaluate("viewer.last.state.terms")
    pg.click("#copy_command")
    pg.wait_for_function("() => ['copied', 'selected: copy it'].includes(document.getElementById('copy_command')"
                         ".textContent)")
    if pg.text_content("#copy_command") == "copied":
        assert pg.evaluate("navigator.clipboard.readText()") == command
    # the background hidden: black where the camera sees only the map, in the URL; shown again
    assert pg.is_checked("#show_background")
    pg.uncheck("#show_background")
    pg.wait_for_function("() => viewer.last.state.show_background === false")
    assert "show_background=0" in pg.url
    pixels = np.array(pg.evaluate("""() => { const c = document.getElementById('frame');
        return Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data); }"""), np.uint8)
    pixels = pixels.reshape(transfer.height, transfer.width, 4)
    cover = bake_hits(transfer) / transfer.spp
    assert (pixels[cover == 0, :3] == 0).all() and pixels[cover > 0, :3].any()
    pg.wait_for_function("() => document.getElementById('command').value.includes('--background none')")
    assert "--background none" in pg.get_attribute("#command", "title")
    with pg.expect_download() as info:
        pg.click("#download")
    rgba = np.asarray(Image.open(info.value.path()))
    assert rgba.shape == (transfer.height, transfer.width, 4) and (rgba[cover == 0, 3] == 0).all()
    pg.check("#show_background")
    pg.wait_for_function("() => viewer.last.state.show_background === true")
    assert "show_background" not in pg.url and pg.evaluate("viewer.errors") == 0


def test_browser_object_bake_offers_no_map_and_no_background_toggle(serve_object, page):
    v = serve_object()
    pg = page()
    pg.goto(v.url)
    _frames(pg, 1)
    assert pg.is_disabled("#map_file") and pg.is_disabled("#show_background")
    pg.wait_for_function("() => document.getElementById('command').value.includes('--translate')")
    with pg.expect_download() as info:
        pg.click("#download")
    assert info.value.suggested_filename.endswith(".png")


def test_upload_names_are_shown_not_paths():
    assert uploads.shown_name("../../etc/passwd") == "passwd"
    assert uploads.shown_name("a\\b\\c.hdr") == "c.hdr"
    assert uploads.shown_name("..") == "map" and uploads.shown_name("") == "map"
    assert uploads.shown_name("x\u202e\x00\n.hdr") == "x.hdr"
    assert len(uploads.shown_name("a" * 1000 + ".exr")) == uploads.MAX_NAME_CHARS
    with pytest.raises(uploads.Refused) as e:
        uploads.extension("map.exe")
    assert e.value.status == 415


def test_the_maps_taken_from_pages_are_bounded(serve, bake_file, monkeypatch):
    monkeypatch.setattr(test_viewer.viewer_module, "MAX_UPLOADED_MAPS", 1)
    v = serve()
    good = bake_file[1].read_bytes()

    async def talk():
        async with aiohttp.ClientSession() as client:
            assert (await post(client, v, good, "one.exr"))[0] == 200
            status, data = await post(client, v, good, "two.exr")
            assert status == 409 and one_line(data["error"]) and "no more" in data["error"]
    in_a_thread(talk)
    assert v.limits.maps == 3 and os.listdir(v.uploads.folder) == []


def test_the_command_run_writes_the_picture_the_viewer_shows(transfer, bake_file, tmp_path):
    from click.testing import CliRunner
    from PIL import Image

    from wavlight.cli.main import main
    from wavlight.relight.pictures import png

    v = Viewer(transfer, maps=[str(bake_file[1])])
    state, _ = test_viewer.sanitise({"rotate_y": 75, "env": 1, "terms": 100, "exposure": 1.25, "tonemap": "aces"},
                                    v.limits)
    args = shlex.split(v.command(state))[1:]
    args[args.index("-o") + 1] = str(tmp_path / "frame.png")
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    written = np.asarray(Image.open(tmp_path / "frame.png").convert("RGB")).astype(int)
    linear, _ = v.frame(state, v.detail(state))
    shown = np.asarray(Image.open(io.BytesIO(png(linear, state["exposure"], state["tonemap"])))).astype(int)
    assert written.shape == shown.shape and np.abs(written - shown).max() <= 1
