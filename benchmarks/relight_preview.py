"""Preview frames at the bake's automatic choice: frames/s of relit frames at 512 x 512, the
current code against a baseline revision, timed alternately on the same bake.

The bake: benchmarks/scenes/bunny_ggx.toml under st_fagans_interior_1k (its map turned to 0)
at --size, every choice the bake's own (camera samples, texel levels, K, priority: the pilot's),
from the cache in /tmp/relight-bench/ (made here if it is not there: minutes) or --bake FILE (a
bake made with `wavlight bake SCENE -o FILE --width 512 --height 512`, the scene's map swapped).
Its frames under the baked map and under each map of --env (default potsdamer_platz_1k), at
each K of --terms ("auto": the bake's own), in two modes:

- repeat: --frames frames at the scene's rotation, as `wavlight frame BAKE --repeat N --json`;
- turntable: --frames frames of a full turn from the scene's rotation, each written as a PNG
  into a temporary folder between frames (not timed), as `wavlight frame BAKE --turntable N`.

Each subject (the baseline: --baseline REV, a `git archive` of that revision; the current: this
checkout's package) runs in a worker process that loads the bake, makes 3 untimed frames per
map and K, then the timed ones; --rounds rounds alternate baseline and current, so that the
drift of a shared machine's load falls on both alike. Per frame: Transfer.frame_timed's parts
(lighting_seconds: the projection of the turned map and its Haar transform; terms_seconds: the
selection of the K terms; product_seconds: the sparse product; assembly_seconds: the rest, the
background where camera samples missed, the copy back and the finiteness check; the current
code reports background_seconds, the first of these, too), its
frame_seconds, and the process's CPU seconds over the call (every thread's: the kernels run on
both cores). Medians over all rounds' frames: frames/s = 1 / frame_seconds (whole frames, as
--json reports them); computation frames/s = 1 / (lighting + terms + product). The target
(>= 60 whole frames/s at K = 256 under both maps, repeat and turntable) is judged on the current
code; the load average is recorded at the start and end of every worker.

    python benchmarks/relight_preview.py [--bake FILE] [--size 512] [--env potsdamer_platz_1k]
        [--terms 256,auto] [--frames 30] [--rounds 3] [--baseline REV] [--wait-load 1.0]
        [--wait-minutes 40] [-o FILE]

The figures in benchmarks/results/relight_preview.json come from

    python benchmarks/relight_preview.py --bake /tmp/preview-bench/bunny512.wlt --baseline d5a040a --wait-load 2 \
        --wait-minutes 10
"""
from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import relight_common as rc  # noqa: E402

SCENE = "bunny_ggx/st_fagans_interior_1k"
PARTS = ("lighting_seconds", "terms_seconds", "product_seconds", "assembly_seconds", "frame_seconds")
WARMUP = 3


# ----------------------------------------------------------------------------- the worker
def worker(spec: dict) -> dict:
    """Frames of one subject: {map: {K: {mode: [per-frame dicts]}}}, with the load and the
    package's path. Only API the baseline has too: Transfer.load, environment, frame_timed,
    lighting.turntable, save_image."""
    import time

    import wavlight
    from wavlight.relight.lighting import turntable

    load0 = [round(x, 2) for x in os.getloadavg()]
    transfer = wavlight.Transfer.load(spec["bake"], verify=False)
    folder = tempfile.mkdtemp(prefix="wavlight-preview-")
    out = {}
    try:
        for name in spec["envs"]:
            env = None if name == "baked" else transfer.environment(rc.envmap(name))
            per_k = out[name] = {}
            for k in spec["terms"]:
                terms = transfer.terms if k == "auto" else int(k)
                for i in range(WARMUP):
                    transfer.frame_timed(env, 11.1 * i, 1.0, terms)
                modes = {"repeat": [None] * spec["frames"],
                         "turntable": turntable(transfer.scene_rotate_y, spec["frames"])}
                per_mode = per_k[k] = {}
                for mode, rotations in modes.items():
                    rows = per_mode[mode] = []
                    for i, rot in enumerate(rotations):
                        c0 = time.process_time()
                        image, st = transfer.frame_timed(env, rot, 1.0, terms)
                        cpu = time.process_time() - c0
                        rows.append({**{p: st[p] for p in PARTS}, "cpu_seconds": cpu, "terms": st["terms"],
                                     "entries_read": st["entries_read"],
                                     "background_seconds": st.get("background_seconds")})
                        if mode == "turntable":
                            wavlight.save_image(os.path.join(folder, f"frame-{i:04d}.png"), image)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    import wavlight.kernels

    return {"frames": out, "load_average": load0, "load_average_end": [round(x, 2) for x in os.getloadavg()],
            "package": os.path.dirname(wavlight.__file__), "kernels": list(wavlight.kernels.__path__),
            "bake": transfer.summary()}


def run_worker(spec: dict, pythonpath: str | None) -> dict:
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    res = subprocess.run([sys.executable, os.path.abspath(__file__), "--worker", json.dumps(spec)],
                         capture_output=True, text=True, env=env, cwd=tempfile.gettempdir())
    if res.returncode != 0:
        sys.exit(f"relight_preview: the worker failed:\n{res.stderr.strip()}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def baseline_tree(rev: str) -> str:
    """A folder with the package at revision ``rev`` (git archive), kernels where the package
    looks for them."""
    folder = tempfile.mkdtemp(prefix="wavlight-baseline-")
    archive = subprocess.run(["git", "-C", ROOT, "archive", rev], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", folder], input=archive, check=True)
    os.symlink(os.path.join("..", "kernels"), os.path.join(folder, "wavlight", "kernels"))
    return folder


# ----------------------------------------------------------------------------- summary
def summarise(frames: list) -> dict:
    med = {p: statistics.median(f[p] for f in frames) for p in PARTS + ("cpu_seconds",)}
    bg = [f["background_seconds"] for f in frames if f.get("background_seconds") is not None]
    med["background_seconds"] = statistics.median(bg) if bg else None   # (the baseline does not report it)
    compute = statistics.median(f["lighting_seconds"] + f["terms_seconds"] + f["product_seconds"] for f in frames)
    return {"frames": len(frames), "terms": frames[0]["terms"], "entries_read": frames[0]["entries_read"], **med,
            "compute_seconds": compute, "frames_per_second": 1.0 / med["frame_seconds"],
            "compute_frames_per_second": 1.0 / compute,
            "frame_seconds_p10": float(sorted(f["frame_seconds"] for f in frames)[len(frames) // 10]),
            "frame_seconds_p90": float(sorted(f["frame_seconds"] for f in frames)[(9 * len(frames)) // 10])}


def main():
    if len(sys.argv) == 3 and sys.argv[1] == "--worker":
        print(json.dumps(worker(json.loads(sys.argv[2]))))
        return
    ap = rc.parser(__doc__)
    ap.add_argument("--bake", default=None, help="a bake file to relight (default: the cache's, made if missing)")
    ap.add_argument("--size", type=int, default=512, help="image width and height of the bake made here")
    ap.add_argument("--env", default="potsdamer_platz_1k", help="other maps, comma-separated (names in envmaps/)")
    ap.add_argument("--terms", default="256,auto", help="the K to time, comma-separated; auto: the bake's own")
    ap.add_argument("--frames", type=int, default=30, help="timed frames per map, K, mode and round")
    ap.add_argument("--rounds", type=int, default=3, help="rounds, each the baseline's worker then the current's")
    ap.add_argument("--baseline", default=None, help="the revision to compare with (none: the current code alone)")
    args = rc.parse(ap, "relight_preview", 40)
    if args.bake is None:
        transfer, info = rc.cached_bake(rc.scene_dict(SCENE), args.size, None)
        bake, cached = info["path"], info["cached"]
        transfer.close()
    else:
        bake, cached = os.path.abspath(args.bake), True
    envs = ["baked"] + [e for e in args.env.split(",") if e]
    terms = [t if t == "auto" else int(t) for t in args.terms.split(",") if t]
    spec = {"bake": bake, "envs": envs, "terms": terms, "frames": args.frames}
    subjects = {"current": None}
    base_dir = None
    if args.baseline:
        base_dir = baseline_tree(args.baseline)
        subjects = {"baseline": base_dir, "current": None}
    started = rc.begin(args)
    runs = {s: [] for s in subjects}
    try:
        for r in range(args.rounds):
            for subject, path in subjects.items():
                print(f"round {r + 1}/{args.rounds}: {subject}", file=sys.stderr, flush=True)
                runs[subject].append(run_worker(spec, path))
    finally:
        if base_dir:
            shutil.rmtree(base_dir, ignore_errors=True)
    rows = []
    for subject, results in runs.items():
        for name in envs:
            for k in terms:
                for mode in ("repeat", "turntable"):
                    frames = [f for res in results for f in res["frames"][name][str(k)][mode]]
                    per_round = [1.0 / statistics.median(f["frame_seconds"] for f in res["frames"][name][str(k)][mode])
                                 for res in results]
                    rows.append({"subject": subject, "env": name, "K": k, "mode": mode, **summarise(frames),
                                 "frames_per_second_by_round": per_round})
    current = [r for r in rows if r["subject"] == "current" and r["K"] == 256]
    target = None
    if current:
        worst = min(current, key=lambda r: r["frames_per_second"])
        target = {"K": 256, "target": 60, "frames_per_second_min": worst["frames_per_second"],
                  "at": {k: worst[k] for k in ("env", "mode")},
                  "met": bool(worst["frames_per_second"] >= 60)}
    bake_info = runs["current"][0]["bake"]
    shown = [{**{k: v for k, v in r.items() if not k.endswith("_seconds") and k != "frames_per_second_by_round"},
              **{p.replace("_seconds", "_ms"): None if r[p] is None else 1e3 * r[p]
                 for p in PARTS + ("background_seconds", "cpu_seconds", "compute_seconds")}}
             for r in rows]
    print(f"frames {bake_info['width']}x{bake_info['height']}, {bake_info['texels']} texels, {bake_info['spp']} spp, "
          f"auto K {bake_info['terms']}; medians of {args.rounds} x {args.frames} frames (ms)")
    cols = ["lighting_ms", "terms_ms", "product_ms", "assembly_ms", "background_ms", "frame_ms", "cpu_ms",
            "frames_per_second", "compute_frames_per_second"]
    print(rc.table(shown, ["subject", "env", "K", "mode", "terms", *cols], {c: "{:.2f}" for c in cols}))
    if target:
        print(f"K = 256: at least {target['frames_per_second_min']:.1f} whole frames/s ({target['at']}); "
              f"target >= 60: {'met' if target['met'] else 'NOT met'}")
    loads = {s: [[res["load_average"], res["load_average_end"]] for res in results] for s, results in runs.items()}
    rc.finish(args.output, {"scene": SCENE, "bake": {"path": bake, "cached": cached, **{
        k: bake_info[k] for k in ("width", "height", "spp", "texels", "terms", "priority", "file_bytes", "entries")}},
        "baseline": args.baseline, "envs": envs, "terms": terms, "frames": args.frames, "rounds": args.rounds,
        "warmup": WARMUP, "packages": {s: results[0]["package"] for s, results in runs.items()},
        "worker_load_average": loads, "rows": rc.rounded(rows), "target": target}, started)


if __name__ == "__main__":
    main()
