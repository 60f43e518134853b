"""The viewer's state: what a page may ask for (its URL's parameters and its messages) and how
a value that cannot be used is replaced, with a one-line note (:func:`sanitise`); the limits of
each kind of bake (:class:`Limits` of a lighting bake, :class:`ObjectLimits` of an object bake,
:class:`ViewLimits` of a view bake: each names the parameters of the factors its bake holds
fixed); the orbit of a view bake's camera (:func:`orbit_eye`, :func:`orbit_angles`), the range of
an object's translation (:func:`translate_range`) and the size of a preview (:func:`preview_terms`,
:func:`preview_size`); and a page's text message read within bounds (:func:`read_message`)."""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass

import numpy as np

from ..display import TONEMAP
from ..errors import described, shown
from .pictures import ENCODINGS

#: exposure slider, stops: the frame is multiplied by 2^exposure
EXPOSURE_RANGE = (-12.0, 12.0)
#: a state message is small: a larger one is answered with a one-line note and ignored (the
#: socket stays open)
MAX_MESSAGE_BYTES = 1 << 16
#: a message nested deeper than this (arrays and objects; a state is 2 deep) is answered with a note
#: and ignored, before it is parsed
MAX_MESSAGE_DEPTH = 16
#: an integer in a message with more digits than this is answered with a note and the message
#: ignored (fewer digits beyond the floats' range are clamped like any number out of range)
MAX_INTEGER_DIGITS = 1000
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


def preview_terms(terms: int) -> int:
    """The terms of a frame drawn while a slider is dragged: a quarter of K, at least 16 (never
    more than K)."""
    return min(terms, max(16, terms // 4))


@dataclass(frozen=True)
class Limits:
    """What a state may hold: the maps (index 0 the baked one), the largest K (every
    coefficient of the texels), the defaults."""

    maps: int
    max_terms: int
    rotate_y: float
    terms: int
    converge: bool = False
    #: the URL parameters of the factors this bake holds fixed, and why (a note when given)
    held = ("translate", *CAMERA_KEYS)
    why = "this bake varies the lighting (the objects and the camera stay where they are)"


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
    held = ("env", "terms", *CAMERA_KEYS, "show_background")
    why = "this bake varies an object (its lighting and the camera are fixed)"


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
    held = ("rotate_y", "env", "terms", "translate")
    why = "this bake varies the view (its lighting and objects are fixed)"


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


def _show_background(params, notes):
    """Whether the frame shows the map where the camera sees it: true unless given as JSON false
    or "0"/"false" (anything else: true, with a note)."""
    if "show_background" not in params:
        return True
    raw = params.get("show_background")
    if raw is False or raw in ("0", "false"):
        return False
    if raw is True or raw in ("1", "true"):
        return True
    notes.append(f"show_background={shown(raw, 40)} is not true or false: using true")
    return True


def _held_fixed(params, limits, notes):
    """A note for each parameter of the factors the bake of ``limits`` holds fixed (it is ignored)."""
    for key in limits.held:
        if key in params:
            notes.append(f"{key}={shown(params.get(key), 40)} does not apply: {limits.why}")


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
    _held_fixed(params, limits, notes)
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
    _held_fixed(params, limits, notes)
    encoding, preview, converge = _encoding_and_flags(params, limits.converge, notes)
    show_background = _show_background(params, notes)
    return ({"azimuth": az, "elevation": el, "distance": dist, "exposure": exposure, "tonemap": tonemap,
             "show_background": show_background, "encoding": encoding,
             "preview": preview, "converge": converge}, notes)


def sanitise(params, limits):
    """(state, notes): the viewer's state from URL parameters or a page's message (a mapping of
    strings or JSON values; other keys are ignored), every value usable, and one line per value
    that was replaced.

    rotate_y: degrees, wrapped into [0, 360), default the scene's; exposure: stops in
    EXPOSURE_RANGE (clamped), default 0; tonemap: one of TONEMAP's curves, else the default
    (clamp); terms: an integer in [1, max_terms] (clamped; a
    fraction is rounded), default the bake's; env: an index of the maps, else 0 (the baked
    map); show_background: whether the map is shown where the camera sees it (false only as JSON
    false or "0"/"false"), default true; encoding: one of ENCODINGS, else the first; preview and
    converge: booleans (true only as JSON true or "1"/"true"; converge only where the estimator
    exists). A value that is not a finite number becomes the default; ``translate`` (an object's
    place) and the camera's ``azimuth``, ``elevation`` and ``distance`` do not apply and get a note.

    With :class:`ObjectLimits` (a bake that varies one object): translate: "x,y,z" (or a list of
    three numbers), each clamped to its range, the object's own where it is not three finite
    numbers; rotate_y: the object's rotation about +Y, degrees, wrapped into [0, 360); exposure,
    encoding, preview and converge as above; ``env``, ``terms`` and ``show_background`` (the
    background is the bake's static image) do not apply and get a note.

    With :class:`ViewLimits` (a bake that varies the view): azimuth: degrees, wrapped into
    [0, 360); elevation: degrees, clamped to [-ELEVATION_LIMIT, ELEVATION_LIMIT]; distance:
    clamped to [distance_lo, distance_hi] (> 0), 4 significant digits; each default the scene
    camera's; exposure, show_background, encoding, preview and converge as above; ``rotate_y``,
    ``env``, ``terms`` and ``translate`` do not apply and get a note (as ``azimuth``, ``elevation``
    and ``distance`` do on the other bakes)."""
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
    show_background = _show_background(params, notes)
    _held_fixed(params, limits, notes)
    return ({"rotate_y": rot, "exposure": exposure, "tonemap": tonemap, "terms": terms, "env": env,
             "show_background": show_background, "encoding": encoding,
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
