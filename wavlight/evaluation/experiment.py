"""Batch experiments: scenes x strategies x budgets x repetitions, measured against a reference.

    results = wavlight.evaluation.experiment.run_experiment("experiments/example.toml", "out/example")

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
                              # or a Mitsuba peer: mitsuba:mis | mitsuba:mis_comp | mitsuba:light | mitsuba:bsdf,
                              # or relight (below: bake_spp, levels, frames)
    label = "wavelet-p5"      # default: the id; names the output folders and chart lines
    wavelet_levels = 5        # optional: any strategy option by its scene key, as in a scene's
    light_levels = 9          # [render] table (wavlight.strategies.OPTIONS, docs/cli.md); an option
    wavelet_candidates = 16   # that does not apply to the id (APPLIES) is an error, not ignored
    sampler = "stratified"    # (the sampler applies to every strategy)

    [budgets]
    spp = [4, 16, 64]         # equal-spp budgets
    seconds = [0.5, 2.0]      # equal-time budgets: total seconds (setup + sampling) per render
    repetitions = 3           # seeds 0 .. repetitions-1 (default 3)

At least one of ``spp`` and ``seconds`` is required. Errors name the file and the key
(``exp.toml: [budgets].spp: must be a non-empty list of integers >= 1, got [0]``) and raise
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
  again, with a one-line warning; so is a record that is damaged (not JSON, not an object, a
  field missing or of the wrong kind, or not this run's: :data:`RUN_FIELDS`), and likewise
  a reference's or a pilot's record, or a reference image that cannot be read. Both files
  are written atomically, the record last; temporaries that a killed experiment left
  (``.wavlight-<pid>...``) are removed at the start of the next run.
- **Limits**, checked before anything is rendered: at most :data:`MAX_RUNS` runs, pilot_spp at
  most MAX_SPP / 4, threads at most MAX_THREADS (4096), the largest size's render memory
  (:func:`wavlight.imageio.check_memory`, per worker) within the memory available; every
  reference file read and checked (size, NaN, all black) up front; no input (the spec, a
  scene, its map or meshes, a reference) where the experiment writes (its files in DIR and
  the folders runs/, reference/, pilot/, charts/, bakes/). A time budget whose spp would pass MAX_SPP
  is capped there with a warning.
- **Mitsuba peers.** ``id = "mitsuba:<mis|mis_comp|light|bsdf>"`` renders with
  :func:`wavlight.evaluation.peers.render_mitsuba` (same scene, size, spp, seed; its setup includes
  scene conversion and a JIT warm-up; ``threads`` does not apply). The default label is
  the id with ``-`` for ``:`` (``mitsuba-mis``); wavlight options are rejected. Without
  Mitsuba 3 (llvm_ad_rgb) the spec is rejected (``[[strategies]][i].id: 'mitsuba:mis'
  needs Mitsuba 3 ...``), not skipped. Warm-up, pilots, time budgets, resume and metrics
  are as for wavlight strategies; run hashes also cover Mitsuba's version.
- **Relit frames.** ``id = "relight"`` bakes each scene once at the run size
  (:func:`wavlight.relight.bake.bake` with ``bake_spp`` camera samples per pixel, default 16, and
  ``levels`` texel levels, default chosen from the scene) into ``DIR/bakes/<scene>/<label>.wlt``
  with its record (hash of the scene, size and settings; reused on resume), and renders each
  run with the bake's unbiased estimator (:func:`wavlight.relight.converge.converge`, the
  scene's own lighting). Each run's ``setup_seconds`` is the bake's seconds divided by
  ``frames`` (default 100): the frames one bake serves while only the lighting changes.
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
  before its first run. ``results.json`` records ``executor``. ``workers`` is at most
  :data:`MAX_WORKERS` (64), and never more processes than runs are started. A Dask scheduler
  must answer, with a worker, within :data:`DASK_TIMEOUT` (20 s; ``dask_timeout``): its
  greeting is read first with a deadline and a size limit, so that a service that never
  answers or speaks another protocol is one line naming the address; while runs are pending
  and none finishes for that long, the scheduler must answer again within it and have a
  worker (:func:`_dask_completed`).
- **Metrics** (:mod:`wavlight.evaluation.metrics`) are computed after the runs, from the saved
  images and the reference, so they always match the current reference: per run mse,
  relmse (both corrected by the reference's variance when its stderr is known),
  max_error, max_rel_error; per (scene, strategy, budget) the mean, sd, min and max of
  those over the repetitions, the mean per-pixel variance over the repetitions
  (``variance``, ``rel_variance``), ``bias`` with ``bias_se``, and relMSE x time
  (``relmse_x_seconds``, lower is better at any budget). ``bias`` and ``bias_se`` are
  :func:`wavlight.evaluation.metrics.bias` of the per-pixel channel mean (:func:`_bias`): the channels
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
  :func:`wavlight.evaluation.metrics.error_map` of repetition 0 at equal time, on a fixed scale
  0..1 (values above 1 saturate). Equal time means the largest ``seconds`` budget when
  there is one; otherwise T = the largest mean total time that every strategy reaches,
  and each strategy shows its budget closest to T (in log time).
"""
from __future__ import annotations

import hashlib
import math
import os
import time
import warnings

import numpy as np

from . import metrics
from .charts import error_charts, error_maps, require_matplotlib
from .records import (INTEGER, NUMBER, ROWS, TABLE, TEXT, content_hash, csv_text, image_problem, read_image,
                      read_json, record_problem, remove_stale, save_run_image, write_json, write_text)
from .spec import PEER_PREFIX, RELIGHT, Budget, SceneSpec, Spec, StrategySpec, load_spec
from ..cluster import DASK_TIMEOUT, connect, finished
from ..errors import SanitisedInputWarning, WavlightError, one_line, shown
from ..atomic import remove_stale_temporaries
from ..imageio import check_memory, check_not_input, same_file, scene_files
from ..integrator import render_full
from ..scene import MAX_SPP, load_scene
from ..threads import MAX_THREADS
from ..version import __version__


PILOT_SEED = 999_999
WARMUP_SIZE = 8
#: Most runs (scenes x strategies x budgets x repetitions) in one experiment: each is a render
#: and two files, and the run list is built before the first render. Checked before anything
#: is rendered or allocated.
MAX_RUNS = 100_000
#: Most local worker processes (``workers``): each is a Python with OpenCL (about 0.3-0.4 GB)
#: rendering one run at a time; more processes than runs are never started.
MAX_WORKERS = 64

#: What the records of a resume must hold to be used (records.record_problem); anything else is
#: a damaged record: a one-line warning, and the run, reference or pilot is made again.
RUN_FIELDS = {"hash": TEXT, "scene": TEXT, "strategy": TEXT, "strategy_id": TEXT, "options": TABLE,
              "budget": TEXT, "budget_kind": TEXT, "target_seconds": (NUMBER, None), "spp": INTEGER,
              "seed": INTEGER, "setup_seconds": NUMBER, "render_seconds": NUMBER, "total_seconds": NUMBER,
              "image": TEXT, "stats": (TABLE, None)}
REFERENCE_FIELDS = {"hash": TEXT, "strategy": TEXT, "spp": INTEGER, "seed": INTEGER}
PILOT_FIELDS = {"hash": TEXT, "points": ROWS, "setup_seconds": NUMBER, "render_a": NUMBER, "render_b": NUMBER}
BAKE_FIELDS = {"hash": TEXT, "file": TEXT, "bake_seconds": NUMBER}


# ----------------------------------------------------------------------------- the experiment file


# ----------------------------------------------------------------------------- files


# ----------------------------------------------------------------------------- running
class _Runner:
    def __init__(self, spec: Spec, out_dir: str, progress, resume: bool, workers: int = 1):
        self.spec, self.out, self.progress, self.resume = spec, out_dir, progress, resume
        self.scenes, self.scene_hash, self.size = {}, {}, {}
        self.file_references = {}
        runs = len(spec.scenes) * len(spec.strategies) * len(spec.budgets) * spec.repetitions
        if runs > MAX_RUNS:   # before any scene is loaded or any run listed
            raise WavlightError(f"{spec.path}: [budgets].repetitions: {len(spec.scenes)} scene(s) x "
                                f"{len(spec.strategies)} strateg{'y' if len(spec.strategies) == 1 else 'ies'} x "
                                f"{len(spec.budgets)} budget(s) x {spec.repetitions} repetition(s) make {runs} runs; "
                                f"at most {MAX_RUNS} are supported")
        if any(b.kind == "seconds" for b in spec.budgets) and 4 * spec.pilot_spp > MAX_SPP:
            raise WavlightError(f"{spec.path}: [experiment].pilot_spp: the pilots render pilot_spp and 4 x pilot_spp; "
                                f"must be at most {MAX_SPP // 4}, got {spec.pilot_spp}")
        if spec.threads is not None and spec.threads > MAX_THREADS:
            raise WavlightError(f"{spec.path}: [experiment].threads: must be at most {MAX_THREADS}, got {spec.threads}")
        for s in spec.scenes:
            scene = load_scene(s.path)
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
            if s.reference is not None:   # read and checked now, not after other scenes' renders
                self.file_references[s.name] = self._reference_file(s)
        self._check_outputs()
        w, h = max(self.size.values(), key=lambda wh: wh[0] * wh[1])
        check_memory(f"{spec.path}: {'[experiment].size' if spec.size else 'a scene size'}", w, h,
                     copies=max(1, min(workers, runs)))
        self.warm = set()
        self.bakes = {}   # (scene name, strategy label) -> the run options of a relight strategy
        self.done = 0
        self.rendered = self.reused = 0
        n_ref = sum(1 for s in spec.scenes if s.reference is None)
        n_pilot = len(spec.scenes) * len(spec.strategies) if any(b.kind == "seconds" for b in spec.budgets) else 0
        n_bake = len(spec.scenes) * sum(1 for st in spec.strategies if st.id == RELIGHT)
        self.total = n_ref + n_pilot + n_bake + len(spec.scenes) * len(spec.strategies) * len(spec.budgets) * spec.repetitions

    def _check_outputs(self):
        """Refuse, before anything is written, an input (the spec, a scene file, its map or a mesh,
        a reference file) that lies where this experiment writes: its files in out_dir and the
        folders runs/, reference/, pilot/, charts/ and bakes/ there."""
        spec, out = self.spec, os.path.abspath(self.out)
        inputs = [spec.path]
        for s in spec.scenes:   # the scene file and what it reads (Scene.files: its map and meshes)
            files = getattr(self.scenes.get(s.name), "files", None)
            inputs += [s.path, *files] if files is not None else scene_files(s.path)
        inputs += [f for s in spec.scenes for f in (s.reference, s.reference_stderr) if f is not None]
        mine = [os.path.join(out, n) for n in ("spec.toml", "results.json", "results.csv", "runs.csv")]
        check_not_input(mine, inputs)
        for folder in ("runs", "reference", "pilot", "charts", "bakes"):
            root = os.path.join(out, folder)
            for inp in inputs:
                real = os.path.realpath(inp)
                if any(p == root or p.startswith(root + os.sep) for p in (os.path.abspath(inp), real)) or (
                        os.path.isdir(root) and same_file(os.path.dirname(real), root)):
                    raise WavlightError(f"{self.out}: {folder}/ is written by the experiment and holds an input of "
                                        f"it ({inp}); choose another output folder")

    def _reference_file(self, s: SceneSpec):
        """A given reference image (and stderr) read and checked: (image, stderr or None, info)."""
        w, h = self.size[s.name]
        image = read_image(s.reference)
        if image.shape[:2] != (h, w):
            raise WavlightError(f"{s.reference}: reference image is {image.shape[1]}x{image.shape[0]}, "
                                f"the experiment renders {s.name} at {w}x{h}")
        bad = int((~np.isfinite(image)).any(axis=-1).sum())
        if bad:   # every metric would be NaN
            raise WavlightError(f"{s.reference}: reference image has {bad} NaN or Inf pixel(s)")
        if not np.any(image > 0):   # as a black environment: relative errors would be undefined
            raise WavlightError(f"{s.reference}: reference image is black everywhere; relative errors against "
                                "a black reference are undefined")
        stderr = None
        if s.reference_stderr is not None:
            stderr = read_image(s.reference_stderr)
            if stderr.shape != image.shape:
                raise WavlightError(f"{s.reference_stderr}: stderr image is {stderr.shape[1]}x"
                                    f"{stderr.shape[0]}, the reference is {w}x{h}")
            if not np.all(np.isfinite(stderr)) or np.any(stderr < 0):
                raise WavlightError(f"{s.reference_stderr}: stderr must be finite and non-negative")
        return image, stderr, {"file": s.reference, "stderr_file": s.reference_stderr,
                               "corrected": stderr is not None}

    def step(self, what):
        self.done += 1
        if self.progress:
            self.progress(self.done, self.total, what)

    def run_options(self, s: SceneSpec, st: StrategySpec) -> dict:
        """What a render of ``st`` needs besides spp and seed: its options, and for relight the
        bake file and its seconds (:meth:`bake`)."""
        return self.bake(s, st) if st.id == RELIGHT else st.options

    def bake(self, s: SceneSpec, st: StrategySpec) -> dict:
        """The relight strategy's bake of this scene at the run size, made once (reused on
        resume while the scene, size and bake settings are the same): DIR/bakes/<scene>/<label>.wlt
        and its record. Returns the runs' options: the settings, the file and ``bake_seconds``."""
        if (s.name, st.label) in self.bakes:
            return self.bakes[s.name, st.label]
        from ..relight.bake import bake
        from ..relight.transfer import Transfer

        folder = os.path.join(self.out, "bakes", s.name)
        path, rec_path = os.path.join(folder, f"{st.label}.wlt"), os.path.join(folder, f"{st.label}.json")
        key = content_hash({**self.base_key(s.name), **self.strategy_key(st), "bake": "lighting"})
        what = f"{s.name}/{st.label}: bake"
        rec = self._record(rec_path, BAKE_FIELDS, f"the {what}")
        usable = rec is not None and rec["hash"] == key and rec["bake_seconds"] >= 0
        if usable:
            try:
                Transfer.load(path).close()
            except WavlightError as e:
                warnings.warn(f"{path}: {e}: baking {s.name}/{st.label} again", stacklevel=4)
                usable = False
        if usable:
            self.step(what + " (done before)")
        else:
            w, h = self.size[s.name]
            os.makedirs(folder, exist_ok=True)
            t0 = time.perf_counter()
            bake(self.scenes[s.name], output=path, width=w, height=h, spp=st.options["bake_spp"],
                 levels=st.options.get("levels"), threads=self.spec.threads).close()
            rec = {"hash": key, "file": os.path.relpath(path, self.out),
                   "bake_seconds": round(time.perf_counter() - t0, 4)}
            write_json(rec_path, rec)
            self.step(what)
        options = {**st.options, "transfer": os.path.abspath(path), "bake_seconds": rec["bake_seconds"]}
        self.bakes[s.name, st.label] = options
        return options

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
                "wavlight": __version__, "threads": self.spec.threads}   # threads: timings

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
            return self.file_references[s.name]
        ref = self.spec.reference
        folder = os.path.join(self.out, "reference")
        img_path = os.path.join(folder, f"{s.name}.exr")
        se_path = os.path.join(folder, f"{s.name}.stderr.exr")
        rec_path = os.path.join(folder, f"{s.name}.json")
        key = content_hash({**self.base_key(s.name), **ref, "sampler": "independent"})
        rec = self._record(rec_path, REFERENCE_FIELDS, f"{s.name}'s reference")
        if rec is not None and rec["hash"] == key:
            problem = next((f"{os.path.basename(p)} {why}" for p in (img_path, se_path)
                            for why in [image_problem(p, w, h)] if why), None)
            if problem is None:
                image, stderr = read_image(img_path), read_image(se_path)
                if np.all(stderr >= 0):
                    self.step(f"{s.name}: reference (done before)")
                    return image, stderr, rec
                problem = f"{os.path.basename(se_path)} has negative standard errors"
            warnings.warn(f"{rec_path}: the reference's image {problem}: rendering {s.name}'s reference again",
                          stacklevel=4)
        # always independent samples: the per-pixel standard error subtracted from every metric
        # is exact for them, an upper bound (about 2x the variance, measured) for stratified
        r = self.render(s.name, ref["strategy"], {"sampler": "independent"}, ref["spp"], ref["seed"])
        save_run_image(img_path, r.image)
        save_run_image(se_path, r.stderr)
        rec = {"hash": key, "scene": s.name, **ref, "width": w, "height": h,
               "image": os.path.relpath(img_path, self.out), "stderr": os.path.relpath(se_path, self.out),
               "setup_seconds": r.stats["setup_seconds"], "render_seconds": r.stats["render_seconds"],
               "corrected": True}
        write_json(rec_path, rec)
        self.step(f"{s.name}: reference, {ref['strategy']} {ref['spp']} spp")
        return r.image, r.stderr, rec

    # -- time budgets
    def pilot(self, s: SceneSpec, st: StrategySpec):
        """Fit of this scene and strategy's cost: setup seconds and sampling a + b spp."""
        path = os.path.join(self.out, "pilot", s.name, f"{st.label}.json")
        p1, p2 = self.spec.pilot_spp, 4 * self.spec.pilot_spp
        longest = max(b.value for b in self.spec.budgets if b.kind == "seconds")
        key = content_hash({**self.base_key(s.name), **self.strategy_key(st), "pilot": [p1, p2], "longest": longest})
        rec = self._record(path, PILOT_FIELDS, f"the {s.name}/{st.label} pilot")
        if rec is not None and rec["hash"] == key:
            if rec["render_b"] > 0 and rec["render_a"] >= 0 and rec["setup_seconds"] >= 0:
                self.step(f"{s.name}/{st.label}: pilot (done before)")
                return rec
            warnings.warn(f"{path}: the pilot's fit is not usable (a cost per spp of {rec['render_b']!r} s): "
                          f"measuring the {s.name}/{st.label} pilot again", stacklevel=4)
        self.warm_up(s.name, st.id, self.run_options(s, st))
        points = []

        def measure(spp):
            r = self.render(s.name, st.id, self.run_options(s, st), spp, PILOT_SEED)
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
        p3 = self.spp_for(fit(), longest, most=most_spp(st))
        if p3 > 2 * p2:
            measure(p3)
        model = fit()
        rec = {"hash": key, "scene": s.name, "strategy": st.label, "points": points, **model}
        write_json(path, rec)
        self.step(f"{s.name}/{st.label}: pilot")
        return rec

    def _record(self, path, fields, what):
        """A resume record that can be used (None: none, or resume off). A damaged one (not JSON,
        not an object, a field missing or of the wrong kind) warns in one line and is redone."""
        if not self.resume or not os.path.exists(path):
            return None
        rec = read_json(path)
        problem = "is not valid JSON" if rec is None else record_problem(rec, fields)
        if problem is None:
            return rec
        warnings.warn(f"{path}: the record of {what} {problem}: making it again", stacklevel=4)
        return None

    @staticmethod
    def spp_for(pilot, seconds, where=None, most: int = MAX_SPP):
        """The spp that the pilot's fit gives for a budget of ``seconds`` (1 .. ``most``, the most
        the strategy's render takes: :func:`most_spp`). A budget that would need more is capped
        there with a warning naming ``where``."""
        with np.errstate(all="ignore"):
            spp = (seconds - pilot["setup_seconds"] - pilot["render_a"]) / pilot["render_b"]
        if not math.isfinite(spp) or spp > most:
            if where is not None:
                warnings.warn(f"{where}: a time budget of {seconds:g} s would need about "
                              f"{spp:.3g} spp; capped at the most a render takes, {most} spp "
                              "(the run will take less time than its budget)", stacklevel=4)
            return most
        return int(max(1, round(spp)))

    # -- one run
    def prepare(self, s: SceneSpec, st: StrategySpec, budget: Budget, spp: int, seed: int):
        """(record, None) for a run finished before (counted as reused), else (None, job)."""
        folder = os.path.join(self.out, "runs", s.name, st.label, budget.key)
        img_path = os.path.join(folder, f"{seed}.exr")
        rec_path = os.path.join(folder, f"{seed}.json")
        what = f"{s.name}/{st.label}/{budget.key}/seed {seed}"
        key = content_hash({**self.base_key(s.name), **self.strategy_key(st), "spp": spp, "seed": seed})
        rec = self._record(rec_path, RUN_FIELDS, what)
        if rec is not None and rec["hash"] == key:
            expected = {"scene": s.name, "strategy": st.label, "budget": budget.key, "spp": spp, "seed": seed,
                        "image": os.path.relpath(img_path, self.out)}
            wrong = next((k for k, v in expected.items() if rec[k] != v), None)
            problem = (image_problem(img_path, *self.size[s.name]) if wrong is None
                       else f"is not this run's (its record's {wrong!r} is {shown(rec[wrong])})")
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
                "strategy": st.id, "options": dict(self.run_options(s, st)), "spp": job["spp"], "seed": job["seed"],
                "threads": self.spec.threads}

    def render_local(self, job):
        s, st = job["s"], job["st"]
        self.warm_up(s.name, st.id, self.run_options(s, st))
        r = self.render(s.name, st.id, self.run_options(s, st), job["spp"], job["seed"])
        return {"image": r.image, "stats": r.stats}

    def finish(self, job, result):
        """Write a rendered run's image, then its record."""
        s, st, budget = job["s"], job["st"], job["budget"]
        save_run_image(job["img_path"], result["image"])
        stats = result["stats"]
        rec = {"hash": job["key"], "scene": s.name, "strategy": st.label, "strategy_id": st.id,
               "options": st.options, "budget": budget.key, "budget_kind": budget.kind,
               "target_seconds": budget.value if budget.kind == "seconds" else None,
               "spp": job["spp"], "seed": job["seed"], "width": stats["width"], "height": stats["height"],
               "setup_seconds": stats["setup_seconds"], "render_seconds": stats["render_seconds"],
               "total_seconds": round(stats["setup_seconds"] + stats["render_seconds"], 4),
               "image": os.path.relpath(job["img_path"], self.out), "stats": stats,
               "finished": time.strftime("%Y-%m-%dT%H:%M:%S")}
        write_json(job["rec_path"], rec)
        self.rendered += 1
        self.step(job["what"])
        return rec

    def run(self, s: SceneSpec, st: StrategySpec, budget: Budget, spp: int, seed: int):
        rec, job = self.prepare(s, st, budget, spp, seed)
        return rec if job is None else self.finish(job, self.render_local(job))


def most_spp(st: StrategySpec) -> int:
    """The most spp a render of ``st`` takes: a scene's MAX_SPP, or for ``relight`` the unbiased
    frame's bound (wavlight.relight.settings FRAME["spp"])."""
    if st.id == RELIGHT:
        from ..relight.settings import FRAME
        return int(FRAME["spp"].hi)
    return MAX_SPP


_TRANSFERS = {}   # per process: bake file -> Transfer (read once)


def _render(scene, strategy_id, options, spp, width, height, seed, threads):
    """One render by wavlight (``wavlight.render_full``), by a peer (``mitsuba:<strategy>``) or
    the relit frame's unbiased estimator of a bake (``relight``; the size is the bake's)."""
    if strategy_id == RELIGHT:
        from ..relight.converge import converge
        from ..relight.transfer import Transfer

        path = options["transfer"]
        if path not in _TRANSFERS:
            _TRANSFERS[path] = Transfer.load(path)
        t0 = time.perf_counter()
        r = converge(_TRANSFERS[path], scene, spp=spp, seed=seed, threads=threads)
        # the bake amortized over the frames it serves (``frames``), as the setup of each
        r.stats.update(setup_seconds=round(options["bake_seconds"] / options.get("frames", 100), 4),
                       render_seconds=round(time.perf_counter() - t0, 4), strategy=RELIGHT)
        return r
    if strategy_id.startswith(PEER_PREFIX):
        from . import peers
        return peers.render_mitsuba(scene, strategy_id[len(PEER_PREFIX):], spp=spp, width=width, height=height,
                                    seed=seed)
    return render_full(scene, spp=spp, strategy=strategy_id, width=width, height=height, seed=seed,
                                threads=threads, **options)


_WORKER = {"scenes": {}, "warm": set()}  # per process: loaded scenes, (scene, strategy) pairs warmed up


#: how often a worker process looks whether the experiment's process is still there
PARENT_POLL_SECONDS = 1.0


def exit_with_parent(parent: int) -> None:
    """A worker process's initializer: a daemon thread ends the worker once ``parent`` (the
    experiment's process) is gone. A parent killed outright (SIGKILL, out of memory) cannot
    shut its pool down, and its workers would otherwise wait for tasks for ever."""
    import threading

    def watch():
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_SECONDS)
        os._exit(1)

    threading.Thread(target=watch, name="wavlight-parent-watch", daemon=True).start()


def run_task(task: dict) -> dict:
    """One run, as a pure function for worker processes: ``task`` (from ``_Runner.task``: scene
    file and its hash, size, strategy id and options, spp, seed, threads) -> ``{"image", "stats"}``.

    The scene is loaded (untimed) once per process and checked against the hash of the file the
    experiment read; each (scene, strategy) gets the untimed 8x8 warm-up before its first run in
    this process, as in-process runs do."""
    path, digest = task["scene_path"], task["scene_hash"]
    scene = _WORKER["scenes"].get((path, digest))
    if scene is None:
        with open(path, "rb") as fh:
            if hashlib.sha256(fh.read()).hexdigest() != digest:
                raise WavlightError(f"{path}: this worker sees a different scene file than the experiment read")
        with warnings.catch_warnings():   # the experiment's own process warned when it read the scene
            warnings.simplefilter("ignore", SanitisedInputWarning)
            scene = _WORKER["scenes"][(path, digest)] = load_scene(path)
    w, h = task["size"]
    strategy, options, threads = task["strategy"], task["options"], task["threads"]
    warm = (path, digest, strategy, tuple(sorted(options.items())))
    if warm not in _WORKER["warm"]:
        _render(scene, strategy, options, 1, WARMUP_SIZE, WARMUP_SIZE, 0, threads)
        _WORKER["warm"].add(warm)
    r = _render(scene, strategy, options, task["spp"], w, h, task["seed"], threads)
    return {"image": np.asarray(r.image, np.float32), "stats": r.stats}


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
        import logging

        client = connect(dask_address, getattr(runner, "dask_timeout", DASK_TIMEOUT))
        # distributed logs a lost scheduler as tracebacks (its reconnection attempts) on stderr:
        # while this experiment uses the cluster, only its critical messages; the error raised
        # below names the address and what failed, in one line
        logs = [logging.getLogger(name) for name in list(logging.root.manager.loggerDict)
                if name == "distributed" or name.startswith("distributed.")]
        levels = [log.level for log in logs]
        for log in logs:
            log.setLevel(logging.CRITICAL)
        try:
            futures = client.map(run_task, tasks, pure=False)
            where = {f.key: n for n, f in enumerate(futures)}
            try:
                for f in finished(client, futures, dask_address, getattr(runner, "dask_timeout", DASK_TIMEOUT)):
                    n = where[f.key]
                    try:
                        result = f.result()
                    except WavlightError:
                        raise
                    except Exception as e:   # noqa: BLE001 (the cluster's: lost scheduler, killed worker)
                        raise WavlightError(f"dask {dask_address}: {jobs[n][1]['what']} failed on the cluster "
                                            f"({type(e).__name__}: {one_line(e, 160)}); the runs finished before are "
                                            "kept: run the experiment again to resume") from None
                    out[jobs[n][0]] = runner.finish(jobs[n][1], result)
            except BaseException:
                try:
                    client.cancel(futures)
                except Exception:   # noqa: BLE001 (the scheduler is gone)
                    pass
                raise
        finally:
            try:
                client.close(timeout=5)
            except Exception:   # noqa: BLE001
                pass
            for log, level in zip(logs, levels):
                log.setLevel(level)
        return out
    import concurrent.futures as cf
    import multiprocessing
    from concurrent.futures.process import BrokenProcessPool
    pool = cf.ProcessPoolExecutor(max_workers=min(workers, len(tasks)),
                                  mp_context=multiprocessing.get_context("spawn"),
                                  initializer=exit_with_parent, initargs=(os.getpid(),))
    try:
        futures = {pool.submit(run_task, t): n for n, t in enumerate(tasks)}
        for f in cf.as_completed(futures):
            n = futures[f]
            try:
                result = f.result()
            except BrokenProcessPool:
                raise WavlightError(f"a worker process died while rendering {jobs[n][1]['what']} (killed, or out of "
                                    "memory); the runs finished before are kept: run the experiment again to "
                                    "resume") from None
            out[jobs[n][0]] = runner.finish(jobs[n][1], result)
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


def run_experiment(spec_path, out_dir, progress=None, resume=True, workers=1, dask_address=None,
                   dask_timeout=None) -> dict:
    """Run (or resume) an experiment; write results, charts and error maps to out_dir.

    ``progress(done, total, what)`` is called after each reference, pilot and run
    (including runs found finished). Returns the dict written to ``results.json``:
    ``groups`` (one per scene, strategy and budget), ``runs``, ``reference``,
    ``equal_time`` (the budget each strategy shows in the error maps), ``files``,
    ``rendered`` and ``reused`` (run counts of this call).

    ``workers`` (1 .. MAX_WORKERS) local processes, or ``dask_address``, whose scheduler must
    answer, with a worker, within ``dask_timeout`` seconds (default DASK_TIMEOUT). Temporaries that a
    killed experiment left in ``out_dir`` are removed first (:func:`records.remove_stale`).
    """
    t_start = time.perf_counter()
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= MAX_WORKERS:
        raise WavlightError(f"workers must be an integer in 1..{MAX_WORKERS} (local processes, each a Python with "
                            f"OpenCL rendering one run at a time), got {shown(workers)}")
    if not isinstance(out_dir, (str, os.PathLike)) or not os.fspath(out_dir):
        raise WavlightError(f"out_dir must be a folder path, got {shown(out_dir)}")
    if progress is not None and not callable(progress):
        raise WavlightError(f"progress must be a callable or None, got {shown(progress)}")
    if not isinstance(resume, bool):
        raise WavlightError(f"resume must be True or False, got {shown(resume)}")
    dask_timeout = DASK_TIMEOUT if dask_timeout is None else dask_timeout
    if (isinstance(dask_timeout, bool) or not isinstance(dask_timeout, (int, float))
            or not 0 < dask_timeout <= 3600):
        raise WavlightError(f"dask_timeout must be a number of seconds in (0, 3600], got {shown(dask_timeout)}")
    if dask_address is not None and workers != 1:
        raise WavlightError("give workers or a dask scheduler address, not both")
    require_matplotlib()
    spec = load_spec(spec_path)
    if dask_address is not None:   # fail before rendering references and pilots
        connect(dask_address, dask_timeout).close()
    out_dir = os.fspath(out_dir)
    if not isinstance(out_dir, str):
        out_dir = os.fsdecode(out_dir)
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise WavlightError(f"{out_dir}: exists and is not a folder")
    try:   # loads and checks the scenes before out_dir exists
        runner = _Runner(spec, out_dir, progress, resume, 1 if dask_address is not None else workers)
        runner.dask_timeout = dask_timeout
    except MemoryError:
        raise WavlightError(f"{spec.path}: not enough memory to load the experiment's scenes") from None
    try:
        os.makedirs(out_dir, exist_ok=True)
        remove_stale_temporaries(out_dir)   # what a killed experiment's writers left
        for folder in ("charts", "reference", "pilot", "runs"):
            remove_stale(os.path.join(out_dir, folder))
        write_text(os.path.join(out_dir, "spec.toml"), spec.text.decode("utf-8", errors="replace"))
    except OSError as e:
        raise WavlightError(f"{out_dir}: cannot write ({e.strerror})") from None
    try:
        return _run(runner, t_start, workers, dask_address)
    except OSError as e:
        raise WavlightError(f"{e.filename or out_dir}: cannot write ({e.strerror})") from None
    except MemoryError:
        raise WavlightError(f"{spec.path}: not enough memory for the experiment (at "
                            f"{'x'.join(map(str, max(runner.size.values(), key=lambda wh: wh[0] * wh[1])))} "
                            "pixels per run)") from None


SUITES = ("stability",)


def run_suite(name, out_dir, progress=None, **options) -> tuple[dict, str]:
    """Run a built-in suite instead of an experiment file: (results dict, text table).

    ``stability``: :func:`wavlight.evaluation.stability.run_stability` (``options`` go to it).
    """
    if name not in SUITES:
        raise WavlightError(f"unknown suite {shown(name)} ({' | '.join(SUITES)})")
    from . import stability
    import inspect
    known = set(inspect.signature(stability.run_stability).parameters) - {"out_dir", "progress"}
    unknown = sorted(set(options) - known)
    if unknown:
        raise WavlightError(f"suite {name}: unknown option {unknown[0]!r} ({' | '.join(sorted(known))})")
    results = stability.run_stability(out_dir, progress=progress, **options)
    return results, stability.format_table(results)


def _run(runner: _Runner, t_start, workers=1, dask_address=None):
    spec, out_dir = runner.spec, runner.out
    references, pilots = {}, {}
    records, jobs = [], []
    # every reference and pilot first (they set the spp of time budgets, and whatever fails in
    # them fails before any run), then the runs
    for s in spec.scenes:
        references[s.name] = runner.reference(s)
    for s in spec.scenes:   # relight's bakes, once per scene, before its pilots and runs
        for st in spec.strategies:
            if st.id == RELIGHT:
                runner.bake(s, st)
    if any(b.kind == "seconds" for b in spec.budgets):
        for s in spec.scenes:
            for st in spec.strategies:
                pilots[s.name, st.label] = runner.pilot(s, st)
    for s in spec.scenes:
        for st in spec.strategies:
            for budget in spec.budgets:
                spp = (int(budget.value) if budget.kind == "spp" else
                       runner.spp_for(pilots[s.name, st.label], budget.value,
                                      f"{spec.path}: [budgets].seconds: {s.name}/{st.label}", most_spp(st)))
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
        images = np.stack([read_image(os.path.join(out_dir, r["image"])) for r in recs])
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
    write_text(os.path.join(out_dir, "results.csv"), csv_text(groups, GROUP_COLUMNS))
    write_text(os.path.join(out_dir, "runs.csv"), csv_text(runs, RUN_COLUMNS))
    files += error_charts(spec, groups, out_dir)
    files += error_maps(spec, groups, runs, references, equal_time, out_dir)
    results["files"] = files
    results["seconds"] = round(time.perf_counter() - t_start, 2)
    write_json(os.path.join(out_dir, "results.json"), results)
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
                         "(wavlight.evaluation.peers): its error includes that difference")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- charts


