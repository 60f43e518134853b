"""Batch experiments: scenes x strategies x budgets x repetitions, measured against a reference.

    results = wavlight.experiment.run_experiment("experiments/example.toml", "out/example")

or ``wavlight experiment experiments/example.toml -o out/example``.

The experiment file (TOML; relative paths are relative to the experiment file)::

    [experiment]
    name = "example"          # default: the file's stem
    size = [64, 48]           # width, height for every scene (default: each scene's own)
    threads = 2               # render threads (default: two per core, as render_full)
    pilot_spp = 4             # time budgets: first pilot renders at pilot_spp and 4 x pilot_spp

    [reference]               # for scenes without a reference file
    strategy = "mis"          # default "mis"
    spp = 1024                # default 1024, at least 2 (its stderr is needed)
    seed = 1000003            # default 1000003; not one of the repetitions' seeds 0..R-1
                              # (rendered with independent samples whatever the scene says:
                              # its standard error, subtracted from the metrics, is exact then)

    [[scenes]]
    path = "../scenes/default.toml"
    name = "default"          # default: the file's stem; names the output folders
    size = [64, 48]           # overrides [experiment].size for this scene
    reference = "ref.exr"     # optional: a reference image instead of rendering one
    reference_stderr = "ref_se.exr"  # optional: its per-pixel standard error

    [[strategies]]
    id = "wavelet"            # uniform | cosine | bsdf | light | mis | wavelet | ...,
                              # or a Mitsuba peer: mitsuba:mis | mitsuba:mis_comp | mitsuba:light | mitsuba:bsdf
    label = "wavelet-p5"      # default: the id; names the output folders and chart lines
    wavelet_levels = 5        # optional strategy options (as --wavelet-levels, --light-levels,
    light_levels = 9          # --wavelet-candidates, --wavelet-slots): wavelet_levels,
    wavelet_candidates = 16   # wavelet_candidates and wavelet_slots (2 or 4) for wavelet only,
                              # light_levels for light, mis, mis_comp, wavelet and
                              # sir (OPTION_STRATEGIES); given to another strategy, an option is
                              # an error, not silently ignored
    sampler = "stratified"    # optional: independent (default) | stratified (as --sampler)

    [budgets]
    spp = [4, 16, 64]         # equal-spp budgets
    seconds = [0.5, 2.0]      # equal-time budgets: total seconds (setup + sampling) per render
    repetitions = 3           # seeds 0 .. repetitions-1 (default 3)

At least one of ``spp`` and ``seconds`` is required. Errors name the file and the key
(``exp.toml: [budgets].spp: must be a list of integers >= 1, got [0]``) and raise
:class:`wavlight.errors.WavlightError`.

Decisions:

- **Timing.** Every run records ``setup_seconds`` (precomputation: ray-tracing
  structure, light tree, product tables, kernel set-up) and ``render_seconds``
  (sampling), from :func:`wavlight.render_full`; ``total_seconds`` is their sum and is
  the x axis of the error-versus-time charts. Scene loading is not timed (once per
  scene). Kernel compilation is paid once per process, not per render: before its first
  timed render every (scene, strategy) gets an untimed 8x8, 1 spp warm-up render.
- **Time budgets.** For a budget of T seconds the spp is chosen from pilot renders
  (seed 999999, full size) of that scene and strategy: at ``pilot_spp`` and 4 x
  ``pilot_spp``, then (when it is larger still) at the spp that this first fit gives for
  the largest T, as short renders are dominated by timing noise. Sampling time is
  fitted as a + b spp by least squares through the pilots, setup is their mean, and
  spp = max(1, round((T - setup - a) / b)). The pilot is cached in
  ``DIR/pilot/<scene>/<strategy>.json`` so that a resumed experiment keeps the same spp.
  The charts use the measured total time of each run, not T. A budget that even 1 spp
  exceeds (a run at 1 spp took longer than T, e.g. T below the setup time) is kept at
  1 spp and marked ``budget_exceeded`` in ``results.json`` and the CSV files: a run whose
  own time exceeded T, a group whose mean time did (only then is it warned about, once per
  scene, strategy and budget, naming T and the time 1 spp took).
- **Reference.** Rendered once per scene with ``[reference]`` and cached as
  ``DIR/reference/<scene>.exr`` with its standard error ``<scene>.stderr.exr`` and a
  ``<scene>.json`` (settings, hash, timings); re-rendered when its settings or the scene
  file change. With a reference file and no stderr file, the metrics are not corrected
  for the reference's noise (``results.json`` says so per scene).
- **Runs and resume.** Each run writes its image ``DIR/runs/<scene>/<strategy>/<budget>/
  <seed>.exr`` (float32, so metrics can be recomputed exactly) and then its record
  ``<seed>.json`` (settings, timings, render stats, hash). The hash covers the scene
  file's bytes, size, strategy id and options, spp, seed, ``threads`` (timings depend on
  it) and wavlight's version (not files the scene refers to). A run whose record exists with the same hash and whose
  image reads as a finite image of the right size is not rendered again (``resume=False``
  renders everything again, references and pilots included); an image that is missing,
  cannot be read (truncated, corrupt), has another size or NaN / Inf pixels is rendered
  again, with a one-line warning. Both files are written atomically, the record last.
- **Mitsuba peers.** ``id = "mitsuba:<mis|mis_comp|light|bsdf>"`` renders with
  :func:`wavlight.peers.render_mitsuba` (same scene, size, spp, seed; its setup includes
  scene conversion and a JIT warm-up; ``threads`` does not apply). The default label is
  the id with ``-`` for ``:`` (``mitsuba-mis``); wavlight options are rejected. Without
  Mitsuba 3 (llvm_ad_rgb) the spec is rejected (``[[strategies]][i].id: 'mitsuba:mis'
  needs Mitsuba 3 ...``), not skipped. Warm-up, pilots, time budgets, resume and metrics
  are as for wavlight strategies; run hashes also cover Mitsuba's version.
- **Parallel runs.** ``workers=N`` (N > 1) renders the runs in a process pool of the
  ``spawn`` context (OpenCL contexts must not be forked); ``dask_address="tcp://H:P"``
  submits them to an existing dask.distributed scheduler. References, pilots and resume
  checks happen first, in this process; each run to render is then the pure function
  :func:`run_task` (scene file + its hash, size, strategy, options, spp, seed, threads)
  -> image and stats, and this process writes its image and record as it arrives, so
  workers need only read the scene files (at the same paths, checked by hash) and a
  resumed experiment keeps what finished. Images and metrics are identical to in-process
  runs (renders are deterministic for a seed); timings are not: concurrent renders
  contend for the cores (set ``threads`` to cores / N), and time budgets' spp come from
  pilots measured alone. Each worker process warms up each (scene, strategy) untimed
  before its first run. ``results.json`` records ``executor``.
- **Metrics** (:mod:`wavlight.metrics`) are computed after the runs, from the saved
  images and the reference, so they always match the current reference: per run mse,
  relmse (both corrected by the reference's variance when its stderr is known),
  max_error, max_rel_error; per (scene, strategy, budget) the mean, sd, min and max of
  those over the repetitions, the mean per-pixel variance over the repetitions
  (``variance``, ``rel_variance``), ``bias`` with ``bias_se``, and relMSE x time
  (``relmse_x_seconds``, lower is better at any budget). ``bias`` and ``bias_se`` are
  :func:`wavlight.metrics.bias` of the per-pixel channel mean (:func:`_bias`): the channels
  share a pixel's samples and their noise correlates (about 0.95), so pooling them as
  independent values would understate the SE (by up to sqrt(3)); the reference's SE of
  a channel mean is the mean of its channels' SEs (exact for perfect correlation, an
  upper bound otherwise).
- **Outputs** in DIR: ``results.json`` (everything), ``results.csv`` (one row per scene,
  strategy and budget), ``runs.csv`` (one row per run), ``spec.toml`` (a copy of the
  experiment file), and in ``charts/`` (PNG and SVG, matplotlib without pyplot, so no
  global backend is touched): ``<scene>-spp`` and ``<scene>-time``, relMSE versus spp
  and versus total seconds, log-log, one line per strategy through the mean over the
  repetitions (points joined in spp order; x on the time chart is the mean total time), with a band from the smallest to the largest repetition (min-max, not a
  standard deviation: with 2-3 repetitions that is the honest spread); non-positive
  values (possible after the reference correction) are not drawn. ``error-maps``: per
  scene the reference and, per strategy, the false-colour map of
  :func:`wavlight.metrics.error_map` of repetition 0 at equal time, on a fixed scale
  0..1 (values above 1 saturate). Equal time means the largest ``seconds`` budget when
  there is one; otherwise T = the largest mean total time that every strategy reaches,
  and each strategy shows its budget closest to T (in log time).
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import re
import tempfile
import time
import tomllib
import warnings
from dataclasses import dataclass, field

import numpy as np

from . import metrics
from .errors import SanitisedInputWarning, WavlightError
from .sampler import SAMPLERS
from .scene import MAX_SIDE, MAX_SPP, STRATEGIES, WAVELET_SLOTS
from .scene import _Table as SceneTable

PILOT_SEED = 999_999
PEER_PREFIX = "mitsuba:"
WARMUP_SIZE = 8
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")
#: [[strategies]] options -> the wavlight strategies that take them (as render_full passes them on:
#: wavelet_levels is the product depth of wavelet; light_levels the depth of a light tree, which
#: uniform, cosine, bsdf and structured do not build; the sampler draws every strategy's numbers)
OPTION_STRATEGIES = {"wavelet_levels": ("wavelet",), "wavelet_candidates": ("wavelet",), "wavelet_slots": ("wavelet",),
                     "light_levels": ("light", "mis", "mis_comp", "wavelet", "sir"),
                     "sampler": STRATEGIES}


# ----------------------------------------------------------------------------- the experiment file
@dataclass
class SceneSpec:
    name: str
    path: str
    size: tuple | None = None
    reference: str | None = None
    reference_stderr: str | None = None


@dataclass
class StrategySpec:
    label: str
    id: str
    options: dict = field(default_factory=dict)  # wavelet_levels, light_levels, sampler


@dataclass
class Budget:
    kind: str     # "spp" | "seconds"
    value: float

    @property
    def key(self):
        return f"spp{int(self.value)}" if self.kind == "spp" else f"{self.value:g}s"


@dataclass
class Spec:
    path: str
    name: str
    scenes: list
    strategies: list
    budgets: list
    repetitions: int
    reference: dict
    size: tuple | None = None
    threads: int | None = None
    pilot_spp: int = 4
    text: bytes = b""


class _Table(SceneTable):
    """One TOML table of the experiment file: the scene parser's table (errors name the file
    and the key, unknown keys rejected) with the experiment's own value kinds."""

    def get(self, key, kind, default=None, required=False, lo=None):
        self.used.add(key)
        if key not in self.data:
            if required:
                self.fail(key, "is required")
            return default
        v = self.data[key]
        is_int = lambda x: isinstance(x, int) and not isinstance(x, bool)
        is_num = lambda x: (isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x))
        if kind == "int":
            if not is_int(v) or (lo is not None and v < lo):
                self.fail(key, f"must be an integer{f' >= {lo}' if lo is not None else ''}, got {v!r}")
        elif kind == "float":
            if not is_num(v) or (lo is not None and v <= lo):
                self.fail(key, f"must be a number{f' > {lo}' if lo is not None else ''}, got {v!r}")
            v = float(v)
        elif kind == "str":
            if not isinstance(v, str) or not v:
                self.fail(key, f"must be a non-empty string, got {v!r}")
        elif kind == "ints":
            if not isinstance(v, list) or not v or not all(is_int(x) and x >= lo for x in v):
                self.fail(key, f"must be a non-empty list of integers >= {lo}, got {v!r}")
            if len(set(v)) != len(v):
                self.fail(key, f"has repeated values: {v!r}")
        elif kind == "floats":
            if not isinstance(v, list) or not v or not all(is_num(x) and x > lo for x in v):
                self.fail(key, f"must be a non-empty list of numbers > {lo}, got {v!r}")
            v = [float(x) for x in v]
            if len(set(v)) != len(v):
                self.fail(key, f"has repeated values: {v!r}")
        elif kind == "size":
            if (not isinstance(v, list) or len(v) != 2
                    or not all(is_int(x) and 1 <= x <= MAX_SIDE for x in v)):
                self.fail(key, f"must be [width, height], integers 1..{MAX_SIDE}, got {v!r}")
            v = (int(v[0]), int(v[1]))
        return v

    def name_key(self, key, default):
        v = self.get(key, "str", default)
        if not _NAME.match(v):
            self.fail(key, f"must be letters, digits, '_', '.', '+', '-' (it names folders), got {v!r}")
        return v


def load_spec(path) -> Spec:
    """Read and validate an experiment file (see the module docstring for its format)."""
    path = str(path)
    if not os.path.isfile(path):
        raise WavlightError(f"{path}: no such file")
    try:
        with open(path, "rb") as fh:
            text = fh.read()
        doc = tomllib.loads(text.decode("utf-8"))
    except tomllib.TOMLDecodeError as e:
        raise WavlightError(f"{path}: malformed TOML: {e}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise WavlightError(f"{path}: cannot read: {e}") from None
    base = os.path.dirname(os.path.abspath(path))
    unknown = sorted(set(doc) - {"experiment", "reference", "scenes", "strategies", "budgets"})
    if unknown:
        raise WavlightError(f"{path}: {unknown[0]}: unknown table")

    e = _Table(path, "[experiment]", doc.get("experiment", {}))
    name = e.name_key("name", os.path.splitext(os.path.basename(path))[0])
    size = e.get("size", "size")
    threads = e.get("threads", "int", lo=1)
    pilot_spp = e.get("pilot_spp", "int", 4, lo=1)
    e.done()

    r = _Table(path, "[reference]", doc.get("reference", {}))
    reference = {"strategy": r.get("strategy", "str", "mis"), "spp": r.get("spp", "int", 1024, lo=2),
                 "seed": r.get("seed", "int", 1_000_003, lo=0)}
    if reference["strategy"] not in STRATEGIES:
        r.fail("strategy", f"unknown strategy {reference['strategy']!r} ({' | '.join(STRATEGIES)})")
    if reference["spp"] > MAX_SPP:
        r.fail("spp", f"must be at most {MAX_SPP}, got {reference['spp']}")
    r.done()

    def rel(p):
        return os.path.normpath(os.path.join(base, p))

    scenes_doc = doc.get("scenes")
    if not isinstance(scenes_doc, list) or not scenes_doc:
        raise WavlightError(f"{path}: [[scenes]]: at least one [[scenes]] table with a path is required")
    scenes = []
    for i, s in enumerate(scenes_doc):
        t = _Table(path, f"[[scenes]][{i}]", s)
        p = t.get("path", "str", required=True)
        full = rel(p)
        if not os.path.isfile(full):
            t.fail("path", f"no such file {full}")
        sname = t.name_key("name", os.path.splitext(os.path.basename(p))[0])
        if any(x.name == sname for x in scenes):
            t.fail("name", f"scene name {sname!r} is used twice (give each a distinct name)")
        ssize = t.get("size", "size")
        ref, ref_se = t.get("reference", "str"), t.get("reference_stderr", "str")
        if ref is not None:
            ref = rel(ref)
            if not os.path.isfile(ref):
                t.fail("reference", f"no such file {ref}")
            _check_image(t, "reference", ref)
        if ref_se is not None:
            if ref is None:
                t.fail("reference_stderr", "needs reference")
            ref_se = rel(ref_se)
            if not os.path.isfile(ref_se):
                t.fail("reference_stderr", f"no such file {ref_se}")
            _check_image(t, "reference_stderr", ref_se)
        t.done()
        scenes.append(SceneSpec(sname, full, ssize, ref, ref_se))

    strat_doc = doc.get("strategies")
    if not isinstance(strat_doc, list) or not strat_doc:
        raise WavlightError(f"{path}: [[strategies]]: at least one [[strategies]] table with an id is required")
    strats = []
    for i, s in enumerate(strat_doc):
        t = _Table(path, f"[[strategies]][{i}]", s)
        sid = t.get("id", "str", required=True)
        if sid.startswith(PEER_PREFIX):
            from . import peers
            if sid[len(PEER_PREFIX):] not in peers.STRATEGIES:
                t.fail("id", f"unknown Mitsuba strategy {sid!r} "
                             f"({' | '.join(PEER_PREFIX + k for k in peers.STRATEGIES)})")
            if not peers.available():
                t.fail("id", f"{sid!r} needs Mitsuba 3 with its llvm_ad_rgb variant, which is not available "
                             "(pip install 'wavlight[peers]'; Debian: libllvm19)")
        elif sid not in STRATEGIES:
            t.fail("id", f"unknown strategy {sid!r} ({' | '.join(STRATEGIES)} | "
                         f"mitsuba:mis | mitsuba:mis_comp | mitsuba:light | mitsuba:bsdf)")
        label = t.name_key("label", sid.replace(":", "-"))
        if any(x.label == label for x in strats):
            t.fail("label", f"label {label!r} is used twice (give each strategy a distinct label)")
        options = {}
        wl = t.get("wavelet_levels", "int", lo=0)
        if wl is not None:
            if wl > 11:
                t.fail("wavelet_levels", f"must be at most 11, got {wl}")
            options["wavelet_levels"] = wl
        wc = t.get("wavelet_candidates", "int", lo=0)
        if wc is not None:
            if wc == 1 or wc > 64:
                t.fail("wavelet_candidates", f"must be 0 (the MIS pair) or 2..64, got {wc}")
            options["wavelet_candidates"] = wc
        ws = t.get("wavelet_slots", "int", lo=2)
        if ws is not None:
            if ws not in WAVELET_SLOTS:
                t.fail("wavelet_slots", f"must be 2 or 4, got {ws}")
            options["wavelet_slots"] = ws
        ll = t.get("light_levels", "int", lo=1)
        if ll is not None:
            if ll > 11:
                t.fail("light_levels", f"must be at most 11, got {ll}")
            options["light_levels"] = ll
        smp = t.get("sampler", "str")
        if smp is not None:
            if smp not in SAMPLERS:
                t.fail("sampler", f"unknown sampler {smp!r} ({' | '.join(SAMPLERS)})")
            options["sampler"] = smp
        if options and sid.startswith(PEER_PREFIX):
            t.fail(sorted(options)[0], f"is a wavlight option; {sid!r} takes none")
        for opt in options:
            if sid not in OPTION_STRATEGIES[opt]:
                t.fail(opt, f"does not apply to {sid!r} (only to {' | '.join(OPTION_STRATEGIES[opt])})")
        t.done()
        strats.append(StrategySpec(label, sid, options))

    b = _Table(path, "[budgets]", doc.get("budgets", {}))
    spps = b.get("spp", "ints", lo=1)
    seconds = b.get("seconds", "floats", lo=0)
    repetitions = b.get("repetitions", "int", 3, lo=1)
    if spps is None and seconds is None:
        b.fail("spp", "give spp = [...] and/or seconds = [...]")
    if spps is not None and max(spps) > MAX_SPP:
        b.fail("spp", f"must be at most {MAX_SPP}, got {max(spps)}")
    if reference["seed"] < repetitions:   # the reference would repeat a run's samples exactly
        b.fail("repetitions", f"the runs' seeds 0..{repetitions - 1} include the reference's seed "
               f"{reference['seed']} ([reference].seed)")
    b.done()
    budgets = [Budget("spp", v) for v in sorted(spps or [])] + [Budget("seconds", v) for v in sorted(seconds or [])]
    keys = [x.key for x in budgets]
    if len(set(keys)) != len(keys):
        b.fail("seconds", f"values too close to tell apart in folder names: {keys}")
    return Spec(path, name, scenes, strats, budgets, repetitions, reference, size, threads, pilot_spp, text)


# ----------------------------------------------------------------------------- files
def _hash(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()[:16]


def _publish(tmp, path):
    """Give a finished temporary file the usual mode (mkstemp makes it private), rename it."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    os.replace(tmp, path)


def _write_text(path, text):
    """Atomically: a temporary file in the same folder renamed over the target."""
    folder = os.path.dirname(path)
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".wavlight-", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "w", newline="") as fh:
            fh.write(text)
        _publish(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _json_safe(obj):
    """obj with every non-finite float as None (JSON has no NaN or Infinity)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def _check_image(t, key, path):
    """A spec error, before anything is written, if OpenImageIO cannot open the image."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        t.fail(key, f"cannot read {path} as an image ({oiio.geterror().strip() or 'unknown format'})")
    inp.close()


def _write_json(path, obj):
    _write_text(path, json.dumps(_json_safe(obj), indent=1, allow_nan=False) + "\n")


def _read_json(path):
    try:
        with open(path) as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return None


def _read_image(path):
    from .envmap import read_image
    return read_image(path)


def _image_problem(path, width, height):
    """Why a finished run's image cannot be reused (None: it can): missing, unreadable (a
    truncated or corrupt file), another size, or NaN / Inf pixels."""
    if not os.path.isfile(path):
        return "is missing"
    try:
        image = _read_image(path)
    except (WavlightError, ValueError, OSError):
        return "cannot be read"
    if image.shape != (height, width, 3):
        return f"has shape {image.shape}, not ({height}, {width}, 3)"
    bad = int((~np.isfinite(image)).any(axis=-1).sum())
    return f"has {bad} NaN or Inf pixel(s)" if bad else None


def _save_image(path, image):
    from .imageio import save_image
    os.makedirs(os.path.dirname(path), exist_ok=True)
    save_image(path, image)


# ----------------------------------------------------------------------------- running
class _Runner:
    def __init__(self, spec: Spec, out_dir: str, progress, resume: bool):
        import wavlight

        self.wavlight = wavlight
        self.spec, self.out, self.progress, self.resume = spec, out_dir, progress, resume
        self.scenes, self.scene_hash, self.size = {}, {}, {}
        for s in spec.scenes:
            scene = wavlight.load_scene(s.path)
            if scene.environment.is_black:   # as `wavlight render`: every image and error would be 0
                raise WavlightError(f"{s.path}: [environment]: the environment is black everywhere; "
                                    "relative errors against a black reference are undefined")
            self.scenes[s.name] = scene
            try:
                with open(s.path, "rb") as fh:
                    self.scene_hash[s.name] = hashlib.sha256(fh.read()).hexdigest()
            except OSError as e:
                raise WavlightError(f"{s.path}: cannot read ({e.strerror})") from None
            self.size[s.name] = s.size or spec.size or (scene.width, scene.height)
        self.warm = set()
        self.done = 0
        self.rendered = self.reused = 0
        n_ref = sum(1 for s in spec.scenes if s.reference is None)
        n_pilot = len(spec.scenes) * len(spec.strategies) if any(b.kind == "seconds" for b in spec.budgets) else 0
        self.total = n_ref + n_pilot + len(spec.scenes) * len(spec.strategies) * len(spec.budgets) * spec.repetitions

    def step(self, what):
        self.done += 1
        if self.progress:
            self.progress(self.done, self.total, what)

    def render(self, scene_name, strategy_id, options, spp, seed):
        w, h = self.size[scene_name]
        return _render(self.scenes[scene_name], strategy_id, options, spp, w, h, seed, self.spec.threads)

    def warm_up(self, scene_name, strategy_id, options):
        key = (scene_name, strategy_id, tuple(sorted(options.items())))
        if key not in self.warm:
            _render(self.scenes[scene_name], strategy_id, options, 1, WARMUP_SIZE, WARMUP_SIZE, 0,
                    self.spec.threads)
            self.warm.add(key)

    def base_key(self, scene_name):
        w, h = self.size[scene_name]
        return {"scene": self.scene_hash[scene_name], "width": w, "height": h,
                "wavlight": self.wavlight.__version__, "threads": self.spec.threads}   # threads: timings

    @staticmethod
    def strategy_key(st: StrategySpec):
        key = {"strategy": st.id, "options": st.options}
        if st.id.startswith(PEER_PREFIX):
            import mitsuba
            key["mitsuba"] = mitsuba.__version__
        return key

    # -- the reference
    def reference(self, s: SceneSpec):
        """(image, stderr or None, info) for one scene."""
        w, h = self.size[s.name]
        if s.reference is not None:
            image = _read_image(s.reference)
            if image.shape[:2] != (h, w):
                raise WavlightError(f"{s.reference}: reference image is {image.shape[1]}x{image.shape[0]}, "
                                    f"the experiment renders {s.name} at {w}x{h}")
            bad = int((~np.isfinite(image)).any(axis=-1).sum())
            if bad:   # every metric would be NaN
                raise WavlightError(f"{s.reference}: reference image has {bad} NaN or Inf pixel(s)")
            stderr = None
            if s.reference_stderr is not None:
                stderr = _read_image(s.reference_stderr)
                if stderr.shape != image.shape:
                    raise WavlightError(f"{s.reference_stderr}: stderr image is {stderr.shape[1]}x"
                                        f"{stderr.shape[0]}, the reference is {w}x{h}")
                if not np.all(np.isfinite(stderr)) or np.any(stderr < 0):
                    raise WavlightError(f"{s.reference_stderr}: stderr must be finite and non-negative")
            return image, stderr, {"file": s.reference, "stderr_file": s.reference_stderr,
                                   "corrected": stderr is not None}
        ref = self.spec.reference
        folder = os.path.join(self.out, "reference")
        img_path = os.path.join(folder, f"{s.name}.exr")
        se_path = os.path.join(folder, f"{s.name}.stderr.exr")
        rec_path = os.path.join(folder, f"{s.name}.json")
        key = _hash({**self.base_key(s.name), **ref, "sampler": "independent"})
        rec = _read_json(rec_path) if self.resume else None
        if rec and rec.get("hash") == key and os.path.isfile(img_path) and os.path.isfile(se_path):
            self.step(f"{s.name}: reference (done before)")
            return _read_image(img_path), _read_image(se_path), rec
        # always independent samples: the per-pixel standard error subtracted from every metric
        # is exact for them, an upper bound (about 2x the variance, measured) for stratified
        r = self.render(s.name, ref["strategy"], {"sampler": "independent"}, ref["spp"], ref["seed"])
        _save_image(img_path, r.image)
        _save_image(se_path, r.stderr)
        rec = {"hash": key, "scene": s.name, **ref, "width": w, "height": h,
               "image": os.path.relpath(img_path, self.out), "stderr": os.path.relpath(se_path, self.out),
               "setup_seconds": r.stats["setup_seconds"], "render_seconds": r.stats["render_seconds"],
               "corrected": True}
        _write_json(rec_path, rec)
        self.step(f"{s.name}: reference, {ref['strategy']} {ref['spp']} spp")
        return r.image, r.stderr, rec

    # -- time budgets
    def pilot(self, s: SceneSpec, st: StrategySpec):
        """Fit of this scene and strategy's cost: setup seconds and sampling a + b spp."""
        path = os.path.join(self.out, "pilot", s.name, f"{st.label}.json")
        p1, p2 = self.spec.pilot_spp, 4 * self.spec.pilot_spp
        longest = max(b.value for b in self.spec.budgets if b.kind == "seconds")
        key = _hash({**self.base_key(s.name), **self.strategy_key(st), "pilot": [p1, p2], "longest": longest})
        rec = _read_json(path) if self.resume else None
        if rec and rec.get("hash") == key:
            self.step(f"{s.name}/{st.label}: pilot (done before)")
            return rec
        self.warm_up(s.name, st.id, st.options)
        points = []

        def measure(spp):
            r = self.render(s.name, st.id, st.options, spp, PILOT_SEED)
            points.append({"spp": spp, "setup_seconds": r.stats["setup_seconds"],
                           "render_seconds": r.stats["render_seconds"]})

        def fit():
            x = np.array([p["spp"] for p in points], float)
            y = np.array([p["render_seconds"] for p in points], float)
            b, a = np.polyfit(x, y, 1)
            if b <= 0:
                b, a = max(y[-1], 1e-6) / x[-1], 0.0
            return {"setup_seconds": float(np.mean([p["setup_seconds"] for p in points])),
                    "render_a": max(float(a), 0.0), "render_b": float(b)}

        measure(p1)
        measure(p2)
        # A third pilot near the largest budget's spp: short pilots are dominated by noise.
        p3 = self.spp_for(fit(), longest)
        if p3 > 2 * p2:
            measure(p3)
        model = fit()
        rec = {"hash": key, "scene": s.name, "strategy": st.label, "points": points, **model}
        _write_json(path, rec)
        self.step(f"{s.name}/{st.label}: pilot")
        return rec

    @staticmethod
    def spp_for(pilot, seconds):
        spp = (seconds - pilot["setup_seconds"] - pilot["render_a"]) / pilot["render_b"]
        return int(min(max(1, round(spp)), MAX_SPP))

    # -- one run
    def prepare(self, s: SceneSpec, st: StrategySpec, budget: Budget, spp: int, seed: int):
        """(record, None) for a run finished before (counted as reused), else (None, job)."""
        folder = os.path.join(self.out, "runs", s.name, st.label, budget.key)
        img_path = os.path.join(folder, f"{seed}.exr")
        rec_path = os.path.join(folder, f"{seed}.json")
        what = f"{s.name}/{st.label}/{budget.key}/seed {seed}"
        key = _hash({**self.base_key(s.name), **self.strategy_key(st), "spp": spp, "seed": seed})
        rec = _read_json(rec_path) if self.resume else None
        if rec and rec.get("hash") == key:
            problem = _image_problem(img_path, *self.size[s.name])
            if problem is None:
                self.reused += 1
                self.step(what + " (done before)")
                return rec, None
            warnings.warn(f"{img_path}: the run's image {problem}: rendering {what} again", stacklevel=4)
        job = {"s": s, "st": st, "budget": budget, "spp": spp, "seed": seed, "key": key, "what": what,
               "img_path": img_path, "rec_path": rec_path}
        return None, job

    def task(self, job) -> dict:
        """The job as the plain arguments of :func:`run_task` (picklable, no paths to write)."""
        s, st = job["s"], job["st"]
        return {"scene_path": s.path, "scene_hash": self.scene_hash[s.name], "size": tuple(self.size[s.name]),
                "strategy": st.id, "options": dict(st.options), "spp": job["spp"], "seed": job["seed"],
                "threads": self.spec.threads}

    def render_local(self, job):
        s, st = job["s"], job["st"]
        self.warm_up(s.name, st.id, st.options)
        r = self.render(s.name, st.id, st.options, job["spp"], job["seed"])
        return {"image": r.image, "stats": r.stats}

    def finish(self, job, result):
        """Write a rendered run's image, then its record."""
        s, st, budget = job["s"], job["st"], job["budget"]
        _save_image(job["img_path"], result["image"])
        stats = result["stats"]
        rec = {"hash": job["key"], "scene": s.name, "strategy": st.label, "strategy_id": st.id,
               "options": st.options, "budget": budget.key, "budget_kind": budget.kind,
               "target_seconds": budget.value if budget.kind == "seconds" else None,
               "spp": job["spp"], "seed": job["seed"], "width": stats["width"], "height": stats["height"],
               "setup_seconds": stats["setup_seconds"], "render_seconds": stats["render_seconds"],
               "total_seconds": round(stats["setup_seconds"] + stats["render_seconds"], 4),
               "image": os.path.relpath(job["img_path"], self.out), "stats": stats,
               "finished": time.strftime("%Y-%m-%dT%H:%M:%S")}
        _write_json(job["rec_path"], rec)
        self.rendered += 1
        self.step(job["what"])
        return rec

    def run(self, s: SceneSpec, st: StrategySpec, budget: Budget, spp: int, seed: int):
        rec, job = self.prepare(s, st, budget, spp, seed)
        return rec if job is None else self.finish(job, self.render_local(job))


def _render(scene, strategy_id, options, spp, width, height, seed, threads):
    """One render by wavlight (``wavlight.render_full``) or by a peer (``mitsuba:<strategy>``)."""
    if strategy_id.startswith(PEER_PREFIX):
        from . import peers
        return peers.render_mitsuba(scene, strategy_id[len(PEER_PREFIX):], spp=spp, width=width, height=height,
                                    seed=seed)
    import wavlight
    return wavlight.render_full(scene, spp=spp, strategy=strategy_id, width=width, height=height, seed=seed,
                                threads=threads, **options)


_WORKER = {"scenes": {}, "warm": set()}  # per process: loaded scenes, (scene, strategy) pairs warmed up


def run_task(task: dict) -> dict:
    """One run, as a pure function for worker processes: ``task`` (from ``_Runner.task``: scene
    file and its hash, size, strategy id and options, spp, seed, threads) -> ``{"image", "stats"}``.

    The scene is loaded (untimed) once per process and checked against the hash of the file the
    experiment read; each (scene, strategy) gets the untimed 8x8 warm-up before its first run in
    this process, as in-process runs do."""
    import wavlight
    path, digest = task["scene_path"], task["scene_hash"]
    scene = _WORKER["scenes"].get((path, digest))
    if scene is None:
        with open(path, "rb") as fh:
            if hashlib.sha256(fh.read()).hexdigest() != digest:
                raise WavlightError(f"{path}: this worker sees a different scene file than the experiment read")
        with warnings.catch_warnings():   # the experiment's own process warned when it read the scene
            warnings.simplefilter("ignore", SanitisedInputWarning)
            scene = _WORKER["scenes"][(path, digest)] = wavlight.load_scene(path)
    w, h = task["size"]
    strategy, options, threads = task["strategy"], task["options"], task["threads"]
    warm = (path, digest, strategy, tuple(sorted(options.items())))
    if warm not in _WORKER["warm"]:
        _render(scene, strategy, options, 1, WARMUP_SIZE, WARMUP_SIZE, 0, threads)
        _WORKER["warm"].add(warm)
    r = _render(scene, strategy, options, task["spp"], w, h, task["seed"], threads)
    return {"image": np.asarray(r.image, np.float32), "stats": r.stats}


_DASK_ADDRESS = re.compile(r"^(tcp|tls|ucx|ws|wss)://[^/\s]+:\d+/?$")


def _dask_client(address):
    """A dask.distributed client of the scheduler at ``address`` (tcp://HOST:PORT), or a one-line
    WavlightError: not installed, not an address, or no scheduler there within 20 s."""
    if not isinstance(address, str) or not _DASK_ADDRESS.match(address):
        raise WavlightError(f"dask {address!r}: expected a scheduler address tcp://HOST:PORT")
    try:
        from distributed import Client
    except ImportError:
        raise WavlightError(f"dask {address}: dask.distributed is not installed "
                            "(pip install 'wavlight[dask]')") from None
    try:
        return Client(address, timeout=20)
    except (OSError, TimeoutError, ValueError) as e:
        raise WavlightError(f"dask {address}: cannot connect to the scheduler ({e})") from None


def _execute(runner: _Runner, jobs, workers: int, dask_address):
    """Render ``jobs`` [(index, job)] -> {index: record}: in this process, in a spawn-context
    process pool, or on a dask.distributed scheduler. Records are written as runs finish."""
    out = {}
    if dask_address is None and workers == 1:
        for i, job in jobs:
            out[i] = runner.finish(job, runner.render_local(job))
        return out
    if not jobs:
        return out
    tasks = [runner.task(job) for _, job in jobs]
    if dask_address is not None:
        from distributed import as_completed
        client = _dask_client(dask_address)
        try:
            futures = client.map(run_task, tasks, pure=False)
            where = {f.key: n for n, f in enumerate(futures)}
            try:
                for f in as_completed(futures):
                    n = where[f.key]
                    out[jobs[n][0]] = runner.finish(jobs[n][1], f.result())
            except BaseException:
                client.cancel(futures)
                raise
        finally:
            client.close()
        return out
    import concurrent.futures as cf
    import multiprocessing
    pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"))
    try:
        futures = {pool.submit(run_task, t): n for n, t in enumerate(tasks)}
        for f in cf.as_completed(futures):
            n = futures[f]
            out[jobs[n][0]] = runner.finish(jobs[n][1], f.result())
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    return out


def _stat(values):
    v = [x for x in values if x is not None]
    if not v:
        return None, None, None, None
    a = np.asarray(v, np.float64)
    sd = float(a.std(ddof=1)) if len(a) > 1 else None
    return float(a.mean()), sd, float(a.min()), float(a.max())


def run_experiment(spec_path, out_dir, progress=None, resume=True, workers=1, dask_address=None) -> dict:
    """Run (or resume) an experiment; write results, charts and error maps to out_dir.

    ``progress(done, total, what)`` is called after each reference, pilot and run
    (including runs found finished). Returns the dict written to ``results.json``:
    ``groups`` (one per scene, strategy and budget), ``runs``, ``reference``,
    ``equal_time`` (the budget each strategy shows in the error maps), ``files``,
    ``rendered`` and ``reused`` (run counts of this call).
    """
    t_start = time.perf_counter()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise WavlightError(f"workers must be an integer >= 1, got {workers!r}")
    if not isinstance(out_dir, (str, os.PathLike)) or not str(out_dir):
        raise WavlightError(f"out_dir must be a folder path, got {out_dir!r}")
    if progress is not None and not callable(progress):
        raise WavlightError(f"progress must be a callable or None, got {progress!r}")
    if dask_address is not None and workers != 1:
        raise WavlightError("give workers or a dask scheduler address, not both")
    spec = load_spec(spec_path)
    if dask_address is not None:
        _dask_client(dask_address).close()   # fail before rendering references and pilots
    out_dir = str(out_dir)
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise WavlightError(f"{out_dir}: exists and is not a folder")
    runner = _Runner(spec, out_dir, progress, resume)   # loads and checks the scenes before out_dir exists
    try:
        os.makedirs(out_dir, exist_ok=True)
        _write_text(os.path.join(out_dir, "spec.toml"), spec.text.decode("utf-8"))
    except OSError as e:
        raise WavlightError(f"{out_dir}: cannot write ({e.strerror})") from None
    try:
        return _run(runner, t_start, workers, dask_address)
    except OSError as e:
        raise WavlightError(f"{e.filename or out_dir}: cannot write ({e.strerror})") from None


SUITES = ("stability",)


def run_suite(name, out_dir, progress=None, **options) -> tuple[dict, str]:
    """Run a built-in suite instead of an experiment file: (results dict, text table).

    ``stability``: :func:`wavlight.stability.run_stability` (``options`` go to it).
    """
    if name not in SUITES:
        raise WavlightError(f"unknown suite {name!r} ({' | '.join(SUITES)})")
    from . import stability
    results = stability.run_stability(out_dir, progress=progress, **options)
    return results, stability.format_table(results)


def _run(runner: _Runner, t_start, workers=1, dask_address=None):
    spec, out_dir = runner.spec, runner.out
    references = {}
    records, jobs = [], []
    # references and pilots here (they set the spp of time budgets), then the runs
    for s in spec.scenes:
        references[s.name] = runner.reference(s)
        for st in spec.strategies:
            pilot = runner.pilot(s, st) if any(b.kind == "seconds" for b in spec.budgets) else None
            for budget in spec.budgets:
                spp = int(budget.value) if budget.kind == "spp" else runner.spp_for(pilot, budget.value)
                for seed in range(spec.repetitions):
                    rec, job = runner.prepare(s, st, budget, spp, seed)
                    if job is not None:
                        jobs.append((len(records), job))
                    records.append(rec)
    for i, rec in _execute(runner, jobs, workers, dask_address).items():
        records[i] = rec

    # -- metrics, from the saved images
    runs, groups = [], []
    by_group = {}
    for rec in records:
        by_group.setdefault((rec["scene"], rec["strategy"], rec["budget"]), []).append(rec)
    for (scene, label, bkey), recs in by_group.items():
        ref, ref_se, _ = references[scene]
        images = np.stack([_read_image(os.path.join(out_dir, r["image"])) for r in recs])
        per = []
        for r, img in zip(recs, images):
            m = {"mse": metrics.mse(img, ref, ref_se), "relmse": metrics.relmse(img, ref, ref_se),
                 "max_error": metrics.max_error(img, ref), "max_rel_error": metrics.max_error(img, ref, relative=True)}
            row = {k: r[k] for k in ("scene", "strategy", "strategy_id", "budget", "budget_kind", "target_seconds",
                                     "spp", "seed", "setup_seconds", "render_seconds", "total_seconds", "image")}
            row.update(m)
            row["budget_exceeded"] = _budget_exceeded(r)
            per.append(row)
        runs.extend(per)
        g = {k: recs[0][k] for k in ("scene", "strategy", "strategy_id", "options", "budget", "budget_kind",
                                     "target_seconds", "spp")}
        g["repetitions"] = len(recs)
        for name in ("setup_seconds", "render_seconds"):
            g[name] = _stat([p[name] for p in per])[0]
        g["total_seconds"], g["total_seconds_sd"], g["total_seconds_min"], g["total_seconds_max"] = \
            _stat([p["total_seconds"] for p in per])
        for name in ("mse", "relmse"):
            g[name], g[name + "_sd"], g[name + "_min"], g[name + "_max"] = _stat([p[name] for p in per])
        if len(images) >= 2:
            g["variance"] = metrics.mean_variance(images)
            g["rel_variance"] = metrics.relative_variance(images, ref)
        else:
            g["variance"] = g["rel_variance"] = None
        g["bias"], g["bias_se"] = _bias(images, ref, ref_se)
        # the group's mean time, not any one run's: at a budget just above 1 spp's time, timing
        # noise alone would flip a per-run flag from run to run
        g["budget_exceeded"] = _budget_exceeded(g)
        if g["budget_exceeded"]:
            warnings.warn(f"{scene}/{label}: the time budget of {g['target_seconds']:g} s cannot be met even at "
                          f"1 spp: 1 spp took {g['total_seconds']:.3g} s (setup {g['setup_seconds']:.3g} s)",
                          stacklevel=3)
        g["max_error"] = max(p["max_error"] for p in per)
        g["max_rel_error"] = max(p["max_rel_error"] for p in per)
        g["relmse_x_seconds"] = g["relmse"] * g["total_seconds"]
        groups.append(g)

    equal_time = _equal_time(spec, groups)
    reference_info = {}
    for s in spec.scenes:
        info = {k: v for k, v in references[s.name][2].items() if k != "hash"}
        reference_info[s.name] = info
    results = {"experiment": spec.name, "spec": os.path.abspath(spec.path), "out_dir": os.path.abspath(out_dir),
               "repetitions": spec.repetitions, "scenes": [s.name for s in spec.scenes],
               "strategies": [{"label": st.label, "id": st.id, "options": st.options} for st in spec.strategies],
               "budgets": [b.key for b in spec.budgets], "reference": reference_info,
               "metrics_note": "mse and relmse corrected by the reference's variance where reference.corrected",
               "equal_time": equal_time, "groups": groups, "runs": runs,
               "rendered": runner.rendered, "reused": runner.reused,
               "executor": (f"dask {dask_address}" if dask_address is not None
                            else "in-process" if workers == 1 else f"{workers} processes")}
    files = ["results.json", "results.csv", "runs.csv"]
    _write_text(os.path.join(out_dir, "results.csv"), _csv(groups, GROUP_COLUMNS))
    _write_text(os.path.join(out_dir, "runs.csv"), _csv(runs, RUN_COLUMNS))
    files += _charts(spec, groups, out_dir)
    files += _error_maps(spec, groups, runs, references, equal_time, out_dir)
    results["files"] = files
    results["seconds"] = round(time.perf_counter() - t_start, 2)
    _write_json(os.path.join(out_dir, "results.json"), results)
    return results


def _budget_exceeded(rec) -> bool:
    """A time budget not met even at 1 spp: the run (or the group, on average) took longer."""
    return rec["budget_kind"] == "seconds" and rec["spp"] == 1 and rec["total_seconds"] > rec["target_seconds"]


def _bias(images, ref, ref_se):
    """:func:`metrics.bias` of the channel means, (bias, SE or None): a pixel's colour channels
    share its samples, so their noise correlates (~0.95) and pooling them as independent values
    understates the SE (up to sqrt(3)x). The reference's SE of a channel mean is taken as the
    mean of its channels' SEs: exact for perfectly correlated channels, an upper bound always."""
    x = np.asarray(images, np.float64).mean(axis=-1, keepdims=True)
    r = np.asarray(ref, np.float64).mean(axis=-1, keepdims=True)
    s = None if ref_se is None else np.asarray(ref_se, np.float64).mean(axis=-1, keepdims=True)
    return metrics.bias(x, r, s)


def _equal_time(spec: Spec, groups) -> dict:
    """{scene: {strategy: budget key}} shown in the error maps (see the module docstring)."""
    out = {}
    seconds = [b for b in spec.budgets if b.kind == "seconds"]
    for s in spec.scenes:
        mine = [g for g in groups if g["scene"] == s.name]
        if seconds:
            key = seconds[-1].key
            out[s.name] = {st.label: key for st in spec.strategies}
            continue
        reach = min(max(g["total_seconds"] for g in mine if g["strategy"] == st.label) for st in spec.strategies)
        out[s.name] = {}
        for st in spec.strategies:
            cand = [g for g in mine if g["strategy"] == st.label]
            best = min(cand, key=lambda g: abs(math.log(max(g["total_seconds"], 1e-9) / max(reach, 1e-9))))
            out[s.name][st.label] = best["budget"]
    return out


# ----------------------------------------------------------------------------- tables
GROUP_COLUMNS = ["scene", "strategy", "strategy_id", "budget", "spp", "target_seconds", "repetitions",
                 "setup_seconds", "render_seconds", "total_seconds", "total_seconds_min", "total_seconds_max",
                 "mse", "mse_sd", "relmse", "relmse_sd", "relmse_min", "relmse_max", "relmse_x_seconds",
                 "variance", "rel_variance", "bias", "bias_se", "max_error", "max_rel_error", "budget_exceeded"]
RUN_COLUMNS = ["scene", "strategy", "strategy_id", "budget", "spp", "target_seconds", "seed", "setup_seconds",
               "render_seconds", "total_seconds", "mse", "relmse", "max_error", "max_rel_error", "budget_exceeded",
               "image"]


def _csv(rows, columns) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for row in rows:
        w.writerow(["" if row.get(c) is None else row[c] for c in columns])
    return buf.getvalue()


def _g(x, fmt=".3g"):
    return "-" if x is None else format(x, fmt)


def format_summary(results: dict) -> str:
    """The results as a plain-text table, one block per scene (what the CLI prints)."""
    head = ["strategy", "budget", "spp", "setup s", "total s", "relMSE", "±sd", "relMSE·s", "MSE",
            "bias", "±se", "max err"]
    lines = [f"experiment {results['experiment']}: {len(results['runs'])} runs "
             f"({results['rendered']} rendered, {results['reused']} reused), "
             f"{results['repetitions']} repetition{'s' if results['repetitions'] != 1 else ''}; "
             "relMSE: mean over repetitions"]
    for scene in results["scenes"]:
        ref = results["reference"][scene]
        src = ref.get("file") or f"{ref['strategy']} {ref['spp']} spp"
        lines += ["", f"{scene} (reference: {src}"
                  f"{'' if ref.get('corrected') else ', no stderr: metrics not corrected'})"]
        rows = [head]
        for g in results["groups"]:
            if g["scene"] != scene:
                continue
            rows.append([g["strategy"], g["budget"], str(g["spp"]), _g(g["setup_seconds"], ".3f"),
                         _g(g["total_seconds"], ".3f"), _g(g["relmse"], ".4g"), _g(g["relmse_sd"], ".2g"),
                         _g(g["relmse_x_seconds"], ".3g"), _g(g["mse"], ".4g"), _g(g["bias"], ".2g"),
                         _g(g["bias_se"], ".2g"), _g(g["max_error"], ".3g")])
        widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
        for r in rows:
            lines.append("  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))))
        approx = sorted({(run["strategy"], m) for run in results["runs"] if run["scene"] == scene
                         for m in (run.get("stats") or {}).get("approximated_materials") or []})
        for strategy, material in approx:   # a peer's error then holds a bias that spp never removes
            lines.append(f"  note: {strategy} renders material {material!r} with an approximation "
                         "(wavlight.peers): its error includes that difference")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- charts
def _colours(spec):
    from matplotlib import colormaps
    cmap = colormaps["tab10"]
    return {st.label: cmap(i % 10) for i, st in enumerate(spec.strategies)}


def _save_figure(fig, out_dir, stem):
    folder = os.path.join(out_dir, "charts")
    os.makedirs(folder, exist_ok=True)
    names = []
    for ext in ("png", "svg"):
        path = os.path.join(folder, f"{stem}.{ext}")
        fd, tmp = tempfile.mkstemp(prefix=".wavlight-", suffix="." + ext, dir=folder)
        os.close(fd)
        try:
            fig.savefig(tmp, format=ext, dpi=120, metadata={"Date": None} if ext == "svg" else None)
            _publish(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
        names.append(os.path.relpath(path, out_dir))
    return names


def _charts(spec: Spec, groups, out_dir) -> list:
    from matplotlib.figure import Figure

    colours = _colours(spec)
    files = []
    for s in spec.scenes:
        mine = [g for g in groups if g["scene"] == s.name]
        positive = [v for g in mine for v in (g["relmse_min"], g["relmse"]) if v is not None and v > 0]
        floor = min(positive) / 10 if positive else None
        for axis, xkey, xlabel in (("spp", "spp", "samples per pixel"),
                                   ("time", "total_seconds", "total seconds per render (setup + sampling)")):
            fig = Figure(figsize=(6.4, 4.4), layout="constrained")
            ax = fig.add_subplot()
            for st in spec.strategies:
                # joined in spp order on both charts: a noisy time must not zig-zag the line
                pts = sorted((g for g in mine if g["strategy"] == st.label), key=lambda g: (g["spp"], g[xkey]))
                x = np.array([g[xkey] for g in pts], float)
                y = np.array([g["relmse"] for g in pts], float)
                lo = np.array([g["relmse_min"] for g in pts], float)
                hi = np.array([g["relmse_max"] for g in pts], float)
                c = colours[st.label]
                ax.plot(x, np.where(y > 0, y, np.nan), "o-", color=c, label=st.label, lw=1.5, ms=4)
                if floor is not None and len(pts) and spec.repetitions > 1:
                    ax.fill_between(x, np.maximum(lo, floor), np.maximum(hi, floor), color=c, alpha=0.18, lw=0)
            if floor is not None:
                ax.set_xscale("log")
                ax.set_yscale("log")
            ax.set_xlabel(xlabel)
            ax.set_ylabel("relMSE")
            ax.grid(True, which="both", alpha=0.3)
            band = f"band: min-max of {spec.repetitions} repetitions" if spec.repetitions > 1 else "1 repetition"
            ax.set_title(f"{s.name}: relMSE vs {'spp' if axis == 'spp' else 'time'} (line: mean; {band})",
                         fontsize=9)
            ax.legend(fontsize=8)
            files += _save_figure(fig, out_dir, f"{s.name}-{axis}")
    return files


def _error_maps(spec: Spec, groups, runs, references, equal_time, out_dir) -> list:
    from matplotlib.figure import Figure

    from .imageio import srgb_encode

    rows, cols = len(spec.scenes), 1 + len(spec.strategies)
    w0, h0 = max((references[s.name][0].shape[1], references[s.name][0].shape[0]) for s in spec.scenes)
    cell = 2.4
    fig = Figure(figsize=(cols * cell + 1.0, rows * (cell * h0 / w0 + 0.5) + 0.4), layout="constrained")
    axes = np.asarray(fig.subplots(rows, cols, squeeze=False))
    im = None
    for i, s in enumerate(spec.scenes):
        ref = references[s.name][0]
        ax = axes[i, 0]
        ax.imshow(srgb_encode(ref), interpolation="nearest")
        ax.set_title(f"{s.name}\nreference", fontsize=8)
        for j, st in enumerate(spec.strategies):
            ax = axes[i, j + 1]
            bkey = equal_time[s.name][st.label]
            g = next(g for g in groups if g["scene"] == s.name and g["strategy"] == st.label and g["budget"] == bkey)
            run = next(r for r in runs if r["scene"] == s.name and r["strategy"] == st.label
                       and r["budget"] == bkey and r["seed"] == 0)
            img = _read_image(os.path.join(out_dir, run["image"]))
            im = ax.imshow(metrics.error_map(img, ref), cmap="inferno", vmin=0.0, vmax=1.0, interpolation="nearest")
            ax.set_title(f"{st.label}: {g['spp']} spp, {run['total_seconds']:.2f} s\nrelMSE {run['relmse']:.3g}",
                         fontsize=8)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    if im is not None:
        bar = fig.colorbar(im, ax=axes[:, 1:].ravel().tolist(), extend="max", shrink=0.9)
        bar.set_label("relative error √(mean (x−r)² / (r²+0.01))", fontsize=8)
    fig.suptitle(f"{spec.name}: error maps at equal time (seed 0)", fontsize=10)
    return _save_figure(fig, out_dir, "error-maps")
