"""Experiment files (TOML): parsing and validation. The format: :mod:`wavlight.evaluation.experiment`."""
from __future__ import annotations

import math
import os
import re
import tomllib
from dataclasses import dataclass, field

from ..errors import WavlightError, file_problem, shown
from ..relight.settings import BAKE
from ..scene import MAX_SIDE, MAX_SPP
from ..strategies import APPLIES, STRATEGIES
from ..scene import Table as SceneTable


PEER_PREFIX = "mitsuba:"
#: The relit frames' unbiased estimator (:func:`wavlight.relight.converge.converge`) as an
#: experiment strategy: each scene baked once (:func:`wavlight.relight.bake.bake`), its time
#: amortized over ``frames`` frames in every run's setup seconds.
RELIGHT = "relight"
#: the reference's seed unless [reference].seed gives one: far from the repetitions' seeds 0..R-1
#: (also the stability suite's references)
REFERENCE_SEED = 1_000_003
#: relight's keys in a [[strategies]] table: (kind, default, lowest, highest); the bake's ranges are
#: its records' (wavlight.relight.settings.BAKE), its camera samples fixed by default (no pilot's choice)
RELIGHT_KEYS = {"bake_spp": ("int", 16, BAKE["spp"].lo, BAKE["spp"].hi),
                "levels": ("int", None, BAKE["levels"].lo, BAKE["levels"].hi), "frames": ("int", 100, 1, 10 ** 9)}


_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")


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


class SpecTable(SceneTable):
    """One TOML table of the experiment file: the scene parser's table (errors name the file
    and the key, unknown keys rejected) with the experiment's own value kinds."""

    def get(self, key, kind, default=None, required=False, lo=None):
        present, v = self.lookup(key, required)
        if not present:
            return default
        is_int = lambda x: isinstance(x, int) and not isinstance(x, bool)
        is_num = lambda x: (isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x))
        if kind == "int":
            if not is_int(v) or (lo is not None and v < lo):
                self.fail(key, f"must be an integer{f' >= {lo}' if lo is not None else ''}, got {shown(v)}")
        elif kind == "float":
            if not is_num(v) or (lo is not None and v <= lo):
                self.fail(key, f"must be a number{f' > {lo}' if lo is not None else ''}, got {shown(v)}")
            v = float(v)
        elif kind == "str":
            if not isinstance(v, str) or not v:
                self.fail(key, f"must be a non-empty string, got {shown(v)}")
        elif kind == "ints":
            if not isinstance(v, list) or not v or not all(is_int(x) and x >= lo for x in v):
                self.fail(key, f"must be a non-empty list of integers >= {lo}, got {shown(v)}")
            if len(set(v)) != len(v):
                self.fail(key, f"has repeated values: {shown(v)}")
        elif kind == "floats":
            if not isinstance(v, list) or not v or not all(is_num(x) and x > lo for x in v):
                self.fail(key, f"must be a non-empty list of numbers > {lo}, got {shown(v)}")
            v = [float(x) for x in v]
            if len(set(v)) != len(v):
                self.fail(key, f"has repeated values: {shown(v)}")
        elif kind == "size":
            if (not isinstance(v, list) or len(v) != 2
                    or not all(is_int(x) and 1 <= x <= MAX_SIDE for x in v)):
                self.fail(key, f"must be [width, height], integers 1..{MAX_SIDE}, got {shown(v)}")
            v = (int(v[0]), int(v[1]))
        return v

    def name_key(self, key, default):
        v = self.get(key, "str", default)
        if not _NAME.match(v):
            self.fail(key, f"must be letters, digits, '_', '.', '+', '-' (it names folders), got {shown(v)}")
        return v


def load_spec(path) -> Spec:
    """Read and validate an experiment file (see the module docstring for its format)."""
    path = str(path)
    problem = file_problem(path)
    if problem:
        raise WavlightError(f"{path}: {problem}")
    try:
        with open(path, "rb") as fh:
            text = fh.read()
        doc = tomllib.loads(text.decode("utf-8"))
    except tomllib.TOMLDecodeError as e:
        raise WavlightError(f"{path}: malformed TOML: {e}") from None
    except RecursionError:
        raise WavlightError(f"{path}: values nested too deeply for an experiment file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise WavlightError(f"{path}: cannot read: {e}") from None
    base = os.path.dirname(os.path.abspath(path))
    unknown = sorted(set(doc) - {"experiment", "reference", "scenes", "strategies", "budgets"})
    if unknown:
        raise WavlightError(f"{path}: {unknown[0]}: unknown table")

    e = SpecTable(path, "[experiment]", doc.get("experiment", {}))
    name = e.name_key("name", os.path.splitext(os.path.basename(path))[0])
    size = e.get("size", "size")
    threads = e.get("threads", "int", lo=1)
    pilot_spp = e.get("pilot_spp", "int", 4, lo=1)
    e.done()

    r = SpecTable(path, "[reference]", doc.get("reference", {}))
    reference = {"strategy": r.get("strategy", "str", "mis"), "spp": r.get("spp", "int", 1024, lo=2),
                 "seed": r.get("seed", "int", REFERENCE_SEED, lo=0)}
    if reference["strategy"] not in STRATEGIES:
        r.fail("strategy", f"unknown strategy {reference['strategy']!r} ({' | '.join(STRATEGIES)})")
    if reference["spp"] > MAX_SPP:
        r.fail("spp", f"must be at most {MAX_SPP}, got {reference['spp']}")
    r.done()

    def rel(p):
        return os.path.normpath(os.path.join(base, p))

    def tables(key, needs):
        """The [[key]] tables in turn; none at all is an error naming what each needs."""
        items = doc.get(key)
        if not isinstance(items, list) or not items:
            raise WavlightError(f"{path}: [[{key}]]: at least one [[{key}]] table with {needs} is required")
        for i, item in enumerate(items):
            yield SpecTable(path, f"[[{key}]][{i}]", item)

    def image_file(t, key):
        """The image that ``key`` names, relative to the spec's folder, checked as a reference."""
        full = rel(t.get(key, "str"))
        if file_problem(full):
            t.fail(key, f"{file_problem(full)} ({full})")
        check_image(t, key, full)
        return full

    scenes = []
    for t in tables("scenes", "a path"):
        p = t.get("path", "str", required=True)
        full = rel(p)
        if file_problem(full):
            t.fail("path", f"{file_problem(full)} ({full})")
        sname = t.name_key("name", os.path.splitext(os.path.basename(p))[0])
        if any(x.name == sname for x in scenes):
            t.fail("name", f"scene name {sname!r} is used twice (give each a distinct name)")
        ssize = t.get("size", "size")
        ref = image_file(t, "reference") if t.has("reference") else None
        ref_se = None
        if t.has("reference_stderr"):
            if ref is None:
                t.fail("reference_stderr", "needs reference")
            ref_se = image_file(t, "reference_stderr")
        t.done()
        scenes.append(SceneSpec(sname, full, ssize, ref, ref_se))

    strats = []
    for t in tables("strategies", "an id"):
        sid = t.get("id", "str", required=True)
        if sid.startswith(PEER_PREFIX):
            from . import peers
            if sid[len(PEER_PREFIX):] not in peers.STRATEGIES:
                t.fail("id", f"unknown Mitsuba strategy {sid!r} "
                             f"({' | '.join(PEER_PREFIX + k for k in peers.STRATEGIES)})")
            if not peers.available():
                t.fail("id", f"{sid!r} needs Mitsuba 3 with its llvm_ad_rgb variant, which is not available "
                             "(pip install 'wavlight[peers]'; Debian: libllvm19)")
        elif sid not in STRATEGIES and sid != RELIGHT:
            t.fail("id", f"unknown strategy {sid!r} ({' | '.join(STRATEGIES)} | {RELIGHT} | "
                         f"mitsuba:mis | mitsuba:mis_comp | mitsuba:light | mitsuba:bsdf)")
        label = t.name_key("label", sid.replace(":", "-"))
        if any(x.label == label for x in strats):
            t.fail("label", f"label {label!r} is used twice (give each strategy a distinct label)")
        options = t.options()   # the strategies' settings, as in a scene's [render] table
        if options and sid.startswith(PEER_PREFIX):
            t.fail(sorted(options)[0], f"is a wavlight option; {sid!r} takes none")
        if sid == RELIGHT:
            if options:
                t.fail(sorted(options)[0], f"is a render option; {RELIGHT!r} takes {', '.join(RELIGHT_KEYS)}")
            for key, (kind, default, lo, hi) in RELIGHT_KEYS.items():
                v = t.get(key, kind, default, lo=lo)
                if v is not None and v > hi:
                    t.fail(key, f"must be at most {hi}, got {v}")
                if v is not None:
                    options[key] = v
        for opt in options:
            if sid != RELIGHT and sid not in APPLIES[opt]:
                t.fail(opt, f"does not apply to {sid!r} (only to {' | '.join(APPLIES[opt])})")
        t.done()
        strats.append(StrategySpec(label, sid, options))

    b = SpecTable(path, "[budgets]", doc.get("budgets", {}))
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


def check_image(t, key, path):
    """A spec error, before anything is written, if OpenImageIO cannot open the image."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        t.fail(key, f"cannot read {path} as an image ({oiio.geterror().strip() or 'unknown format'})")
    inp.close()
