"""Bake files and frames, as a hostile user would give them.

A bake file's header is checked against its sections before any kernel runs: a header edited
by hand (its checksums signed again, as a forger would: the checks must not rely on them), a bit
flipped anywhere in it, a section whose contents no bake writes, a file that is not a regular
file, a file truncated or overwritten while frames are made from it: one line ``Error: ...``
and exit code 2, or the very frame of the unmodified file; never a traceback, a segfault, a NaN
image or a wrong frame with exit code 0. Angles of any finite size are reduced modulo 360
exactly, so that a frame at 1e308 degrees is the frame at fmod(1e308, 360); absurd
translations and cameras are refused with the limit stated; the unbiased frames of view and
object bakes take their samples in passes of bounded size at any spp.

Three tiny bakes of one scene (a ball over a floor under a sky with a sun, 16 x 12) are made
once per module: lighting, object and view. The cases copy them and damage the copies.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

import wavlight
from scenes_util import over_floor, toml_text, write_sun_sky
from test_cli import run_process, stderr_lines
from test_relight_cli import one_error_line, run
from wavlight.envmap import read_image
from wavlight.errors import WavlightError
from wavlight.relight import Transfer, store
from wavlight.relight.converge import converge
from wavlight.relight.moving import MovingObject
from wavlight.relight.view_frames import ViewFrames

SCENE = over_floor({"shape": "sphere", "name": "ball", "translate": [0.0, 0.5, 0.0], "radius": 0.5,
                    "subdivisions": 2}, width=16, height=12, target=(0.0, 0.3, 0.0))
FAST = ["--spp", "2", "--levels", "3", "--terms", "32", "--priority", "area"]
#: the arguments of a frame whose result does not depend on the header's defaults
EXPLICIT = {"rotate_y": 40.0, "terms": 32, "priority": "area"}


@pytest.fixture(scope="module")
def bakes(tmp_path_factory, device):
    """The scene's folder and its lighting, object and view bakes (paths)."""
    folder = tmp_path_factory.mktemp("bake_hostile")
    write_sun_sky(folder)
    (folder / "scene.toml").write_text(toml_text(SCENE))
    r = run("bake", folder / "scene.toml", "-o", folder / "light.wlt", *FAST, "-q")
    assert r.exit_code == 0, r.output
    plastic = dict(SCENE, materials={**SCENE["materials"], "m": {"type": "plastic", "albedo": [0.7, 0.3, 0.1]}})
    (folder / "plastic.toml").write_text(toml_text(plastic))
    r = run("bake", folder / "plastic.toml", "-o", folder / "plastic.wlt", *FAST, "-q")   # with plastic's coat
    assert r.exit_code == 0, r.output
    scene = wavlight.load_scene(folder / "scene.toml")
    wavlight.bake(scene, folder / "object.wlt", spp=2, levels=3, terms=32, priority="area", vary="object",
                  object="ball", static_spp=4).close()
    wavlight.bake(scene, folder / "view.wlt", vary="view", levels=3, density=30.0).close()
    return folder


# ----------------------------------------------------------------------------- forging files
def parts(path):
    """(the file's bytes, its header as a dict), read without any check."""
    raw = Path(path).read_bytes()
    n = len(store.MAGIC)
    length = int(np.frombuffer(raw[n:n + 8], np.uint64)[0])
    return raw, json.loads(raw[n + 8:n + 8 + length])


def forge(src, dst, edit=None, sections=None, sign: bool = True):
    """Write a copy of bake file ``src`` to ``dst`` with its header edited (``edit(header)``
    changes the dict in place) and sections replaced (name -> array of the same bytes), their
    CRC-32 and (with ``sign``) the header's checksum computed anew; a header that outgrows its
    space moves the sections (data_offset and file_bytes follow, unless the edit set them)."""
    raw, header = parts(src)
    base = header["data_offset"]
    data = bytearray(raw[base:])
    for name, array in (sections or {}).items():
        meta = header["sections"][name]
        b = np.ascontiguousarray(array).tobytes()
        assert len(b) == meta["bytes"], name
        data[meta["offset"]:meta["offset"] + len(b)] = b
        meta["crc32"] = zlib.crc32(b)
    before = dict(header)
    if edit is not None:
        edit(header)
    moves = header.get("data_offset") == before["data_offset"] and header.get("file_bytes") == before["file_bytes"]

    def text():
        if sign and "header_crc32" in header:
            header["header_crc32"] = store.header_checksum(header)
        return json.dumps(header).encode().replace(json.dumps(DEEP).encode(), b"[" * 100_000 + b"]" * 100_000)

    head = store.MAGIC + np.uint64(len(text())).tobytes() + text()
    while len(head) > base and moves:
        base = -(-(len(head) + 64) // store.ALIGN) * store.ALIGN
        header["data_offset"], header["file_bytes"] = base, base + len(data)
        head = store.MAGIC + np.uint64(len(text())).tobytes() + text()
    Path(dst).write_bytes(head + b"\0" * max(base - len(head), 0) + bytes(data))
    return Path(dst)


def section(path, name):
    """A section of a bake file as a writable array (a copy)."""
    return np.array(Transfer.load(path)._s[name])


def setter(*keys, value):
    def edit(h):
        for k in keys[:-1]:
            h = h[k]
        h[keys[-1]] = value(h[keys[-1]]) if callable(value) else value
    return edit


def deleter(*keys):
    def edit(h):
        for k in keys[:-1]:
            h = h[k]
        del h[keys[-1]]
    return edit


#: a header value forge writes as lists nested 100 000 deep (json.dumps itself would overflow the stack)
DEEP = "nested 100 000 deep"


def deep_header(h):
    h["measured"] = DEEP


# ----------------------------------------------------------------------------- header edits
#: case: (edit of the header, words of the message) on the lighting bake
HEADER_CASES = {
    "spp one more": (setter("spp", value=lambda v: v + 1), ("spp",)),
    "spp 0": (setter("spp", value=0), ("spp",)),
    "spp 65": (setter("spp", value=65), ("spp",)),
    "block 0": (setter("block", value=0), ("block",)),
    "block 12": (setter("block", value=12), ("block",)),
    "block 17": (setter("block", value=17), ("block",)),
    "width 0": (setter("width", value=0), ("width",)),
    "width 12": (setter("width", value=12), ("width",)),
    "width -5": (setter("width", value=-5), ("width",)),
    "width 1e9": (setter("width", value=10 ** 9), ("width",)),
    "height 0": (setter("height", value=0), ("height",)),
    "height -5": (setter("height", value=-5), ("height",)),
    "height 1e9": (setter("height", value=10 ** 9), ("height",)),
    "blocks -2 -2": (setter("blocks", value=[-2, -2]), ("blocks",)),
    "blocks a string": (setter("blocks", value="ab"), ("blocks",)),
    "data_offset negative": (setter("data_offset", value=-64), ("data_offset",)),
    "data_offset a string": (setter("data_offset", value="0"), ("data_offset",)),
    "section offset negative": (setter("sections", "entry_data", "offset", value=-10 ** 6), ("entry_data",)),
    "section offset beyond a C long": (setter("sections", "rms", "offset", value=-(1 << 70)), ("rms",)),
    "dtype ,f4": (setter("sections", "albedo", "dtype", value=",f4"), ("albedo", "dtype")),
    "dtype <f8": (setter("sections", "albedo", "dtype", value="<f8"), ("albedo", "dtype")),
    "dtype of python code": (setter("sections", "albedo", "dtype", value="__import__('os').getcwd()"),
                             ("albedo", "dtype")),
    "dtype a list": (setter("sections", "albedo", "dtype", value=["<f4"]), ("albedo", "dtype")),
    "shape transposed": (setter("sections", "albedo", "shape", value=lambda s: [s[1], s[0], 3]), ("albedo",)),
    "environment_rotate_y renamed": (deleter("environment_rotate_y"), ("environment_rotate_y",)),
    "environment_rotate_y a string": (setter("environment_rotate_y", value="30"), ("environment_rotate_y",)),
    "environment_rotate_y NaN": (setter("environment_rotate_y", value=float("nan")), ("environment_rotate_y",)),
    "vary view without its sections": (setter("vary", value="view"), ("view_",)),
    "vary object without its sections": (setter("vary", value="object"), ("object",)),
    "vary unknown": (setter("vary", value="weather"), ("vary",)),
    "a header 100 000 deep": (deep_header, ("header",)),
    "bits 16 over 8-bit entries": (setter("bits", value=16), ("bits",)),
    "n_levels one more": (setter("n_levels", value=lambda v: v + 1), ("n_levels",)),
    "n_levels 0": (setter("n_levels", value=0), ("n_levels",)),
    "n_levels 40": (setter("n_levels", value=40), ("n_levels",)),
    "terms 0": (setter("terms", value=0), ("terms",)),
    "terms -3": (setter("terms", value=-3), ("terms",)),
    "terms a float": (setter("terms", value=32.5), ("terms",)),
    "scene path with a NUL": (setter("scene", "path", value="scene\0.toml"), ("scene",)),
    "camera eye of strings": (setter("camera", "eye", value=["a", "b", "c"]), ("camera",)),
}


@pytest.mark.parametrize("case", sorted(HEADER_CASES))
def test_header_edits_are_one_line(bakes, tmp_path, case):
    edit, words = HEADER_CASES[case]
    path = forge(bakes / "light.wlt", tmp_path / "edited.wlt", edit)
    out = tmp_path / "f.png"
    for args in ([], ["--json"], ["--spp", "1"]):   # the approximate frame, its report, the unbiased frame
        one_error_line(run("frame", path, "-o", out, *args), "edited.wlt", *words)
    with pytest.raises(WavlightError, match="edited.wlt"):
        Transfer.load(path)
    assert not out.exists()


#: case: (the lighting bake's section and what to do to it (array -> array), words of the message)
SECTION_CASES = {
    "a background pixel beyond the image": ("background_pixel", lambda a: np.where(np.arange(len(a)) == len(a) - 1,
                                                                                   np.uint32(1 << 20), a),
                                            ("background_pixel",)),
    "a NaN background direction": ("background_dir", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 4,
                                                                        np.float32("nan"), a), ("background_dir",)),
    "an infinite background direction": ("background_dir", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 5,
                                                                              np.float32("inf"), a),
                                         ("background_dir",)),
    "a black environment": ("environment", lambda a: np.zeros_like(a), ("black everywhere",)),
    "a NaN albedo": ("albedo", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 7, np.float32("nan"), a),
                     ("albedo",)),
    "a NaN rms": ("rms", lambda a: np.full_like(a, np.nan), ("rms",)),
    "an albedo beyond any scene's": ("albedo", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 7,
                                                                  np.float32(3e38), a), ("albedo",)),
}


@pytest.mark.parametrize("case", sorted(SECTION_CASES))
def test_section_contents_are_checked(bakes, tmp_path, case):
    name, change, words = SECTION_CASES[case]
    a = section(bakes / "light.wlt", name)
    assert a.size, f"the bake has no {name} to damage"
    path = forge(bakes / "light.wlt", tmp_path / "edited.wlt", sections={name: change(a)})
    for args in ([], ["--spp", "1"]):
        one_error_line(run("frame", path, "-o", tmp_path / "f.exr", *args), "edited.wlt", *words)
    assert not (tmp_path / "f.exr").exists()


def test_a_frame_that_overflows_is_one_line(bakes, tmp_path):
    """Entries whose scales are finite but whose product with the lighting overflows float32: the
    library's frame is an error naming the file, not an image of Inf."""
    scale = section(bakes / "light.wlt", "entry_scale")
    path = forge(bakes / "light.wlt", tmp_path / "edited.wlt", sections={"entry_scale": np.full_like(scale, 1e37)})
    tr = Transfer.load(path)
    with pytest.raises(WavlightError, match="edited.wlt.*overflows"):
        tr.frame()
    tr.close()
    one_error_line(run("frame", path, "-o", tmp_path / "f.exr"), "edited.wlt", "overflows")


#: case: (edit of the header, sections (name -> array -> array), words) on the object bake
OBJECT_CASES = {
    "no object": (deleter("object"), {}, ("object",)),
    "a negative radius": (setter("object", "radius", value=-1.0), {}, ("radius",)),
    "a centre of strings": (setter("object", "center", value=["x", "y", "z"]), {}, ("center",)),
    "product_levels beyond the leaves": (setter("product_levels", value=lambda v: v + 1), {}, ("product_levels",)),
    "NaN product leaves": (None, {"product_leaves": lambda a: np.full_like(a, np.nan)}, ("product_leaves",)),
    "infinite product leaves": (None, {"product_leaves": lambda a: np.full_like(a, np.inf)}, ("product_leaves",)),
    "a NaN static image": (None, {"static": lambda a: np.full_like(a, np.nan)}, ("static",)),
    "sections of a lighting bake": (setter("vary", value="lighting"), {}, ("static",)),
    "the floor as the moving object": (setter("object", "index", value=1), {}, ("moving object",)),
    "an object beyond the scene's": (setter("object", "index", value=5), {}, ("moving object",)),
    "the map turned otherwise": (setter("environment_rotate_y", value=lambda v: v + 10.0), {}, ("turned",)),
    "a coat on an object bake": (setter("coat", value=True), {}, ("coat",)),
}

#: case: (edit of the header, sections (name -> array -> array), words) on the lighting bake of
#: the scene in plastic, which holds plastic's coat (store.COAT_SECTIONS)
COAT_CASES = {
    "coat dropped": (deleter("coat"), {}, ("coat_blocks",)),
    "coat a string": (setter("coat", value="yes"), {}, ("coat",)),
    "coat 1": (setter("coat", value=1), {}, ("coat",)),
    "coat_blocks of floats": (setter("sections", "coat_blocks", "dtype", value="<f4"), {}, ("coat_blocks", "dtype")),
    "coat entries of 16 bits": (setter("sections", "coat_entry_data", "dtype", value="<i2"), {},
                                ("coat_entry_data", "dtype")),
    "coat_offsets one block more": (setter("sections", "coat_offsets", "shape", value=lambda v: [v[0], v[1] + 1]), {},
                                    ("coat_offsets",)),
    "coat_offsets reshaped": (setter("sections", "coat_offsets", "shape", value=lambda v: [v[0] // 2, v[1] * 2]), {},
                              ("coat_offsets",)),
    "coat_entry_data of other rows": (setter("sections", "coat_entry_data", "shape",
                                             value=lambda v: [v[0] * 2, v[1] // 2]), {}, ("coat_entry_data",)),
    "coat_entry_scale moved": (setter("sections", "coat_entry_scale", "offset", value=lambda v: v + 64), {},
                               ("coat_entry_scale",)),
    "coat_blocks rank 2": (setter("sections", "coat_blocks", "shape", value=lambda v: [v[0], 1]), {},
                           ("coat_blocks",)),
    "a coat block beyond the image": (None, {"coat_blocks": lambda a: a + 1000}, ("coat_blocks",)),
    "a negative coat block": (None, {"coat_blocks": lambda a: a - 1000}, ("coat_blocks",)),
    "coat blocks out of order": (None, {"coat_blocks": lambda a: a[::-1].copy() if len(a) > 1 else a + 1000},
                                 ("coat_blocks",)),
    "a coat offset beyond the entries": (None, {"coat_offsets": lambda a: np.where(a >= 0, a + 5, a)},
                                         ("coat_offsets",)),
    "a coat offset below -1": (None, {"coat_offsets": lambda a: np.where(a < 0, -7, a)}, ("coat_offsets",)),
    "NaN coat scales": (None, {"coat_entry_scale": lambda a: np.full_like(a, np.nan)}, ("coat_entry_scale",)),
    "negative coat scales": (None, {"coat_entry_scale": lambda a: -a - 1.0}, ("coat_entry_scale",)),
}


@pytest.mark.parametrize("case", sorted(COAT_CASES))
def test_coat_edits_are_one_line(bakes, tmp_path, case):
    """Every field, offset, shape and dtype of plastic's coat is checked before a frame reads it."""
    edit, changes, words = COAT_CASES[case]
    src = bakes / "plastic.wlt"
    path = forge(src, tmp_path / "edited.wlt", edit, {k: f(section(src, k)) for k, f in changes.items()})
    for args in ([], ["--spp", "1"]):   # the approximate frame, the unbiased frame
        one_error_line(run("frame", path, "-o", tmp_path / "f.exr", *args), "edited.wlt", *words)
    with pytest.raises(WavlightError, match="edited.wlt"):
        Transfer.load(path)
    assert not (tmp_path / "f.exr").exists()


def test_the_plastic_bake_frames(bakes, tmp_path):
    """The unedited plastic bake: its coat is there and its frames are written."""
    tr = Transfer.load(bakes / "plastic.wlt")
    assert tr.header["coat"] and len(tr._s["coat_blocks"]) > 0 and tr._s["coat_entry_scale"].size > 0
    tr.close()
    for args in ([], ["--spp", "1"]):
        r = run("frame", bakes / "plastic.wlt", "-o", tmp_path / "f.exr", *args)
        assert r.exit_code == 0, r.output

#: case: (sections (name -> array -> array), words) on the view bake
VIEW_CASES = {
    "a lattice entry beyond the cache": ({"view_lattice": lambda a: np.where(np.arange(len(a)) == 3, 1 << 30, a)},
                                         ("view_lattice",)),
    "a negative lattice entry": ({"view_lattice": lambda a: np.where(np.arange(len(a)) == 3, -7, a)},
                                 ("view_lattice",)),
    "a face's first entry beyond the lattice": ({"view_face_base": lambda a: a + (1 << 40)}, ("view_face_base",)),
    "a face of no subdivisions": ({"view_face_k": lambda a: np.zeros_like(a)}, ("view_face_k",)),
    "a material beyond the scene's": ({"view_material": lambda a: a + 99}, ("material",)),
    "NaN normals": ({"view_normal": lambda a: np.full_like(a, np.nan)}, ("view_normal",)),
    "NaN positions": ({"view_position": lambda a: np.full_like(a, np.nan)}, ("view_position",)),
}


@pytest.mark.parametrize("case", sorted(OBJECT_CASES))
def test_object_bake_edits_are_one_line(bakes, tmp_path, case):
    edit, changes, words = OBJECT_CASES[case]
    src = bakes / "object.wlt"
    path = forge(src, tmp_path / "edited.wlt", edit, {k: f(section(src, k)) for k, f in changes.items()})
    for spp in ("1", "4"):
        one_error_line(run("frame", path, "--translate", 0.3, 0.5, 0.0, "--spp", spp, "-o", tmp_path / "f.exr"),
                       "edited.wlt", *words)
    assert not (tmp_path / "f.exr").exists()


@pytest.mark.parametrize("case", sorted(VIEW_CASES))
def test_view_bake_edits_are_one_line(bakes, tmp_path, case):
    changes, words = VIEW_CASES[case]
    src = bakes / "view.wlt"
    path = forge(src, tmp_path / "edited.wlt", None, {k: f(section(src, k)) for k, f in changes.items()})
    for args in (["--mode", "point"], ["--mode", "pixel"], ["--spp", "1"]):
        one_error_line(run("frame", path, "--eye", 1.0, 2.0, 3.0, *args, "-o", tmp_path / "f.exr"), "edited.wlt",
                       *words)
    assert not (tmp_path / "f.exr").exists()


def test_older_format_is_named(bakes, tmp_path):
    """A file of another format version is named as such (bake again), even with its header
    checksum missing: the version is read before anything that depends on it."""
    path = forge(bakes / "light.wlt", tmp_path / "old.wlt", lambda h: (h.pop("header_crc32"),
                                                                        h.update(version=store.FORMAT_VERSION - 1)))
    one_error_line(run("frame", path, "-o", tmp_path / "f.png"), "old.wlt",
                   f"version {store.FORMAT_VERSION - 1}", "bake the scene again")


def test_unsigned_header_edits_fail_the_checksum(bakes, tmp_path):
    """An edit of a field no section describes (the default rotation, the terms) changes the
    header's checksum: one line, not a frame of other defaults."""
    for edit in (setter("environment_rotate_y", value=lambda v: v + 90.0), setter("terms", value=8),
                 setter("priority", value="magnitude")):
        path = forge(bakes / "light.wlt", tmp_path / "edited.wlt", edit, sign=False)
        one_error_line(run("frame", path, "-o", tmp_path / "f.png"), "edited.wlt", "damaged", "checksum")
    path = forge(bakes / "light.wlt", tmp_path / "edited.wlt", deleter("header_crc32"))
    one_error_line(run("frame", path, "-o", tmp_path / "f.png"), "edited.wlt", "damaged", "checksum")


# ----------------------------------------------------------------------------- bits flipped
def header_span(path) -> int:
    """Bytes of the file's magic, header length and header."""
    raw, _ = parts(path)
    return len(store.MAGIC) + 8 + int(np.frombuffer(raw[len(store.MAGIC):len(store.MAGIC) + 8], np.uint64)[0])


def flipped(raw: bytes, bit: int) -> bytes:
    b = bytearray(raw)
    b[bit >> 3] ^= 1 << (bit & 7)
    return bytes(b)


def outcome(path, reference, **frame_args):
    """'error' (a one-line WavlightError), 'same' (the reference frame) or what went wrong."""
    try:
        tr = Transfer.load(path)
        try:
            image = tr.frame(**frame_args)
        finally:
            tr.close()
    except WavlightError as e:
        return "error" if "\n" not in str(e) and str(path) in str(e) else f"error of {len(str(e).splitlines())} lines"
    except Exception as e:   # noqa: BLE001 (what the test is after)
        return f"{type(e).__name__}: {e}"
    return "same" if np.array_equal(image, reference) else "another frame"


def resigned(raw: bytes, bit: int) -> bytes | None:
    """The file with ``bit`` of its header text flipped and the header's checksum (and length)
    written anew (None where the flip leaves no JSON object with a checksum to sign)."""
    n = len(store.MAGIC) + 8
    length = int(np.frombuffer(raw[len(store.MAGIC):n], np.uint64)[0])
    base = json.loads(raw[n:n + length])["data_offset"]
    text = flipped(raw[n:n + length], bit)
    try:
        header = json.loads(text)
    except (ValueError, RecursionError):
        return None
    if not isinstance(header, dict) or "header_crc32" not in header:
        return None
    header["header_crc32"] = store.header_checksum(header)
    again = json.dumps(header).encode()
    if n + len(again) > base:
        return None
    return raw[:len(store.MAGIC)] + np.uint64(len(again)).tobytes() + again + bytes(base - n - len(again)) + raw[base:]


def test_fuzzed_header_bits_give_one_line_or_the_frame(bakes, tmp_path):
    """A sample of the header's bits flipped (fixed seed; benchmarks/bake_fuzz.py flips every
    one): an error of one line or the unmodified file's frame. Raw flips read with the file's
    defaults; flips signed again (the checks alone stand) read with explicit rotation, terms and
    priority, so that a default no section describes does not count as a wrong frame."""
    src = bakes / "light.wlt"
    raw = src.read_bytes()
    tr = Transfer.load(src)
    plain, explicit = tr.frame(), tr.frame(**EXPLICIT)
    tr.close()
    bits = header_span(src) * 8
    rng = np.random.default_rng(2024)
    seen = {}
    path = tmp_path / "flipped.wlt"
    for bit in rng.choice(bits, 240, replace=False):
        path.write_bytes(flipped(raw, int(bit)))
        seen[("raw", int(bit))] = outcome(path, plain)
    text_bits = (bits - (len(store.MAGIC) + 8) * 8)
    signed = 0
    for bit in rng.choice(text_bits, 1200, replace=False):
        data = resigned(raw, int(bit))
        if data is None:
            continue
        path.write_bytes(data)
        seen[("signed", int(bit))] = outcome(path, explicit, **EXPLICIT)
        signed += 1
        if signed == 120:
            break
    bad = {k: v for k, v in seen.items() if v not in ("error", "same")}
    assert not bad, bad
    assert signed == 120 and "error" in seen.values()


def test_flipped_bits_in_a_child_process(bakes, tmp_path):
    """Bits of the fields kernels take their strides and counts from, flipped in files that
    real processes read (a segfault would be a negative exit code there): one line, or the
    unmodified file's frame."""
    src = bakes / "light.wlt"
    raw = src.read_bytes()
    args = ["-o", tmp_path / "f.exr", "--terms", 32, "--rotate-y", 40, "--priority", "area"]
    reference = run_process("frame", src, *args)
    assert reference.code == 0, reference.describe()
    expected = read_image(str(tmp_path / "f.exr"))
    text = raw[:header_span(src)]
    n = 8 * (len(store.MAGIC) + 8)
    bits = []
    for key in (b'"spp": ', b'"block": ', b'"n_levels": ', b'"width": '):
        at = 8 * (text.index(key) + len(key))
        bits += [at, at + 1]                  # two bits of the value's first digit
    for bit in bits:
        for data, name in ((flipped(raw, bit), "raw.wlt"), (resigned(raw, bit - n), "signed.wlt")):
            if data is None:
                continue
            (tmp_path / name).write_bytes(data)
            os.unlink(tmp_path / "f.exr")
            p = run_process("frame", tmp_path / name, *args)
            assert p.code in (0, 2), (bit, name, p.describe())
            assert "Traceback" not in p.stderr, (bit, name, p.describe())
            if p.code == 2:
                lines = [ln for ln in stderr_lines(p) if not ln.startswith(("warning:", "note:"))]
                assert len(lines) == 1 and lines[0].startswith("Error: "), (bit, name, p.describe())
                assert not (tmp_path / "f.exr").exists()
            else:
                np.testing.assert_array_equal(read_image(str(tmp_path / "f.exr")), expected)
            (tmp_path / "f.exr").touch()


# ----------------------------------------------------------------------------- angles
HUGE = (1e16, 1e18, 1e19, 3e19, 1e25, 1e50, 1e308, -1e308, -7.3e17, 2.0 ** 80 + 2.0 ** 28)


def test_huge_rotations_are_the_reduced_rotations(bakes):
    """A frame at any finite angle is the frame at fmod(angle, 360): the angle is reduced before
    the projection, the radians and the float32 casts."""
    tr = Transfer.load(bakes / "light.wlt")
    for angle in HUGE:
        np.testing.assert_array_equal(tr.frame(rotate_y=angle), tr.frame(rotate_y=math.fmod(angle, 360.0)),
                                      err_msg=str(angle))
        np.testing.assert_array_equal(tr.lighting(rotate_y=angle), tr.lighting(rotate_y=math.fmod(angle, 360.0)))
    tr.close()


def test_huge_rotations_of_the_unbiased_frame(bakes):
    tr = Transfer.load(bakes / "light.wlt")
    for angle in (1e300, -3e19):
        a = converge(tr, rotate_y=angle, spp=1, seed=3)
        b = converge(tr, rotate_y=math.fmod(angle, 360.0), spp=1, seed=3)
        np.testing.assert_array_equal(a.image, b.image)
        assert a.stats["rotate_y"] == math.fmod(angle, 360.0)
    tr.close()


def test_huge_turntable_and_rotation_on_the_command_line(bakes, tmp_path):
    src = bakes / "light.wlt"
    for angle in ("1e308", "1e50", "3e19", "1e16"):
        reduced = repr(math.fmod(float(angle), 360.0))
        r = run("frame", src, "--rotate-y", angle, "-o", tmp_path / "a.exr", "--json")
        assert r.exit_code == 0, r.output
        assert json.loads(r.stdout)["rotate_y"] == float(reduced)
        assert run("frame", src, "--rotate-y", reduced, "-o", tmp_path / "b.exr").exit_code == 0
        np.testing.assert_array_equal(read_image(str(tmp_path / "a.exr")),
                                      read_image(str(tmp_path / "b.exr")))
        for folder, at in (("ta", angle), ("tb", reduced)):
            r = run("frame", src, "--rotate-y", at, "--turntable", 3, "-o", tmp_path / folder, "-q")
            assert r.exit_code == 0, r.output
        for i in range(3):
            name = f"frame-{i:04d}.png"
            assert (tmp_path / "ta" / name).read_bytes() == (tmp_path / "tb" / name).read_bytes(), (angle, i)


def test_huge_object_rotation_is_the_reduced_rotation(bakes):
    tr = Transfer.load(bakes / "object.wlt")
    mover = MovingObject(tr)
    for angle in (1e308, 1e19, -4e17):
        a = mover.frame((0.3, 0.5, 0.0), [0.0, 1.0, 0.0, angle], spp=2, seed=1)
        b = mover.frame((0.3, 0.5, 0.0), [0.0, 1.0, 0.0, math.fmod(angle, 360.0)], spp=2, seed=1)
        np.testing.assert_array_equal(a.image, b.image, err_msg=str(angle))
    tr.close()


# ----------------------------------------------------------------------------- flags
@pytest.mark.parametrize("bake, args, words", [
    ("light.wlt", ["--scale", "0"], ("--scale", "black")),
    ("object.wlt", ["--translate", "1e308", "0", "0"], ("--translate", "1e+18")),
    ("object.wlt", ["--translate", "0", "-3e18", "0"], ("--translate", "1e+18")),
    ("view.wlt", ["--eye", "1e308", "0", "0"], ("--eye", "1e+18")),
    ("view.wlt", ["--target", "0", "0", "-1e300"], ("--target", "1e+18")),
])
def test_absurd_flags_are_one_line(bakes, tmp_path, bake, args, words):
    r = run("frame", bakes / bake, *args, "-o", tmp_path / "f.exr")
    one_error_line(r, *words)
    assert "warning" not in r.stderr.lower()
    assert not (tmp_path / "f.exr").exists()


def test_an_object_axis_of_huge_components_is_its_direction(bakes):
    tr = Transfer.load(bakes / "object.wlt")
    mover = MovingObject(tr)
    a = mover.frame((0.3, 0.5, 0.0), [1e308, 1e308, 0.0, 30.0], spp=2, seed=1)
    b = mover.frame((0.3, 0.5, 0.0), [1.0, 1.0, 0.0, 30.0], spp=2, seed=1)
    assert np.all(np.isfinite(a.image))
    np.testing.assert_allclose(a.image, b.image, rtol=1e-5, atol=1e-6)
    tr.close()


def _fifo(p):
    os.mkfifo(p)


def _loop(p):
    os.symlink(p.with_name(p.name + ".b"), p)
    os.symlink(p, p.with_name(p.name + ".b"))


@pytest.mark.parametrize("make, words", [(_fifo, ("FIFO",)), (_loop, ("symbolic link loop",))])
def test_bake_paths_that_are_not_files(tmp_path, make, words):
    path = tmp_path / "odd.wlt"
    make(path)
    for command in (["frame", path, "-o", tmp_path / "f.png"], ["view", path, "--no-browser"]):
        r = run(*command)
        one_error_line(r, "odd.wlt", *words)
        assert "no such" not in r.stderr


def test_view_refuses_a_damaged_bake_at_start_up(bakes, tmp_path):
    """`wavlight view` of a damaged bake ends at start-up in one line (it would serve its page)."""
    pytest.importorskip("aiohttp")
    path = forge(bakes / "light.wlt", tmp_path / "edited.wlt", setter("spp", value=lambda v: v + 1))
    command = [sys.executable, "-c", "from wavlight.cli.main import main; main()", "view", str(path), "--no-browser",
               "--port", "0"]
    try:
        p = subprocess.run(command, capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("wavlight view served a damaged bake file")
    lines = [ln for ln in p.stderr.splitlines() if ln.strip() and not ln.startswith(("note:", "warning:"))]
    assert p.returncode == 2 and len(lines) == 1 and lines[0].startswith("Error: ") and "spp" in lines[0], p.stderr


# ----------------------------------------------------------------------------- files that change
CHANGE = r"""
import os, shutil, sys
import numpy as np
from wavlight.relight import Transfer
from wavlight.relight.view_frames import ViewFrames
path, other, kind = sys.argv[1:4]

def frame(tr, frames):
    if kind == "view":
        return frames.frame(eye=[1.0, 2.0, 3.0])[0]
    return tr.frame(rotate_y=40.0)

tr = Transfer.load(path)
frames = ViewFrames(tr) if kind == "view" else None
first = frame(tr, frames)
os.truncate(path, 100)                     # truncated in place
assert np.array_equal(frame(tr, frames), first)
shutil.copyfile(other, path)               # another bake written over it in place
assert np.array_equal(frame(tr, frames), first)
os.truncate(path, 0)
tr.save(path + ".saved")                   # the file as it was loaded
again = Transfer.load(path + ".saved")
assert np.array_equal(frame(again, ViewFrames(again) if kind == "view" else None), first)
print("ok")
"""


@pytest.mark.parametrize("kind", ["lighting", "view"])
def test_a_bake_file_changed_under_its_frames(bakes, tmp_path, kind):
    """A bake file truncated or overwritten in place (cp other.wlt live.wlt) while frames are made
    from it: the frames go on from what was loaded (a truncated memory map would end the process
    with SIGBUS)."""
    name = "view.wlt" if kind == "view" else "light.wlt"
    live = tmp_path / name
    live.write_bytes((bakes / name).read_bytes())
    other = bakes / ("light.wlt" if kind == "view" else "object.wlt")
    p = subprocess.run([sys.executable, "-c", CHANGE, str(live), str(other), kind], capture_output=True, text=True,
                       timeout=600)
    assert p.returncode == 0 and p.stdout.strip() == "ok", (p.returncode, p.stderr[-3000:])


# ----------------------------------------------------------------------------- frames in passes
def _agree(a, b, label):
    """Two independent unbiased estimates of one image agree within their standard errors: sums
    over 4 x 4 blocks of pixels, per channel, and the whole image."""
    var = a.stderr.astype(np.float64) ** 2 + b.stderr.astype(np.float64) ** 2
    blocks = lambda x: x.reshape(3, 4, 4, 4, 3).sum(axis=(1, 3))   # noqa: E731  (12 blocks of 16 pixels)
    z = blocks(a.image.astype(np.float64) - b.image) / np.sqrt(blocks(var) + 1e-30)
    z_total = (a.image.astype(np.float64) - b.image).sum() / np.sqrt(var.sum())
    assert np.abs(z).max() < 4.0 and abs(z_total) < 3.5, (label, np.abs(z).max(), z_total)


def test_object_frames_in_passes_are_unbiased(bakes, monkeypatch):
    """An object frame of more samples per pixel than a pass takes them in passes: the same
    estimator (against a frame of one pass, another seed), the kernel and its numpy twin on the
    same random numbers, and the bound reported."""
    from wavlight.relight import moving

    tr = Transfer.load(bakes / "object.wlt")
    one = MovingObject(tr).frame((0.3, 0.5, 0.0), spp=16, seed=1)
    monkeypatch.setattr(moving, "PASS_SPP", 3)
    passes = MovingObject(tr).frame((0.3, 0.5, 0.0), spp=16, seed=2)
    assert passes.stats["pass_spp"] == 3 and one.stats["pass_spp"] == 16
    assert passes.stats["pass_samples"] == 3 * 16 * 12
    _agree(passes, one, "object frame in passes")
    twin = MovingObject(tr, backend="numpy").frame((0.3, 0.5, 0.0), spp=16, seed=2)
    diff = np.abs(passes.image - twin.image).max(2)
    assert (diff > 1e-3 * (1 + np.abs(twin.image).max(2))).mean() < 0.03, diff.max()
    tr.close()


def test_view_frames_in_passes_are_unbiased(bakes, monkeypatch):
    from wavlight.relight import view_frames

    tr = Transfer.load(bakes / "view.wlt")
    frames = ViewFrames(tr)
    one = frames.converge([1.0, 2.0, 3.0], [0.0, 0.3, 0.0], 40.0, 16, 12, spp=16, seed=1)
    monkeypatch.setattr(view_frames, "PASS_SPP", 3)
    passes = frames.converge([1.0, 2.0, 3.0], [0.0, 0.3, 0.0], 40.0, 16, 12, spp=16, seed=2)
    assert passes.stats["pass_spp"] == 3 and one.stats["pass_spp"] == 16
    _agree(passes, one, "view frame in passes")
    tr.close()


# ----------------------------------------------------------------------------- memory at large spp
GROWTH = r"""
import sys
from wavlight.cli.main import main
main(sys.argv[1:])
"""


def peak_memory(args, seconds: float, limit: int) -> tuple[int, bool]:
    """(the peak resident memory of ``wavlight ARGS`` in a child process, bytes; whether it
    finished) over at most ``seconds``; the child is stopped there, or once its peak passes
    ``limit`` bytes."""
    p = subprocess.Popen([sys.executable, "-c", GROWTH, *map(str, args)], stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    peak, start = 0, time.monotonic()
    try:
        while time.monotonic() - start < seconds and peak <= limit:
            pid, status, usage = os.wait4(p.pid, os.WNOHANG)
            if pid:
                p.returncode = os.waitstatus_to_exitcode(status)
                return max(peak, usage.ru_maxrss << 10), p.returncode == 0
            try:
                with open(f"/proc/{p.pid}/status") as fh:
                    peak = max(peak, next(int(ln.split()[1]) << 10 for ln in fh if ln.startswith("VmHWM")))
            except (OSError, StopIteration):
                pass
            time.sleep(0.05)
        return peak, False
    finally:
        if p.returncode is None:
            p.kill()
            p.wait()


@pytest.mark.slow
@pytest.mark.parametrize("bake, args", [
    ("view.wlt", ["--eye", "1", "2", "3", "--width", "64", "--height", "48"]),
    ("object.wlt", ["--translate", "0.3", "0.5", "0"]),
])
def test_unbiased_frames_at_huge_spp_stay_in_bounded_memory(bakes, tmp_path, bake, args):
    """The unbiased frames of view and object bakes at 65 536 spp hold no more memory than at 64
    spp, one pass (passes of at most 64 samples per pixel), where they grew by hundreds of MB a
    second; measured over their first 15 s (or the whole frame)."""
    out = ["-o", tmp_path / "f.exr"]
    small, finished = peak_memory(["frame", bakes / bake, *args, "--spp", 64, *out], 600.0, 8 << 30)
    assert finished
    big, _ = peak_memory(["frame", bakes / bake, *args, "--spp", 65536, *out], 15.0, small + (2 << 30))
    assert big - small < 256 << 20, f"{big >> 20} MiB at 65536 spp, {small >> 20} MiB at 64 spp"
