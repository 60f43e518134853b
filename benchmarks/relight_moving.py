"""Frames in which one object moves (wavlight.relight.moving, a bake with --vary object): the
Stanford bunny of benchmarks/scenes/bunny_ggx.toml (ggx 0.2 gold) moved and turned over its lambert
floor under rooitou_park_1k (a small, very bright sun: hard shadows), at SIZE x SIZE (default 256).
Both are fetched data (wavlight.data): downloaded on first use, or read from WAVLIGHT_DATA.

Measured:

- the bake: wall seconds (the transfer of the scene without the bunny, its product with the
  fixed lighting on 16 x 16 texels, and the scene without the bunny converged by `wavelet` at
  --static-spp) and the file's size. The frames read only the product and the converged image,
  so the transfer is baked at --levels 4 (16 x 16 texels, the product's own resolution; the
  automatic choice would take 128 x 128 texels for the sun, which these frames never read);
- the preview frame (the moving estimator at --preview-spp samples per pixel, what the viewer
  draws while a slider is dragged) at --placements places: the median frame time over --frames
  frames per place and the frames per second, beside the viewer's tone map and JPEG encoding of
  it (benchmarks/viewer_fps.py measures the page's side for lighting bakes); the target is
  >= 10 frames/s. Each frame is a new place (a drag through the place: 1 cm and 1 degree a
  frame) and a new seed, so that nothing is kept from the frame before; the same drag at the
  viewer's fixed seed 0 (which keeps the camera rays) is timed beside it;
- where a preview frame's time goes: every stage of MovingObject.frame wrapped by a timer (the
  time of a stage excludes the stages it calls; the chunks run on a pool of threads, so the
  stages overlap and their sum exceeds the frame's), the median over the frames of each place;
- the target: relMSE = mean(((x - r)^2 - s_r^2) / (r^2 + 0.01)) (wavlight.evaluation.metrics.relmse,
  the reference's variance subtracted) against `mis` at --ref-spp of the moved scene, at
  --error-placements places and --seeds seeds, for the moving frame at --spp (its time: the
  frame alone, the bake and the scene loaded and its first frame made; a new seed each time, so
  that nothing of a frame before is kept) and `wavelet` rendered from scratch (setup + render:
  each place is a scene of its own) at --spp, alternating, then `wavelet` at equal time (the spp
  whose setup + render takes the frame's median time, from its own seconds per spp); the same
  with the stratified sampler beside (the moving frame's camera samples and shading uniforms
  are stratified); per pixel class (the pixels rendered in full, those whose value the object's
  occlusion changes, the others) each one's part of relMSE; the ratios (relMSE, time, efficiency
  = the inverse of their product, the equal-time relMSE ratio; the target is <= 0.5), and the same
  with the bake's wall time amortized over 10, 100, 1000 frames (modelled: wavelet's relMSE as
  1 / spp), with the frames at which the bake pays for itself. The floor the bake leaves: the
  relMSE the converged image without the bunny adds where the frame uses it,
  mean(s_static^2 / (r^2 + 0.01)) over the pixels not rendered in full;
- the variance analysis (--no-analysis leaves it out): at each place, each class's part of
  relMSE at 1, 2, 4, 8, 16 and 64 directions per camera sample, with the frame's wall and CPU
  seconds; at the second place, on the pixels the object shadows, the occlusion D by the numpy
  twin with one or four directions, independent or stratified over the pixel's directions.

Nothing is cached in the repository: the bake file and the references (keyed by the scene, the
settings and a hash of wavlight/ and kernels/) go to --cache (default /tmp/relight-moving/).

    python benchmarks/relight_moving.py            # -> benchmarks/results/relight_moving.json
    python benchmarks/relight_moving.py --quick    # a small, fast run (96 x 96, fewer samples)
"""
from __future__ import annotations

import argparse
import contextlib
import glob
import hashlib
import json
import os
import statistics
import sys
import threading
import time
import tomllib

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import needs  # noqa: E402
from provenance import add_output_argument, provenance, write_result  # noqa: E402

ROOT = os.path.dirname(HERE)
SCENE = os.path.join(HERE, "scenes", "bunny_ggx.toml")
ENVMAP = "rooitou_park_1k"     # a wavlight.data asset
TARGET_FPS = 10.0
#: the target: a frame's relMSE at most this share of wavelet's at equal time
TARGET_EQUAL_TIME = 0.5
#: the bake amortized over this many frames
AMORTIZED = (10, 100, 1000)
#: the variance analysis: directions per camera sample of the occlusion D
ANALYSIS_DIRECTIONS = (1, 2, 4, 8, 16, 64)
#: places of the bunny over its floor: translation (x, 0, z) and degrees about +Y
PLACES = [((0.0, 0.0, 0.0), 0.0), ((0.6, 0.0, 0.4), 45.0), ((-0.7, 0.0, -0.5), 120.0), ((0.3, 0.0, -1.0), 250.0)]


# ----------------------------------------------------------------------------- the scene
def bunny_dict(translate=None, rotate_y=None) -> dict:
    """benchmarks/scenes/bunny_ggx.toml as a dict under rooitou_park_1k, the bunny named "bunny"
    (and moved)."""
    with open(SCENE, "rb") as fh:
        d = tomllib.load(fh)
    d["environment"]["file"] = f"data:{ENVMAP}"
    d["environment"]["rotate_y"] = 0.0
    bunny = d["objects"][0]
    bunny["name"] = "bunny"
    if translate is not None:
        bunny["translate"] = [float(x) for x in translate]
    if rotate_y is not None:
        bunny["rotate"] = [0.0, 1.0, 0.0, float(rotate_y)]
    return d


def load(d):
    import wavlight

    return wavlight.load_dict(d, base_dir=os.path.join(ROOT, "scenes"))


def source_hash() -> str:
    h = hashlib.sha256()
    for path in sorted(glob.glob(os.path.join(ROOT, "wavlight", "**", "*.py"), recursive=True)
                       + glob.glob(os.path.join(ROOT, "kernels", "*"))):
        h.update(os.path.relpath(path, ROOT).encode())
        with open(path, "rb") as fh:
            h.update(fh.read())
    return h.hexdigest()[:16]


def reference(cache, d, size, spp, seed, reuse):
    """(image, stderr, info) of `mis` at ``spp`` of the dict ``d``; kept in ``cache``."""
    import wavlight

    key = hashlib.sha256(json.dumps(["mis", d, size, spp, seed, source_hash()], sort_keys=True)
                         .encode()).hexdigest()[:20]
    path = os.path.join(cache, f"reference-{key}.npz")
    if reuse and os.path.exists(path):
        z = np.load(path)
        return z["image"], z["stderr"], dict(json.loads(str(z["info"])), cached=True)
    t0 = time.perf_counter()
    r = wavlight.render_full(load(d), spp=spp, strategy="mis", width=size, height=size, seed=seed)
    info = {"spp": spp, "seed": seed, "wall_seconds": round(time.perf_counter() - t0, 2)}
    tmp = path + f".{os.getpid()}.tmp.npz"
    np.savez(tmp, image=r.image, stderr=r.stderr, info=json.dumps(info))
    os.replace(tmp, path)
    return r.image, r.stderr, dict(info, cached=False)


# ----------------------------------------------------------------------------- stage timer
class Stages:
    """Exclusive wall time per stage: a stage's time leaves out the stages it calls. Each thread
    keeps its own stack (the frame shades the pixels rendered in full on a second thread), so the
    stages of the two threads overlap in time and their sum exceeds the frame's."""

    def __init__(self):
        self.seconds: dict[str, float] = {}
        self._local = threading.local()
        self._lock = threading.Lock()

    def wrap(self, label, fn):
        def timed(*args, **kwargs):
            stack = self._local.__dict__.setdefault("stack", [])
            frame = [label, time.perf_counter(), 0.0]     # label, start, time of the stages called
            stack.append(frame)
            try:
                return fn(*args, **kwargs)
            finally:
                stack.pop()
                total = time.perf_counter() - frame[1]
                with self._lock:
                    self.seconds[label] = self.seconds.get(label, 0.0) + total - frame[2]
                if stack:
                    stack[-1][2] += total
        return timed

    def take(self) -> dict:
        out, self.seconds = self.seconds, {}
        return out


@contextlib.contextmanager
def staged(mover, stages: Stages):
    """MovingObject ``mover`` with every stage of its frame timed (restored on exit)."""
    from wavlight import camera
    from wavlight.relight import moving

    patched = []

    def patch(owner, name, label):
        patched.append((owner, name, getattr(owner, name), name in getattr(owner, "__dict__", {})))
        setattr(owner, name, stages.wrap(label, getattr(owner, name)))

    class TimedTree(moving.HaarTree):
        def __init__(self, *a, **k):
            stages.wrap("product trees: build (once, kept)", super().__init__)(*a, **k)

    patch(mover, "frame", "frame: mean and variance (numpy), the wait for the chunks' threads")
    patch(mover, "_chunk", "chunk: static image, sample sets (numpy)")
    patch(mover, "_object_pixels", "object pixels: mask (numpy)")
    patch(mover, "_sphere_pixels", "object pixels: cone test (numpy)")
    patch(mover, "_boxes", "object pixels: triangle boxes (numpy)")
    patch(mover, "_full", "wavelet pixels: hits, shadow rays set-up (numpy)")
    patch(mover, "_shader", "wavelet pixels: wavelet shading (OpenCL shade)")
    patch(mover._kernels, "points", "wavelet pixels: shading points (OpenCL moving_points)")
    patch(mover, "_occlusion", "occlusion D: records, sums (numpy)")
    patch(mover._kernels, "occlusion", "occlusion D: directions, box test, records (OpenCL moving_occlusion)")
    patch(mover, "_trace_object", "object rays: to its frame (numpy)")
    patch(mover, "_camera", "camera: sample cache (numpy)")
    patch(camera, "pass_rays", "camera: rays (OpenCL camera_rays)")
    patch(mover.rest_tracer, "intersect_uv", "trace: camera rays vs the rest (embree)")
    patch(mover.rest_tracer, "occluded", "trace: shadow rays vs the rest (embree)")
    patch(mover.object_tracer, "intersect_uv", "trace: camera rays vs the object (embree)")
    patch(mover.object_tracer, "occluded", "trace: shadow rays vs the object (embree)")
    tree = moving.HaarTree
    moving.HaarTree = TimedTree
    try:
        yield
    finally:
        moving.HaarTree = tree
        for owner, name, value, own in reversed(patched):
            if own or isinstance(owner, type(moving)):
                setattr(owner, name, value)
            else:
                delattr(owner, name)


def wait_for_quiet(limit, minutes):
    """Wait (polling every 30 s, at most ``minutes``) until the 1-minute load average is below
    ``limit``; what happened."""
    t0 = time.monotonic()
    while True:
        la = os.getloadavg()[0]
        if la < limit or time.monotonic() - t0 + 30 > minutes * 60:
            return {"quiet": la < limit, "limit": limit, "load": round(la, 2), "waited_seconds": round(time.monotonic() - t0)}
        print(f"relight_moving: load {la:.2f} >= {limit}; waiting 30 s", file=sys.stderr, flush=True)
        time.sleep(30)


def max_rss_mb() -> float:
    import resource

    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)


def load_average():
    return [round(x, 2) for x in os.getloadavg()]


# ----------------------------------------------------------------------------- the target
def pixel_classes(mover, R, T, ref, ref_se, size):
    """(H, W) masks of the variance analysis: ``object``, the pixels rendered in full (those
    that may see the object); ``shadowed``, the others where the converged image without the
    object exceeds the reference by more than 4 standard errors (the object's shadow and its
    occlusion of the sky: where D is not 0); ``others``."""
    obj = mover._object_pixels(R, T, size, size)
    diff = (mover.static - np.asarray(ref, np.float64)).mean(2)
    sigma = np.sqrt((mover.static_se ** 2 + np.asarray(ref_se, np.float64) ** 2).mean(2))
    shadowed = ~obj & (diff > 4 * sigma)
    return {"object": obj, "shadowed": shadowed, "others": ~obj & ~shadowed}


def class_shares(image, ref, ref_se, classes) -> dict:
    """Each class's part of relMSE (its pixels' terms summed over all the image's values: the
    parts add up to relMSE)."""
    from wavlight.evaluation.metrics import EPS

    x, r = np.asarray(image, np.float64), np.asarray(ref, np.float64)
    terms = (((x - r) ** 2 - np.asarray(ref_se, np.float64) ** 2) / (r * r + EPS)).mean(2)
    return {k: round(float(terms[m].sum() / terms.size), 7) for k, m in classes.items()}


def compare(args, transfer, scene, mover, bake_wall) -> dict:
    """The moving frame at --spp against `wavelet` of the moved scene (a render from scratch:
    its setup counted), at --seeds seeds and --error-placements places, alternating the two;
    `wavelet` with the stratified sampler beside it (the moving frame's camera samples and
    shading uniforms are stratified); both again at equal time; per-class relMSE; the bake
    amortized."""
    import wavlight
    from wavlight.evaluation.metrics import relmse

    size, spp = args.size, args.spp
    seeds = [1 + k for k in range(args.seeds)]
    rows = []
    for i in range(1, 1 + args.error_placements):
        translate, degrees = PLACES[i]
        where = (list(translate), [0.0, 1.0, 0.0, degrees])
        d = bunny_dict(translate, degrees)
        print(f"reference: mis {args.ref_spp} spp of place {i} ...", file=sys.stderr, flush=True)
        ref, ref_se, ref_info = reference(args.cache, d, size, args.ref_spp, 10_000 + i, not args.no_reuse)
        moved = load(d)
        classes = pixel_classes(mover, *mover.placement(*where), ref, ref_se, size)

        def render(seed, n, sampler="independent"):
            c0, t0 = time.process_time(), time.perf_counter()
            out = wavlight.render_full(moved, spp=n, strategy="wavelet", width=size, height=size, seed=seed,
                                       sampler=sampler)
            return out, time.perf_counter() - t0, time.process_time() - c0

        runs = {"moving": [], "wavelet": [], "wavelet_stratified": []}
        mover.frame(*where, spp=spp, seed=0)   # the place's first frame (not timed)
        for seed in seeds:   # alternating: the load drifts
            mover._mask_key = None   # the place's pixel mask made again: per-frame preparation, timed
            c0, t0 = time.process_time(), time.perf_counter()
            m = mover.frame(*where, spp=spp, seed=seed)
            runs["moving"].append((m.image, time.perf_counter() - t0, 0.0, time.process_time() - c0))
            for name, sampler in (("wavelet", "independent"), ("wavelet_stratified", "stratified")):
                out, secs, cpu = render(seed, spp, sampler)
                runs[name].append((out.image, secs, out.stats["setup_seconds"], cpu))
        t_moving = statistics.median(r[1] for r in runs["moving"])
        methods = {}
        for name, rs in runs.items():
            methods[name] = {"spp": spp, "seconds": [round(r[1], 3) for r in rs],
                             "seconds_median": round(statistics.median(r[1] for r in rs), 3),
                             "cpu_seconds_median": round(statistics.median(r[3] for r in rs), 3),
                             "relmse": [round(relmse(r[0], ref, ref_se), 7) for r in rs],
                             "classes": [class_shares(r[0], ref, ref_se, classes) for r in rs]}
            methods[name]["relmse_mean"] = round(float(np.mean(methods[name]["relmse"])), 7)
            if name != "moving":
                setup = statistics.median(r[2] for r in rs)
                methods[name]["setup_seconds_median"] = round(setup, 3)
                per_spp = max(methods[name]["seconds_median"] - setup, 1e-6) / spp
                methods[name]["render_seconds_per_spp"] = round(per_spp, 5)
        for name, sampler in (("wavelet", "independent"), ("wavelet_stratified", "stratified")):   # equal time
            w = methods[name]
            spp_eq = int(max(1, round((t_moving - w["setup_seconds_median"]) / w["render_seconds_per_spp"])))
            eq = [render(seed, spp_eq, sampler) for seed in seeds]
            methods[f"{name}_equal_time"] = {
                "spp": spp_eq, "seconds": [round(e[1], 3) for e in eq],
                "seconds_median": round(statistics.median(e[1] for e in eq), 3),
                "cpu_seconds_median": round(statistics.median(e[2] for e in eq), 3),
                "relmse": [round(relmse(e[0].image, ref, ref_se), 7) for e in eq]}
            eq_row = methods[f"{name}_equal_time"]
            eq_row["relmse_mean"] = round(float(np.mean(eq_row["relmse"])), 7)
        floor = mover.static_se ** 2 / (np.asarray(ref, np.float64) ** 2 + 1e-2)
        rows.append({"place": i, "translate": translate, "rotate_y": degrees, "reference": ref_info,
                     "static_floor_relmse": round(float(np.mean(np.where(classes["object"][..., None], 0.0,
                                                                         floor))), 7),
                     "reference_noise_relmse": round(float(np.mean(np.asarray(ref_se, np.float64) ** 2 /
                                                                   (np.asarray(ref, np.float64) ** 2 + 1e-2))), 7),
                     "pixels": {k: int(v.sum()) for k, v in classes.items()}, "methods": methods,
                     "load_average": load_average()})
        line = ", ".join(f"{k} {v['relmse_mean']:.4g} ({v['spp']} spp, {v['seconds_median']:.2f} s)"
                         for k, v in methods.items())
        print(f"place {i}: relMSE {line}", file=sys.stderr, flush=True)
    return summarize(rows, bake_wall, spp) | {"spp": spp, "seeds": seeds, "ref_spp": args.ref_spp,
                                                "max_rss_mb": max_rss_mb()}


def summarize(rows, bake_wall, spp) -> dict:
    """The ratios over all places and seeds (per place: means of relMSE, medians of seconds; then
    their geometric mean over the places): relMSE ratio and time ratio at equal spp, efficiency
    (the inverse of their product: above 1 the moving frame is the more efficient), the equal-time
    relMSE ratio (measured: wavelet rendered at the spp that takes the frame's time), the same
    against wavelet with the stratified sampler, the ratio of the process's CPU seconds (every
    thread's: PoCL's, embree's; less moved by other processes' load than the wall time's), and
    the bake amortized over AMORTIZED frames
    (modelled: wavelet's relMSE as 1 / spp at its measured seconds per spp and setup, the frame's
    seconds plus the bake's over the frames)."""
    def gmean(values):
        return float(np.exp(np.mean(np.log(values))))

    per_place = []
    for row in rows:
        m = row["methods"]
        mv, w = m["moving"], m["wavelet"]
        r_m, r_w, t_m, t_w = mv["relmse_mean"], w["relmse_mean"], mv["seconds_median"], w["seconds_median"]
        per_place.append({"place": row["place"], "relmse_ratio": r_m / r_w, "time_ratio": t_m / t_w,
                          "efficiency": (r_w * t_w) / (r_m * t_m),
                          "equal_time_relmse_ratio": r_m / m["wavelet_equal_time"]["relmse_mean"],
                          "stratified_relmse_ratio": r_m / m["wavelet_stratified"]["relmse_mean"],
                          "stratified_time_ratio": t_m / m["wavelet_stratified"]["seconds_median"],
                          "cpu_time_ratio": mv["cpu_seconds_median"] / w["cpu_seconds_median"],
                          "stratified_equal_time_relmse_ratio":
                              r_m / m["wavelet_stratified_equal_time"]["relmse_mean"],
                          "r_m": r_m, "r_w": r_w, "t_m": t_m, "t_w": t_w, "setup_w": w["setup_seconds_median"],
                          "per_spp_w": w["render_seconds_per_spp"]})
    keys = ("relmse_ratio", "time_ratio", "efficiency", "equal_time_relmse_ratio", "stratified_relmse_ratio",
            "stratified_time_ratio", "stratified_equal_time_relmse_ratio", "cpu_time_ratio")
    overall = {k: round(gmean([p[k] for p in per_place]), 4) for k in keys}
    overall["meets_target"] = bool(overall["equal_time_relmse_ratio"] <= TARGET_EQUAL_TIME)
    overall["target"] = f"equal-time relMSE ratio <= {TARGET_EQUAL_TIME}"
    frames = []
    for n in AMORTIZED:
        eff, eq, tr = [], [], []
        for p in per_place:
            t = p["t_m"] + bake_wall / n
            r_w_eq = p["r_w"] * spp * p["per_spp_w"] / max(t - p["setup_w"], p["per_spp_w"])
            eff.append((p["r_w"] * p["t_w"]) / (p["r_m"] * t))
            eq.append(p["r_m"] / r_w_eq)
            tr.append(t / p["t_w"])
        frames.append({"frames": n, "time_ratio": round(gmean(tr), 4), "efficiency": round(gmean(eff), 4),
                       "equal_time_relmse_ratio": round(gmean(eq), 4)})
    # break-even: the frames from which the bake's time is paid for, per place (then the largest)
    even, target = [], []
    for p in per_place:
        spare = p["r_w"] * p["t_w"] / p["r_m"] - p["t_m"]             # efficiency 1
        even.append(bake_wall / spare if spare > 0 else None)
        spare_t = p["setup_w"] + TARGET_EQUAL_TIME * spp * p["per_spp_w"] * p["r_w"] / p["r_m"] - p["t_m"]
        target.append(bake_wall / spare_t if spare_t > 0 else None)
    worst = lambda v: None if any(x is None for x in v) else int(np.ceil(max(v)))   # noqa: E731
    return {"places": rows, "per_place": [{k: (round(v, 4) if isinstance(v, float) else v) for k, v in p.items()}
                                          for p in per_place],
            "overall": overall,
            "amortized": {"bake_seconds": round(bake_wall, 2), "frames": frames,
                          "break_even_frames": worst(even), "target_frames": worst(target),
                          "model": "wavelet's relMSE as 1/spp at its measured seconds per spp and setup; the "
                                   "frame's seconds plus the bake's over the frames"}}


def variance_analysis(args, transfer, scene) -> dict:
    """Where the occlusion estimate's variance comes from: (1) at every place compared, per pixel
    class, the moving frame at 1, 2, 4, 8, 16 and 64 directions per camera sample (the kernels;
    3 seeds), its relMSE, wall and CPU seconds, and relMSE x CPU seconds over that at 4
    directions (the default); (2) at the second place, on the shadowed pixels, D by the numpy
    twin with one and four directions per camera sample, independent or stratified over the
    pixel (the estimator before and after)."""
    from wavlight.evaluation.metrics import relmse
    from wavlight.relight import moving
    from wavlight.relight.moving import MovingObject, counter_uniforms

    size = args.size
    out = {"spp": args.spp, "places": []}
    movers = {nd: MovingObject(transfer, scene, directions=nd) for nd in ANALYSIS_DIRECTIONS}
    for i in range(1, 1 + args.error_placements):
        translate, degrees = PLACES[i]
        where = (list(translate), [0.0, 1.0, 0.0, degrees])
        ref, ref_se, _ = reference(args.cache, bunny_dict(translate, degrees), size, args.ref_spp, 10_000 + i,
                                   not args.no_reuse)
        classes = pixel_classes(movers[4], *movers[4].placement(*where), ref, ref_se, size)
        rows = []
        for nd, mover in movers.items():
            mover.frame(*where, spp=args.spp, seed=0)
            shares, wall, cpu, err = [], [], [], []
            for seed in (1, 2, 3):
                mover._mask_key = None
                c0, t0 = time.process_time(), time.perf_counter()
                r = mover.frame(*where, spp=args.spp, seed=seed)
                wall.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
                shares.append(class_shares(r.image, ref, ref_se, classes))
                err.append(relmse(r.image, ref, ref_se))
            rows.append({"directions": nd, "relmse": round(float(np.mean(err)), 7),
                         "seconds_median": round(statistics.median(wall), 3),
                         "cpu_seconds_median": round(statistics.median(cpu), 3),
                         "classes": {k: round(float(np.mean([s[k] for s in shares])), 7) for k in classes}})
            print(f"analysis: place {i}, {nd} directions: {rows[-1]}", file=sys.stderr, flush=True)
        at4 = next(r for r in rows if r["directions"] == 4)
        for r in rows:
            r["relmse_cpu_over_4"] = round(r["relmse"] * r["cpu_seconds_median"]
                                           / (at4["relmse"] * at4["cpu_seconds_median"]), 3)
        out["places"].append({"place": i, "translate": translate, "rotate_y": degrees,
                              "pixels": {k: int(v.sum()) for k, v in classes.items()}, "directions": rows})
    i = 2 if args.error_placements >= 2 else 1
    translate, degrees = PLACES[i]
    where = (list(translate), [0.0, 1.0, 0.0, degrees])
    ref, ref_se, _ = reference(args.cache, bunny_dict(translate, degrees), size, args.ref_spp, 10_000 + i,
                               not args.no_reuse)
    classes = pixel_classes(movers[4], *movers[4].placement(*where), ref, ref_se, size)
    out["twin_place"] = i
    # the numpy twin on the shadowed pixels: independent against stratified directions
    mover = MovingObject(transfer, scene, backend="numpy", directions=1)
    R, T = mover.placement(*where)
    spp = args.spp
    cam = mover._camera(0, 0, size * size, spp, 1, keep=False)
    rest = np.flatnonzero(np.repeat(classes["shadowed"].reshape(-1), spp) & (cam.prim >= 0))
    pixels = np.flatnonzero(classes["shadowed"].reshape(-1))
    static = mover.static.reshape(-1, 3)[pixels]
    r = np.asarray(ref, np.float64).reshape(-1, 3)[pixels]
    s2 = np.asarray(ref_se, np.float64).reshape(-1, 3)[pixels] ** 2
    stratified_uniforms = moving.stratified_uniforms

    def independent(seed, tile, stream, first, slots, spp_, directions=1):
        slots = np.asarray(slots, np.int64)
        return counter_uniforms(seed, tile, stream, np.repeat(first + slots, directions),
                                np.tile(np.arange(directions), len(slots)))

    out["numpy_twin_shadowed"] = []
    try:
        for nd in (1, 4):
            mover.directions = nd
            for label, fn in (("independent", independent), ("stratified", stratified_uniforms)):
                moving.stratified_uniforms = fn
                parts = []
                for seed in (1, 2, 3):
                    D, _ = mover._occlusion(R, T, cam, rest, 0, size * size, spp, seed, 0, 0)
                    per_pixel = np.zeros((size * size, 3))
                    np.add.at(per_pixel, rest // spp, D)
                    B = static - per_pixel[pixels] / spp
                    parts.append(float((((B - r) ** 2 - s2) / (r * r + 1e-2)).sum() / (3 * size * size)))
                out["numpy_twin_shadowed"].append({"directions": nd, "uniforms": label,
                                                   "shadowed_relmse": round(float(np.mean(parts)), 7)})
                print(f"analysis: twin {nd} {label}: {out['numpy_twin_shadowed'][-1]}", file=sys.stderr, flush=True)
    finally:
        moving.stratified_uniforms = stratified_uniforms
    return out


# ----------------------------------------------------------------------------- the run
def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    ap.add_argument("--size", type=int, default=256, help="image width and height (default 256)")
    ap.add_argument("--bake-spp", type=int, default=4, help="camera samples per pixel of the bake (default 4)")
    ap.add_argument("--levels", type=int, default=4, help="texel levels of the bake (default 4: 16 x 16)")
    ap.add_argument("--static-spp", type=int, default=256,
                    help="samples per pixel of the converged image without the bunny (default 256)")
    ap.add_argument("--preview-spp", type=int, default=1, help="samples per pixel of the preview frame (default 1)")
    ap.add_argument("--placements", type=int, default=4, help=f"places timed, at most {len(PLACES)} (default 4)")
    ap.add_argument("--frames", type=int, default=5, help="preview frames timed per place (default 5)")
    ap.add_argument("--spp", type=int, default=16, help="samples per pixel of the error comparison (default 16)")
    ap.add_argument("--error-placements", type=int, default=3,
                    help="places of the error comparison, from the second (default 3)")
    ap.add_argument("--seeds", type=int, default=3, help="seeds of the frames compared at each place (default 3)")
    ap.add_argument("--no-analysis", dest="analysis", action="store_false",
                    help="leave out the variance analysis of the occlusion estimate")
    ap.add_argument("--ref-spp", type=int, default=4096, help="samples per pixel of the mis reference (default 4096)")
    ap.add_argument("--cache", default="/tmp/relight-moving", help="bake file and references (default /tmp/relight-moving)")
    ap.add_argument("--no-reuse", action="store_true", help="render the references again")
    ap.add_argument("--quick", action="store_true",
                    help="a small run: 96 x 96, static 64 spp, 2 places of 3 frames, 1 error place, reference 512 spp")
    ap.add_argument("--wait-load", type=float, default=1.5, metavar="L",
                    help="before timing, wait until the 1-minute load average is below L (default 1.5)")
    ap.add_argument("--wait-minutes", type=float, default=0.0, metavar="M",
                    help="wait at most M minutes for that (default 0: no wait; the load is recorded either way)")
    add_output_argument(ap, "relight_moving")
    args = ap.parse_args()
    if args.quick:
        args.size, args.static_spp, args.placements, args.frames = 96, 64, 2, 3
        args.error_placements, args.ref_spp, args.seeds = 1, 512, 2
    for name in ("size", "bake_spp", "static_spp", "preview_spp", "placements", "frames", "spp", "ref_spp", "seeds"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be at least 1")
    needs.fetch("relight_moving", ENVMAP, "bunny")
    args.placements = min(args.placements, len(PLACES))
    args.error_placements = min(max(args.error_placements, 0), len(PLACES) - 1)
    waited = wait_for_quiet(args.wait_load, args.wait_minutes) if args.wait_minutes > 0 else None
    prov = provenance()

    import wavlight
    from wavlight.relight.moving import MovingObject
    from wavlight.relight.viewer import encode

    os.makedirs(args.cache, exist_ok=True)
    t_run = time.perf_counter()
    size = args.size
    scene = load(bunny_dict())
    bake_path = os.path.join(args.cache, f"bunny-{size}-n{args.levels}-s{args.static_spp}.wlt")
    print(f"baking {bake_path} ...", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    transfer = wavlight.bake(scene, bake_path, width=size, height=size, spp=args.bake_spp, levels=args.levels,
                             terms=64, priority="area", vary="object", object="bunny", static_spp=args.static_spp)
    bake_wall = time.perf_counter() - t0
    result = {"scene": "benchmarks/scenes/bunny_ggx.toml, bunny moved over its floor", "environment": ENVMAP,
              "width": size, "height": size, "target_fps": TARGET_FPS, "quick": args.quick, "waited": waited,
              "bake": {"wall_seconds": round(bake_wall, 2), "file_bytes": transfer.file_bytes,
                       "file_megabytes": round(transfer.file_bytes / 1e6, 2), "spp": args.bake_spp,
                       "texels": f"{1 << transfer.n_levels}x{1 << transfer.n_levels}",
                       "product_texels": f"{1 << transfer.header['product_levels']}x"
                                         f"{1 << transfer.header['product_levels']}",
                       "static": transfer.header["static"], "transfer_seconds": transfer.measured["bake_seconds"],
                       "path": bake_path}}
    print(f"bake: {bake_wall:.1f} s, {transfer.file_bytes / 1e6:.1f} MB", file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    mover = MovingObject(transfer, scene)
    result["bake"]["viewer_setup_seconds"] = round(time.perf_counter() - t0, 3)

    def placement(i, k=None):
        """Place i; with k, frame k of a drag through it (1 cm and 1 degree a frame): a new place
        every frame, so that nothing of the place is kept from the frame before."""
        translate, degrees = PLACES[i]
        if k is None:
            return list(translate), [0.0, 1.0, 0.0, degrees]
        return [translate[0] + 0.01 * k, translate[1], translate[2]], [0.0, 1.0, 0.0, degrees + k]

    # -- the preview frame's rate, and where its time goes
    mover.frame(*placement(0), spp=args.preview_spp, seed=0)      # warm-up: the kernels compiled
    stages = Stages()
    places, all_times, all_viewer, per_stage = [], [], [], {}
    for i in range(args.placements):
        times = []
        for k in range(args.frames):   # a new place and a new seed every frame: nothing kept
            t0 = time.perf_counter()
            r = mover.frame(*placement(i, k), spp=args.preview_spp, seed=1000 * i + k)
            times.append(time.perf_counter() - t0)
        viewer_times = []
        for k in range(args.frames):   # as the viewer draws a drag: seed 0, its camera rays and samples kept
            t0 = time.perf_counter()
            mover.frame(*placement(i, k), spp=args.preview_spp, seed=0)
            viewer_times.append(time.perf_counter() - t0)
        all_viewer += viewer_times
        staged_times = []
        with staged(mover, stages):
            for k in range(max(2, args.frames // 2)):
                t0 = time.perf_counter()
                mover.frame(*placement(i, k), spp=args.preview_spp, seed=100 + 1000 * i + k)
                staged_times.append(time.perf_counter() - t0)
                for label, s in stages.take().items():
                    per_stage.setdefault(label, []).append(s)
        t0 = time.perf_counter()
        jpeg = encode(r.image, 0.0, "jpeg")
        encode_s = time.perf_counter() - t0
        median = statistics.median(times)
        all_times += times
        places.append({"translate": PLACES[i][0], "rotate_y": PLACES[i][1], "frame_ms_median": round(median * 1e3, 1),
                       "fps": round(1.0 / median, 2), "frame_ms": [round(t * 1e3, 1) for t in times],
                       "viewer_frame_ms_median": round(statistics.median(viewer_times) * 1e3, 1),
                       "timed_frame_ms_median": round(statistics.median(staged_times) * 1e3, 1),
                       "object_pixels": r.stats["object_pixels"],
                       "object_pixel_share": round(r.stats["object_pixels"] / (size * size), 3),
                       "rays_per_frame": r.stats["rays"], "jpeg_encode_ms": round(encode_s * 1e3, 2),
                       "jpeg_bytes": len(jpeg)})
        print(f"place {i}: {PLACES[i]}: preview frame {median * 1e3:.0f} ms ({1 / median:.2f} frames/s; "
              f"{statistics.median(viewer_times) * 1e3:.0f} ms at the viewer's fixed seed), "
              f"{r.stats['object_pixels']} pixels in full", file=sys.stderr, flush=True)
    median_all = statistics.median(all_times)
    stage_ms = {label: round(statistics.median(v) * 1e3, 2) for label, v in per_stage.items()}
    stage_ms = dict(sorted(stage_ms.items(), key=lambda kv: -kv[1]))
    stage_total = sum(stage_ms.values())
    encode_ms = statistics.median(p["jpeg_encode_ms"] for p in places)
    result["preview"] = {"spp": args.preview_spp, "frames_per_place": args.frames, "places": places,
                         "load_average": load_average(), "max_rss_mb": max_rss_mb(),
                         "frame_ms_median": round(median_all * 1e3, 1), "fps": round(1.0 / median_all, 2),
                         "viewer_fps_bound": round(1e3 / (median_all * 1e3 + encode_ms), 2),
                         "meets_target": 1.0 / median_all >= TARGET_FPS,
                         "viewer_frame_ms_median": round(statistics.median(all_viewer) * 1e3, 1),
                         "viewer_fps": round(1.0 / statistics.median(all_viewer), 2),
                         "stages_ms_median": stage_ms, "stages_ms_sum": round(stage_total, 1),
                         "stages_share": {k: round(v / stage_total, 3) for k, v in stage_ms.items()}
                         if stage_total > 0 else {}}

    # -- the target: relMSE and time against wavelet of the moved scene, the bake amortized
    result["error"] = compare(args, transfer, scene, mover, bake_wall)
    if args.analysis:
        result["variance_analysis"] = variance_analysis(args, transfer, scene)
    result["run_seconds"] = round(time.perf_counter() - t_run, 1)

    print(f"\npreview frame ({args.preview_spp} spp, {size} x {size}): median {median_all * 1e3:.0f} ms, "
          f"{1 / median_all:.2f} frames/s (target {TARGET_FPS:g}); with JPEG encoding "
          f"{result['preview']['viewer_fps_bound']} frames/s; at the viewer's fixed seed "
          f"{result['preview']['viewer_frame_ms_median']:.0f} ms", file=sys.stderr)
    print("where a preview frame's time goes (median ms, exclusive):", file=sys.stderr)
    for label, ms in stage_ms.items():
        print(f"  {ms:8.1f}  {label}", file=sys.stderr)
    e = result["error"]["overall"]
    print(f"\n{args.spp} spp: relMSE ratio {e['relmse_ratio']:.3f}, time ratio {e['time_ratio']:.3f}, efficiency "
          f"{e['efficiency']:.2f}; equal time: relMSE ratio {e['equal_time_relmse_ratio']:.3f} "
          f"(target <= {TARGET_EQUAL_TIME}: {'met' if e['meets_target'] else 'not met'})", file=sys.stderr)
    for row in result["error"]["amortized"]["frames"]:
        print(f"  bake over {row['frames']} frames: time ratio {row['time_ratio']:.3f}, efficiency "
              f"{row['efficiency']:.3f}, equal-time relMSE ratio {row['equal_time_relmse_ratio']:.3f}", file=sys.stderr)
    write_result(args.output, result, prov)
    transfer.close()


if __name__ == "__main__":
    main()
