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
answers with frames, one binary message each (:mod:`.pictures`): a 4-byte little-endian length, a
JSON header (the state used, the terms kept, timings) and the picture, JPEG (Pillow) or raw RGBA
(``encoding=`` in the URL). A frame is the frame of the factor the bake varies
(:func:`wavlight.relight.frames.frames_for`: :meth:`Transfer.frame_timed` for a lighting bake)
times 2^exposure through the tone curve, encoded to 8-bit sRGB. The page's state, its limits and
the notes for values replaced are :mod:`.viewstate`'s.

Bad input: a URL or message value that is not a number, not finite or out
of range is replaced by its default or clamped (:func:`sanitise`; an integer beyond the floats'
range is clamped like any other) and the page shows the value used and a one-line note, as it
does for the keys it does not know; a message larger than :data:`MAX_MESSAGE_BYTES`, nested
deeper than :data:`MAX_MESSAGE_DEPTH` (both checked before it is parsed), not JSON, not an
object, of an unknown type, or binary gets a one-line error, and the socket stays open (none of
it is written to stderr). Only what the websocket protocol itself forbids closes the socket, with
the protocol's code: a message over :data:`MESSAGE_CLOSE_BYTES` (1009), text that is not UTF-8
(1007). A socket closed in the middle of a frame ends its tasks without a traceback; a request
whose Host or Origin is not this server (another site in the same browser, DNS rebinding) is
refused (403), on every route.

The run's token. :attr:`Viewer.url` is ``http://127.0.0.1:PORT/?token=...`` (a
``secrets.token_urlsafe`` made per Viewer): every request must carry it (the page keeps it in its
URL, its socket's and its uploads'), else 403 with one line (``GET /`` without it: a hint to open
the URL the viewer printed). :attr:`Viewer.address` is the server without it,
:attr:`Viewer.socket_url` the page's socket.

A designer's tools. ``POST /upload?name=FILE&token=...`` (a lighting bake): the file's bytes,
streamed into the run's temporary folder within its bound (:mod:`.uploads`), read and checked as
any map (:meth:`Viewer.add_map`) and removed; the map joins the list (JSON: its index and name, and
notes), or one line says why not (413, 415, 400; 409 on a bake whose lighting is fixed) and the
maps are kept. A ``{"type": "png"}`` message is answered with the last frame sent as a PNG
(:func:`.pictures.png`, a binary message of type ``png``). Each frame's header carries the
``wavlight frame`` command of its state (:mod:`.reproduce`). A lighting or a view bake's state has
``show_background``: false makes its frames, preview and converged, with background ``none``
(camera samples that miss contribute 0: black where the camera sees only the map;
:meth:`Viewer.background_of`); a lighting bake's PNG then has straight alpha, the share of the
bake's camera samples that hit (:meth:`Viewer.coverage`), a view bake's stays opaque.

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

Converge (:mod:`.progressive`). The control refines the current state's factor with the unbiased
estimator (the frames' own, :meth:`Frames.estimate`), without the K-term and texel approximations:
passes with seeds 0, 1, 2, ..., the first of FIRST_SPP samples per pixel (a standard error needs
two), each next one as many as all before it (2, 2, 4, 8, ...) while a pass takes less than
GROW_SECONDS, merged exactly into
a running mean (:class:`.progressive.RunningMean`: the mean and standard error of all the samples
at once), streamed after each pass with the spp reached and the estimated relative error (the
header's ``converge``: ``spp``, ``passes``, ``pass_spp``, ``pass_seconds``, ``seconds``,
``relative_error``, ``done``; the next pass starts before a pass's picture is encoded and sent, so
that the passes follow each other without waiting for the page); a new exposure or curve shows the same mean again. Any change of
the factor (a slider released, the camera dragged) ends the passes (a pass under way ends at its
next progress report), shows the new state's frame and, the control still pressed, starts the
passes again from there; while a control is held (a preview) no pass runs. The passes of every
page run in a converge thread of their own, with the bake loaded again for it and its own frames
(:meth:`Frames.for_converge`), made and prepared (:meth:`Frames.prepare`: a lighting bake's
footprints and kernels) when the first page opens; a page whose state rested
:data:`WARM_AFTER_SECONDS` after its full frame has its state's shared parts warmed there
(:meth:`Frames.warm`: a lighting's tables and product trees), stopped by a newer state or a
converging page, so that a click pays only for its passes. The other pages' frames do not wait for
a pass (nor its own page's frames once its state moved). A pass runs on :data:`CONVERGE_THREADS`
threads (every core but one, where the estimator takes ``threads``) while other pages are open,
on :data:`ALONE_THREADS` (every core) while the converging page is the only one.

A bake that varies one object (``vary = "object"``, :mod:`wavlight.relight.moving`). The page
offers that factor's controls instead of the lighting's: the object's translation (x, y, z
sliders over :func:`.viewstate.translate_range`, the scene's bounds widened by the object's
bounding radius)
and its rotation about +Y in degrees (``rotate_y``: composed with the object's own rotation, whose
angle about +Y it starts from), with the exposure and the frame rate; the state is in the URL as
``/?translate=0.3,0,0.2&rotate_y=45&exposure=0.5``. A frame is the moving-object estimator
(:meth:`MovingObject.frame`, unbiased, seed 0) at :data:`OBJECT_FRAME_SPP` samples per pixel, or
:data:`OBJECT_PREVIEW_SPP` while a slider is dragged; converge calls the same estimator with seeds
0, 1, 2, ... and accumulates as above, and starts again when the placement changes (a pass under
way runs to its end: the estimator reports no progress). The parameters of
the factor a bake holds fixed (``env`` and ``terms`` on an object bake, ``translate`` on a lighting
bake) follow the rule of any bad value: they are replaced by the bake's own (ignored) with a
one-line note; a translation that is not three finite numbers becomes the object's own, a
component outside its range is clamped.

A bake that varies the view (``vary = "view"``, :mod:`wavlight.relight.view_frames`). The page orbits
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
seeds 0, 1, 2, ... and accumulates as above, and starts again when the camera moves (a pass under
way ends at its next progress report). ``rotate_y``, ``env``, ``terms`` and ``translate`` do not
apply to it and get a note, as do ``azimuth``, ``elevation`` and ``distance`` on the other bakes.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import inspect
import json
import logging
import os
import secrets
import signal
import threading
import time
import warnings
from importlib import resources

import numpy as np
from aiohttp import WSCloseCode, WSMsgType, web

from ..display import TONEMAP
from ..errors import WavlightError, described, shown
from . import serving
from .frames import OBJECT_PREVIEW_SPP, frames_for
from .pictures import ENCODINGS, JPEG_QUALITY, encode, message, png, tone_map
from .progressive import PassSchedule, RunningMean
from .reproduce import frame_command
from .settings import OBJECT_FRAME_SPP, VIEWER
from .uploads import MAP_EXTENSIONS, MAX_UPLOAD_BYTES, MAX_UPLOADED_MAPS, Refused, Uploads
from .viewstate import (CAMERA_KEYS, DISTANCE_FACTORS, ELEVATION_LIMIT, EXPOSURE_RANGE, MAX_INTEGER_DIGITS,
                        MAX_MESSAGE_BYTES, MAX_MESSAGE_DEPTH, VIEW_PREVIEW_PIXELS, Limits, ObjectLimits, ViewLimits,
                        nesting_depth, orbit_angles, orbit_basis, orbit_eye, preview_size, preview_terms, read_message,
                        sanitise, significant, translate_range)

#: the names of the viewer's pictures and state, where they were before their modules (the tests',
#: the benchmarks')
__all__ = ["CAMERA_KEYS", "CONVERGE_THREADS", "DISTANCE_FACTORS", "ELEVATION_LIMIT", "ENCODINGS", "EXPOSURE_RANGE",
           "HOST", "JPEG_QUALITY", "Limits", "MAX_INTEGER_DIGITS", "MAX_MESSAGE_BYTES", "MAX_MESSAGE_DEPTH",
           "OBJECT_FRAME_SPP", "OBJECT_PREVIEW_SPP", "ObjectLimits", "VIEW_PREVIEW_PIXELS", "ViewLimits", "Viewer",
           "encode", "message", "nesting_depth", "orbit_angles", "orbit_basis", "orbit_eye", "preview_size",
           "preview_terms", "read_message", "sanitise", "significant", "tone_map", "translate_range"]

#: the only address the viewer listens on
HOST = "127.0.0.1"
#: frames sent to a page and not yet acknowledged, at most
WINDOW = 2
#: how long a socket waits for an acknowledgement before it sends the next frame anyway
ACK_SECONDS = 1.0
#: a message larger than this closes the socket (the websocket protocol's code 1009, before it is
#: read whole): the most a page's socket buffers
MESSAGE_CLOSE_BYTES = 1 << 20
#: the threads of one converge pass, where the estimator takes ``threads``, while other pages are
#: open: every core but one, which the frame thread keeps (on two cores, a 128 x 128 bake: frames
#: 2.4 ms in the median beside a call on one thread, 5.1 ms beside the estimator's default of two
#: per core, the call no slower); with the converging page alone, ALONE_THREADS (a page that
#: converges draws no frame: a pass of 8 spp at 256 x 256 took 1.3 s on two threads against 1.8 s
#: on one, two cores under a load of 9)
CONVERGE_THREADS = max(1, (os.cpu_count() or 2) - 1)
ALONE_THREADS = os.cpu_count() or 2
#: a page whose state rests this long after its full frame (converge not pressed) has the state's
#: lighting warmed in the converge thread (its tables and product trees), unless a page converges:
#: a click then pays only for its first pass
WARM_AFTER_SECONDS = 0.3
_UNSET = object()
_log = logging.getLogger("wavlight.viewer")


class _Stopped(Exception):
    """A converge pass ended early: the state changed."""


# ----------------------------------------------------------------------------- the server
class Viewer:
    """The viewer of one transfer, through the frames of the factor it varies
    (:func:`wavlight.relight.frames.frames_for`: :class:`~.frames.LightingFrames` under its baked map
    and the ``maps`` given, map files or Environments, index 0 always the baked map;
    :class:`~.frames.ObjectFrames`; :class:`~.frames.CameraFrames`; an object or a view bake takes
    no ``maps``: its lighting is fixed). ``scene``: the baked scene (a Scene or a scene file;
    default: loaded from the file the bake names; a scene that is not the baked one is a one-line
    WavlightError). ``converge``: the unbiased estimator (default the frames' own; None disables
    the control), called with the factor's arguments (:meth:`Frames.arguments`): a lighting bake's
    converge(transfer=, scene=, env=, rotate_y=, scale=, spp=, seed=), an object bake's
    converge(translate=, rotate=, spp=, seed=), a view bake's converge(eye=, target=, fov=, width=,
    height=, spp=, seed=), each returning (image, stderr) or a RenderResult (and given ``progress``
    and ``threads`` where it takes them; a lighting or a view bake's ``background`` too: ``none``
    where the page hides the background). ``preview_pixels``:
    the most pixels of a view bake's frames while the camera is dragged (:func:`preview_size`).
    ``background``: what the camera samples that miss see in a lighting or view bake's frames and
    converged frames (default bilinear: the viewer's picture; ``none`` where a page hides it,
    :meth:`background_of`; the lighting is the map's texels either way; an object bake's
    background is its static image's)."""

    def __init__(self, transfer, maps=VIEWER["maps"].default, converge=_UNSET, scene=None,
                 preview_pixels: int = VIEW_PREVIEW_PIXELS, background: str = VIEWER["background"].default,
                 max_upload_bytes: int = MAX_UPLOAD_BYTES):
        self.transfer = transfer
        #: the per-run secret every request carries (``?token=``): the page's URL, its socket, its uploads
        self.token = secrets.token_urlsafe(24)
        #: the maps sent from the page (:mod:`.uploads`: a temporary folder, bounded in size)
        self.uploads = Uploads(max_upload_bytes)
        #: what the camera samples that miss see in a lighting or a view bake's frames (VIEWER["background"])
        self.background = VIEWER["background"].check(background, "relight.Viewer")
        self.frames = frames_for(transfer, scene, maps, background=self.background)
        self.varies = self.frames.factor
        #: each map's --env in the command that reproduces a frame (index 0, the baked map: none;
        #: a map sent from the page: the file name it had there)
        self.map_files = [None, *(os.fspath(m) if isinstance(m, (str, os.PathLike)) else getattr(m, "name", None)
                                  for m in maps)] if self.varies == "lighting" else [None]
        self.scene_file = os.fspath(scene) if isinstance(scene, (str, os.PathLike)) else None
        self.uploaded = 0       # maps taken from the pages
        self._coverage = None   # a lighting bake's share of camera samples that hit, per pixel (hidden background)
        self.preview_pixels = int(preview_pixels)
        self.converge = self.frames.estimator if converge is _UNSET else converge
        self._default_converge = converge is _UNSET
        try:
            takes = inspect.signature(self.converge).parameters if not self._default_converge and \
                self.converge is not None else {"progress": None, "threads": None}
        except (TypeError, ValueError):
            takes = {}
        self._converge_progress, self._converge_threads = "progress" in takes, "threads" in takes
        self._converge_background = self.varies != "object" and (self._default_converge or "background" in takes)
        self.limits = self.frames.limits(self.converge is not None)
        self.state_keys = (*self.frames.shown_keys, "exposure", "tonemap",
                           *(("show_background",) if self.varies != "object" else ()))
        self._page = resources.files(__package__).joinpath("viewer.html").read_text(encoding="utf-8")
        self._pool = None       # the one thread that computes frames
        self._converge_pool = None   # the one thread that runs converge passes
        self._converging = None      # that thread's own frames (on a copy of the bake)
        self._prepared = None        # the task that made them when the first page opened
        self._warm_key = None        # the factor's value warmed last, and the warming's generation:
        self._warm_generation = 0    # a newer state or a converging page stops a warming under way
        self._warming: set = set()
        self.converging_pages = 0
        self._listener = None
        self._sockets: set = set()
        self._tasks: set = set()
        self._runner = self._thread = self._loop = self._stopping = None
        self.port = None

    # -- the application
    # -- the application
    def application(self) -> web.Application:
        """The aiohttp application: ``/`` the page, ``/ws`` the websocket."""
        app = web.Application(middlewares=[self._watched, self._only_here, self._with_token],
                              client_max_size=1 << 16)   # (an upload is streamed: uploads.MAX_UPLOAD_BYTES)
        app.router.add_get("/", self._page_handler)
        app.router.add_get("/ws", self._socket_handler)
        app.router.add_post("/upload", self._upload_handler)
        app.on_shutdown.append(self._close_sockets)
        return app

    @property
    def url(self) -> str:
        """The page's URL, with the run's token: what ``wavlight view`` prints and opens."""
        return f"{self.address}?token={self.token}"

    @property
    def address(self) -> str:
        """The server's address without the token (a request to it is refused)."""
        return f"http://{HOST}:{self.port}/"

    @property
    def socket_url(self) -> str:
        """The page's websocket, with the token."""
        return f"ws://{HOST}:{self.port}/ws?token={self.token}"

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

    @web.middleware
    async def _with_token(self, request, handler):
        """Requests that carry the run's token (``?token=``, compared in constant time) only: 403
        with one line otherwise (the page without it: a hint to open the URL the viewer printed)."""
        given = request.query.get("token", "")
        if not secrets.compare_digest(given.encode("utf-8", "surrogateescape"), self.token.encode()):
            if request.path == "/" and request.method == "GET":
                return web.Response(status=403, text="refused: open the URL the viewer printed (it carries "
                                    "?token=...; this address alone is not enough)\n")
            return web.Response(status=403, text="refused: this request does not carry the viewer's token\n")
        return await handler(request)

    def _config(self, state, notes) -> dict:
        t = self.transfer
        config = {"vary": self.varies, "state": state, "notes": notes,
                  "exposure_range": list(EXPOSURE_RANGE), "tonemaps": list(TONEMAP.values),
                  "encodings": list(ENCODINGS), "width": t.width, "height": t.height,
                  "converge": self.converge is not None,
                  "converge_note": None if self.converge is not None else
                  "no converge estimator given to this viewer",
                  "window": WINDOW, "token": self.token,
                  "uploads": self.varies == "lighting",
                  "uploads_note": None if self.varies == "lighting" else
                  f"this bake varies {self.frames.fixed}: another map does not apply",
                  "max_upload_bytes": self.uploads.limit, "map_extensions": list(MAP_EXTENSIONS),
                  "background_toggle": self.varies != "object",
                  "background_note": None if self.varies != "object" else
                  f"this bake varies {self.frames.fixed}: its background is the bake's static image",
                  "env_files": self.map_files}
        return {**config, **self.frames.page_config(self.limits, self.preview_pixels)}

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
        if self.converge is not None and self._converging is None and self._converge_pool is not None:
            self._prepared = self._prepared or asyncio.ensure_future(self.run_converge(self.prepare_converge))
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

    async def _upload_handler(self, request):
        """A map sent from the page (POST /upload?name=FILE&token=..., the file's bytes as the
        body): written to the run's folder within its bound (:mod:`.uploads`), read and checked
        as any map (:meth:`add_map`, in the frame thread), then removed; JSON: the new map's
        index and name and the notes of its checks, or ``error``, one line (413 beyond the bound,
        415 a name that is not a map's, 400 a file that is not a usable map, 409 a bake whose
        lighting is fixed or a full list): the maps the viewer had are kept."""
        if self.varies != "lighting":
            return web.json_response({"error": f"this bake varies {self.frames.fixed}: another map does not apply"},
                                     status=409)
        if self.uploaded >= MAX_UPLOADED_MAPS:
            return web.json_response({"error": f"the viewer took {self.uploaded} maps from its pages: no more"},
                                     status=409)
        try:
            path, name = await self.uploads.receive(request, request.query.get("name", ""))
        except Refused as e:
            return web.json_response({"error": e.message}, status=e.status, headers={"Connection": "close"})
        try:
            index, notes = await self.run(self.add_map, path, name)
        except WavlightError as e:
            return web.json_response({"error": described(e).replace(path, name)}, status=400)
        except Exception as e:   # a fault, not bad input: one (rate-limited) line
            _log.error("an upload failed: %s", described(e))
            return web.json_response({"error": f"{name}: cannot be read ({described(e).replace(path, name)})"},
                                     status=400)
        finally:
            try:
                os.unlink(path)
            except OSError:
                pass
        return web.json_response({"index": index, "name": name, "notes": notes})

    def add_map(self, path, name):
        """(index, notes): the map file ``path`` read and checked as any map
        (:func:`wavlight.envmap.read_image`, :class:`wavlight.envmap.Environment`: an unreadable
        file or one that is not an image is a WavlightError; NaN, Inf and negative texels are set
        to 0 and an 8-bit image is decoded from sRGB, each with a note; a map black everywhere is
        refused), named ``name``, added to the maps a page may choose (the limits follow)."""
        from ..envmap import Environment, read_image

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            env = Environment(read_image(path), 1.0, 0.0, name)
        if env.is_black:
            raise WavlightError(f"{name}: the environment is black everywhere; the frame would be black")
        self.frames.maps.append((name, env))
        self.map_files.append(name)
        self.uploaded += 1
        self.limits = self.frames.limits(self.converge is not None)
        return len(self.frames.maps) - 1, [str(w.message).replace(path, name) for w in caught]

    def coverage(self):
        """(H, W) float32: the share of a lighting bake's camera samples of each pixel that hit a
        surface (:func:`wavlight.relight.converge.bake_hits`), the alpha of the PNG of a frame
        without background (:func:`.pictures.png`); None for another bake (a view bake's frames do
        not keep their hit shares: its PNG stays opaque, black where hidden)."""
        if self.varies != "lighting":
            return None
        if self._coverage is None:
            from .converge import bake_hits

            self._coverage = (bake_hits(self.transfer) / float(self.transfer.spp)).astype(np.float32)
        return self._coverage

    def command(self, state, spp=None) -> str:
        """The ``wavlight frame`` command that reproduces the frame of a page's sanitised state
        (:func:`.reproduce.frame_command`; ``spp``: the samples of a converged picture)."""
        env = self.map_files[state["env"]] if self.varies == "lighting" and state["env"] < len(self.map_files) \
            else None
        return frame_command(self.frames, state, self.transfer.path, env, self.scene_file,
                             self.background_of(state), spp)

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

    def detail(self, state):
        """What a frame of the state is computed at (:meth:`Frames.detail`): the terms (fewer for a
        preview) of a lighting bake, the samples per pixel of an object bake, the (width, height) of
        a view bake."""
        return self.frames.detail(state, self.preview_pixels)

    def background_of(self, state):
        """What the frames of a page's state show where camera samples miss: ``none`` with the
        background hidden (show_background false; a lighting or a view bake), else the viewer's
        ``background`` (None for an object bake: its static image's)."""
        if self.varies == "object":
            return None
        return self.background if state.get("show_background", True) else "none"

    def frame_key(self, state, detail):
        """What a frame depends on besides the exposure, the tone curve and the encoding."""
        return (*self.frames.key(state), detail, self.background_of(state))

    def converge_key(self, state):
        """The factor the converged image is of: the lighting (rotation, map), the object's place or
        the camera, and what misses see."""
        return (*self.frames.key(state), self.background_of(state))

    def _factor_state(self, state, detail=None):
        """The factor's state of a page's state (:meth:`Frames.from_page`), with its background."""
        factor = self.frames.from_page(state, detail)
        if self.varies != "object":
            factor["background"] = self.background_of(state)
        return factor

    def frame(self, state, detail):
        """(linear image, stats) of the state at ``detail`` (:meth:`detail`; in the frame thread)."""
        image, stats = self.frames.frame(self._factor_state(state, detail), detail)
        return image, {"frame_seconds": stats.get("frame_seconds", 0.0), "terms": stats.get("terms"),
                       "spp": stats.get("spp"), **({"object_pixels": stats["object_pixels"]}
                                                   if "object_pixels" in stats else {})}

    def converge_call(self, state, spp, seed, stop=None):
        """(image, stderr) of one pass of the estimator at the state's factor (a view bake's camera
        at the bake's size; in the converge thread, with its own frames: :meth:`_converge_side`);
        ``stop`` (a threading.Event) set ends the pass early where the estimator reports its
        progress (then :class:`_Stopped`)."""
        kwargs = {"threads": CONVERGE_THREADS if self.clients > 1 else ALONE_THREADS} if self._converge_threads else {}
        if stop is not None and self._converge_progress:
            def progress(*args):
                if stop.is_set():
                    raise _Stopped()
            kwargs["progress"] = progress
        if self._converge_background:   # the frames' own, or a given estimator that takes it
            kwargs["background"] = self.background_of(state)
        frames = self._converge_side()
        estimator = None if self._default_converge else self.converge
        result = frames.estimate(estimator, frames.from_page(state), spp, seed, **kwargs)
        if hasattr(result, "image"):   # a RenderResult
            return result.image, result.stderr
        return result

    def _converge_side(self):
        """The converge thread's frames, made on its first pass: a copy of the bake (its own maps'
        projectors; the sections shared, read-only: :meth:`Transfer.copy`) and its own frames
        (their caches, trees and kernels are the frame thread's otherwise): the two threads share
        only read-only arrays, so a pass never waits for a frame nor a frame for it."""
        if self._converging is None:
            self._converging = self.frames.for_converge()
        return self._converging

    def warm_later(self, state):
        """The page's state rests: warm its factor's shared parts in the converge thread after
        WARM_AFTER_SECONDS, unless another state comes or a page converges meanwhile (in the loop)."""
        if not self._default_converge or self.converge is None or self._converge_pool is None:
            return
        key = self.converge_key(state)
        self._warm_generation += 1
        if key == self._warm_key:
            return
        generation = self._warm_generation

        async def later():
            await asyncio.sleep(WARM_AFTER_SECONDS)
            if generation != self._warm_generation or self.converging_pages:
                return
            self._warm_key = key
            await self.run_converge(self._warm, state, generation)
        task = asyncio.ensure_future(later())
        self._warming.add(task)
        task.add_done_callback(self._warmed)

    def _warmed(self, task):
        self._warming.discard(task)
        if not task.cancelled() and task.exception() is not None:   # (a pass reports the same failure)
            self._warm_key = None

    def stop_warming(self):
        """A page converges: a warming under way stops at its next tile."""
        self._warm_generation += 1

    def _warm(self, state, generation):
        """Warm the state's shared parts (in the converge thread), tile by tile while it is current."""
        frames = self._converge_side()
        factor = frames.from_page(state)
        if self.varies != "object":
            factor["background"] = self.background_of(state)
        frames.warm(factor, lambda: generation != self._warm_generation or self.converging_pages)

    def prepare_converge(self):
        """Make the converge thread's frames and what their first pass makes regardless of the state
        (a lighting bake's footprints and kernels): run in the converge thread when a page opens,
        so that a click pays only for its state's lighting and passes. A failure here is the first
        pass's to report (it fails the same way): ignored."""
        if self.converge is None:
            return
        try:
            frames = self._converge_side()
            if self._default_converge:
                frames.prepare()
        except Exception:   # (the first pass reports it)
            self._converging = None

    # -- serving
    async def start(self, port: int = VIEWER["port"].default) -> str:
        """Listen on 127.0.0.1:port (0: a free port); the URL. A port in use: a one-line
        WavlightError."""
        serving.one_line_logs("aiohttp.server", "aiohttp.web", "aiohttp.access", "aiohttp.websocket",
                              "wavlight.viewer")
        self.uploads.open()
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
        for task in list(self._warming):
            task.cancel()
        await asyncio.gather(*self._warming, return_exceptions=True)
        if self._prepared is not None:
            self._prepared.cancel()
            await asyncio.gather(self._prepared, return_exceptions=True)
            self._prepared = None
        if self._converging is not None:
            side, self._converging = self._converging, None
            side.close()
            side.transfer.close()
        self.uploads.close()

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


class _Client:
    """One websocket: the newest state it asked for, and the task that answers it with frames."""

    def __init__(self, viewer: Viewer, ws, transport=None):
        self.viewer, self.ws, self.transport = viewer, ws, transport
        self.state = None
        self.wake = asyncio.Event()
        self.acked = asyncio.Event()
        self.sent = self.drawn = 0
        self.shown = None           # (key, exposure, tonemap, encoding, background) of the last frame sent
        self.sending = None         # the task encoding and sending the last frame
        self.picture = None         # (linear image, state, converge report) of the last frame sent: the PNG
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
        if kind == "png":
            unknown = [k for k in data if k != "type"]
            if unknown:
                await self.error(f"unknown keys of a png request ignored: {shown(unknown, 60)}")
            return await self.send_png()
        if kind != "state":
            return await self.error(f"unknown message type {shown(kind, 40)} (state, drawn or png): ignored")
        state, notes = sanitise(data, self.viewer.limits)
        known = {"type", *state, *self.viewer.limits.held}
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

    def _coverage(self, state):
        """The PNG's alpha with the background hidden (:func:`.pictures.png`), or None (opaque)."""
        return None if state.get("show_background", True) else self.viewer.coverage()

    async def send_frame(self, image, state, stats, converge=None, seq=None):
        """Tone map, encode (a worker thread of the loop's default pool) and send, with the
        command that reproduces it; False when the socket has closed. ``seq``: the number already
        given to the frame (else the next)."""
        if seq is None:
            self.sent += 1
            seq = self.sent
        self.picture = (image, state, converge)
        loop = asyncio.get_running_loop()
        t0 = time.perf_counter()
        payload = await loop.run_in_executor(None, encode, image, state["exposure"], state["encoding"],
                                             state["tonemap"])
        h, w = image.shape[:2]
        header = {"type": "frame", "seq": seq, "width": w, "height": h, "encoding": state["encoding"],
                  "state": {k: state[k] for k in self.viewer.state_keys},
                  "command": self.viewer.command(state, converge["spp"] if converge else None),
                  "terms_used": stats.get("terms"), "spp": stats.get("spp"), "preview": bool(stats.get("preview")),
                  "frame_ms": round(1e3 * stats.get("frame_seconds", 0.0), 2),
                  "encode_ms": round(1e3 * (time.perf_counter() - t0), 2), "bytes": len(payload),
                  "converge": converge}
        try:
            await self.ws.send_bytes(message(header, payload))
        except (ConnectionError, RuntimeError):
            return False
        return not self.ws.closed

    async def send_png(self):
        """The last frame sent as a PNG (:func:`.pictures.png`: as the page shows it; a hidden
        background transparent), one binary message of type ``png``; a one-line error before the
        first frame."""
        if self.picture is None:
            return await self.error("no frame yet to save as PNG")
        image, state, _ = self.picture
        payload = await asyncio.get_running_loop().run_in_executor(None, png, image, state["exposure"],
                                                                   state["tonemap"], self._coverage(state))
        h, w = image.shape[:2]
        header = {"type": "png", "width": w, "height": h, "bytes": len(payload),
                  "state": {k: state[k] for k in self.viewer.state_keys}}
        try:
            await self.ws.send_bytes(message(header, payload))
        except (ConnectionError, RuntimeError):
            pass

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
        """The frame of one state, then, with converge (and not a preview: a control held), the
        passes refining it; False once the socket has closed."""
        converging = state["converge"] and not state["preview"] and self.viewer.converge is not None
        if not await self._frame(state):
            return False
        if converging:
            self.shown = None
            self.viewer.converging_pages += 1
            self.viewer.stop_warming()
            try:
                return await self._flush() and await self._converge(state)
            finally:
                self.viewer.converging_pages -= 1
        if not state["preview"]:
            self.viewer.warm_later(state)
        return True

    async def _frame(self, state) -> bool:
        """The state's frame (the relit frame, or its preview), unless it is the one shown."""
        detail = self.viewer.detail(state)
        key = self.viewer.frame_key(state, detail)
        look = (state["exposure"], state["tonemap"], state["encoding"], state.get("show_background", True))
        if self.shown == (key, *look):
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
        self.shown = (key, *look)
        return True

    async def _converge(self, state):
        """Refine the state's factor (the lighting, the object's place or the camera) with passes
        of the estimator (:mod:`.progressive`: seeds 0, 1, 2, ..., spp 2, 2, 4, 8, ...),
        streaming the running mean of all their samples after each; return when that factor or the
        control changes (True), or the socket closed (False)."""
        lighting = self.viewer.converge_key(state)
        run, schedule = RunningMean(), PassSchedule()
        report = None
        job = waiter = None
        stop = threading.Event()
        began = time.perf_counter()

        def same(s):
            return s["converge"] and self.viewer.converge_key(s) == lighting

        def launch(state):
            """The next pass (schedule.spp samples, seed run.passes): (its start, spp, job)."""
            spp = schedule.spp
            return time.perf_counter(), spp, asyncio.ensure_future(
                self.viewer.run_converge(self.viewer.converge_call, state, spp, run.passes, stop))

        try:
            while True:
                if job is None and not schedule.done():
                    t0, spp, job = launch(state)
                while job is None or not job.done():   # (no job: converged; answer exposure changes)
                    waiter = asyncio.ensure_future(self.wake.wait())
                    await asyncio.wait({waiter} if job is None else {job, waiter},
                                       return_when=asyncio.FIRST_COMPLETED)
                    if not waiter.done():
                        waiter.cancel()
                        continue
                    self.wake.clear()
                    if not same(self.state):          # the factor changed: the pass's result is dropped
                        self.wake.set()
                        return True
                    state = self.state                   # the exposure (tone curve, encoding) changed: the mean again
                    if run.mean is not None:
                        await self._window()
                        if not await self.send_frame(run.mean.astype(np.float32), state,
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
                run.add(image, stderr, spp)
                schedule.after(seconds)
                error = run.relative_error()
                report = {"spp": run.spp, "passes": run.passes, "pass_spp": spp, "pass_seconds": round(seconds, 3),
                          "seconds": round(time.perf_counter() - began, 3),
                          "relative_error": None if error is None else round(error, 6), "done": schedule.done()}
                picture = run.mean.astype(np.float32)
                job = None
                if not schedule.done():   # the next pass runs while this one's picture is encoded and sent
                    t0, spp, job = launch(state)
                await self._window()
                if not await self.send_frame(picture, state, {"frame_seconds": seconds, "terms": None}, report):
                    return False
        finally:
            stop.set()            # a pass still running ends at its next progress report
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
