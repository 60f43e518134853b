"""The settings of a bake, a frame and the viewer, declared once: :class:`wavlight.options.Option`
records, keyed by the library's keyword.

``wavlight bake``, ``wavlight frame`` and ``wavlight view`` make their flags from these records
(flag, range, choices, help text and the default shown), the library takes its defaults and
ranges from them (:func:`wavlight.bake`, :meth:`wavlight.relight.Transfer.frame`,
:func:`wavlight.relight.converge.converge`, :class:`wavlight.relight.moving.MovingObject`,
:class:`wavlight.relight.view_frames.ViewFrames`, :class:`wavlight.relight.viewer.Viewer`), and the docs
their tables (:func:`options_table`; ``python docs/update_tables.py``). The few constants that a
default's description names (the pilot's choices of camera samples, the view bake's cache) are
declared here beside it.

A default of None means that the value is chosen at run time or that the setting is not used;
the record's ``default_doc`` says which.
"""
from __future__ import annotations

from dataclasses import replace

from ..display import DISPLAY
from ..options import BACKGROUND, FOV, HEIGHT, SEED, WIDTH, Option, markdown_table
from .lighting import MAX_LEVELS, MAX_TERMS, PRIORITIES
from .store import ENTRY_DTYPES, MAX_SPP, VARIES

# ----------------------------------------------------------------------------- the bake
#: camera samples per pixel a bake chooses among (its pilot: wavlight.relight.bake.choose_model)
SPP_CHOICES = (16, 32, 64)
#: the points of a texel put at least this many point spacings across the narrowest BRDF lobe
LOBE_SPACINGS = 16
#: a view bake's surface cache: this many points over the scene's surface area, unless given a density
CACHE_POINTS = 1 << 16
#: a view bake's points per texel, unless given
VIEW_TEXEL_POINTS = 4
#: the bake's seeds reach seed + 2 (its pilots and an object bake's static image): at most 2^62
RELIGHT_SEED = replace(SEED, hi=2 ** 62, help="Random seed.")

BAKE = {o.key: o for o in (
    replace(WIDTH, default=None, default_doc="the scene's"),
    replace(HEIGHT, default=None, default_doc="the scene's"),
    # at most 64: each pixel's mask of the camera samples that miss is one 64-bit word
    Option("spp", int, "Camera samples per pixel, stratified over the pixel (they share each texel's shadow ray).",
           default_doc=f"the fewest of {', '.join(map(str, SPP_CHOICES))} the tolerance needs, from two pilot bakes "
                       "that measure the noise", lo=1, hi=MAX_SPP),
    Option("levels", int, "Texels: 2^n x 2^n on the lat-long square.",
           default_doc="the fewest that meet the tolerance, from a pilot bake", lo=2, hi=8),
    Option("tolerance", float, "Relative L2 error of frames, measured on held-out rotations: shared by the bake's "
           "noise, the texels' resolution, the terms and the compression.", default=0.02, lo=1e-6, hi=1.0),
    Option("points", int, "Points per texel where the BRDF is evaluated (1, 2 x 2 or 4 x 4 strata).",
           default_doc=f"the fewest that put {LOBE_SPACINGS} point spacings across the narrowest lobe "
                       f"({VIEW_TEXEL_POINTS} for --vary view)", values=(1, 4, 16)),
    Option("bits", int, "Quantization of the stored coefficients.", default=8, values=tuple(ENTRY_DTYPES)),
    Option("terms", int, "The lighting terms K a frame keeps by default.",
           default_doc="the fewest that meet the tolerance", lo=1, hi=MAX_TERMS),
    Option("priority", str, "How frames rank the lighting's terms.",
           default_doc="the better of transfer and area on the pilot", values=PRIORITIES),
    RELIGHT_SEED,
    Option("vary", str, "The factor frames vary: the lighting (map, rotation, scale), one object's place, or the "
           "camera (view: T1 = L V cos on a surface cache; --width, --height and --spp do not apply).",
           default="lighting", values=VARIES),
    Option("density", float, "--vary view: surface cache points per unit area.",
           default_doc=f"{CACHE_POINTS} over the scene's area", lo=1e-12, hi=1e18),
    Option("object", str, "--vary object: the object that moves (its name, or its index among [[objects]]).",
           default_doc="none (--vary object needs it)", metavar="NAME"),
    Option("static_spp", int, "--vary object: samples per pixel of the scene without the object, converged at "
           "the bake.", default=256, lo=2, hi=1 << 20),
    Option("dask_address", str, "Bake the blocks on this dask.distributed scheduler (its workers read the scene "
           "file at the same path); the file is identical to a local bake's.", default_doc="this process",
           flag_name="--dask", metavar="tcp://HOST:PORT"),
)}

# ----------------------------------------------------------------------------- frames
#: an object bake's frame without a given spp (its frames are all unbiased; the viewer's at rest)
OBJECT_FRAME_SPP = 4
#: the unbiased frame's camera samples per pixel where a library caller gives none
#: (wavlight.relight.converge.converge, ViewFrames.converge; ``wavlight frame --spp`` always gives them)
UNBIASED_SPP = 16
#: a written frame of a view bake (``wavlight frame``) in --mode pixel: S x S rays per pixel
#: (docs/decisions/view-point-mode.md); in --mode point more rays do not sharpen the blend: 1
WRITTEN_SUPERSAMPLE = 4
_VIEW = "A bake with --vary view: "

FRAME = {o.key: o for o in (
    Option("env", str, "Another environment map: a file or data:NAME, a map of wavlight.data.",
           default_doc="the baked one", metavar="FILE"),
    Option("rotate_y", float, "Rotation of the map about +Y, degrees, absolute as the scene's rotate_y.",
           default_doc="the scene's", metavar="DEG"),
    Option("scale", float, "Radiance scale.", default=1.0, lo=0.0, hi=1e30),
    replace(BACKGROUND, help=BACKGROUND.help + " Frames of a lighting or a view bake."),
    Option("terms", int, "Lighting terms K kept.", default_doc="the bake's choice", lo=1, hi=BAKE["terms"].hi),
    Option("priority", str, "How the K terms are chosen.", default_doc="the bake's", values=PRIORITIES),
    Option("turntable", int, "N frames of a full turn about +Y into the folder -o DIR (PNG; and an animated PNG, "
           "and an MP4 with the extra video).",
           default_doc="none: one frame", lo=1, hi=3600, metavar="N"),
    Option("repeat", int, "Frames of the same state computed to time one, for every factor (frame_seconds: the "
           "median wall time; frames_per_second: its inverse).", default=5,
           default_doc="5; 1 for an unbiased frame (--spp, and every frame of a bake with --vary object)", lo=1,
           hi=1000),
    Option("spp", int, "The unbiased frame instead: N camera samples per pixel, directions from the product of "
           "transfer and lighting and from the BSDF, true shadow rays (reloads the baked scene).",
           default_doc=f"none: the relit frame; a bake with --vary object: {OBJECT_FRAME_SPP} (its frames are "
                       "unbiased)", lo=1, hi=1 << 16, metavar="N"),
    replace(RELIGHT_SEED, help="Random seed (--spp)."),
    Option("translate", float, "A bake with --vary object: the object's translation (absolute, replacing its own).",
           default_doc="its own", count=3, metavar="X Y Z"),
    Option("rotate", float, "A bake with --vary object: the object's rotation, axis and degrees (absolute).",
           default_doc="its own", count=4, metavar="AX AY AZ DEG"),
    Option("scene", str, "The scene the bake was made from, where it is not at the path the bake recorded (--spp).",
           default_doc="the path the bake recorded", metavar="FILE"),
    Option("eye", float, _VIEW + "the camera's position.", default_doc="the scene's", count=3, metavar="X Y Z"),
    Option("target", float, _VIEW + "the point the camera looks at.", default_doc="the scene's", count=3,
           metavar="X Y Z"),
    replace(FOV, key="fov", help=_VIEW + "the vertical field of view, degrees.", default=None,
            default_doc="the scene's", metavar="DEG"),
    replace(WIDTH, help=_VIEW + "image width.", default=None, default_doc="the bake's"),
    replace(HEIGHT, help=_VIEW + "image height.", default=None, default_doc="the bake's"),
    Option("orbit", int, _VIEW + "N frames of an orbit of the eye about the target (about +Y) into the folder "
           "-o DIR (PNG; and an animated PNG, and an MP4 with the extra video).", default_doc="none: one frame", lo=1,
           hi=3600, metavar="N"),
    Option("refine", float, _VIEW + "a BRDF node's angular radius at most REFINE times its distance from the lobe "
           "plus the lobe's width, divided by g >= sqrt(share / MASS) (a power of two) where the node holds more "
           "than MASS of the transfer (smaller: more nodes, closer to the texels' sum).", default=0.6, lo=1e-4,
           hi=100.0),
    Option("mass", float, _VIEW + "a node holding more than this share of the transfer's mass (a sun) is refined "
           "further (0: by the lobe alone).", default=0.003, lo=0.0, hi=1.0),
    Option("mode", str, _VIEW + "a product per cache point, blended per pixel (fast: the viewer's), or per pixel "
           "of its points' blended transfer with the pixel's shading normal and view (closer to mis; slower).",
           default="pixel", values=("point", "pixel")),
    Option("supersample", int, _VIEW + "S x S rays per pixel, averaged (a mesh's facets can be smaller than a "
           "pixel).", default_doc=f"{WRITTEN_SUPERSAMPLE} in --mode pixel, 1 in --mode point (the viewer's frame)",
           lo=1, hi=16, metavar="S"),
    Option("tau", float, "A bake with --vary view, --mode pixel: the tolerance of the correction of the baked "
           "cosine to the face's (0: none).", default=0.1, lo=0.0, hi=100.0),
    *DISPLAY,   # wavlight.display: the PNG frames' and the animations' exposure and tone curve
)}

# ----------------------------------------------------------------------------- the viewer
VIEWER = {o.key: o for o in (
    Option("maps", str, "A map to choose from in the page: a file or data:NAME, a map of wavlight.data "
           "(repeatable; the baked map is always the first).",
           default=(), default_doc="the baked map alone", flag_name="--env", metavar="FILE",
           repeatable=True),
    replace(BACKGROUND, default="bilinear",
            help=BACKGROUND.help + " A bake that varies the lighting or the view (an object bake shows its static "
            "image's)."),
    Option("port", int, "The port on 127.0.0.1 (0: a free one).", default=0, lo=0, hi=65535),
    Option("scene", str, "The scene the bake was made from, where it is not at the path the bake recorded (converge; "
           "a bake with --vary object or --vary view needs it for every frame).",
           default_doc="the path the bake recorded", metavar="FILE"),
    Option("no_browser", bool, "Print the URL only; do not open the system browser.", default=False,
           negatable=False),
)}

#: the settings of each command
COMMANDS = {"bake": BAKE, "frame": FRAME, "view": VIEWER}


def options_table(command: str, keywords: bool = False, keys=None) -> str:
    """The markdown table of a command's settings (docs/cli.md, docs/relight.md), or of those
    among ``keys``: flag, with ``keywords`` the library's keyword, values, default, meaning."""
    records = COMMANDS[command]
    chosen = records.values() if keys is None else [records[k] for k in keys]
    return markdown_table(chosen, scene_keys=keywords, key_head="keyword")
