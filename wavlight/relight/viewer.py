"""The interactive viewer of a bake file (``wavlight view PATH``): a page served on
127.0.0.1 with sliders for the rotation of the map, the exposure (logarithmic, in stops) and
the lighting terms K, a choice of tone curve and among the maps given, the frame rate the page
draws, and a "converge" control that refines the current lighting with the unbiased estimator.

    viewer = Viewer(wavlight.Transfer.load("bunny.wlt"), maps=["grace.hdr"])
    viewer.serve(port=0, ready=print)            # blocks; or start_background() / stop_background()

One aiohttp ``web.Application``: ``GET /`` is the page (viewer.html, everything inline, with
the state read from its URL, ``/?rotate_y=120&exposure=0.5&terms=256&env=1`` (``&tonemap=aces``
where the curve is not the default), sanitised and
written into it), ``GET /ws`` a websocket. The page sends the state as JSON; the server
answers with frames, one binary message each: a 4-byte little-endian length, a JSON header
(the state used, the terms kept, timings) and the picture, JPEG (Pillow) or raw RGBA
(``encoding=`` in the URL). A frame is the transfer's frame (:meth:`Transfer.frame_timed`)
times 2^exposure through the tone curve (``tonemap``: :data:`wavlight.display.CURVES`, the
curves of ``wavlight render --tonemap``), encoded to 8-bit sRGB in numpy (a lookup table of the
sRGB curve, :func:`wavlight.display.encode8_lut`).

Bad input: a URL or message value that is not a number, not finite or out
of range is replaced by its default or clamped (:func:`sanitise`; an integer beyond the floats'
range is clamped like any other) and the page shows the value used and a one-line note, as it
does for the keys it does not know; a message larger than :data:`MAX_MESSAGE_BYTES`, nested
deeper than :data:`MAX_MESSAGE_DEPTH` (both checked before it is parsed), not JSON, not an
object, of an unknown type, or binary gets a one-line error, and the socket stays open (none of
it is written to stderr). Only what the websocket protocol itself forbids closes the socket, with
the protocol's code: a message over :data:`MESSAGE_CLOSE_BYTES` (1009), text that is not UTF-8
(1007). A socket closed in the middle of a frame ends its tasks without a traceback; a request
whose Host or Origin is not this server (another site in the same browser) is refused.

Connections (:mod:`wavlight.relight.serving`). The viewer accepts connections itself: at the file
descriptor limit a new one is answered 503 and closed at once, with one log line per interval,
while the pages open keep their frames; idle, half-open and slowloris HTTP connections are cut
after ``serving.HTTP_IDLE_SECONDS``; a websocket is pinged every ``serving.WS_HEARTBEAT_SECONDS``
(closed without a pong) and closed (code ``serving.IDLE_CLOSE_CODE``, after a one-line note) when
its page sent nothing for ``serving.WS_IDLE_SECONDS``: the page then connects again when a
control moves. Log lines are one line each, each kind at most once per
``serving.LOG_INTERVAL_SECONDS``.

Frames. Each socket has its own task; the transfer's frames (not thread-safe) run in one worker
thread shared by all sockets, so that two browsers both get frames, in turn; a frame is tone
mapped, encoded and sent (another thread) while the next is computed. Only the newest state is
drawn: states that arrive while a frame is computed replace each other, and at most
:data:`WINDOW` frames are in flight before the page acknowledges one (a slow page is not sent a
backlog). While a slider is dragged the page may ask for a preview (``preview``: fewer terms,
:func:`preview_terms`), and for the full frame when it is released.

Converge. :func:`wavlight.relight.converge.converge` (where that module exists; else the button
is disabled) estimates the frame's true image without the K-term and texel approximations. The
control calls it repeatedly at the current lighting with seeds 0, 1, 2, ..., from 2 spp (a
standard error needs two samples) doubling while a call stays short, and streams the average
weighted by spp after each call (each call is unbiased and independent, so the average is, and
its standard error is sqrt(sum w_k^2 e_k^2) with w_k = spp_k / sum spp); a new exposure shows
the same average again. It stops as soon as the lighting (rotation, map) changes or the control
is released: the page releases it when the rotation, the map or K moves, and a call under way
ends at its next progress report. The calls of every page run in a converge thread of their own,
with the bake loaded again for it (and, for the default estimator of an object or a view bake,
its own moving object or view frames): a call takes seconds, and the other pages' frames do not
wait for it (nor its own page's frames once its lighting moved). A call runs on
:data:`CONVERGE_THREADS` threads (every core but one, where the estimator takes ``threads``).

A bake that varies one object (``vary = "object"``, :mod:`wavlight.relight.moving`). The page
offers that factor's controls instead of the lighting's: the object's translation (x, y, z
sliders over :func:`translate_range`, the scene's bounds widened by the object's bounding radius)
and its rotation about +Y in degrees (``rotate_y``: composed with the object's own rotation, whose
angle about +Y it starts from), with the exposure and the frame rate; the state is in the URL as
``/?translate=0.3,0,0.2&rotate_y=45&exposure=0.5``. A frame is the moving-object estimator
(:meth:`MovingObject.frame`, unbiased, seed 0) at :data:`OBJECT_FRAME_SPP` samples per pixel, or
:data:`OBJECT_PREVIEW_SPP` while a slider is dragged; converge calls the same estimator with seeds
0, 1, 2, ... and accumulates as above, and stops when the placement changes (a call under way
runs to its end: the estimator reports no progress). The parameters of
the factor a bake holds fixed (``env`` and ``terms`` on an object bake, ``translate`` on a lighting
bake) follow the rule of any bad value: they are replaced by the bake's own (ignored) with a
one-line note; a translation that is not three finite numbers becomes the object's own, a
component outside its range is clamped.

A bake that varies the view (``vary = "view"``, :mod:`wavlight.relight.view`). The page orbits
the camera about the scene camera's target: dragging on the picture turns it (azimuth about the
camera's up, elevation above the plane normal to it), the wheel or a slider sets the distance;
the state is in the URL as ``/?azimuth=30&elevation=15&distance=4.2&exposure=0.5`` and starts
from the scene's camera (:func:`orbit_angles` of its eye and target). The camera's eye is
:func:`orbit_eye` of the state, its target, up and field of view the scene's. The elevation is
kept within [-ELEVATION_LIMIT, ELEVATION_LIMIT] degrees (the view never along the up) and the
distance within the scene's distance times :data:`DISTANCE_FACTORS` (always > 0), both clamped
with a note. A frame is the approximate frame (:meth:`ViewFrames.frame`) at the bake's size, or
at :func:`preview_size` (at most :data:`VIEW_PREVIEW_PIXELS` pixels, its aspect kept) while the
camera is dragged; converge calls :meth:`ViewFrames.converge` (unbiased) at the bake's size with
seeds 0, 1, 2, ... and accumulates as above, and stops when the camera moves (a call under way
ends at its next progress report). ``rotate_y``, ``env``, ``terms`` and ``translate`` do not
apply to it and get a note, as do ``azimuth``, ``elevation`` and ``distance`` on the other bakes.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import inspect
import io
import json
import logging
import math
import os
import re
import signal
import struct
import threading
import time
from dataclasses import dataclass
from importlib import resources

import numpy as np
from aiohttp import WSCloseCode, WSMsgType, web

from ..display import TONEMAP, encode8_lut
from ..errors import WavlightError, described, shown
from ..scene import load_scene, rotation
from . import serving
from .settings import OBJECT_FRAME_SPP, VIEWER

try:   # the unbiased estimator of a relit frame, where this version has it
    from .converge import converge as _converge_function
except ImportError:
    _converge_function = None

#: the only address the viewer listens on
HOST = "127.0.0.1"
#: frame encodings a page may ask for (``encoding=`` in the URL); the first is the default
#: (benchmarks/viewer_fps.py measures both)
ENCODINGS = ("jpeg", "raw")
JPEG_QUALITY = 90
#: exposure slider, stops: the frame is multiplied by 2^exposure
EXPOSURE_RANGE = (-12.0, 12.0)
#: frames sent to a page and not yet acknowledged, at most
WINDOW = 2
#: how long a socket waits for an acknowledgement before it sends the next frame anyway
ACK_SECONDS = 1.0
#: a state message is small: a larger one is answered with a one-line note and ignored (the
#: socket stays open)
MAX_MESSAGE_BYTES = 1 << 16
#: a message larger than this closes the socket (the websocket protocol's code 1009, before it is
#: read whole): the most a page's socket buffers
MESSAGE_CLOSE_BYTES = 1 << 20
#: a message nested deeper than this (arrays and objects; a state is 2 deep) is answered with a note
#: and ignored, before it is parsed
MAX_MESSAGE_DEPTH = 16
#: an integer in a message with more digits than this is answered with a note and the message
#: ignored (fewer digits beyond the floats' range are clamped like any number out of range)
MAX_INTEGER_DIGITS = 1000
#: converge: the first call's spp (2: a standard error needs two samples), doubling while a call
#: takes less than half of CONVERGE_ROUND_SECONDS, up to CONVERGE_MAX_CALL_SPP; refinement ends at
#: CONVERGE_MAX_SPP samples in all
CONVERGE_FIRST_SPP = 2
CONVERGE_ROUND_SECONDS = 0.5
CONVERGE_MAX_CALL_SPP = 64
CONVERGE_MAX_SPP = 1 << 16
#: the threads of one converge call, where the estimator takes ``threads``: every core but one, which
#: the frame thread keeps (on two cores, a 128 x 128 bake: frames 2.4 ms in the median beside a call
#: on one thread, 5.1 ms beside the estimator's default of two per core, the call no slower)
CONVERGE_THREADS = max(1, (os.cpu_count() or 2) - 1)
#: a bake that varies an object: samples per pixel of its frame (OBJECT_FRAME_SPP, the frame's
#: default, :mod:`wavlight.relight.settings`), and of the frame drawn while a slider is dragged
OBJECT_PREVIEW_SPP = 1
#: a bake that varies the view: the camera's elevation stays within this many degrees of the
#: plane normal to its up; the distance within the scene camera's distance times these factors
ELEVATION_LIMIT = 89.0
DISTANCE_FACTORS = (1.0 / 20.0, 20.0)
#: a frame of a view bake drawn while the camera is dragged has at most this many pixels (the bake's
#: size scaled down, its aspect kept): on two cores, a ball on a floor (84k cache points, 32 x 32
#: texels) takes 0.04-0.1 s for the approximate frame at 181 x 181 (about 14 frames/s in the page)
#: against 0.2 s at 512 x 512 (about 5 frames/s)
VIEW_PREVIEW_PIXELS = 1 << 15
#: the URL parameters of a view bake's camera
CAMERA_KEYS = ("azimuth", "elevation", "distance")
#: the URL parameters of the factor each kind of bake holds fixed (its page has no control for them)
HELD_FIXED = {"lighting": ("translate", *CAMERA_KEYS), "object": ("env", "terms", *CAMERA_KEYS),
              "view": ("rotate_y", "env", "terms", "translate")}
_UNSET = object()
_log = logging.getLogger("wavlight.viewer")


# ----------------------------------------------------------------------------- pictures
def tone_map(image: np.ndarray, exposure: float = 0.0, alpha: bool = False,
             tonemap: str = TONEMAP.default) -> np.ndarray:
    """(H, W, 3) (or (H, W, 4) with ``alpha``: opaque) uint8 sRGB of the linear (H, W, 3) image
    times 2^exposure through the tone curve; NaN shows black and +Inf white
    (:func:`wavlight.display.encode8_lut`: within one 8-bit level of the written PNGs)."""
    return encode8_lut(image, exposure, tonemap, alpha)


def encode(image: np.ndarray, exposure: float, encoding: str, tonemap: str = TONEMAP.default) -> bytes:
    """The frame's picture as the page decodes it: JPEG (quality :data:`JPEG_QUALITY`) or raw
    RGBA rows (W x H x 4 bytes)."""
    if encoding == "raw":
        return tone_map(image, exposure, alpha=True, tonemap=tonemap).tobytes()
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(tone_map(image, exposure, tonemap=tonemap)).save(out, "JPEG", quality=JPEG_QUALITY)
    return out.getvalue()


def message(header: dict, payload: bytes = b"") -> bytes:
    """One binary frame message: uint32 LE length of the JSON header, the header, the payload."""
    text = json.dumps(header, separators=(",", ":")).encode()
    return struct.pack("<I", len(text)) + text + payload


def preview_terms(terms: int) -> int:
    """The terms of a frame drawn while a slider is dragged: a quarter of K, at least 16 (never
    more than K)."""
    return min(terms, max(16, terms // 4))


# ----------------------------------------------------------------------------- the state
@dataclass(frozen=True)
class Limits:
    """What a state may hold: the maps (index 0 the baked one), the largest K (every
    coefficient of the texels), the defaults."""

    maps: int
    max_terms: int
    rotate_y: float
    terms: int
    converge: bool = False


@dataclass(frozen=True)
class ObjectLimits:
    """What the state of a bake that varies one object may hold: the object's own translation
    (the default), the range of each component (lo, hi: (3,) tuples), the sliders' step, the
    default rotation about +Y (degrees) and whether converge exists."""

    translate: tuple
    lo: tuple
    hi: tuple
    step: float
    rotate_y: float
    converge: bool = False


@dataclass(frozen=True)
class ViewLimits:
    """What the state of a bake that varies the view may hold: the scene camera's azimuth,
    elevation (degrees) and distance (the defaults), the distance's range (lo > 0, hi) and whether
    converge exists."""

    azimuth: float
    elevation: float
    distance: float
    distance_lo: float
    distance_hi: float
    converge: bool = False


def orbit_basis(up):
    """(a, u, b) unit, orthonormal and right-handed (a = u x b): u the camera's ``up``, b the
    direction of +Z (or +X where +Z is along u) made normal to u; for u = +Y they are +X, +Y, +Z."""
    u = np.asarray(up, np.float64)
    u = u / np.linalg.norm(u)
    for ref in ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0)):
        b = np.asarray(ref) - np.dot(ref, u) * u
        if np.linalg.norm(b) > 1e-6:
            break
    b = b / np.linalg.norm(b)
    return np.cross(u, b), u, b


def orbit_eye(target, up, azimuth, elevation, distance) -> np.ndarray:
    """The eye at ``distance`` from ``target`` in the direction of azimuth and elevation (degrees)
    in :func:`orbit_basis`: target + distance (cos e sin a A + sin e U + cos e cos a B); for up = +Y,
    azimuth 0 is on +Z and 90 on +X."""
    a_ax, u_ax, b_ax = orbit_basis(up)
    az, el = math.radians(azimuth), math.radians(elevation)
    d = math.cos(el) * math.sin(az) * a_ax + math.sin(el) * u_ax + math.cos(el) * math.cos(az) * b_ax
    return np.asarray(target, np.float64) + float(distance) * d


def orbit_angles(eye, target, up):
    """(azimuth in [0, 360), elevation in [-90, 90], distance) of ``eye`` about ``target``: the
    inverse of :func:`orbit_eye`."""
    a_ax, u_ax, b_ax = orbit_basis(up)
    rel = np.asarray(eye, np.float64) - np.asarray(target, np.float64)
    distance = float(np.linalg.norm(rel))
    if distance == 0.0:
        return 0.0, 0.0, 0.0
    azimuth = math.degrees(math.atan2(float(rel @ a_ax), float(rel @ b_ax))) % 360.0
    elevation = math.degrees(math.asin(min(max(float(rel @ u_ax) / distance, -1.0), 1.0)))
    return azimuth, elevation, distance


def significant(x: float, digits: int = 4) -> float:
    """x rounded to ``digits`` significant digits (the page's Number(x.toPrecision(digits)))."""
    return float(f"{x:.{digits}g}")


def preview_size(width: int, height: int, pixels: int = VIEW_PREVIEW_PIXELS):
    """(w, h) of a view bake's frame drawn while the camera is dragged: width x height scaled by
    min(1, sqrt(pixels / (width height))), each side rounded and at least 1."""
    scale = min(1.0, math.sqrt(pixels / float(width * height)))
    return max(1, round(width * scale)), max(1, round(height * scale))


def translate_range(scene, obj, center, radius, default):
    """(lo (3,), hi (3,), step) of the translation sliders of ``obj`` in ``scene``: the translations
    T for which c + T (c = ``center``, the centre of its bounding sphere in its own frame, before
    any rotation) lies inside the bounds of the scene's geometry (the object at its own place)
    widened by the sphere's ``radius`` on every side, rounded outwards to a grid of ``step`` (a
    power of ten, about 1/200 of the widest span), and always holding the ``default`` translation."""
    used = scene.vertices[np.unique(scene.faces)].astype(np.float64)
    lo = used.min(0) - radius - np.asarray(center, np.float64)
    hi = used.max(0) + radius - np.asarray(center, np.float64)
    default = np.asarray(default, np.float64)
    lo, hi = np.minimum(lo, default), np.maximum(hi, default)
    span = float((hi - lo).max())
    step = 10.0 ** math.floor(math.log10(span / 200.0)) if span > 0 else 0.01
    lo, hi = np.floor(lo / step) * step, np.ceil(hi / step) * step
    digits = max(0, -math.floor(math.log10(step)))
    return tuple(round(float(x), digits) for x in lo), tuple(round(float(x), digits) for x in hi), step


def _number(key, raw, default, notes, period=None):
    """raw as a float, or ``default`` with a note where it is not a finite number. An integer
    beyond the floats' range (JSON has no limit) is +-inf, which the ranges clamp (the notes show
    it as given); with ``period`` (an angle's 360) it is reduced modulo the period first, exactly."""
    if isinstance(raw, bool) or raw is None:
        value = None
    elif isinstance(raw, int):
        if period is not None:
            raw = raw % period
        try:
            value = float(raw)
        except OverflowError:   # a finite number too large for a float: the end of every range
            return math.inf if raw > 0 else -math.inf
    elif isinstance(raw, float):
        value = raw
    elif isinstance(raw, str) and len(raw) <= 64:
        try:
            value = float(raw.strip())
        except ValueError:
            value = None
    else:
        value = None
    if value is None:
        notes.append(f"{key}={shown(raw, 40)} is not a number: using {default:g}")
        return float(default)
    if not math.isfinite(value):
        notes.append(f"{key}={shown(raw, 40)} is not finite: using {default:g}")
        return float(default)
    return value


def _clamped(key, value, lo, hi, notes, raw=None):
    """value clamped to [lo, hi], with a note (showing ``raw``, as given, where value is infinite:
    an integer beyond the floats' range)."""
    if value < lo or value > hi:
        used = min(max(value, lo), hi)
        text = f"{value:g}" if math.isfinite(value) else shown(raw, 40)
        notes.append(f"{key}={text} is outside [{lo:g}, {hi:g}]: using {used:g}")
        return used
    return value


def _angle(key, params, default, notes):
    """An angle in degrees wrapped into [0, 360) (3 decimals), ``default`` where absent."""
    if key not in params:
        return default
    return round(_number(key, params.get(key), default, notes, period=360) % 360.0, 3) % 360.0


def _exposure(params, notes):
    """The exposure in stops, clamped to EXPOSURE_RANGE (3 decimals), 0 where absent."""
    if "exposure" not in params:
        return 0.0
    raw = params.get("exposure")
    return round(_clamped("exposure", _number("exposure", raw, 0.0, notes), *EXPOSURE_RANGE, notes, raw), 3)


def _tonemap(params, notes):
    """The tone curve, one of TONEMAP's values, the default where absent or unknown (a note)."""
    raw = params.get("tonemap", TONEMAP.default)
    if raw in TONEMAP.values:
        return raw
    notes.append(f"tonemap={shown(raw, 40)} is not one of {', '.join(TONEMAP.values)}: using {TONEMAP.default}")
    return TONEMAP.default


def _held_fixed(params, kind, notes):
    """A note for each parameter of the factor a bake of ``kind`` holds fixed (it is ignored)."""
    why = {"lighting": "this bake varies the lighting (the objects and the camera stay where they are)",
           "object": "this bake varies an object (its lighting and the camera are fixed)",
           "view": "this bake varies the view (its lighting and objects are fixed)"}[kind]
    for key in HELD_FIXED[kind]:
        if key in params:
            notes.append(f"{key}={shown(params.get(key), 40)} does not apply: {why}")


def _encoding_and_flags(params, converge_exists, notes):
    get = params.get
    encoding = ENCODINGS[0]
    if "encoding" in params:
        if get("encoding") in ENCODINGS:
            encoding = get("encoding")
        else:
            notes.append(f"encoding={shown(get('encoding'), 40)} is not one of {', '.join(ENCODINGS)}: "
                         f"using {encoding}")

    def flag(key):
        raw = get(key, False)
        return raw is True or raw in ("1", "true")

    return encoding, flag("preview"), flag("converge") and converge_exists


def _translation(raw, limits: ObjectLimits, notes):
    """A translation from "x,y,z" or a list of three numbers, each component clamped to its range;
    the object's own where it is not three finite numbers."""
    default = list(limits.translate)

    def text(v):
        return ",".join(f"{x:g}" for x in v)
    if isinstance(raw, str) and len(raw) <= 200:
        parts = raw.split(",")
    elif isinstance(raw, (list, tuple)):
        parts = list(raw)
    else:
        parts = None
    if parts is None or len(parts) != 3:
        notes.append(f"translate={shown(raw, 40)} is not three numbers x,y,z: using {text(default)}")
        return default
    values = []
    for part in parts:
        quiet: list[str] = []
        values.append(_number("translate", part, 0.0, quiet))
        if quiet:
            why = "finite numbers" if "not finite" in quiet[0] else "numbers"
            notes.append(f"translate={shown(raw, 40)} is not three {why} x,y,z: using {text(default)}")
            return default
    used = [round(min(max(v, lo), hi), 4) for v, lo, hi in zip(values, limits.lo, limits.hi)]
    for axis, v, part, u, lo, hi in zip("xyz", values, parts, used, limits.lo, limits.hi):
        if v < lo or v > hi:
            text = f"{v:g}" if math.isfinite(v) else shown(part, 40)
            notes.append(f"translate {axis}={text} is outside [{lo:g}, {hi:g}]: using {u:g}")
    return used


def _sanitise_object(params, limits: ObjectLimits):
    notes: list[str] = []
    get = params.get
    translate = _translation(get("translate"), limits, notes) if "translate" in params else list(limits.translate)
    rot = _angle("rotate_y", params, limits.rotate_y, notes)
    exposure = _exposure(params, notes)
    tonemap = _tonemap(params, notes)
    _held_fixed(params, "object", notes)
    encoding, preview, converge = _encoding_and_flags(params, limits.converge, notes)
    return ({"translate": translate, "rotate_y": rot, "exposure": exposure, "tonemap": tonemap, "encoding": encoding,
             "preview": preview, "converge": converge}, notes)


def _sanitise_view(params, limits: ViewLimits):
    notes: list[str] = []
    get = params.get
    az = _angle("azimuth", params, limits.azimuth, notes)
    el = _number("elevation", get("elevation"), limits.elevation, notes) if "elevation" in params \
        else limits.elevation
    el = round(_clamped("elevation", el, -ELEVATION_LIMIT, ELEVATION_LIMIT, notes, get("elevation")), 3)
    dist = _number("distance", get("distance"), limits.distance, notes) if "distance" in params \
        else limits.distance
    dist = significant(_clamped("distance", dist, limits.distance_lo, limits.distance_hi, notes, get("distance")))
    exposure = _exposure(params, notes)
    tonemap = _tonemap(params, notes)
    _held_fixed(params, "view", notes)
    encoding, preview, converge = _encoding_and_flags(params, limits.converge, notes)
    return ({"azimuth": az, "elevation": el, "distance": dist, "exposure": exposure, "tonemap": tonemap,
             "encoding": encoding,
             "preview": preview, "converge": converge}, notes)


def sanitise(params, limits):
    """(state, notes): the viewer's state from URL parameters or a page's message (a mapping of
    strings or JSON values; other keys are ignored), every value usable, and one line per value
    that was replaced.

    rotate_y: degrees, wrapped into [0, 360), default the scene's; exposure: stops in
    EXPOSURE_RANGE (clamped), default 0; tonemap: one of TONEMAP's curves, else the default
    (clamp); terms: an integer in [1, max_terms] (clamped; a
    fraction is rounded), default the bake's; env: an index of the maps, else 0 (the baked
    map); encoding: one of ENCODINGS, else the first; preview and converge: booleans (true only
    as JSON true or "1"/"true"; converge only where the estimator exists). A value that is not a
    finite number becomes the default; ``translate`` (an object's place) and the camera's
    ``azimuth``, ``elevation`` and ``distance`` do not apply and get a note.

    With :class:`ObjectLimits` (a bake that varies one object): translate: "x,y,z" (or a list of
    three numbers), each clamped to its range, the object's own where it is not three finite
    numbers; rotate_y: the object's rotation about +Y, degrees, wrapped into [0, 360); exposure,
    encoding, preview and converge as above; ``env`` and ``terms`` do not apply and get a note.

    With :class:`ViewLimits` (a bake that varies the view): azimuth: degrees, wrapped into
    [0, 360); elevation: degrees, clamped to [-ELEVATION_LIMIT, ELEVATION_LIMIT]; distance:
    clamped to [distance_lo, distance_hi] (> 0), 4 significant digits; each default the scene
    camera's; exposure, encoding, preview and converge as above; ``rotate_y``, ``env``, ``terms``
    and ``translate`` do not apply and get a note (as ``azimuth``, ``elevation`` and ``distance``
    do on the other bakes)."""
    if isinstance(limits, ObjectLimits):
        return _sanitise_object(params, limits)
    if isinstance(limits, ViewLimits):
        return _sanitise_view(params, limits)
    notes: list[str] = []
    get = params.get
    rot = _angle("rotate_y", params, limits.rotate_y, notes)
    exposure = _exposure(params, notes)
    tonemap = _tonemap(params, notes)
    if "terms" in params:
        k = _number("terms", get("terms"), limits.terms, notes)
        if math.isfinite(k) and k != round(k):
            notes.append(f"terms={k:g} is not a whole number: using {round(k)}")
            k = float(round(k))
        terms = int(_clamped("terms", k, 1, limits.max_terms, notes, get("terms")))
    else:
        terms = limits.terms
    env = 0
    if "env" in params:
        e = _number("env", get("env"), 0, notes)
        if not math.isfinite(e) or e != round(e) or not 0 <= e < limits.maps:
            notes.append(f"env={shown(get('env'), 40)} is not one of the maps 0..{limits.maps - 1}: using 0")
        else:
            env = int(e)
    encoding, preview, converge = _encoding_and_flags(params, limits.converge, notes)
    _held_fixed(params, "lighting", notes)
    return ({"rotate_y": rot, "exposure": exposure, "tonemap": tonemap, "terms": terms, "env": env,
             "encoding": encoding,
             "preview": preview, "converge": converge}, notes)


_JSON_STRINGS = re.compile(r'"(?:[^"\\]|\\.)*"')
_NOT_BRACKETS = re.compile(r"[^\[\]{}]+")


def nesting_depth(text: str) -> int:
    """The deepest nesting of arrays and objects in JSON ``text`` (brackets inside strings not
    counted), in time linear in its length."""
    depth = most = 0
    for c in _NOT_BRACKETS.sub("", _JSON_STRINGS.sub("", text)):
        if c in "[{":
            depth += 1
            most = max(most, depth)
        else:
            depth -= 1
    return most


def _json_integer(digits: str) -> int:
    if len(digits) > MAX_INTEGER_DIGITS:
        raise ValueError(f"an integer of {len(digits)} digits (at most {MAX_INTEGER_DIGITS})")
    return int(digits)


def read_message(text: str):
    """(the message, None), or (None, a one-line note) for a page's text that is larger than
    :data:`MAX_MESSAGE_BYTES`, nested deeper than :data:`MAX_MESSAGE_DEPTH`, not JSON (an integer
    of more than :data:`MAX_INTEGER_DIGITS` digits included) or not a JSON object. The size and
    depth are checked before the text is parsed; NaN and Infinity are read (the state's values
    then get their note from :func:`sanitise`)."""
    size = len(text.encode("utf-8", "surrogatepass"))
    if size > MAX_MESSAGE_BYTES:
        return None, f"a message of {size} bytes (a state takes at most {MAX_MESSAGE_BYTES}): ignored"
    depth = 0 if text.count("[") + text.count("{") <= MAX_MESSAGE_DEPTH else nesting_depth(text)
    if depth > MAX_MESSAGE_DEPTH:
        return None, f"a message nested {depth} deep (a state at most {MAX_MESSAGE_DEPTH}): ignored"
    try:
        data = json.loads(text, parse_int=_json_integer)
    except (ValueError, RecursionError) as e:
        return None, f"a message that is not JSON ({described(e)}): ignored"
    if not isinstance(data, dict):
        return None, f"a message must be a JSON object, got {shown(data, 40)}: ignored"
    return data, None


class _Stopped(Exception):
    """A converge call ended early: the lighting changed."""


# ----------------------------------------------------------------------------- the server
def _axis_angle(matrix) -> list:
    """[axis x, y, z, degrees] of a 3 x 3 rotation matrix (the inverse of
    :func:`wavlight.scene.rotation`)."""
    m = np.asarray(matrix, np.float64)
    angle = math.acos(min(max((np.trace(m) - 1.0) / 2.0, -1.0), 1.0))
    if angle < 1e-12:
        return [0.0, 1.0, 0.0, 0.0]
    if math.pi - angle < 1e-6:   # a half turn: the axis from the symmetric part
        sym = (m + np.eye(3)) / 2.0
        i = int(np.argmax(np.diag(sym)))
        axis = sym[:, i] / math.sqrt(sym[i, i])
    else:
        axis = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]) / (2.0 * math.sin(angle))
    return [*(float(x) for x in axis), math.degrees(angle)]


class Viewer:
    """The viewer of one transfer under its baked map and the ``maps`` given (map files or
    Environments; index 0 is always the baked map). ``converge``: the unbiased estimator
    (default :func:`wavlight.relight.converge.converge` where it exists; None disables the
    control), called as converge(transfer, scene=, env=, rotate_y=, scale=, spp=, seed=) and
    returning (image, stderr) or a RenderResult; ``scene``: the baked scene for it (default:
    loaded once from the file the bake names).

    A bake that varies one object (``vary = "object"``) is shown through a
    :class:`wavlight.relight.moving.MovingObject` of the transfer and ``scene`` (a Scene or a scene
    file; default the file the bake names), made here (a scene that is not the baked one is a
    one-line WavlightError); ``maps`` must be empty (its lighting is fixed), and ``converge``
    (default the moving object's unbiased frame) is called as converge(translate=, rotate=, spp=,
    seed=).

    A bake that varies the view (``vary = "view"``) is shown through a
    :class:`wavlight.relight.view.ViewFrames` of the transfer and ``scene`` (the same rules);
    ``maps`` must be empty, and ``converge`` (default :meth:`ViewFrames.converge`) is called as
    converge(eye=, target=, fov=, width=, height=, spp=, seed=) and returns a RenderResult or
    (image, stderr). ``preview_pixels``: the most pixels of its frames while the camera is
    dragged (:func:`preview_size`). ``background``: what the camera samples that miss see in a
    lighting or view bake's frames and converged frames (default bilinear: the viewer's picture;
    the lighting is the map's texels either way; an object bake's background is its static image's)."""

    def __init__(self, transfer, maps=VIEWER["maps"].default, converge=_UNSET, scene=None,
                 preview_pixels: int = VIEW_PREVIEW_PIXELS, background: str = VIEWER["background"].default):
        self.transfer = transfer
        #: what the camera samples that miss see in a lighting bake's frames (VIEWER["background"])
        self.background = VIEWER["background"].check(background, "relight.Viewer")
        self.varies = transfer.header.get("vary", "lighting")
        self.mover = self.views = None
        self.preview_pixels = int(preview_pixels)
        self._maps = [("the baked map", None)]
        if self.varies in ("object", "view") and len(maps):
            what = "an object" if self.varies == "object" else "the view"
            raise WavlightError(f"{transfer.path}: this bake varies {what} (its lighting is fixed): "
                                "no other map applies")
        for m in maps:
            env = transfer.environment(m, 1.0)   # a one-line WavlightError for a bad file
            self._maps.append((os.path.basename(os.fspath(m)) if isinstance(m, (str, os.PathLike)) else env.name,
                               env))
        if self.varies == "object":
            from .moving import MovingObject

            self.mover = MovingObject(transfer, scene)
            default_converge = self.mover.frame
        elif self.varies == "view":
            from .view import ViewFrames

            self.views = ViewFrames(transfer, scene, background=self.background)
            default_converge = self.views.converge
        else:
            default_converge = _converge_function
        self.converge = default_converge if converge is _UNSET else converge
        self._default_converge = converge is _UNSET
        try:
            takes = inspect.signature(self.converge).parameters if self.converge is not None else {}
        except (TypeError, ValueError):
            takes = {}
        self._converge_progress, self._converge_threads = "progress" in takes, "threads" in takes
        self._converge_background = "background" in takes
        self._scene = scene
        side = 1 << transfer.n_levels
        if self.views is not None:
            self.limits = self._view_limits()
            self.state_keys = ("azimuth", "elevation", "distance", "exposure", "tonemap")
        elif self.mover is None:
            self.limits = Limits(maps=len(self._maps), max_terms=side * side,
                                 rotate_y=transfer.scene_rotate_y % 360.0,
                                 terms=min(transfer.terms, side * side), converge=self.converge is not None)
            self.state_keys = ("rotate_y", "exposure", "tonemap", "terms", "env")
        else:
            self.limits = self._object_limits()
            self.state_keys = ("translate", "rotate_y", "exposure", "tonemap")
        self._page = resources.files(__package__).joinpath("viewer.html").read_text(encoding="utf-8")
        self._pool = None       # the one thread that computes frames
        self._converge_pool = None   # the one thread that runs converge calls
        self._converging = None      # that thread's own bake (and moving object or view frames)
        self._listener = None
        self._sockets: set = set()
        self._tasks: set = set()
        self._runner = self._thread = self._loop = self._stopping = None
        self.port = None

    def _object_limits(self) -> ObjectLimits:
        """The translation's range (:func:`translate_range`) and the default rotation about +Y:
        the object's own angle where it turns about the Y axis (or not at all), else 0 (the
        slider's rotation is composed with its own)."""
        mover = self.mover
        obj = mover.object
        own = obj.rotate
        self._own_rotation = None
        if own is None:
            rot = 0.0
        elif abs(own[0]) < 1e-12 and abs(own[2]) < 1e-12:
            rot = float(own[3]) * (1.0 if own[1] > 0 else -1.0)
        else:
            rot, self._own_rotation = 0.0, rotation(list(own))
        default = [round(float(x), 4) for x in np.asarray(obj.translate, np.float64)]
        lo, hi, step = translate_range(mover.scene, obj, mover.center, mover.radius, default)
        return ObjectLimits(translate=tuple(default), lo=lo, hi=hi, step=step, rotate_y=round(rot % 360.0, 3) % 360.0,
                            converge=self.converge is not None)

    def _view_limits(self) -> ViewLimits:
        """The scene camera's orbit about its target (:func:`orbit_angles`; the elevation clamped to
        the limit) and the distance's range, :data:`DISTANCE_FACTORS` times its distance."""
        cam = self.views.scene.camera
        az, el, dist = orbit_angles(cam.eye, cam.target, cam.up)
        dist = significant(dist)
        lo, hi = (significant(dist * f) for f in DISTANCE_FACTORS)
        return ViewLimits(azimuth=round(az, 3) % 360.0,
                          elevation=round(min(max(el, -ELEVATION_LIMIT), ELEVATION_LIMIT), 3),
                          distance=dist, distance_lo=lo, distance_hi=hi, converge=self.converge is not None)

    def camera(self, state):
        """(eye (3,), target (3,), fov in degrees) of a state of a view bake: :func:`orbit_eye` of
        its azimuth, elevation and distance about the scene camera's target, with its up."""
        cam = self.views.scene.camera
        eye = orbit_eye(cam.target, cam.up, state["azimuth"], state["elevation"], state["distance"])
        return eye, np.asarray(cam.target, np.float64), float(cam.fov_y)

    def placement(self, state):
        """(translate (3,), rotate [axis, degrees]) of the object in a state of an object bake:
        the slider's rotation about +Y, after the object's own rotation where that is about
        another axis."""
        turn = [0.0, 1.0, 0.0, float(state["rotate_y"])]
        if self._own_rotation is not None:
            turn = _axis_angle(rotation(turn) @ self._own_rotation)
        return list(state["translate"]), turn

    # -- the application
    def application(self) -> web.Application:
        """The aiohttp application: ``/`` the page, ``/ws`` the websocket."""
        app = web.Application(middlewares=[self._watched, self._only_here], client_max_size=1 << 16)
        app.router.add_get("/", self._page_handler)
        app.router.add_get("/ws", self._socket_handler)
        app.on_shutdown.append(self._close_sockets)
        return app

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.port}/"

    @property
    def clients(self) -> int:
        """Open websockets."""
        return len(self._sockets)

    @property
    def running_tasks(self) -> int:
        """Tasks of open websockets still running (0 once every page has gone)."""
        return sum(not t.done() for t in self._tasks)

    def _hosts(self):
        return {f"{HOST}:{self.port}", f"localhost:{self.port}"}

    @web.middleware
    async def _watched(self, request, handler):
        """A request under way: its connection is not idle (:class:`serving.Listener`)."""
        listener, transport = self._listener, request.transport
        if listener is not None:
            listener.request_started(transport)
        try:
            return await handler(request)
        finally:
            if listener is not None:
                listener.request_ended(transport)

    @web.middleware
    async def _only_here(self, request, handler):
        """Requests for this server only: a page of another site (DNS rebinding, a websocket
        opened from elsewhere) is refused with one line."""
        if request.host not in self._hosts():
            return web.Response(status=403, text=f"refused: Host {shown(request.host, 60)} is not this viewer\n")
        origin = request.headers.get("Origin")
        if origin is not None and origin not in {f"http://{h}" for h in self._hosts()}:
            return web.Response(status=403, text=f"refused: Origin {shown(origin, 60)} is not this viewer\n")
        return await handler(request)

    def _config(self, state, notes) -> dict:
        t = self.transfer
        if self.views is not None:
            lim = self.limits
            pw, ph = preview_size(t.width, t.height, self.preview_pixels)
            return {"vary": "view", "state": state, "notes": notes,
                    "default_azimuth": lim.azimuth, "default_elevation": lim.elevation,
                    "default_distance": lim.distance, "distance_min": lim.distance_lo,
                    "distance_max": lim.distance_hi, "elevation_limit": ELEVATION_LIMIT,
                    "exposure_range": list(EXPOSURE_RANGE), "tonemaps": list(TONEMAP.values),
                    "encodings": list(ENCODINGS),
                    "width": t.width, "height": t.height, "preview_width": pw, "preview_height": ph,
                    "converge": self.converge is not None,
                    "converge_note": None if self.converge is not None else "no estimator given to this viewer",
                    "window": WINDOW}
        if self.mover is not None:
            lim = self.limits
            obj = self.mover.object
            return {"vary": "object", "state": state, "notes": notes,
                    "object": obj.name if obj.name else f"object {obj.index}",
                    "translate_min": list(lim.lo), "translate_max": list(lim.hi), "translate_step": lim.step,
                    "default_translate": list(lim.translate), "default_rotate_y": lim.rotate_y,
                    "exposure_range": list(EXPOSURE_RANGE), "tonemaps": list(TONEMAP.values),
                    "encodings": list(ENCODINGS),
                    "width": t.width, "height": t.height, "converge": self.converge is not None,
                    "converge_note": None if self.converge is not None else "no estimator given to this viewer",
                    "window": WINDOW, "frame_spp": OBJECT_FRAME_SPP, "preview_spp": OBJECT_PREVIEW_SPP}
        return {"vary": "lighting", "state": state, "notes": notes, "maps": [name for name, _ in self._maps],
                "max_terms": self.limits.max_terms, "default_terms": self.limits.terms,
                "exposure_range": list(EXPOSURE_RANGE), "tonemaps": list(TONEMAP.values),
                "encodings": list(ENCODINGS),
                "width": t.width, "height": t.height, "texels": f"{1 << t.n_levels}x{1 << t.n_levels}",
                "converge": self.converge is not None,
                "converge_note": None if self.converge is not None else
                "needs wavlight.relight.converge (the unbiased estimator), which this version does not have",
                "window": WINDOW, "preview_terms": preview_terms(self.limits.terms)}

    async def _page_handler(self, request):
        state, notes = sanitise(request.query, self.limits)
        config = json.dumps({**self._config(state, notes), "idle_close_code": serving.IDLE_CLOSE_CODE})
        for a, b in (("<", "\\u003c"), (">", "\\u003e"), ("&", "\\u0026")):   # inert inside <script>
            config = config.replace(a, b)
        host = request.host
        csp = (f"default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; "
               f"img-src 'self' blob: data:; connect-src 'self' ws://{host}")
        return web.Response(text=self._page.replace("__CONFIG__", config), content_type="text/html",
                            headers={"Cache-Control": "no-store", "Content-Security-Policy": csp})

    async def _socket_handler(self, request):
        ws = web.WebSocketResponse(heartbeat=serving.WS_HEARTBEAT_SECONDS, max_msg_size=MESSAGE_CLOSE_BYTES,
                                   compress=False)
        await ws.prepare(request)
        transport = request.transport
        if self._listener is not None:
            self._listener.upgraded(transport)
        client = _Client(self, ws, transport)
        self._sockets.add(ws)
        task = asyncio.ensure_future(client.frames())
        self._tasks.add(task)
        try:
            while True:
                left = client.last_heard + serving.WS_IDLE_SECONDS - time.monotonic()
                if left <= 0:
                    await client.close_idle()
                    break
                try:   # (not receive(timeout): the pongs of the heartbeat would restart it)
                    msg = await asyncio.wait_for(ws.receive(), left)
                except TimeoutError:
                    continue
                if msg.type == WSMsgType.TEXT:
                    await client.receive(msg.data)
                elif msg.type == WSMsgType.BINARY:
                    client.heard()
                    await client.error("a binary message: the viewer's messages are JSON text (ignored)")
                else:   # closed; ERROR: a message too large, text that is not UTF-8 (closed with the protocol's code)
                    break
        except ConnectionError:
            pass
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            self._tasks.discard(task)
            self._sockets.discard(ws)
            if not ws.closed:
                try:
                    await asyncio.wait_for(ws.close(), serving.WS_CLOSE_SECONDS)
                except (TimeoutError, ConnectionError, RuntimeError):
                    pass
            if self._listener is not None:   # a peer that reads nothing holds a closing socket: cut it
                self._listener.cut_later(transport)
        return ws

    async def _close_sockets(self, app):
        for ws in list(self._sockets):
            try:
                await ws.close(code=WSCloseCode.GOING_AWAY, message=b"the viewer stopped")
            except (ConnectionError, RuntimeError):
                pass

    # -- the work (a thread for frames, another for converge calls: each with objects of its own)
    async def run(self, fn, *args, **kwargs):
        """fn(*args, **kwargs) in the frame thread."""
        return await self._in(self._pool, fn, *args, **kwargs)

    async def run_converge(self, fn, *args, **kwargs):
        """fn(*args, **kwargs) in the converge thread."""
        return await self._in(self._converge_pool, fn, *args, **kwargs)

    @staticmethod
    async def _in(pool, fn, *args, **kwargs):
        loop = asyncio.get_running_loop()
        future = loop.run_in_executor(pool, lambda: fn(*args, **kwargs))
        # a result nobody waits for any more (its socket closed) must not be logged as lost
        future.add_done_callback(lambda f: f.cancelled() or f.exception())
        return await future

    def _env(self, index):
        return self._maps[index][1]

    def detail(self, state):
        """What a frame of the state is computed at: the terms (fewer for a preview) of a lighting
        bake, the samples per pixel of an object bake, the (width, height) of a view bake."""
        if self.views is not None:
            full = (self.transfer.width, self.transfer.height)
            return preview_size(*full, self.preview_pixels) if state["preview"] else full
        if self.mover is not None:
            return OBJECT_PREVIEW_SPP if state["preview"] else OBJECT_FRAME_SPP
        return preview_terms(state["terms"]) if state["preview"] else state["terms"]

    def frame_key(self, state, detail):
        """What a frame depends on besides the exposure, the tone curve and the encoding."""
        if self.views is not None:
            return (state["azimuth"], state["elevation"], state["distance"], detail)
        if self.mover is not None:
            return (tuple(state["translate"]), state["rotate_y"], detail)
        return (state["rotate_y"], state["env"], detail)

    def converge_key(self, state):
        """The factor the converged image is of: the lighting (rotation, map), the object's place or
        the camera."""
        if self.views is not None:
            return (state["azimuth"], state["elevation"], state["distance"])
        if self.mover is not None:
            return (tuple(state["translate"]), state["rotate_y"])
        return (state["rotate_y"], state["env"])

    def frame(self, state, detail):
        """(linear image, stats) of the state at ``detail`` (:meth:`detail`; in the frame thread)."""
        if self.views is not None:
            eye, target, fov = self.camera(state)
            width, height = detail
            t0 = time.perf_counter()
            result = self.views.frame(eye=eye, target=target, fov=fov, width=width, height=height)
            seconds = time.perf_counter() - t0
            image, stats = (result.image, result.stats) if hasattr(result, "image") else result
            return image, {"frame_seconds": (stats or {}).get("frame_seconds", seconds), "terms": None, "spp": None}
        if self.mover is not None:
            translate, rotate = self.placement(state)
            result = self.mover.frame(translate, rotate, spp=detail, seed=0)
            return result.image, {"frame_seconds": result.stats["render_seconds"], "terms": None, "spp": detail,
                                  "object_pixels": result.stats.get("object_pixels")}
        return self.transfer.frame_timed(self._env(state["env"]), state["rotate_y"], 1.0, detail,
                                         background=self.background)

    def converge_call(self, state, spp, seed, stop=None):
        """(image, stderr) of one call of the estimator at the state's lighting (or the object's
        place, or the camera at the bake's size; in the converge thread, with its own objects:
        :meth:`_converge_side`); ``stop`` (a threading.Event) set ends the call early where the
        estimator reports its progress (then :class:`_Stopped`)."""
        kwargs = {"threads": CONVERGE_THREADS} if self._converge_threads else {}
        if stop is not None and self._converge_progress:
            def progress(*args):
                if stop.is_set():
                    raise _Stopped()
            kwargs["progress"] = progress
        side = self._converge_side()
        if self.views is not None:
            eye, target, fov = self.camera(state)
            result = side.converge(eye=eye, target=target, fov=fov, width=self.transfer.width,
                                   height=self.transfer.height, spp=spp, seed=seed, **kwargs)
        elif self.mover is not None:
            translate, rotate = self.placement(state)
            result = side.converge(translate=translate, rotate=rotate, spp=spp, seed=seed, **kwargs)
        else:
            if self._converge_background:
                kwargs["background"] = self.background
            result = side.converge(side.transfer, scene=self._scene_for_converge(), env=self._env(state["env"]),
                                   rotate_y=state["rotate_y"], scale=1.0, spp=spp, seed=seed, **kwargs)
        if hasattr(result, "image"):   # a RenderResult
            return result.image, result.stderr
        return result

    def _converge_side(self):
        """The converge thread's objects, made on its first call: a copy of the bake (its own
        maps' projectors; the sections shared, read-only: :meth:`Transfer.copy`), and for the
        default estimator of an object or a view bake its own MovingObject or ViewFrames (their
        caches and kernels are the frame thread's otherwise):
        the two threads share only read-only arrays, so a converge call never waits for a frame
        nor a frame for it. (transfer, converge): the estimator to call."""
        if self._converging is None:
            transfer = self.transfer.copy()
            converge = self.converge
            if self._default_converge and self.mover is not None:
                from .moving import MovingObject

                converge = MovingObject(transfer, self.mover.scene).frame
            elif self._default_converge and self.views is not None:
                from .view import ViewFrames

                converge = ViewFrames(transfer, self.views.scene, background=self.background).converge
            self._converging = _ConvergeSide(transfer, converge)
        return self._converging

    def _scene_for_converge(self):
        """The scene of the bake, loaded once (the estimator checks that it is the one baked);
        None where the bake names no scene file that exists (the estimator then says why)."""
        if self._scene is None:
            path = (self.transfer.scene or {}).get("path")
            if path and os.path.isfile(path):
                self._scene = load_scene(path)
        return self._scene

    # -- serving
    async def start(self, port: int = VIEWER["port"].default) -> str:
        """Listen on 127.0.0.1:port (0: a free port); the URL. A port in use: a one-line
        WavlightError."""
        serving.one_line_logs("aiohttp.server", "aiohttp.web", "aiohttp.access", "aiohttp.websocket",
                              "wavlight.viewer")
        self._pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="wavlight-frame")
        self._converge_pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="wavlight-converge")
        self._runner = web.AppRunner(self.application(), access_log=None, handle_signals=False, shutdown_timeout=2.0)
        await self._runner.setup()
        self._listener = serving.Listener(self._runner.server)
        try:
            self.port = await self._listener.start(HOST, port)
        except OSError as e:
            self._listener = None
            await self.stop()
            why = os.strerror(e.errno).lower() if e.errno else described(e)
            raise WavlightError(f"{HOST}:{port}: cannot listen ({why})") from None
        return self.url

    async def stop(self):
        """Stop listening, close the pages' sockets, end the frame and converge threads."""
        if self._listener is not None:
            listener, self._listener = self._listener, None
            await listener.close()
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
        pools = [p for p in (self._pool, self._converge_pool) if p is not None]
        self._pool = self._converge_pool = None
        for pool in pools:
            await asyncio.get_running_loop().run_in_executor(None, lambda p=pool: p.shutdown(wait=True,
                                                                                             cancel_futures=True))
        if self._converging is not None:
            side, self._converging = self._converging, None
            side.transfer.close()

    def serve(self, port: int = VIEWER["port"].default, ready=None) -> None:
        """Serve until SIGINT or SIGTERM; ``ready(url)`` once listening."""
        async def main():
            stop = asyncio.Event()
            loop = asyncio.get_running_loop()
            for sig in (signal.SIGINT, signal.SIGTERM):
                try:
                    loop.add_signal_handler(sig, stop.set)
                except (NotImplementedError, RuntimeError, ValueError):
                    pass
            serving.one_line_logs("asyncio")
            url = await self.start(port)
            try:
                if ready is not None:
                    ready(url)
                await stop.wait()
            finally:
                await self.stop()

        asyncio.run(main())

    def start_background(self, port: int = VIEWER["port"].default, timeout: float = 30.0) -> str:
        """Serve from a thread of its own (tests, benchmarks); the URL. Stop with
        :meth:`stop_background`."""
        started = concurrent.futures.Future()

        def main():
            async def body():
                self._stopping = asyncio.Event()
                try:
                    url = await self.start(port)
                except BaseException as e:
                    started.set_exception(e)
                    return
                started.set_result(url)
                try:
                    await self._stopping.wait()
                finally:
                    await self.stop()

            self._loop = asyncio.new_event_loop()
            try:
                self._loop.run_until_complete(body())
            finally:
                self._loop.close()

        self._thread = threading.Thread(target=main, name="wavlight-viewer", daemon=True)
        self._thread.start()
        return started.result(timeout)

    def stop_background(self, timeout: float = 30.0) -> None:
        """Stop the server of :meth:`start_background` and wait for its thread."""
        if self._thread is None:
            return
        if self._loop is not None and not self._loop.is_closed() and self._stopping is not None:
            try:
                self._loop.call_soon_threadsafe(self._stopping.set)
            except RuntimeError:   # the loop already closed
                pass
        self._thread.join(timeout)
        self._thread = None


@dataclass
class _ConvergeSide:
    """The converge thread's own bake and estimator (:meth:`Viewer._converge_side`)."""

    transfer: object
    converge: object


class _Client:
    """One websocket: the newest state it asked for, and the task that answers it with frames."""

    def __init__(self, viewer: Viewer, ws, transport=None):
        self.viewer, self.ws, self.transport = viewer, ws, transport
        self.state = None
        self.wake = asyncio.Event()
        self.acked = asyncio.Event()
        self.sent = self.drawn = 0
        self.shown = None           # (key, exposure, tonemap, encoding) of the last frame sent
        self.sending = None         # the task encoding and sending the last frame
        self.linear = self.stats = None
        self.last_heard = time.monotonic()

    # -- from the page
    def heard(self):
        """A message came from the page: not idle."""
        self.last_heard = time.monotonic()

    async def receive(self, text: str):
        """Answer a text message: a state (notes for the values replaced and the keys unknown),
        an acknowledgement, or a one-line error for anything else; never raises."""
        self.heard()
        try:
            await self._receive(text)
        except Exception as e:   # a fault here, not bad input: one (rate-limited) line, the socket kept
            _log.error("a message failed: %s", described(e))
            await self.error(f"a message failed: {described(e)}")

    async def _receive(self, text: str):
        data, why = read_message(text)
        if why is not None:
            return await self.error(why)
        kind = data.get("type", "state")
        if kind == "drawn":
            seq = data.get("seq")
            unknown = [k for k in data if k not in ("type", "seq")]
            if not isinstance(seq, int) or isinstance(seq, bool):
                return await self.error(f"an acknowledgement's seq={shown(seq, 40)} is not an integer: ignored")
            if unknown:
                await self.error(f"unknown keys of an acknowledgement ignored: {shown(unknown, 60)}")
            if self.drawn < seq <= self.sent:   # (an older frame's, or one never sent: ignored)
                self.drawn = seq
                self.acked.set()
            return None
        if kind != "state":
            return await self.error(f"unknown message type {shown(kind, 40)} (state or drawn): ignored")
        state, notes = sanitise(data, self.viewer.limits)
        known = {"type", *state, *HELD_FIXED[self.viewer.varies]}
        unknown = [k for k in data if k not in known]
        if unknown:
            notes.append(f"unknown keys ignored: {shown(unknown, 60)}")
        if notes:   # before the frame: the page shows the values used
            await self.send_text({"type": "state", "state": state, "notes": notes})
        self.state = state
        self.wake.set()
        return None

    async def close_idle(self):
        """Close the socket of a page that sent no message for WS_IDLE_SECONDS: a one-line note,
        then code IDLE_CLOSE_CODE; a peer that does not complete the closing within
        WS_CLOSE_SECONDS (one that reads nothing) is cut."""
        note = (f"no message from this page for {serving.WS_IDLE_SECONDS:g} s: the viewer closed its socket "
                "(moving a control connects again)")

        async def close():
            await self.error(note)
            await self.ws.close(code=serving.IDLE_CLOSE_CODE, message=b"idle")
        try:
            await asyncio.wait_for(close(), serving.WS_CLOSE_SECONDS)
        except TimeoutError:
            if self.transport is not None:
                self.transport.abort()
        except (ConnectionError, RuntimeError):
            pass

    async def error(self, text: str):
        await self.send_text({"type": "error", "message": text})

    async def send_text(self, data: dict):
        try:
            await self.ws.send_str(json.dumps(data))
        except (ConnectionError, RuntimeError):
            pass

    # -- to the page
    async def _window(self):
        """Wait while WINDOW frames are unacknowledged (at most ACK_SECONDS)."""
        deadline = time.monotonic() + ACK_SECONDS
        while self.sent - self.drawn >= WINDOW:
            self.acked.clear()
            left = deadline - time.monotonic()
            if left <= 0:
                return
            try:
                await asyncio.wait_for(self.acked.wait(), left)
            except TimeoutError:
                return

    async def send_frame(self, image, state, stats, converge=None, seq=None):
        """Tone map, encode (a worker thread of the loop's default pool) and send; False when
        the socket has closed. ``seq``: the number already given to the frame (else the next)."""
        if seq is None:
            self.sent += 1
            seq = self.sent
        loop = asyncio.get_running_loop()
        t0 = time.perf_counter()
        payload = await loop.run_in_executor(None, encode, image, state["exposure"], state["encoding"],
                                             state["tonemap"])
        h, w = image.shape[:2]
        header = {"type": "frame", "seq": seq, "width": w, "height": h, "encoding": state["encoding"],
                  "state": {k: state[k] for k in self.viewer.state_keys},
                  "terms_used": stats.get("terms"), "spp": stats.get("spp"), "preview": bool(stats.get("preview")),
                  "frame_ms": round(1e3 * stats.get("frame_seconds", 0.0), 2),
                  "encode_ms": round(1e3 * (time.perf_counter() - t0), 2), "bytes": len(payload),
                  "converge": converge}
        try:
            await self.ws.send_bytes(message(header, payload))
        except (ConnectionError, RuntimeError):
            return False
        return not self.ws.closed

    async def _flush(self) -> bool:
        """Wait for the frame being encoded and sent; False when the socket has closed."""
        task, self.sending = self.sending, None
        return True if task is None else await task

    async def frames(self):
        """Answer the newest state with a frame, until the socket closes (then cancelled). A
        frame that fails is one line to the page (and to stderr if it is not a WavlightError)."""
        try:
            while not self.ws.closed:
                await self.wake.wait()
                self.wake.clear()
                await self._window()
                if self.state is None:
                    continue
                try:
                    if not await self._answer(self.state):
                        return
                except WavlightError as e:
                    await self.error(described(e))
                except Exception as e:   # never a traceback
                    _log.error("frame failed: %s", described(e))
                    await self.error(f"frame failed: {described(e)}")
        except asyncio.CancelledError:
            pass
        finally:
            if self.sending is not None and not self.sending.done():
                self.sending.cancel()

    async def _answer(self, state) -> bool:
        """The frame of one state (or the converge rounds); False once the socket has closed."""
        if state["converge"] and self.viewer.converge is not None:
            self.shown = None
            return await self._flush() and await self._converge(state)
        detail = self.viewer.detail(state)
        key = self.viewer.frame_key(state, detail)
        if self.shown == (key, state["exposure"], state["tonemap"], state["encoding"]):
            return True
        if self.shown is None or self.shown[0] != key:
            self.shown = None
            linear, stats = await self.viewer.run(self.viewer.frame, state, detail)
            self.linear, self.stats = linear, dict(stats, preview=state["preview"])
        # the frame is encoded and sent while the next one is computed (in order: one at a time)
        if not await self._flush():
            return False
        self.sent += 1
        self.sending = asyncio.ensure_future(self.send_frame(self.linear, state, self.stats, seq=self.sent))
        self.shown = (key, state["exposure"], state["tonemap"], state["encoding"])
        return True

    async def _converge(self, state):
        """Refine the state's lighting (or the object's place) with repeated calls of the
        estimator, streaming the spp-weighted average after each; return when that factor or the
        control changes (True), or the socket closed (False)."""
        lighting = self.viewer.converge_key(state)
        total, rounds, spp = 0, 0, CONVERGE_FIRST_SPP
        acc = var = report = None
        job = waiter = None
        stop = threading.Event()

        def same(s):
            return s["converge"] and self.viewer.converge_key(s) == lighting

        try:
            while True:
                job = None
                if total < CONVERGE_MAX_SPP:
                    t0 = time.perf_counter()
                    job = asyncio.ensure_future(self.viewer.run_converge(self.viewer.converge_call, state, spp, rounds,
                                                                         stop))
                while job is None or not job.done():   # (no job: converged; answer exposure changes)
                    waiter = asyncio.ensure_future(self.wake.wait())
                    await asyncio.wait({waiter} if job is None else {job, waiter},
                                       return_when=asyncio.FIRST_COMPLETED)
                    if not waiter.done():
                        waiter.cancel()
                        continue
                    self.wake.clear()
                    if not same(self.state):          # the lighting changed: the call's result is dropped
                        self.wake.set()
                        return True
                    state = self.state                   # the exposure (tone curve, encoding) changed: the mean again
                    if acc is not None:
                        await self._window()
                        if not await self.send_frame((acc / total).astype(np.float32), state,
                                                     {"frame_seconds": 0.0, "terms": None}, report):
                            return False
                try:
                    image, stderr = job.result()
                except Exception as e:   # the estimator failed: one line, and the control is released
                    if not isinstance(e, WavlightError):
                        _log.error("converge failed: %s", described(e))
                    await self.send_text({"type": "converge", "stopped": True, "message": described(e)})
                    await self._wait_for_change(lighting)
                    return True
                seconds = time.perf_counter() - t0
                image = np.asarray(image, np.float64)
                stderr = np.asarray(stderr, np.float64)
                if acc is None:
                    acc, var = image * spp, (stderr * spp) ** 2
                else:
                    acc += image * spp
                    var += (stderr * spp) ** 2
                total += spp
                rounds += 1
                mean = acc / total
                level = float(np.mean(mean))
                report = {"spp": total, "rounds": rounds, "call_spp": spp, "call_seconds": round(seconds, 3),
                          "relative_stderr": round(float(np.sqrt(var).mean() / total / level), 6)
                          if level > 0 else None, "done": total >= CONVERGE_MAX_SPP}
                await self._window()
                if not await self.send_frame(mean.astype(np.float32), state,
                                             {"frame_seconds": seconds, "terms": None}, report):
                    return False
                if seconds < CONVERGE_ROUND_SECONDS / 2 and spp < CONVERGE_MAX_CALL_SPP:
                    spp *= 2
        finally:
            stop.set()            # a call still running ends at its next progress report
            for t in (job, waiter):
                if t is not None and not t.done():
                    t.cancel()
                elif t is not None and not t.cancelled():
                    t.exception()     # a result dropped: not "never retrieved"

    async def _wait_for_change(self, lighting):
        while True:
            await self.wake.wait()
            self.wake.clear()
            s = self.state
            if not s["converge"] or self.viewer.converge_key(s) != lighting:
                self.wake.set()
                return
