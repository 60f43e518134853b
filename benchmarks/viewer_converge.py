"""Progressive converge in `wavlight view`, measured in headless chromium (Debian's, driven by
playwright): how soon after the click the first converged picture is drawn, and the samples per
pixel accumulated and the relative error shown within ``--seconds`` (targets, on a 256 x 256 bake
of the bunny: the first picture within 1.5 s, at least 64 spp within 5 s; at 512 x 512 the first
picture within 2 s).

The bake: benchmarks/scenes/bunny_ggx.toml under st_fagans_interior_1k, baked at each size with
16 camera samples and the automatic choices (as benchmarks/relight_converge_speed.py bakes it),
cached in /tmp/wavlight-viewer-converge (baked again when the file no longer loads, or was made
from another scene or size). The viewer serves it on 127.0.0.1 from a thread (stopped at
the end); each run opens a page at a rotation of the map not seen before and waits for its first
frame; then, in a ``rested`` run, for the converge thread's preparation (made when the first page
opened) and the warming of the page's lighting (its tables and product trees, made once the page
rested WARM_AFTER_SECONDS: a user who looks at the frame before the click), in the other run not
at all (the click pays for what is not made yet); then presses "converge" and records, in the
page, the time each pass's picture is drawn with the spp and relative error it shows (the page's
``viewer.converged``). Sizes and the two kinds of run are alternated (--repeats runs each); the
1-minute load average is recorded at each click.

    python benchmarks/viewer_converge.py [--sizes 256,512] [--repeats 2] [--seconds 5]
        [--wait-load 2.0] [--wait-minutes 0] -> benchmarks/results/viewer_converge.json
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from provenance import add_output_argument, provenance, write_result  # noqa: E402

SCENE = "bunny_ggx/st_fagans_interior_1k"
BAKE_SPP = 16
CACHE = "/tmp/wavlight-viewer-converge"
#: size -> (seconds to the first picture, spp within --seconds or None)
TARGETS = {256: (1.5, 64), 512: (2.0, None)}

#: the page records the click's time; each pass drawn is in viewer.converged as [spp, error, time]
HOOK = """() => { window.__clicked = null;
  document.getElementById('converge').addEventListener('click',
    () => { window.__clicked = performance.now(); }, { capture: true }); }"""


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="256,512", help="bake sizes (width = height), comma-separated")
    ap.add_argument("--repeats", type=int, default=2, help="runs per size, alternated")
    ap.add_argument("--seconds", type=float, default=5.0, help="how long after the click a run watches")
    ap.add_argument("--chromium", default=shutil.which("chromium") or shutil.which("chromium-browser"))
    ap.add_argument("--wait-load", type=float, default=2.0, metavar="L",
                    help="wait until the 1-minute load average is below L before timing")
    ap.add_argument("--wait-minutes", type=float, default=0.0, metavar="M",
                    help="wait at most M minutes, polling every 30 s, then run anyway (0: no wait)")
    add_output_argument(ap, "viewer_converge")
    args = ap.parse_args()
    if not args.chromium:
        sys.exit("no chromium found (give --chromium PATH)")
    import relight_common as rc
    import needs

    needs.fetch("viewer_converge", *rc.ASSETS)
    wait = rc.wait_for_quiet(args.wait_load, 30, args.wait_minutes) if args.wait_minutes > 0 else None
    prov = provenance()
    from playwright.sync_api import sync_playwright

    from wavlight.relight.viewer import Viewer

    sizes = [int(s) for s in args.sizes.split(",")]
    base = rc.scene_dict(SCENE)
    scene = rc.load(base)
    viewers, result = {}, {"scene": f"benchmarks/scenes/bunny_ggx.toml under st_fagans_interior_1k ({SCENE})",
                           "bake_spp": BAKE_SPP, "seconds_watched": args.seconds, "chromium": args.chromium,
                           "targets": {str(k): {"first_picture_seconds": v[0], "spp_within_seconds": v[1]}
                                       for k, v in TARGETS.items()},
                           "sizes": {}, "runs": [], "wait": wait}
    try:
        for size in sizes:
            print(f"the {size}x{size} bake (cached, or baked now) ...", file=sys.stderr, flush=True)
            transfer, info = baked(base, scene, size)
            v = Viewer(transfer, scene=scene)
            v.start_background(0)
            viewers[size] = v
            result["sizes"][str(size)] = {"bake": {"n_levels": transfer.n_levels, "terms": transfer.terms,
                                                   "file_bytes": transfer.file_bytes, "cached": info["cached"]}}
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=args.chromium, headless=True, args=["--no-sandbox"])
            result["chromium_version"] = browser.version
            for r in range(args.repeats):
                for size in sizes:
                    for k, rested in enumerate((True, False)):
                        result["runs"].append(run(browser, viewers[size], size, 120.0 + 7.0 * (2 * r + k),
                                                  args.seconds, rested))
            browser.close()
    finally:
        for v in viewers.values():
            v.stop_background()
    for size in sizes:
        result["sizes"][str(size)]["summary"] = {}
        for rested in (True, False):
            runs = [x for x in result["runs"] if x["size"] == size and x["rested"] == rested]
            first = [x["first_picture_seconds"] for x in runs if x["first_picture_seconds"] is not None]
            spp = [x["spp_within"] for x in runs]
            errors = [x["relative_error_within"] for x in runs if x["relative_error_within"] is not None]
            want_first, want_spp = TARGETS.get(size, (None, None))
            summary = {"first_picture_seconds_median": round(statistics.median(first), 3) if first else None,
                       "spp_within_median": statistics.median(spp) if spp else None,
                       "relative_error_within_median": statistics.median(errors) if errors else None,
                       "load_average_median": statistics.median([x["load_average_1min"] for x in runs])}
            if want_first is not None:
                summary["first_picture_met"] = bool(first) and summary["first_picture_seconds_median"] <= want_first
            if want_spp is not None:
                summary["spp_met"] = bool(spp) and summary["spp_within_median"] >= want_spp
            result["sizes"][str(size)]["summary"]["rested" if rested else "clicked_at_once"] = summary
            print(f"{size}x{size} {'rested' if rested else 'at once'}: {summary}", file=sys.stderr, flush=True)
    write_result(args.output, result, prov)


def baked(base, scene, size):
    """(transfer, info) of the cached bake at size x size (made when missing or stale)."""
    import wavlight
    from wavlight.errors import WavlightError

    os.makedirs(CACHE, exist_ok=True)
    path = os.path.join(CACHE, f"bunny_ggx-st_fagans-{size}-spp{BAKE_SPP}.wlt")
    if os.path.exists(path):
        try:
            t = wavlight.Transfer.load(path)
            if (t.width, t.height, t.spp) == (size, size, BAKE_SPP) \
                    and t.scene.get("content_hash") == scene.content_hash:
                return t, {"cached": True}
            t.close()
        except WavlightError as e:
            print(f"baking again: {e}", file=sys.stderr)
    t0 = time.perf_counter()
    t = wavlight.bake(scene, output=path, width=size, height=size, spp=BAKE_SPP)
    return t, {"cached": False, "bake_seconds": round(time.perf_counter() - t0, 2)}


def run(browser, viewer, size, rotate_y, seconds, rested) -> dict:
    """One page at ``rotate_y``: converge pressed (``rested``: once the converge thread has
    prepared and warmed the page's lighting; else as soon as the first frame is drawn), the
    passes drawn within ``seconds`` + 1 s."""
    from wavlight.relight.viewer import WARM_AFTER_SECONDS

    page = browser.new_page(viewport={"width": size + 420, "height": max(size, 400) + 80})
    try:
        t_open = time.perf_counter()
        page.goto(f"{viewer.url}&rotate_y={rotate_y:g}&encoding=jpeg")
        page.wait_for_function("() => window.viewer && viewer.frames >= 1", timeout=60000)
        first_frame = time.perf_counter() - t_open
        if rested:   # the converge thread's preparation (the first page), then the warming of this lighting
            while viewer._prepared is None or not viewer._prepared.done():
                time.sleep(0.02)
            time.sleep(WARM_AFTER_SECONDS + 0.05)
            while viewer._warming:
                time.sleep(0.02)
        prepare = time.perf_counter() - t_open
        page.evaluate(HOOK)
        load = os.getloadavg()[0]
        page.click("#converge")
        time.sleep(seconds + 1.0)
        clicked, passes = page.evaluate("[window.__clicked, viewer.converged]")
        page.click("#converge")   # released: the converge thread stops at its next tile
        page.wait_for_function("() => viewer.last.converge === null", timeout=60000)
    finally:
        page.close()
    passes = [(s, e, (t - clicked) / 1e3) for s, e, t in passes]
    within = [p for p in passes if p[2] <= seconds]
    record = {"size": size, "rotate_y": rotate_y, "rested": rested, "load_average_1min": round(load, 2),
              "first_frame_seconds": round(first_frame, 3), "opened_to_click_seconds": round(prepare, 3),
              "first_picture_seconds": round(passes[0][2], 3) if passes else None,
              "first_picture_spp": passes[0][0] if passes else None,
              "spp_within": within[-1][0] if within else 0,
              "relative_error_within": within[-1][1] if within else None,
              "passes": [[s, None if e is None else round(e, 5), round(t, 3)] for s, e, t in passes]}
    kind = "rested" if rested else "at once"
    print(f"{size}x{size} at {rotate_y:g} degrees ({kind}, load {load:.1f}): first picture "
          f"{record['first_picture_seconds']} s ({record['first_picture_spp']} spp), {record['spp_within']} spp "
          f"within {seconds:g} s, relative error {record['relative_error_within']}", file=sys.stderr, flush=True)
    return record


if __name__ == "__main__":
    main()
