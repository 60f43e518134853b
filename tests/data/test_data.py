"""wavlight.data (named assets, shipped or fetched), data: names in scenes and options, the shipped
scenes (wavlight.demos, `wavlight scenes`, `wavlight render --demo`).

Downloads are tested against an HTTP server on 127.0.0.1 that the tests start (a thread, stopped
after them), serving files made from the shipped assets with hashes computed here; no test needs
the internet or a data folder. The fetched assets' own hashes are checked against the files in
``WAVLIGHT_DATA`` when it is set (CI sets it); see test_fetched_assets_match_the_registry.
"""
from __future__ import annotations

import functools
import hashlib
import http.server
import io
import json
import os
import re
import shutil
import socket
import sys
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import wavlight
from scenes_util import toml_text, write_raw_image
from wavlight import data, demos
from wavlight.cli.main import main
from wavlight.data import derive
from wavlight.envmap import read_image

REPO = Path(__file__).resolve().parents[2]
#: shipped assets must stay small (docs/decisions/data-registry.md)
SHIPPED_LIMIT = 2 << 20


def sha256_of(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def one_line(message: str) -> str:
    assert "\n" not in message and "Traceback" not in message, message
    return message


# ----------------------------------------------------------------------------- a local server
class Server:
    """An HTTP server on 127.0.0.1 serving ``folder`` from a daemon thread; ``paths`` lists the
    paths it was asked for."""

    def __init__(self, folder):
        paths = self.paths = []

        class Handler(http.server.SimpleHTTPRequestHandler):
            def do_GET(self):
                paths.append(self.path)
                super().do_GET()

            def log_message(self, *args):   # quiet
                pass

        handler = functools.partial(Handler, directory=str(folder))
        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def stop(self):
        self.httpd.shutdown()
        self.httpd.server_close()
        self.thread.join(10)


def closed_port() -> int:
    """A port on 127.0.0.1 that nothing listens on (it was free a moment ago)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture
def mirror(tmp_path, monkeypatch):
    """A mirror laid out like the data folder, holding ``envmaps/test_map.exr`` (the bytes of
    the shipped potsdamer_platz_512), served on 127.0.0.1; a registry entry for it (its hash
    computed here); an empty data folder as WAVLIGHT_DATA."""
    monkeypatch.setenv("NO_PROXY", "127.0.0.1")
    folder = tmp_path / "mirror"
    (folder / "envmaps").mkdir(parents=True)
    source = data.path("potsdamer_platz_512")
    shutil.copyfile(source, folder / "envmaps" / "test_map.exr")
    asset = data.Asset(name="test_map", file="envmaps/test_map.exr", sha256=sha256_of(source),
                       bytes=source.stat().st_size, shipped=False, licence="CC0", description="a test map")
    monkeypatch.setenv(data.DATA_ENV, str(tmp_path / "cache"))
    monkeypatch.delenv(data.URL_ENV, raising=False)
    server = Server(folder)
    yield server, asset, tmp_path / "cache"
    server.stop()


class Recorder:
    """pooch's progress-bar interface, recording what it is told."""

    def __init__(self):
        self.total, self.done, self.closed = None, 0, False

    def update(self, n):
        self.done += n

    def reset(self):
        self.done = 0

    def close(self):
        self.closed = True


# ----------------------------------------------------------------------------- the registry
@pytest.mark.parametrize("name", [n for n in data.names() if data.asset(n).shipped])
def test_shipped_asset_matches_its_sha256_and_size(name):
    a = data.asset(name)
    f = data.path(name)
    assert f == data.ASSETS / a.file and f.is_file()
    assert sha256_of(f) == a.sha256 and f.stat().st_size == a.bytes


def test_shipped_assets_are_small_and_free():
    """Together under 2 MiB, and each CC0 or public domain (an MIT package can carry them)."""
    shipped = [data.asset(n) for n in data.names() if data.asset(n).shipped]
    assert sum(a.bytes for a in shipped) <= SHIPPED_LIMIT
    for a in shipped:
        assert "CC0" in a.licence or "public domain" in a.licence, a.name


def test_registry_entries_are_complete():
    """Every entry: a known kind, a sha256 and size, a licence and a description; a fetched one an
    origin at a pinned commit on raw.githubusercontent.com; a derived one an original in the
    registry; every name credited in SOURCES.md."""
    sources = (data.HERE / "SOURCES.md").read_text()
    files = set()
    for name in data.names():
        a = data.asset(name)
        assert a.kind in ("environment map", "mesh"), name
        assert re.fullmatch(r"[0-9a-f]{64}", a.sha256) and a.bytes > 0 and a.licence and a.description, name
        assert a.file not in files, name
        files.add(a.file)
        if not a.shipped:
            assert re.fullmatch(r"[0-9a-f]{40}", a.commit), name
            assert a.url == f"https://raw.githubusercontent.com/{a.repository}/{a.commit}/{a.source}", name
        if a.derived_from is not None:
            assert a.shipped and not data.asset(a.derived_from).shipped, name
        assert f"`{name}`" in sources, f"{name} is not in SOURCES.md"


def test_shipped_maps_are_half_float_lat_long_and_finite():
    import OpenImageIO as oiio

    for name in data.names("environment map"):
        if not data.asset(name).shipped:
            continue
        inp = oiio.ImageInput.open(str(data.path(name)))
        spec = inp.spec()
        inp.close()
        assert (spec.width, spec.height, spec.nchannels) == (512, 256, 3), name
        assert spec.format == oiio.HALF and spec.get_string_attribute("compression") == "zip", name
        pixels = read_image(str(data.path(name)))
        assert np.all(np.isfinite(pixels)) and pixels.min() >= 0 and pixels.max() > 0, name


DATA_FOLDER = os.environ.get(data.DATA_ENV, "").strip()


@pytest.mark.parametrize("checked", ["files in WAVLIGHT_DATA" if DATA_FOLDER else "shipped only: WAVLIGHT_DATA unset"])
def test_fetched_assets_match_the_registry(checked):
    """With WAVLIGHT_DATA set (CI sets it): every fetched asset is in that folder with the
    registry's sha256 and size (nothing is downloaded), and every shipped map holds exactly the
    pixels wavlight/data/derive.py makes from its original there. Without it no fetched file is
    at hand: the test checks the shipped assets only, as its id says, and fails where CI is set
    (docs/decisions/data-registry.md)."""
    if not DATA_FOLDER:
        assert not os.environ.get("CI"), "CI must set WAVLIGHT_DATA to a folder holding the fetched assets"
        for name in data.names():
            a = data.asset(name)
            if a.shipped:
                assert sha256_of(data.path(name)) == a.sha256, name
        return
    for name in data.names():
        a = data.asset(name)
        if a.shipped:
            continue
        f = Path(DATA_FOLDER) / a.file
        assert f.is_file(), f"{name}: {f} missing"
        assert f.stat().st_size == a.bytes and sha256_of(f) == a.sha256, name
    for name in data.names("environment map"):
        if data.asset(name).derived_from:
            np.testing.assert_array_equal(read_image(str(data.path(name))),
                                          derive.derived(name).astype(np.float32), err_msg=name)


# ----------------------------------------------------------------------------- derivation
def test_downsample_keeps_the_energy_and_weights_by_solid_angle():
    """The map's radiance integrated over the sphere is the same before and after (integrated
    here by a fine midpoint rule in theta, not by the texels' closed-form solid angles); a map
    constant within each block is unchanged; a plain mean of the blocks would not keep it."""
    rng = np.random.default_rng(5)
    h, w = 32, 64
    pix = rng.gamma(1.5, 1.0, (h, w, 3))
    pix[3, 7] = 1e4

    def energy(p):
        rows = p.shape[0]
        sub = 256
        theta = (np.arange(rows * sub) + 0.5) * np.pi / (rows * sub)
        row_solid = (np.sin(theta) * np.pi / (rows * sub)).reshape(rows, sub).sum(1) * 2 * np.pi / p.shape[1]
        return np.einsum("h,hwc->c", row_solid, p)

    for factor in (2, 4):
        small = derive.downsample(pix, factor)
        assert small.shape == (h // factor, w // factor, 3)
        np.testing.assert_allclose(energy(small), energy(pix), rtol=1e-7)   # the midpoint rule's own error: 2e-8
        plain = pix.reshape(h // factor, factor, w // factor, factor, 3).mean((1, 3))
        assert not np.allclose(energy(plain), energy(pix), rtol=1e-4)       # a plain mean moves energy
    blocks = np.repeat(np.repeat(rng.random((8, 16, 3)), 2, 0), 2, 1)
    np.testing.assert_allclose(derive.downsample(blocks, 2), blocks[::2, ::2], rtol=1e-12)


def test_downsample_refuses_a_size_not_divisible(tmp_path):
    with pytest.raises(wavlight.WavlightError, match="multiple of 2"):
        derive.downsample(np.ones((5, 8, 3)), 2)


def test_write_exr_is_lossless_for_half_values_and_repeatable(tmp_path):
    """Half values come back exactly; the same pixels give the same bytes (no date in the file)."""
    rng = np.random.default_rng(2)
    pix = rng.gamma(1.0, 3.0, (16, 32, 3)).astype(np.float16)
    a, b = tmp_path / "a.exr", tmp_path / "b.exr"
    derive.write_exr(a, pix)
    derive.write_exr(b, pix)
    np.testing.assert_array_equal(read_image(str(a)), pix.astype(np.float32))
    assert a.read_bytes() == b.read_bytes()
    with pytest.raises(wavlight.WavlightError, match="half float"):
        derive.write_exr(tmp_path / "c.exr", np.full((2, 2, 3), 1e5))


# ----------------------------------------------------------------------------- fetching
def test_fetch_downloads_checks_and_reports_progress(mirror):
    server, asset, cache = mirror
    bar = Recorder()
    got = data.fetch(asset, base_url=server.url, progress=bar)
    assert got == cache / "envmaps" / "test_map.exr"
    assert sha256_of(got) == asset.sha256
    assert bar.total == asset.bytes and bar.done == asset.bytes and bar.closed
    assert server.paths == ["/envmaps/test_map.exr"]
    assert data.fetch(asset, base_url=server.url, progress=bar) == got   # kept: no second request
    assert server.paths == ["/envmaps/test_map.exr"]


class Terminal(io.StringIO):
    """A stderr that says it is a terminal of ``columns`` columns."""

    def __init__(self, columns=80):
        super().__init__()
        self.columns = columns

    def isatty(self):
        return True

    def fileno(self):
        return 2


def test_path_of_a_fetched_asset_downloads_with_a_progress_bar(mirror, monkeypatch):
    """data.path of a registry entry that is not shipped: downloaded from WAVLIGHT_DATA_URL into
    WAVLIGHT_DATA, with a bar on stderr naming the asset where stderr is a terminal, no wider
    than it; then a scene names it."""
    server, asset, cache = mirror
    monkeypatch.setitem(data.registry(), "test_map", asset)
    monkeypatch.setenv(data.URL_ENV, server.url)
    terminal = Terminal(columns=20)
    monkeypatch.setattr(sys, "stderr", terminal)
    monkeypatch.setattr(os, "get_terminal_size", lambda fd=None: os.terminal_size((terminal.columns, 24)))
    got = data.path("test_map")
    assert got == cache / asset.file and sha256_of(got) == asset.sha256
    err = terminal.getvalue()
    assert "100%" in err, err
    shown = [re.sub(r"\x1b\[[0-9;]*[A-Za-z]", "", part) for part in re.split(r"[\r\n]", err)]
    assert max(map(len, shown)) < terminal.columns, shown
    scene = wavlight.load_dict({"environment": {"file": "data:test_map"}})
    assert scene.files == [str(got)]
    np.testing.assert_array_equal(scene.environment.pixels, read_image(str(data.path("potsdamer_platz_512"))))


def test_a_download_draws_nothing_where_stderr_is_not_a_terminal(mirror, monkeypatch, capfd):
    """A pipe or a file as stderr (a script's log): no bar, not even with progress=True."""
    server, asset, cache = mirror
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    data.fetch(asset, base_url=server.url)
    assert sys.stderr.getvalue() == "" and capfd.readouterr().err == ""
    assert sha256_of(cache / asset.file) == asset.sha256


class Oversized:
    """A server on 127.0.0.1 answering every GET with ``body`` (with its Content-Length or,
    ``length=False``, none: read until the connection closes)."""

    def __init__(self, body: bytes, length: bool = True):
        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self):
                self.send_response(200)
                if length:
                    self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                try:
                    self.wfile.write(body)
                except OSError:   # the client stopped reading
                    pass

            def log_message(self, *args):
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def stop(self):
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.mark.parametrize("length", [True, False], ids=["content-length", "no-length"])
def test_a_body_longer_than_the_registry_says_is_refused_as_it_arrives(mirror, length):
    """A mirror serving more bytes than the registry's size (a huge file would fill the disk):
    one line, nothing kept, and the download stops at the registry's size, not at the body's."""
    _, asset, cache = mirror
    server = Oversized(b"\0" * (asset.bytes * 40), length)
    bar = Recorder()
    try:
        with pytest.raises(wavlight.WavlightError) as e:
            data.fetch(asset, base_url=server.url, progress=bar)
    finally:
        server.stop()
    msg = one_line(str(e.value))
    assert msg.startswith("data:test_map: the file downloaded from 127.0.0.1:") and "refused" in msg, msg
    assert f"more than its {asset.bytes} bytes" in msg
    assert bar.done <= asset.bytes + data.CHUNK_BYTES
    assert not any(p.is_file() for p in cache.rglob("*"))


@pytest.mark.parametrize("url", ["http://[::1", "http://", "https:///envmaps"])
def test_a_mirror_url_that_names_no_host_is_one_line(mirror, monkeypatch, url):
    _, asset, cache = mirror
    monkeypatch.setenv(data.URL_ENV, url)
    with pytest.raises(wavlight.WavlightError) as e:
        data.fetch(asset, progress=False)
    assert one_line(str(e.value)) == f"data:test_map: WAVLIGHT_DATA_URL={url}: not an http:// or https:// URL"


def test_a_data_folder_of_a_symbolic_link_loop_or_an_unknown_home_is_one_line(mirror, tmp_path, monkeypatch):
    """WAVLIGHT_DATA a symbolic link to itself, or holding one as its envmaps/, or ~user of no
    user: one line each, also through the command line."""
    server, asset, _ = mirror
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    monkeypatch.setenv(data.DATA_ENV, str(loop))
    with pytest.raises(wavlight.WavlightError) as e:
        data.fetch(asset, base_url=server.url, progress=False)
    assert one_line(str(e.value)) == (f"data:test_map: {loop / 'envmaps'} is a symbolic link loop; set WAVLIGHT_DATA "
                                      "to a folder")
    folder = tmp_path / "inner"
    folder.mkdir()
    (folder / "envmaps").symlink_to(folder / "envmaps")
    with pytest.raises(wavlight.WavlightError, match="is a symbolic link loop"):
        data.fetch(asset, folder=folder, base_url=server.url, progress=False)
    monkeypatch.setenv(data.DATA_ENV, "~no-such-user-of-wavlight/data")
    with pytest.raises(wavlight.WavlightError) as e:
        data.data_dir()
    assert one_line(str(e.value)) == "WAVLIGHT_DATA=~no-such-user-of-wavlight/data: no such home folder"
    scene = tmp_path / "scene.toml"
    scene.write_text('[environment]\nfile = "data:rooitou_park_1k"\n')
    for value in (str(loop), "~no-such-user-of-wavlight/data"):
        monkeypatch.setenv(data.DATA_ENV, value)
        r = CliRunner().invoke(main, ["render", str(scene), "-o", str(tmp_path / "x.png")])
        assert r.exit_code == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert r.stderr.startswith(f"Error: {scene}: [environment].file: ") and "Traceback" not in r.stderr


def test_a_wrong_hash_is_refused_in_one_line(mirror):
    server, asset, cache = mirror
    wrong = replace(asset, sha256="0" * 64)
    with pytest.raises(wavlight.WavlightError) as e:
        data.fetch(wrong, base_url=server.url, progress=False)
    msg = one_line(str(e.value))
    assert msg.startswith("data:test_map: ") and "127.0.0.1" in msg and "refused" in msg, msg
    assert asset.sha256[:16] in msg   # what came, against what was expected
    assert not (cache / asset.file).exists()


def test_no_server_gives_one_line_naming_the_asset_and_the_variable(mirror):
    _, asset, cache = mirror
    port = closed_port()
    with pytest.raises(wavlight.WavlightError) as e:
        data.fetch(asset, base_url=f"http://127.0.0.1:{port}")
    msg = one_line(str(e.value))
    assert msg == (f"data:test_map: cannot download envmaps/test_map.exr from 127.0.0.1:{port} (no connection); "
                   "put the file in a folder and set WAVLIGHT_DATA to it")
    assert not (cache / asset.file).exists()


def test_a_missing_file_on_the_server_is_one_line(mirror):
    server, asset, _ = mirror
    with pytest.raises(wavlight.WavlightError) as e:
        data.fetch(replace(asset, file="envmaps/other.exr"), base_url=server.url, progress=False)
    assert "(HTTP 404)" in one_line(str(e.value)) and "WAVLIGHT_DATA" in str(e.value)


def test_path_of_a_registry_asset_offline_is_one_line(tmp_path, monkeypatch):
    """The real registry's bunny with an empty data folder and no server: one line naming the
    asset, its file and the variable, also through a scene and the command line."""
    port = closed_port()
    monkeypatch.setenv(data.DATA_ENV, str(tmp_path / "empty"))
    monkeypatch.setenv(data.URL_ENV, f"http://127.0.0.1:{port}")
    with pytest.raises(wavlight.WavlightError) as e:
        data.path("bunny")
    assert one_line(str(e.value)).startswith("data:bunny: cannot download meshes/bunny.ply from 127.0.0.1:")
    scene = tmp_path / "scene.toml"
    scene.write_text('[environment]\nprocedural = "sky"\n\n[[objects]]\nmesh = "data:bunny"\n')
    r = CliRunner().invoke(main, ["render", str(scene), "-o", str(tmp_path / "x.png")])
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert r.exit_code == 2 and len(lines) == 1, r.stderr
    assert lines[0].startswith(f"Error: {scene}: [[objects]][0].mesh: data:bunny: cannot download meshes/bunny.ply")
    assert lines[0].endswith("set WAVLIGHT_DATA to it") and not (tmp_path / "x.png").exists()


def test_a_file_in_wavlight_data_is_used_without_a_network(mirror, monkeypatch):
    """WAVLIGHT_DATA holding the file: it is used as it is (the server is never asked, even with
    WAVLIGHT_DATA_URL on a closed port); a file there with other bytes is refused in one line."""
    server, asset, _ = mirror
    folder = Path(os.environ[data.DATA_ENV])
    (folder / "envmaps").mkdir(parents=True)
    shutil.copyfile(data.path("potsdamer_platz_512"), folder / asset.file)
    monkeypatch.setenv(data.URL_ENV, f"http://127.0.0.1:{closed_port()}")
    assert data.fetch(asset) == folder / asset.file
    assert server.paths == []
    (folder / asset.file).write_bytes(b"not a map")
    with pytest.raises(wavlight.WavlightError) as e:
        data.fetch(asset)
    msg = one_line(str(e.value))
    assert msg.startswith(f"data:test_map: {folder / asset.file} is not the registry's file") and "remove it" in msg


def test_data_dir_default_and_override(tmp_path, monkeypatch):
    import platformdirs

    monkeypatch.delenv(data.DATA_ENV, raising=False)
    assert data.data_dir() == Path(platformdirs.user_cache_dir("wavlight")) / "data"
    monkeypatch.setenv(data.DATA_ENV, str(tmp_path))
    assert data.data_dir() == tmp_path
    assert data.local_path("bunny") == tmp_path / "meshes" / "bunny.ply"
    assert data.local_path("spot") == data.ASSETS / "meshes" / "spot.obj"   # shipped: wherever the folder
    (tmp_path / "file").write_text("x")
    monkeypatch.setenv(data.DATA_ENV, str(tmp_path / "file"))
    with pytest.raises(wavlight.WavlightError, match="WAVLIGHT_DATA=.*: not a folder"):
        data.data_dir()


def test_a_mirror_url_must_be_http(mirror, monkeypatch):
    _, asset, _ = mirror
    monkeypatch.setenv(data.URL_ENV, "127.0.0.1:8000")
    with pytest.raises(wavlight.WavlightError, match=r"^data:test_map: WAVLIGHT_DATA_URL=127.0.0.1:8000: not an http"):
        data.fetch(asset)


# ----------------------------------------------------------------------------- data: in scenes
def test_scene_names_shipped_assets(tmp_path):
    """data: names in TOML and in load_dict: the shipped files are read, and the Scene's files
    are those files (its content hash covers them)."""
    (tmp_path / "s.toml").write_text('[environment]\nfile = "data:rooitou_park_512"\n\n'
                                     '[[objects]]\nmesh = "data:spot"\n')
    expected = [str(data.path("rooitou_park_512")), str(data.path("spot"))]
    from_toml = wavlight.load_scene(tmp_path / "s.toml")
    from_dict = wavlight.load_dict({"environment": {"file": "data:rooitou_park_512"},
                                    "objects": [{"mesh": "data:spot"}]})
    for scene in (from_toml, from_dict):
        assert scene.files == expected
        np.testing.assert_array_equal(scene.environment.pixels, read_image(expected[0]))
        assert len(scene.faces) == 5856
    assert from_toml.content_hash == from_dict.content_hash


def test_content_hash_covers_the_assets_bytes(mirror, monkeypatch, tmp_path):
    """The same scene text naming data:test_map, with the asset's file (and its registry hash)
    changed: the content hash changes."""
    _, asset, cache = mirror
    hashes = []
    for source in ("potsdamer_platz_512", "st_fagans_interior_512"):
        folder = tmp_path / source
        (folder / "envmaps").mkdir(parents=True)
        shutil.copyfile(data.path(source), folder / asset.file)
        monkeypatch.setenv(data.DATA_ENV, str(folder))
        monkeypatch.setitem(data.registry(), "test_map", replace(asset, sha256=sha256_of(data.path(source))))
        hashes.append(wavlight.load_dict({"environment": {"file": "data:test_map"}}).content_hash)
    assert hashes[0] != hashes[1]


@pytest.mark.parametrize("key, value, expected", [
    ("file", "data:rooitou_park", r"\[environment\]\.file: data:rooitou_park: unknown asset "
                                  r"\(close names: rooitou_park_1k, rooitou_park_512\)$"),
    ("file", "data:spot", r"\[environment\]\.file: data:spot: is a mesh \(meshes/spot.obj\), not an environment map$"),
    ("mesh", "data:teapott", r"\[\[objects\]\]\[0\]\.mesh: data:teapott: unknown asset \(close names: teapot\)$"),
    ("mesh", "data:potsdamer_platz_512",
     r"\[\[objects\]\]\[0\]\.mesh: data:potsdamer_platz_512: is an environment map"),
])
def test_a_bad_data_name_is_one_scene_error_line(tmp_path, key, value, expected):
    doc = ({"environment": {"file": value}} if key == "file"
           else {"environment": {"procedural": "sky"}, "objects": [{"mesh": value}]})
    (tmp_path / "s.toml").write_text(toml_text(doc))
    for load in (lambda: wavlight.load_scene(tmp_path / "s.toml"), lambda: wavlight.load_dict(doc)):
        with pytest.raises(wavlight.SceneError) as e:
            load()
        assert re.search(expected, one_line(str(e.value))), str(e.value)


def test_an_unknown_name_without_close_ones_lists_the_names_of_its_kind():
    with pytest.raises(wavlight.SceneError) as e:
        wavlight.load_dict({"environment": {"procedural": "sky"}, "objects": [{"mesh": "data:zzz"}]})
    assert str(e.value).endswith(f"unknown asset (known: {', '.join(data.names('mesh'))})")


def test_scene_files_resolves_data_names_without_fetching(tmp_path, monkeypatch):
    from wavlight import imageio

    monkeypatch.setenv(data.DATA_ENV, str(tmp_path / "empty"))
    monkeypatch.setenv(data.URL_ENV, f"http://127.0.0.1:{closed_port()}")
    (tmp_path / "s.toml").write_text('[environment]\nfile = "data:rooitou_park_512"\n\n'
                                     '[[objects]]\nmesh = "data:bunny"\n')
    assert imageio.scene_files(tmp_path / "s.toml")[1:] == [str(data.path("rooitou_park_512")),
                                                            str(tmp_path / "empty" / "meshes" / "bunny.ply")]


# ----------------------------------------------------------------------------- shipped scenes
def test_every_shipped_scene_renders_offline(tmp_path, monkeypatch, device):
    """Every scenes/*.toml at 16 x 16, 1 spp with an empty data folder and no server: each uses
    only built-in shapes, the sky and shipped assets, and starts with a one-line description."""
    monkeypatch.setenv(data.DATA_ENV, str(tmp_path / "empty"))
    monkeypatch.setenv(data.URL_ENV, f"http://127.0.0.1:{closed_port()}")
    files = sorted((REPO / "scenes").glob("*.toml"))
    assert [f.stem for f in files] == demos.names() and "default" in demos.names()
    for f in files:
        assert demos.description(f.stem), f.name
        scene = wavlight.load_scene(f)
        image = wavlight.render(scene, spp=1, width=16, height=16)
        assert image.shape == (16, 16, 3) and np.all(np.isfinite(image)) and image.max() > 0, f.name
    assert not (tmp_path / "empty").exists()


def test_demos_path_and_unknown_name():
    assert demos.path("default") == demos.folder() / "default.toml"
    with pytest.raises(wavlight.WavlightError) as e:
        demos.path("spot_gg")
    assert "did you mean spot_ggx" in one_line(str(e.value))


def test_scenes_command_lists_names_and_descriptions():
    r = CliRunner().invoke(main, ["scenes"])
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    assert [line.split()[0] for line in lines] == demos.names()
    for line, name in zip(lines, demos.names()):
        first = (REPO / "scenes" / f"{name}.toml").read_text().splitlines()[0]
        assert line.endswith(first.lstrip("# ")), line


def test_render_demo(tmp_path, device):
    out = tmp_path / "x.png"
    r = CliRunner().invoke(main, ["render", "--demo", "default", "--spp", "1", "--width", "32", "--height", "32",
                                  "-o", str(out), "--json"])
    assert r.exit_code == 0, r.output
    stats = json.loads(r.stdout)
    assert (stats["width"], stats["height"], stats["spp"]) == (32, 32, 1) and out.stat().st_size > 0


@pytest.mark.parametrize("args, words", [
    (["--demo", "default", "SCENE"], "not both"),
    ([], "give a SCENE file, or --demo NAME"),
    (["--demo", "nope"], "no shipped scene 'nope'"),
])
def test_render_scene_or_demo_one_line(tmp_path, args, words):
    args = [str(REPO / "scenes" / "default.toml") if a == "SCENE" else a for a in args]
    r = CliRunner().invoke(main, ["render", *args, "-o", str(tmp_path / "x.png")])
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert r.exit_code == 2 and len(lines) == 1 and lines[0].startswith("Error: ") and words in lines[0], r.stderr
    assert not (tmp_path / "x.png").exists()


def test_frame_env_takes_a_data_name(tmp_path, device):
    """`wavlight frame --env data:NAME` relights with the asset's map: the frame equals the one
    made with the file's path."""
    rng = np.random.default_rng(0)
    write_raw_image(tmp_path / "sky.exr", rng.uniform(0.2, 2.0, (16, 32, 3)).astype(np.float32))
    (tmp_path / "scene.toml").write_text(toml_text({
        "render": {"width": 16, "height": 12}, "environment": {"file": "sky.exr"},
        "objects": [{"shape": "sphere", "center": [0.0, 0.5, 0.0], "radius": 0.5, "subdivisions": 2}]}))
    bake = tmp_path / "s.wlt"
    run = lambda *a: CliRunner().invoke(main, [str(x) for x in a])
    r = run("bake", tmp_path / "scene.toml", "-o", bake, "--spp", "2", "--levels", "3", "--terms", "32", "-q")
    assert r.exit_code == 0, r.output
    for env, out in (("data:potsdamer_platz_512", "a.exr"), (data.path("potsdamer_platz_512"), "b.exr")):
        r = run("frame", bake, "--env", env, "-o", tmp_path / out, "-q")
        assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(read_image(str(tmp_path / "a.exr")), read_image(str(tmp_path / "b.exr")))
    r = run("frame", bake, "--env", "data:spot", "-o", tmp_path / "c.exr")
    assert r.exit_code == 2 and "data:spot: is a mesh" in r.stderr and not (tmp_path / "c.exr").exists()
    r = run("frame", bake, "--env", "data:nope", "-o", tmp_path / "c.exr")   # the maps' names only
    assert r.exit_code == 2 and "data:nope: unknown asset (known: " in r.stderr, r.stderr
    assert not any(name in r.stderr for name in data.names("mesh")), r.stderr


class Trickle:
    """A server on 127.0.0.1 that announces ``length`` bytes and sends one every ``pause`` s
    (or, ``pause=None``, nothing at all after its headers)."""

    def __init__(self, length: int, pause):
        stop = self.stop_event = threading.Event()

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self):
                self.send_response(200)
                self.send_header("Content-Length", str(length))
                self.end_headers()
                try:
                    for _ in range(length):
                        if stop.wait(60 if pause is None else pause):
                            return
                        self.wfile.write(b"\0")
                        self.wfile.flush()
                except OSError:   # the client went away
                    pass

            def log_message(self, *args):
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def stop(self):
        self.stop_event.set()
        self.httpd.shutdown()
        self.httpd.server_close()


def test_a_trickling_mirror_stops_at_the_deadline(mirror, monkeypatch):
    """A mirror that sends a byte every 0.05 s meets every read's timeout; the download's deadline
    (here 1 s) stops it: one line naming the asset and the variable, nothing kept."""
    import time

    _, asset, cache = mirror
    monkeypatch.setattr(data, "DOWNLOAD_SECONDS", 1.0)
    monkeypatch.setattr(data, "DOWNLOAD_RATE", 1e12)
    server = Trickle(asset.bytes, 0.05)
    t0 = time.monotonic()
    try:
        with pytest.raises(wavlight.WavlightError) as e:
            data.fetch(asset, base_url=server.url, progress=False)
    finally:
        server.stop()
    assert time.monotonic() - t0 < 10
    msg = one_line(str(e.value))
    assert msg.startswith("data:test_map: the download from 127.0.0.1:") and "took more than 1 s" in msg, msg
    assert data.DATA_ENV in msg
    assert not any(p.is_file() for p in cache.rglob("*"))


def test_a_silent_mirror_times_out_in_one_line(mirror, monkeypatch):
    """Headers, then no byte at all: the read's timeout (here 0.5 s) gives one line."""
    _, asset, cache = mirror
    monkeypatch.setattr(data, "READ_SECONDS", 0.5)
    server = Trickle(asset.bytes, None)
    try:
        with pytest.raises(wavlight.WavlightError) as e:
            data.fetch(asset, base_url=server.url, progress=False)
    finally:
        server.stop()
    msg = one_line(str(e.value))
    assert msg.startswith("data:test_map: cannot download") and "timed out" in msg, msg
    assert not any(p.is_file() for p in cache.rglob("*"))
