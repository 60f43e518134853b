"""The factor a bake varies, as a type: the frames of a lighting bake (:class:`LightingFrames`:
the map, its rotation and scale change, Chen & Gao sec. 2 eq. 8 for the relit frame and eq. 12 for
the unbiased one), of an object bake (:class:`ObjectFrames`: one object's place changes, the
moving-object estimator of :mod:`.moving`) and of a view bake (:class:`CameraFrames`: the camera
changes, :class:`wavlight.relight.view_frames.ViewFrames`). :func:`frames_for` chooses the type once, from
the bake file's ``vary``; the command line's ``frame`` and the viewer then speak to one interface:

    frames = frames_for(transfer, scene)          # LightingFrames, ObjectFrames or CameraFrames
    state = frames.state_from(settings)           # `wavlight frame`'s flags (the others' refused)
    image, stats = frames.frame(state)            # the bake's frame of that state
    result = frames.converge(state, spp, seed)    # the unbiased frame (a RenderResult)
    for image, stats in frames.sequence(frames.turn(state, 36)): ...   # a turntable, an orbit

What each type holds: ``factor`` (the bake's ``vary``), ``flags`` (the keys of `wavlight frame`'s
flags that set its factor; the other factors' flags are refused on its bakes, :meth:`Frames.held`),
``fixed`` (what the bake holds fixed, for notes and errors), ``sequence_flag`` (the flag of a
sequence of frames: ``turntable``, ``orbit``; an object's turn about +Y has none on the command
line). A state is a dict of the factor's values in the library's terms (a lighting: ``env``,
``rotate_y``, ``scale``, ``terms``, ``priority``; an object: ``translate``, ``rotate``; a camera:
``eye``, ``target``, ``fov``, ``width``, ``height`` and the approximate frame's settings). What
camera samples that miss see (``background``, :data:`wavlight.options.BACKGROUND`: the map's
nearest texel, its bilinear filter or none; the lighting is the map's texels either way) is a
lighting or a view bake's Frames' own, given to :func:`frames_for`; a state's ``background`` (the
viewer's hidden background: ``none``) replaces it for that frame.

The viewer's side (:mod:`.viewer`): :meth:`Frames.limits` (what a page may ask for, a
:mod:`.viewstate` limits type), :meth:`Frames.page_config` (the page's controls), a page's state
as the factor's state (:meth:`Frames.from_page`) at a ``detail`` (:meth:`Frames.detail`: the terms, the
spp or the size of a frame, smaller while a control is held), :meth:`Frames.key` (the factor's
value: passes of converge accumulate while it stays), and :meth:`Frames.estimate` (a given estimator,
or the type's own unbiased frame, called with the factor's arguments). :meth:`Frames.for_converge`
makes a Frames of its own for the viewer's converge thread (a copy of the bake: the two threads
share only read-only arrays), :meth:`Frames.prepare` makes what its first pass would regardless
of the state, :meth:`Frames.warm` what the passes of one state share (a lighting's tables and
product trees) before the first is asked for.
"""
from __future__ import annotations

import math
import os
import time

import numpy as np

from ..errors import WavlightError
from ..scene import MAX_COORDINATE, rotation
from .settings import FRAME, OBJECT_FRAME_SPP
from .viewstate import (DISTANCE_FACTORS, ELEVATION_LIMIT, VIEW_PREVIEW_PIXELS, Limits, ObjectLimits, ViewLimits,
                        orbit_angles, orbit_eye, preview_size, preview_terms, significant, translate_range)

#: `wavlight frame`'s flags of each factor (the keys of relight.settings.FRAME)
LIGHTING_FLAGS = ("env", "rotate_y", "scale", "terms", "priority", "turntable")
OBJECT_FLAGS = ("translate", "rotate")
VIEW_FLAGS = ("eye", "target", "fov", "width", "height", "orbit", "refine", "mass", "mode", "supersample", "tau")
#: the flag of what camera samples that miss see: a lighting or a view bake's (an object bake's
#: background is its static image's, rendered at the bake)
BACKGROUND_FLAGS = ("background",)
#: the approximate frame's settings of a view bake (view.still_settings)
APPROXIMATE = ("refine", "mass", "mode", "supersample", "tau")
#: a bake that varies an object: samples per pixel of the frame drawn while a slider is held
OBJECT_PREVIEW_SPP = 1


def axis_angle(matrix) -> list:
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


def _given(settings, keys) -> dict:
    return {k: settings[k] for k in keys if settings.get(k) is not None}


class Frames:
    """The frames of a bake that varies one factor (module docstring); a subclass per factor."""

    factor = ""
    flags: tuple = ()
    fixed = ""
    sequence_flag = None
    #: whether every frame is unbiased (an object bake's), not only those of :meth:`converge`
    unbiased = False
    #: the page's state keys of the factor's value (a converged image is of one), and those a
    #: frame's header shows (beside the exposure and the tone curve)
    page_keys: tuple = ()
    shown_keys: tuple = ()

    def __init__(self, transfer, scene=None, background: str = FRAME["background"].default):
        self.transfer = transfer
        self.given_scene = scene
        #: what camera samples that miss see (FRAME["background"]; an object bake's is its image's)
        self.background = FRAME["background"].check(background, "relight.frames")

    # -- `wavlight frame`
    @classmethod
    def refuse_held(cls, path, settings) -> None:
        """A WavlightError (one line) for a flag of a factor the bake at ``path`` holds fixed."""
        for key in LIGHTING_FLAGS + OBJECT_FLAGS + VIEW_FLAGS + BACKGROUND_FLAGS:
            if key not in cls.flags and settings.get(key) is not None:
                raise WavlightError(f"{path}: this bake varies {cls.fixed}; {FRAME[key].flag} does not apply "
                                    f"(bake with --vary {_FACTOR_OF_FLAG[key]})")

    def state_from(self, settings) -> dict:
        """The factor's state from `wavlight frame`'s settings (None: the bake's own)."""
        raise NotImplementedError

    def inputs(self) -> list:
        """The files a frame reads (an output may not be one of them)."""
        return []

    def frame(self, state, detail=None):
        """(linear image (H, W, 3) float32, stats with ``frame_seconds``) of the state."""
        raise NotImplementedError

    def converge(self, state, spp: int, seed: int = 0, progress=None, threads=None):
        """The unbiased frame of the state (a RenderResult: image, stderr, stats)."""
        return self.estimate(None, state, spp, seed, progress=progress, threads=threads)

    def turn(self, state, count: int) -> list:
        """``count`` states of a full turn about +Y from ``state`` (a turntable, an orbit)."""
        raise NotImplementedError

    def sequence(self, states, detail=None):
        """The frames of ``states`` in turn: (image, stats) each, ``frame_seconds`` the wall time of
        each :meth:`frame`."""
        for state in states:
            t0 = time.perf_counter()
            image, stats = self.frame(state, detail)
            yield image, dict(stats, frame_seconds=time.perf_counter() - t0)

    def report(self, state, stats) -> dict:
        """The factor's fields of `wavlight frame --json` for a frame of ``state``."""
        return {}

    # -- the viewer
    def limits(self, converge: bool):
        raise NotImplementedError

    def page_config(self, limits, preview_pixels: int = VIEW_PREVIEW_PIXELS) -> dict:
        """The page's controls of the factor (its part of the page's config)."""
        raise NotImplementedError

    def detail(self, page, preview_pixels: int = VIEW_PREVIEW_PIXELS):
        """What a frame of the page's state is computed at (smaller while a control is held)."""
        return None

    def key(self, page) -> tuple:
        """The factor's value in a page's state: a converged image is of one key."""
        return tuple(tuple(page[k]) if isinstance(page[k], list) else page[k] for k in self.page_keys)

    def from_page(self, page, detail=None) -> dict:
        """The factor's state of a page's (sanitised) state."""
        raise NotImplementedError

    def estimator(self):
        """The type's own unbiased estimator, called with :meth:`arguments`."""
        raise NotImplementedError

    def arguments(self, state) -> dict:
        """The keyword arguments of the factor's estimator for ``state``."""
        raise NotImplementedError

    def estimate(self, estimator, state, spp: int, seed: int, **kwargs):
        """``estimator`` (None: the type's own) of ``state`` with ``spp`` and ``seed`` (and the
        ``progress`` and ``threads`` given, where not None)."""
        fn = self.estimator() if estimator is None else estimator
        extra = {k: v for k, v in kwargs.items() if v is not None}
        return fn(**self.arguments(state), spp=spp, seed=seed, **extra)

    def for_converge(self):
        """A Frames of the same factor on a copy of the bake (the converge thread's)."""
        return type(self)(self.transfer.copy(), self.scene_for_converge(), background=self.background)

    def scene_for_converge(self):
        return self.given_scene

    def prepare(self) -> None:
        """Make what the first unbiased frame makes regardless of the state."""

    def warm(self, state, stop=None) -> None:
        """Make what the unbiased frames of ``state`` share before the first is asked for (a
        lighting's tables and product trees), until ``stop()`` is true; nothing by default."""

    def close(self) -> None:
        """Release what the frames keep (device memory)."""


class LightingFrames(Frames):
    """A lighting bake: the map (the baked one or ``maps``), its rotation about +Y, its scale and
    the terms K change; the objects and the camera stay. The relit frame is
    :meth:`Transfer.frame_timed` (eq. 8), the unbiased one a
    :class:`~wavlight.relight.converge.ConvergeFrames`'s (eq. 12; kept: a second frame under the
    same lighting pays only for its passes)."""

    factor = "lighting"
    flags = LIGHTING_FLAGS + BACKGROUND_FLAGS
    fixed = "the lighting (its objects and camera are fixed)"
    sequence_flag = "turntable"
    page_keys = ("rotate_y", "env")
    shown_keys = ("rotate_y", "terms", "env")

    def __init__(self, transfer, scene=None, maps=(), background: str = FRAME["background"].default):
        super().__init__(transfer, scene, background)
        self.maps = [("the baked map", None)]
        for m in maps:
            env = transfer.environment(m, 1.0)   # a one-line WavlightError for a bad file
            self.maps.append((os.path.basename(os.fspath(m)) if isinstance(m, (str, os.PathLike)) else env.name, env))
        self._frames = None   # the ConvergeFrames, made on the first unbiased frame

    def state_from(self, settings) -> dict:
        rotate_y, scale = settings.get("rotate_y"), settings.get("scale")
        if rotate_y is not None and not math.isfinite(rotate_y):
            raise WavlightError(f"--rotate-y must be a finite number of degrees, got {rotate_y}")
        scale = FRAME["scale"].default if scale is None else scale
        env = None
        if settings.get("env") is not None:
            env = self.transfer.environment(settings["env"], scale)
        if (env if env is not None else self.transfer.environment(None, scale)).is_black:
            scaled = f" times --scale {scale:g}" if scale != 1.0 else ""
            raise WavlightError(f"{settings.get('env') or self.transfer.path}: the environment{scaled} is black "
                                "everywhere; the frame would be black")
        return {"env": env, "rotate_y": rotate_y, "scale": 1.0 if env is not None else scale,   # (env: scaled)
                "terms": settings.get("terms"), "priority": settings.get("priority")}

    def frame(self, state, detail=None):
        terms = state.get("terms") if detail is None else detail
        return self.transfer.frame_timed(state.get("env"), state.get("rotate_y"), state.get("scale", 1.0), terms,
                                         state.get("priority"), background=state.get("background") or self.background)

    def turn(self, state, count):
        from .lighting import turntable

        start = self.transfer.scene_rotate_y if state.get("rotate_y") is None else state["rotate_y"]
        return [dict(state, rotate_y=r) for r in turntable(start, count)]

    def report(self, state, stats) -> dict:
        t = self.transfer
        return {"terms": stats.get("terms"), "entries_read": stats.get("entries_read"),
                "texels": f"{1 << t.n_levels}x{1 << t.n_levels}", "priority": state.get("priority") or t.priority,
                "rotate_y": stats.get("rotate_y"), "background": self.background, "measured": t.measured,
                "memory_bytes_per_frame": int((stats.get("entries_read") or 0)
                                              * (t.block ** 2 * t.bits // 8 + 20))}

    # -- the viewer
    def limits(self, converge):
        side = 1 << self.transfer.n_levels
        return Limits(maps=len(self.maps), max_terms=side * side, rotate_y=self.transfer.scene_rotate_y % 360.0,
                      terms=min(self.transfer.terms, side * side), converge=converge)

    def page_config(self, limits, preview_pixels=VIEW_PREVIEW_PIXELS) -> dict:
        t = self.transfer
        return {"maps": [name for name, _ in self.maps], "max_terms": limits.max_terms,
                "default_terms": limits.terms, "texels": f"{1 << t.n_levels}x{1 << t.n_levels}",
                "preview_terms": preview_terms(limits.terms)}

    def detail(self, page, preview_pixels=VIEW_PREVIEW_PIXELS):
        return preview_terms(page["terms"]) if page["preview"] else page["terms"]

    def from_page(self, page, detail=None) -> dict:
        return {"env": self.maps[page["env"]][1], "rotate_y": page["rotate_y"], "scale": 1.0,
                "terms": page.get("terms") if detail is None else detail}

    def estimator(self):
        if self._frames is None:
            from .converge import ConvergeFrames

            self._frames = ConvergeFrames(self.transfer, self.scene_for_converge())
        frames, background = self._frames, self.background

        def unbiased(transfer=None, scene=None, env=None, rotate_y=None, scale=1.0, spp=2, seed=0, progress=None,
                     threads=None, background=background):
            frames.threads = threads if threads is not None else frames.threads
            return frames.frame(env, rotate_y, scale, spp, seed, progress, background=background)
        return unbiased

    def arguments(self, state) -> dict:
        return {"transfer": self.transfer, "scene": self.scene_for_converge(), "env": state.get("env"),
                "rotate_y": state.get("rotate_y"), "scale": state.get("scale", 1.0)}

    def for_converge(self):
        other = LightingFrames(self.transfer.copy(), self.scene_for_converge(), background=self.background)
        other.maps = self.maps
        return other

    def scene_for_converge(self):
        """The scene of the bake: the one given, else loaded once from the file the bake names
        (None where there is none: the estimator then says why)."""
        if self.given_scene is None:
            from ..scene import load_scene

            path = (self.transfer.scene or {}).get("path")
            if path and os.path.isfile(path):
                self.given_scene = load_scene(path)
        return self.given_scene

    def prepare(self):
        self.estimator()
        self._frames.prepare(background=self.background)

    def warm(self, state, stop=None):
        self.estimator()
        self._frames.warm(state.get("env"), state.get("rotate_y"), state.get("scale", 1.0), stop=stop,
                          background=state.get("background") or self.background)

    def close(self):
        if self._frames is not None:
            self._frames.close()


class ObjectFrames(Frames):
    """An object bake: one object's translation and rotation change; its lighting and the camera
    stay. Every frame is the moving-object estimator's (unbiased: :class:`.moving.MovingObject`),
    at OBJECT_FRAME_SPP samples per pixel (OBJECT_PREVIEW_SPP while a page's slider is held)."""

    factor = "object"
    flags = OBJECT_FLAGS
    fixed = "an object (its lighting and camera are fixed)"
    page_keys = shown_keys = ("translate", "rotate_y")
    unbiased = True

    def __init__(self, transfer, scene=None, background: str = FRAME["background"].default):
        super().__init__(transfer, scene, background)   # (not used: the static image's background)
        from .moving import MovingObject

        self.mover = MovingObject(transfer, scene)
        self.given_scene = self.mover.scene
        own = self.mover.object.rotate
        self._own_rotation = None
        if own is None:
            self.own_rotate_y = 0.0
        elif abs(own[0]) < 1e-12 and abs(own[2]) < 1e-12:
            self.own_rotate_y = float(own[3]) * (1.0 if own[1] > 0 else -1.0)
        else:   # the page's rotation about +Y is composed with the object's own
            self.own_rotate_y, self._own_rotation = 0.0, rotation(list(own))

    def state_from(self, settings) -> dict:
        translate = settings.get("translate")
        if translate is not None and not all(math.isfinite(x) and abs(x) <= MAX_COORDINATE for x in translate):
            raise WavlightError(f"--translate must be three finite numbers within the ray tracer's range (|x| <= "
                                f"{MAX_COORDINATE:g}), got {' '.join(str(x) for x in translate)}")
        return {"translate": translate, "rotate": settings.get("rotate"), "spp": settings.get("spp"),
                "seed": FRAME["seed"].default if settings.get("seed") is None else settings["seed"]}

    def inputs(self) -> list:
        return [self.mover.scene.path, *self.mover.scene.files]

    def frame(self, state, detail=None):
        spp = detail if detail is not None else state.get("spp")
        result = self.mover.frame(state.get("translate"), state.get("rotate"), spp=spp,
                                  seed=state.get("seed", FRAME["seed"].default))
        return result.image, dict(result.stats, frame_seconds=result.stats["render_seconds"], terms=None,
                                  stderr=result.stderr)

    def turn(self, state, count):
        """The object turned about +Y through a full turn, from its own rotation."""
        start = self.own_rotate_y
        return [dict(state, rotate=self.rotate_of(start + 360.0 * i / count)) for i in range(count)]

    def rotate_of(self, rotate_y: float) -> list:
        """[axis, degrees]: ``rotate_y`` about +Y, after the object's own rotation where that is
        about another axis."""
        turn = [0.0, 1.0, 0.0, float(rotate_y)]
        if self._own_rotation is not None:
            turn = axis_angle(rotation(turn) @ self._own_rotation)
        return turn

    def report(self, state, stats) -> dict:
        return {k: v for k, v in stats.items() if k != "stderr"}

    # -- the viewer
    def limits(self, converge):
        mover = self.mover
        default = [round(float(x), 4) for x in np.asarray(mover.object.translate, np.float64)]
        lo, hi, step = translate_range(mover.scene, mover.object, mover.center, mover.radius, default)
        return ObjectLimits(translate=tuple(default), lo=lo, hi=hi, step=step,
                            rotate_y=round(self.own_rotate_y % 360.0, 3) % 360.0, converge=converge)

    def page_config(self, limits, preview_pixels=VIEW_PREVIEW_PIXELS) -> dict:
        obj = self.mover.object
        return {"object": obj.name if obj.name else f"object {obj.index}", "translate_min": list(limits.lo),
                "translate_max": list(limits.hi), "translate_step": limits.step,
                "default_translate": list(limits.translate), "default_rotate_y": limits.rotate_y,
                "frame_spp": OBJECT_FRAME_SPP, "preview_spp": OBJECT_PREVIEW_SPP}

    def detail(self, page, preview_pixels=VIEW_PREVIEW_PIXELS):
        return OBJECT_PREVIEW_SPP if page["preview"] else OBJECT_FRAME_SPP

    def placement(self, page):
        """(translate (3,), rotate [axis, degrees]) of the object in a page's state."""
        return list(page["translate"]), self.rotate_of(page["rotate_y"])

    def from_page(self, page, detail=None) -> dict:
        translate, rotate = self.placement(page)
        return {"translate": translate, "rotate": rotate, "spp": detail, "seed": 0}

    def estimator(self):
        return self.mover.frame

    def arguments(self, state) -> dict:
        return {"translate": state.get("translate"), "rotate": state.get("rotate")}

    def estimate(self, estimator, state, spp, seed, **kwargs):
        # the moving object's estimator reports no progress and takes no threads
        fn = self.estimator() if estimator is None else estimator
        return fn(**self.arguments(state), spp=spp, seed=seed)

    def for_converge(self):
        return ObjectFrames(self.transfer.copy(), self.mover.scene)


class CameraFrames(Frames):
    """A view bake: the camera (eye, target, field of view, size) changes; the lighting and the
    objects stay. The frame is :meth:`ViewFrames.frame` (approximate), the unbiased one
    :meth:`ViewFrames.converge`."""

    factor = "view"
    flags = VIEW_FLAGS + BACKGROUND_FLAGS
    fixed = "the view (its lighting and objects are fixed)"
    sequence_flag = "orbit"
    page_keys = shown_keys = ("azimuth", "elevation", "distance")

    def __init__(self, transfer, scene=None, background: str = FRAME["background"].default):
        super().__init__(transfer, scene, background)
        from .view_frames import ViewFrames

        self.views = ViewFrames(transfer, scene, background=self.background)
        self.given_scene = self.views.scene

    def state_from(self, settings) -> dict:
        from .view_frames import still_settings

        for key in ("eye", "target"):
            if settings.get(key) is not None and not all(math.isfinite(x) and abs(x) <= MAX_COORDINATE
                                                         for x in settings[key]):
                raise WavlightError(f"{FRAME[key].flag} must be three finite numbers within the ray tracer's range "
                                    f"(|x| <= {MAX_COORDINATE:g}), got {' '.join(str(x) for x in settings[key])}")
        fov = settings.get("fov")
        why = None if fov is None else FRAME["fov"].problem(fov)
        if why:
            raise WavlightError(f"--fov {why}")
        approximate = _given(settings, APPROXIMATE)
        if settings.get("spp") is not None and approximate:
            raise WavlightError(f"{FRAME[next(iter(approximate))].flag} sets the approximate frame; --spp renders the "
                                "unbiased one: give one of them")
        opts = still_settings(**approximate)
        if settings.get("tau") is not None and opts["mode"] != "pixel":
            raise WavlightError("--tau corrects the cosine of --mode pixel: give it with --mode pixel")
        cam = self.views.camera(settings.get("eye"), settings.get("target"), fov)   # checked before any work
        width, height = self.views.size(settings.get("width"), settings.get("height"))
        return {"eye": cam.eye, "target": cam.target, "fov": cam.fov_y, "width": width, "height": height, **opts}

    def inputs(self) -> list:
        return [self.views.scene.path, *self.views.scene.files]

    def frame(self, state, detail=None):
        width, height = (state["width"], state["height"]) if detail is None else detail
        opts = {k: state[k] for k in APPROXIMATE if k in state}
        t0 = time.perf_counter()
        result = self.views.frame(state["eye"], state["target"], state["fov"], width, height,
                                  background=state.get("background"), **opts)
        image, stats = (result.image, result.stats) if hasattr(result, "image") else result
        stats = dict(stats or {})
        stats.setdefault("frame_seconds", time.perf_counter() - t0)
        return image, dict(stats, terms=None, spp=None)

    def turn(self, state, count):
        from .view_frames import orbit_eyes

        return [dict(state, eye=e) for e in orbit_eyes(state["eye"], state["target"], count)]

    def report(self, state, stats) -> dict:
        opts = {k: state[k] for k in APPROXIMATE if k in state}
        return {"width": state["width"], "height": state["height"], "eye": np.asarray(state["eye"]).tolist(),
                "target": np.asarray(state["target"]).tolist(), "fov": state["fov"], **opts,
                "tau": opts.get("tau") if opts.get("mode") == "pixel" else None,
                "texels": f"{1 << self.transfer.n_levels}x{1 << self.transfer.n_levels}",
                "timings": {k: round(v, 6) for k, v in stats.items() if k.endswith("_seconds")},
                "cache_points_shaded": stats.get("cache_points_shaded"),
                "nodes_per_point": stats.get("nodes_per_point"), "model": self.transfer.header.get("model"),
                "background": self.background}

    # -- the viewer
    def limits(self, converge):
        cam = self.views.scene.camera
        az, el, dist = orbit_angles(cam.eye, cam.target, cam.up)
        dist = significant(dist)
        lo, hi = (significant(dist * f) for f in DISTANCE_FACTORS)
        el = round(min(max(el, -ELEVATION_LIMIT), ELEVATION_LIMIT), 3)
        return ViewLimits(azimuth=round(az, 3) % 360.0, elevation=el, distance=dist, distance_lo=lo, distance_hi=hi,
                          converge=converge)

    def page_config(self, limits, preview_pixels=VIEW_PREVIEW_PIXELS) -> dict:
        t = self.transfer
        pw, ph = preview_size(t.width, t.height, preview_pixels)
        return {"default_azimuth": limits.azimuth, "default_elevation": limits.elevation,
                "default_distance": limits.distance, "distance_min": limits.distance_lo,
                "distance_max": limits.distance_hi, "elevation_limit": ELEVATION_LIMIT,
                "preview_width": pw, "preview_height": ph}

    def detail(self, page, preview_pixels=VIEW_PREVIEW_PIXELS):
        full = (self.transfer.width, self.transfer.height)
        return preview_size(*full, preview_pixels) if page["preview"] else full

    def camera(self, page):
        """(eye (3,), target (3,), fov in degrees) of a page's state: :func:`orbit_eye` of its
        azimuth, elevation and distance about the scene camera's target, with its up."""
        cam = self.views.scene.camera
        eye = orbit_eye(cam.target, cam.up, page["azimuth"], page["elevation"], page["distance"])
        return eye, np.asarray(cam.target, np.float64), float(cam.fov_y)

    def from_page(self, page, detail=None) -> dict:
        eye, target, fov = self.camera(page)
        width, height = (self.transfer.width, self.transfer.height) if detail is None else detail
        return {"eye": eye, "target": target, "fov": fov, "width": width, "height": height}

    def estimator(self):
        return self.views.converge

    def arguments(self, state) -> dict:
        return {"eye": state["eye"], "target": state["target"], "fov": state["fov"], "width": state["width"],
                "height": state["height"]}

    def for_converge(self):
        return CameraFrames(self.transfer.copy(), self.views.scene, background=self.background)


#: the type of each factor a bake may vary (relight.settings BAKE["vary"])
FRAMES = {"lighting": LightingFrames, "object": ObjectFrames, "view": CameraFrames}
_FACTOR_OF_FLAG = {**{k: "lighting" for k in LIGHTING_FLAGS}, **{k: "object" for k in OBJECT_FLAGS},
                   **{k: "view" for k in VIEW_FLAGS}, **{k: "lighting" for k in BACKGROUND_FLAGS}}


def frames_for(transfer, scene=None, maps=(), background: str = FRAME["background"].default) -> Frames:
    """The frames of ``transfer`` by the factor it varies (:attr:`Transfer.varies`); ``scene``: the
    scene it was baked from (default: the file the bake names); ``maps``: other maps of a lighting
    bake (an object or a view bake's lighting is fixed: a one-line WavlightError); ``background``:
    what camera samples that miss see in a lighting or a view bake's frames (nearest, bilinear or
    none; an object bake's background is its static image's)."""
    kind = FRAMES[transfer.varies]
    if kind is not LightingFrames:
        if len(maps):
            raise WavlightError(f"{transfer.path}: this bake varies {kind.fixed}: no other map applies")
        return kind(transfer, scene, background=background)
    return kind(transfer, scene, maps, background=background)
