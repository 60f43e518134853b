"""The ``wavlight frame`` command that reproduces a viewer's picture (:func:`frame_command`), made
from the page's sanitised state (:func:`wavlight.relight.viewstate.sanitise`) and the flags'
records (:data:`wavlight.relight.settings.FRAME`), so that the page can offer it to copy.

What it holds, per factor the bake varies: a lighting bake's rotation (``--rotate-y``), map
(``--env``: the file the viewer was given, or the name of a map sent from the page: its temporary
copy is removed when the viewer stops, so the command names the file as the page named it, to be
given as a path on the machine that has it), terms K and background filter; an object bake's
translation and rotation (``--translate``, ``--rotate``: the page's rotation about +Y composed
with the object's own, :meth:`ObjectFrames.rotate_of`) and its samples per pixel; a view bake's
eye (``--eye``: :func:`orbit_eye` of the azimuth, elevation and distance about the scene camera's
target), ``--mode point`` (the viewer's approximate frame) and background filter; always the
exposure and the tone curve (``--exposure``, ``--tonemap``) and ``--scene`` where the viewer was
given one. With ``spp`` (the samples a converged picture reached) the command is the unbiased
frame instead (``--spp N --seed 0``): the same estimator with as many samples as the page's
running mean (whose passes had seeds 0, 1, 2, ...), so the same picture within its noise, not
the same samples. The page's background hidden is ``--background none`` (frames whose camera
samples that miss contribute 0).
"""
from __future__ import annotations

import shlex

from .settings import FRAME, OBJECT_FRAME_SPP

#: the output the command writes (a PNG: the exposure and tone curve apply)
OUTPUT = "frame.png"


def _number(x) -> str:
    """A float as the shortest text that reads back as the same float."""
    x = float(x)
    return str(int(x)) if x.is_integer() and abs(x) < 1e15 else repr(x)


def frame_args(frames, state, bake_path, env_file=None, scene=None, background=None, spp=None) -> list:
    """The arguments (after ``wavlight``) of ``wavlight frame`` for the page's sanitised
    ``state`` of ``frames`` (:func:`wavlight.relight.frames.frames_for`'s): ``bake_path`` the bake
    file, ``env_file`` the ``--env`` of the state's map (None: the baked map), ``scene`` the
    ``--scene`` given to the viewer (None: the path the bake recorded), ``background`` what
    misses see (a lighting or a view bake's: its filter, or none with the background hidden),
    ``spp`` the samples per pixel of a converged picture (None: the frame the viewer draws at
    rest)."""
    args = ["frame", str(bake_path), "-o", OUTPUT]

    def flag(key, *values):
        args.extend([FRAME[key].flag, *(v if isinstance(v, str) else _number(v) for v in values)])

    if frames.factor == "lighting":
        flag("rotate_y", state["rotate_y"])
        if env_file is not None:
            flag("env", str(env_file))
        if spp is None:
            flag("terms", int(state["terms"]))
    elif frames.factor == "object":
        translate, rotate = frames.placement(state)
        flag("translate", *translate)
        flag("rotate", *rotate)
        spp = OBJECT_FRAME_SPP if spp is None else spp
    else:
        eye = frames.camera(state)[0]
        flag("eye", *(float(x) for x in eye))
        if spp is None:
            flag("mode", "point")
    if spp is not None:
        flag("spp", int(spp))
        flag("seed", 0)
    if background is not None and "background" in frames.flags:
        flag("background", background)
    flag("exposure", state["exposure"])
    flag("tonemap", state["tonemap"])
    if scene is not None:
        flag("scene", str(scene))
    return args


def frame_command(frames, state, bake_path, env_file=None, scene=None, background=None, spp=None) -> str:
    """:func:`frame_args` as one line of shell (``wavlight frame ...``, each argument quoted where
    it needs it)."""
    return shlex.join(["wavlight", *frame_args(frames, state, bake_path, env_file, scene, background, spp)])
