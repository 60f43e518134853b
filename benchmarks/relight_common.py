"""What benchmarks/relight_*.py share (not a benchmark itself: it writes no result): the scenes
as dicts, the cache of bakes and references in /tmp/relight-bench/ (never in the repository),
the error measures, the wait for a quiet machine, and the parsing, provenance and writing of
each script's result (:func:`parser`, :func:`parse`, :func:`begin`, :func:`finish`).

Scenes (dicts of the scene-file structure, :func:`wavlight.load_dict`):

- ``bunny_ggx/<map>``: benchmarks/scenes/bunny_ggx.toml (ggx 0.2 gold bunny on a lambert 0.5 floor) under
  ``<map>`` (st_fagans_interior_1k, potsdamer_platz_1k, rooitou_park_1k);
- ``bunny_lambert/rooitou_park_1k``: the same bunny in lambert, albedo 0.7, on its floor under
  the park's sun (a diffuse object with hard shadows);
- ``sphere_ggx/rooitou_park_1k``: a ggx 0.2 gold sphere of radius 0.5 resting on the same floor,
  same camera, under the sun;
- ``spot_lambert/<map>``: scenes/spot_ggx.toml (Keenan Crane's Spot on a lambert floor) with Spot
  in lambert, its copper's albedo, under ``<map>`` (rooitou_park_1k: the park's low sun, long
  shadows on the floor).

Maps and the bunny are named as ``data:NAME`` (:mod:`wavlight.data`): fetched on first use, or
found in the folder that ``WAVLIGHT_DATA`` names; :func:`begin` fetches every one of
:data:`ASSETS` before anything is timed.

A frame of a bake at rotation r (or under another map) is compared with ``mis`` of the same dict
with ``environment.rotate_y = r`` (or ``environment.file`` swapped): :func:`lit`.

Cache: a bake is kept as /tmp/relight-bench/bakes/<key>.wlt with a <key>.json beside it (the
wall time and the load average of the bake); a reference as references/<key>.npz. The key
hashes the scene dict, every setting, and the source files the result depends on (so an edit of
the bake or the renderer keys other files; FORMAT_VERSION alone would not notice a changed layout).
"""
from __future__ import annotations

import argparse
import copy
import glob
import hashlib
import json
import os
import sys
import time
import tomllib

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
CACHE = os.environ.get("RELIGHT_BENCH_CACHE", "/tmp/relight-bench")
#: the wavlight.data assets the relight benchmarks read (their scenes' maps, relight_error.py's
#: other maps, the bunny)
ASSETS = ("bunny", "spot", "rooitou_park_1k", "st_fagans_interior_1k", "potsdamer_platz_1k", "empty_warehouse_01_1k",
          "kiara_1_dawn_1k", "immenstadter_horn_1k")
EPS = 1e-2   # wavlight.evaluation.metrics.EPS

#: the sources a bake file depends on
BAKE_SOURCES = ["wavlight/relight/bake.py", "wavlight/relight/store.py", "wavlight/relight/lighting.py",
                "wavlight/haar/*.py", "wavlight/camera.py", "wavlight/raytrace.py", "wavlight/bsdfs.py",
                "wavlight/envmap.py", "wavlight/scene.py", "wavlight/rng.py", "kernels/relight.cl", "kernels/haar.cl",
                "kernels/*.h"]
#: the sources a `mis` reference depends on (not the relighting's kernels and modules)
RENDER_SOURCES = ["wavlight/integrator.py", "wavlight/shading.py", "wavlight/strategies/__init__.py",
                  "wavlight/strategies/base.py", "wavlight/strategies/light.py", "wavlight/envmap.py",
                  "wavlight/camera.py", "wavlight/raytrace.py", "wavlight/bsdfs.py", "wavlight/sampler.py",
                  "wavlight/rng.py", "wavlight/scene.py", "wavlight/warp.py", "kernels/shade.cl", "kernels/tree.cl",
                  "kernels/camera.cl", "kernels/common.h", "kernels/warp.h", "kernels/bsdf.h", "kernels/product.h",
                  "kernels/rng.h", "kernels/simd.h"]


def source_hash(patterns) -> str:
    h = hashlib.sha256()
    for pat in patterns:
        for path in sorted(glob.glob(os.path.join(ROOT, pat))):
            h.update(os.path.relpath(path, ROOT).encode())
            with open(path, "rb") as fh:
                h.update(fh.read())
    return h.hexdigest()[:16]


def worktree_state() -> dict:
    """The work tree's changes to the library at the time of the run (provenance records only
    'dirty'): a hash of `git diff HEAD` over wavlight/ and kernels/ and the files it touches."""
    import subprocess

    try:
        diff = subprocess.run(["git", "-C", ROOT, "diff", "HEAD", "--", "wavlight", "kernels"], capture_output=True,
                              timeout=30).stdout
        names = subprocess.run(["git", "-C", ROOT, "diff", "HEAD", "--name-only", "--", "wavlight", "kernels"],
                               capture_output=True, text=True, timeout=30).stdout.split()
    except (OSError, subprocess.TimeoutExpired):
        return {}
    return {"library_diff_sha256": hashlib.sha256(diff).hexdigest()[:16] if diff else None, "library_changed": names,
            "bake_sources": source_hash(BAKE_SOURCES), "render_sources": source_hash(RENDER_SOURCES)}


# ----------------------------------------------------------------------------- scenes
def envmap(name: str) -> str:
    """The map ``name`` (a wavlight.data asset, e.g. ``rooitou_park_1k``) as a scene names it."""
    return f"data:{name.removesuffix('.hdr')}"


def bunny_ggx(env: str) -> dict:
    with open(os.path.join(HERE, "scenes", "bunny_ggx.toml"), "rb") as fh:
        d = tomllib.load(fh)
    d["environment"]["file"] = envmap(env)
    d["environment"]["rotate_y"] = 0.0
    return d


def bunny_lambert(env: str, albedo: float = 0.7) -> dict:
    d = bunny_ggx(env)
    d["materials"]["gold"] = {"type": "lambert", "albedo": [albedo, albedo, albedo]}
    return d


def sphere_ggx(env: str) -> dict:
    d = bunny_ggx(env)
    d["objects"][0] = {"shape": "sphere", "center": [-0.15, 0.83, 0.0], "radius": 0.5, "material": "gold"}
    return d


def spot_lambert(env: str) -> dict:
    with open(os.path.join(ROOT, "scenes", "spot_ggx.toml"), "rb") as fh:
        d = tomllib.load(fh)
    d["environment"]["file"] = envmap(env)
    d["environment"]["rotate_y"] = 0.0
    d["materials"]["copper"] = {"type": "lambert", "albedo": d["materials"]["copper"]["albedo"]}
    return d


SCENES = {"bunny_ggx": bunny_ggx, "bunny_lambert": bunny_lambert, "sphere_ggx": sphere_ggx,
          "spot_lambert": spot_lambert}


def scene_dict(name: str) -> dict:
    """'bunny_ggx/potsdamer_platz_1k' -> its dict."""
    kind, env = name.split("/")
    return SCENES[kind](env)


def lit(d: dict, rotate_y: float | None = None, env: str | None = None) -> dict:
    """The dict with its map turned to ``rotate_y`` degrees and/or swapped for ``env``."""
    d = copy.deepcopy(d)
    if env is not None:
        d["environment"]["file"] = envmap(env)
    if rotate_y is not None:
        d["environment"]["rotate_y"] = float(rotate_y)
    return d


def load(d: dict):
    import wavlight

    return wavlight.load_dict(d, base_dir=os.path.join(HERE, "scenes"))


def _key(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:20]


# ----------------------------------------------------------------------------- cache
def cached_bake(d: dict, size: int, spp: int, levels=None, terms=None, priority=None, tolerance: float = 0.02,
                bits: int = 8, seed: int = 0, reuse: bool = True, tag: str = "", progress=None):
    """(Transfer, info): the bake of ``d`` at size x size, from the cache or made by this call (info:
    wall seconds and load average of the bake, and whether it came from the cache)."""
    import wavlight

    folder = os.path.join(CACHE, "bakes")
    os.makedirs(folder, exist_ok=True)
    key = _key("bake", d, size, spp, levels, terms, priority, tolerance, bits, seed, source_hash(BAKE_SOURCES))
    path = os.path.join(folder, f"{tag}{key}.wlt")
    side = os.path.join(folder, f"{tag}{key}.json")
    if reuse and os.path.exists(path) and os.path.exists(side):
        try:
            transfer = wavlight.Transfer.load(path)
            with open(side) as fh:
                info = json.load(fh)
            return transfer, dict(info, cached=True, path=path)
        except (wavlight.WavlightError, KeyError, ValueError, OSError) as e:   # another layout: bake again
            print(f"relight cache: {path}: {e}; baking again", file=sys.stderr)
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    transfer = wavlight.bake(load(d), output=path, width=size, height=size, spp=spp, levels=levels,
                             tolerance=tolerance, bits=bits, terms=terms, priority=priority, seed=seed,
                             progress=progress)
    info = {"wall_seconds": round(time.perf_counter() - t0, 3), "load_average": [round(x, 2) for x in load0],
            "load_average_end": [round(x, 2) for x in os.getloadavg()],
            "utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    with open(side, "w") as fh:
        json.dump(info, fh)
    return transfer, dict(info, cached=False, path=path)


def reference_check(d: dict, size: int, image, stderr, spp: int = 256, seed: int = 777) -> float:
    """||R - Q||^2 / sum(s_R^2 + s_Q^2) for a fresh `mis` render Q at ``spp``: about 1 where the
    cached reference R is an estimate of the same image (far from it for another scene, map,
    rotation or estimator)."""
    import wavlight

    q = wavlight.render_full(load(d), spp=spp, strategy="mis", width=size, height=size, seed=seed)
    diff = np.asarray(image, np.float64) - q.image
    expect = (np.asarray(stderr, np.float64) ** 2 + np.asarray(q.stderr, np.float64) ** 2).sum()
    return float((diff * diff).sum() / expect)


def cached_reference(d: dict, size: int, spp: int, seed: int = 10_000, reuse: bool = True):
    """(image, stderr, info) of ``mis`` at ``spp`` for the dict ``d`` at size x size. The cache is
    keyed by the scene and settings; a reference made by other renderer sources (RENDER_SOURCES)
    is checked against a fresh 256-spp render (:func:`reference_check` within 0.7 .. 1.5) and
    rendered again if it fails."""
    import wavlight

    folder = os.path.join(CACHE, "references")
    os.makedirs(folder, exist_ok=True)
    key = _key("mis", d, size, spp, seed)
    path = os.path.join(folder, f"{key}.npz")
    sources = source_hash(RENDER_SOURCES)
    if reuse and os.path.exists(path):
        z = np.load(path)
        info = json.loads(str(z["info"]))
        if info.get("render_sources") == sources or sources in info.get("checked_sources", []):
            return z["image"], z["stderr"], dict(info, cached=True)
        ratio = reference_check(d, size, z["image"], z["stderr"])
        if 0.7 < ratio < 1.5:
            info.setdefault("checked_sources", []).append(sources)
            info.setdefault("checks", []).append(round(ratio, 4))
            tmp = path + f".{os.getpid()}.tmp.npz"
            np.savez(tmp, image=z["image"], stderr=z["stderr"], info=json.dumps(info))
            os.replace(tmp, path)
            return z["image"], z["stderr"], dict(info, cached=True)
        print(f"relight cache: {path}: fails its check against the current renderer sources ({ratio:.3f}); "
              "rendering again", file=sys.stderr)
    t0 = time.perf_counter()
    r = wavlight.render_full(load(d), spp=spp, strategy="mis", width=size, height=size, seed=seed)
    info = {"spp": spp, "seed": seed, "size": size, "scene": d, "render_sources": sources,
            "wall_seconds": round(time.perf_counter() - t0, 3), "render_seconds": r.stats.get("render_seconds"),
            "load_average": [round(x, 2) for x in os.getloadavg()]}
    tmp = path + f".{os.getpid()}.tmp.npz"
    np.savez(tmp, image=r.image, stderr=r.stderr, info=json.dumps(info))
    os.replace(tmp, path)
    return r.image, r.stderr, dict(info, cached=False)


# ----------------------------------------------------------------------------- errors
def reference_noise(ref, stderr) -> float:
    """sqrt(sum stderr^2) / ||R||: the reference's own relative L2 noise."""
    ref, s = np.asarray(ref, np.float64), np.asarray(stderr, np.float64)
    return float(np.sqrt((s * s).sum()) / np.linalg.norm(ref))


def _grad(x):
    return x[:, 1:] - x[:, :-1], x[1:, :] - x[:-1, :]


def errors(image, ref, stderr) -> dict:
    """Relative L2 (raw, and with the reference's noise taken out in quadrature), relMSE (raw
    and with the reference's variance subtracted, as wavlight.evaluation.metrics.relmse), and
    the relative H1 error (Sobolev: values and forward-difference gradients, Ng et al. 2003's
    suggestion), raw and noise-corrected (the differences of the reference carry s_i^2 + s_j^2)."""
    from wavlight.evaluation.metrics import relmse

    x, r = np.asarray(image, np.float64), np.asarray(ref, np.float64)
    s2 = np.asarray(stderr, np.float64) ** 2
    e = x - r
    n_r2, n_e2, noise2 = float((r * r).sum()), float((e * e).sum()), float(s2.sum())
    gx, gy = _grad(e)
    rx, ry = _grad(r)
    g_e2 = float((gx * gx).sum() + (gy * gy).sum())
    g_r2 = float((rx * rx).sum() + (ry * ry).sum())
    g_noise2 = float((s2[:, 1:] + s2[:, :-1]).sum() + (s2[1:, :] + s2[:-1, :]).sum())
    h1_raw = np.sqrt((n_e2 + g_e2) / (n_r2 + g_r2))
    h1 = np.sqrt(max(n_e2 + g_e2 - noise2 - g_noise2, 0.0) / max(n_r2 + g_r2 - noise2 - g_noise2, 1e-300))
    return {"rel_l2": float(np.sqrt(max(n_e2 - noise2, 0.0) / n_r2)), "rel_l2_raw": float(np.sqrt(n_e2 / n_r2)),
            "relmse": relmse(x, r, np.sqrt(s2)), "relmse_raw": relmse(x, r),
            "h1": float(h1), "h1_raw": float(h1_raw)}


# ----------------------------------------------------------------------------- load
def load_average():
    return [round(x, 2) for x in os.getloadavg()]


def wait_for_quiet(limit: float = 1.0, poll: float = 60.0, minutes: float = 40.0) -> dict:
    """Wait until the 1-minute load average is below ``limit`` (polling every ``poll`` s, at most
    ``minutes``); returns what happened. ``minutes`` 0: no wait."""
    t0 = time.monotonic()
    samples = []
    while True:
        la = os.getloadavg()[0]
        samples.append(round(la, 2))
        if la < limit:
            return {"quiet": True, "limit": limit, "waited_seconds": round(time.monotonic() - t0), "polled": samples}
        if time.monotonic() - t0 + poll > minutes * 60:
            print(f"relight: the load stayed at or above {limit} for {minutes:g} minutes ({samples[-5:]}); "
                  "running anyway", file=sys.stderr)
            return {"quiet": False, "limit": limit, "waited_seconds": round(time.monotonic() - t0), "polled": samples}
        print(f"relight: load {la:.2f} >= {limit}; waiting {poll:g} s", file=sys.stderr, flush=True)
        time.sleep(poll)


class _Formatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """--help: the script's docstring as written, and each option's default."""


def parser(doc: str) -> argparse.ArgumentParser:
    """The argument parser of a relight benchmark: its docstring as the --help text."""
    return argparse.ArgumentParser(description=doc, formatter_class=_Formatter)


#: the bake that benchmarks/relight_bake.py times and benchmarks/relight_frame.py relights
BAKE_SCENE = "bunny_ggx/rooitou_park_1k"


def add_bake_arguments(ap) -> None:
    """--size, --levels and --spp of the bake of relight_bake.py and relight_frame.py."""
    ap.add_argument("--size", type=int, default=512, help="image width and height")
    ap.add_argument("--levels", type=int, default=6, help="texel levels n of the bake (2^n x 2^n texels)")
    ap.add_argument("--spp", type=int, default=16, help="camera samples per pixel of the bake")


def parse(ap, name: str, default_minutes: float):
    """Add --wait-load, --wait-minutes and -o (default benchmarks/results/<name>.json) and parse."""
    from provenance import add_output_argument

    ap.add_argument("--wait-load", type=float, default=1.0, metavar="L",
                    help="wait until the 1-minute load average is below L before timing")
    ap.add_argument("--wait-minutes", type=float, default=default_minutes, metavar="M",
                    help="wait at most M minutes, polling every 60 s, then run anyway (0: no wait)")
    add_output_argument(ap, name)
    return ap.parse_args()


def begin(args) -> dict:
    """The example data fetched (benchmarks/needs.py), the wait for a quiet machine (--wait-load,
    --wait-minutes), then the run's provenance and the library's state: what :func:`finish` records."""
    import needs
    from provenance import provenance

    needs.fetch(os.path.basename(sys.argv[0]), *ASSETS)
    wait = wait_for_quiet(args.wait_load, 60, args.wait_minutes) if args.wait_minutes > 0 else None
    return {"provenance": provenance(), "wait": wait, "library": worktree_state()}


def finish(output: str, data: dict, started: dict):
    """Write ``data`` with the wait, the library's state at the start and at the end and the
    provenance of :func:`begin` to ``output`` (benchmarks/provenance.py write_result)."""
    from provenance import write_result

    return write_result(output, {**data, "wait": started["wait"], "library": started["library"],
                                 "library_end": worktree_state()}, started["provenance"])


def rounded(value, digits: int = 5):
    """``value`` (nested dicts and lists) with every float rounded to ``digits`` significant digits."""
    if isinstance(value, float):
        return float(f"{value:.{digits}g}") if np.isfinite(value) else value
    if isinstance(value, dict):
        return {k: rounded(v, digits) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [rounded(v, digits) for v in value]
    return value


def columns(rows, keys) -> dict:
    """Dict rows as one table: {"columns": keys, "rows": [[value per key], ...]} (a compact result)."""
    return {"columns": list(keys), "rows": [[r.get(k) for k in keys] for r in rows]}


def from_columns(t: dict) -> list:
    """The dict rows of a :func:`columns` table."""
    return [dict(zip(t["columns"], row)) for row in t["rows"]]


def mean_sd(values) -> dict:
    """{"relmse": mean, "relmse_sd": sample standard deviation (None for one value)}."""
    return {"relmse": float(np.mean(values)), "relmse_sd": float(np.std(values, ddof=1)) if len(values) > 1 else None}


def table(rows, columns, formats=None) -> str:
    """A plain text table of dict rows."""
    formats = formats or {}

    def fmt(c, v):
        if v is None:
            return "-"
        f = formats.get(c)
        return (f.format(v) if f else (f"{v:.4g}" if isinstance(v, float) else str(v)))

    cells = [[fmt(c, r.get(c)) for c in columns] for r in rows]
    widths = [max(len(c), *(len(row[i]) for row in cells)) if cells else len(c) for i, c in enumerate(columns)]
    lines = ["  ".join(c.rjust(w) for c, w in zip(columns, widths))]
    lines += ["  ".join(v.rjust(w) for v, w in zip(row, widths)) for row in cells]
    return "\n".join(lines)
