"""End-to-end frames per second of `wavlight view` (the target: >= 20 frames/s at 512 x 512,
K = 256, colour), in headless chromium (Debian's, driven by playwright).

The bunny scene is baked once at WIDTH x HEIGHT (64 x 64 texels, K = 256) and cached in
/tmp/wavlight-viewer-bench (baked again when the file no longer loads, or was made from another
scene or size). The viewer serves it on 127.0.0.1 from a thread; the page is loaded with
``?terms=256&encoding=E`` and turns the rotation slider by one degree every 8 ms (an input
event, as a drag at 125 Hz without the preview: every frame has all K terms), for ``--seconds`` after a
second of warm-up; the server draws the newest state each time, so the rate is the pipeline's
(frame, tone map and encoding on the server, the socket, decoding and drawing in the page).
Measured for each encoding (alternated, ``--repeats`` times), and once for the first encoding
with the drag preview (K/4 terms while a slider is held). Also recorded: the frame alone
(Transfer.frame_timed, the same rotations) and each encoding's cost alone.

With ``--vary view`` the viewer of a bake that varies the view: the bunny of
benchmarks/relight_view.py (turned 40 degrees, rooitou_park_1k) baked with ``--vary view`` at the
automatic choice, through its ``cached_view_bake`` (the cache in /tmp/relight-bench/view-bakes, so
the bake that script made is the one shown); at the bake's size (the scene's, 512 x 512). The
page turns the azimuth slider by one degree every ``--interval-ms`` (full frames, each encoding,
``--repeats`` times; then once holding the slider: the preview's smaller frames), and once the
camera is orbited by a drag on the picture (the mouse moved one pixel along x every
``--interval-ms`` by playwright, back and forth, the button held: preview frames; a move is a
round trip to the browser, so on two cores they come about every 20 ms, still faster than the
frames; the rate of moves is recorded).

With ``--vary object`` the viewer of a bake that varies one object: the bunny of
benchmarks/relight_moving.py baked as that script bakes it (``--vary object``, 256 x 256, 16 x 16
texels, the converged image without the bunny at 256 spp; cached in /tmp/wavlight-viewer-bench).
The page moves the x translation slider by 1 cm every ``--interval-ms`` (back and forth within
0.5 of the bunny's own place) and, in other runs, turns the bunny about +Y by one degree (full
frames at the viewer's OBJECT_FRAME_SPP, each encoding, ``--repeats`` times; then each control
once held: the OBJECT_PREVIEW_SPP preview). Both record the frame alone (Viewer.frame, full and
preview) and each encoding's cost alone, beside the page's rate.

    python benchmarks/viewer_fps.py                  # -> benchmarks/results/viewer-fps.json
    python benchmarks/viewer_fps.py --vary view      # -> benchmarks/results/viewer-fps-view.json
    python benchmarks/viewer_fps.py --vary object    # -> benchmarks/results/viewer-fps-object.json
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from provenance import provenance, result_path, write_result  # noqa: E402

ROOT = os.path.dirname(HERE)
SCENE = os.path.join(HERE, "scenes", "bunny_ggx.toml")
CACHE = "/tmp/wavlight-viewer-bench"

#: the measurement both scripts share: after ``warmup`` seconds, the frames drawn for ``seconds``,
#: the page's frame rate each second and the headers of the frames (LOG: the fields kept of one)
WATCH = """setTimeout(() => {
    const f0 = viewer.frames, t0 = performance.now();
    let last = viewer.last;
    const watch = setInterval(() => { if (viewer.last !== last) { last = viewer.last; log(last); } }, 10);
    const sample = setInterval(() => rates.push(parseFloat(document.getElementById('fps').textContent)), 1000);
    setTimeout(() => {
      const frames = viewer.frames - f0, elapsed = (performance.now() - t0) / 1000;
      [TIMERS].forEach(clearInterval);
      done({frames, elapsed, rates, headers});
    }, seconds * 1000);
  }, warmup * 1000);"""

ANIMATE = """([seconds, warmup, drag, interval]) => new Promise((done) => {
  const slider = document.getElementById('rotate_y');
  if (drag) slider.dispatchEvent(new PointerEvent('pointerdown', {bubbles: true}));
  const headers = [], rates = [];
  const log = (h) => headers.push([h.frame_ms, h.encode_ms, h.bytes, h.terms_used]);
  let r = 0;
  const timer = setInterval(() => { r = (r + 1) % 360; slider.value = r;
                                    slider.dispatchEvent(new Event('input', {bubbles: true})); }, interval);
  """ + WATCH.replace("TIMERS", "timer, watch, sample") + """
})"""

#: view and object bakes: window.__measure(seconds, warmup) counts the frames drawn for ``seconds``
#: after ``warmup`` seconds, with the page's frame rate each second and the headers of the frames
MEASURE = """() => { window.__measure = (seconds, warmup) => new Promise((done) => {
  const headers = [], rates = [];
  const log = (h) => headers.push([h.frame_ms, h.encode_ms, h.bytes, h.width * h.height, h.preview ? 1 : 0]);
  """ + WATCH.replace("TIMERS", "watch, sample") + """
}); }"""

#: a slider moved by ``step`` every ``interval`` ms (an input event each time; held first with
#: ``drag``): wrapped into [lo, hi) with ``wrap``, else back and forth between lo and hi
SWEEP = """([id, seconds, warmup, drag, interval, lo, hi, step, wrap]) => new Promise((done) => {
  const slider = document.getElementById(id);
  if (drag) slider.dispatchEvent(new PointerEvent('pointerdown', {bubbles: true}));
  let v = Number(slider.value), dir = 1;
  const timer = setInterval(() => {
    v += dir * step;
    if (wrap) v = lo + (((v - lo) % (hi - lo)) + (hi - lo)) % (hi - lo);
    else if (v > hi || v < lo) { dir = -dir; v = Math.min(hi, Math.max(lo, v)); }
    slider.value = v;
    slider.dispatchEvent(new Event('input', {bubbles: true}));
  }, interval);
  window.__measure(seconds, warmup).then((r) => { clearInterval(timer); done(r); });
})"""
#: how far the orbit drag moves the mouse either side of the picture's middle, pixels
ORBIT_PIXELS = 80
#: the view bake: benchmarks/relight_view.py's scene and turn (its defaults)
VIEW_SCENE, VIEW_TURN = "bunny_ggx", 40.0
#: the object bake: benchmarks/relight_moving.py's defaults
OBJECT_BAKE_SPP, OBJECT_LEVELS, OBJECT_STATIC_SPP = 4, 4, 256
#: the x translation slider moves within this distance of the object's own place
OBJECT_SWEEP = 0.5


def baked(width, height, levels, terms):
    """The cached bake file (made when missing or stale)."""
    import wavlight
    from wavlight.errors import WavlightError

    os.makedirs(CACHE, exist_ok=True)
    path = os.path.join(CACHE, f"bunny_ggx-{width}x{height}-n{levels}-k{terms}.wlt")
    scene = wavlight.load_scene(SCENE)
    if os.path.exists(path):
        try:
            t = wavlight.Transfer.load(path)
            if (t.width, t.height, t.n_levels, t.terms) == (width, height, levels, terms) \
                    and t.scene.get("content_hash") == scene.content_hash:
                t.frame(rotate_y=1.0)
                return path, False
        except WavlightError as e:
            print(f"baking again: {e}", file=sys.stderr)
    print(f"baking {path} ...", file=sys.stderr)
    wavlight.bake(scene, output=path, width=width, height=height, spp=4, levels=levels, terms=terms).close()
    return path, True


def frame_alone(transfer, terms, n=40):
    times = []
    for i in range(n):
        times.append(transfer.frame_timed(rotate_y=float(i), terms=terms)[1]["frame_seconds"])
    return statistics.median(times[5:])


def encode_alone(image, encoding, n=20):
    from wavlight.relight.viewer import encode

    times, size = [], 0
    for _ in range(n):
        t0 = time.perf_counter()
        size = len(encode(image, 0.0, encoding))
        times.append(time.perf_counter() - t0)
    return statistics.median(times), size


OUTPUTS = {"lighting": "viewer-fps", "view": "viewer-fps-view", "object": "viewer-fps-object"}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vary", choices=tuple(OUTPUTS), default="lighting",
                    help="the bake shown: lighting (default; rotation slider), view (orbit) or object (translation "
                         "and turn)")
    ap.add_argument("--width", type=int, default=None, help="lighting: 512 (default); object: 256; view: the scene's")
    ap.add_argument("--height", type=int, default=None, help="as --width")
    ap.add_argument("--levels", type=int, default=None,
                    help="texel levels: lighting 6 (default), object 4, view the automatic choice")
    ap.add_argument("--terms", type=int, default=256, help="lighting: K (default 256)")
    ap.add_argument("--seconds", type=float, default=5.0, help="measured per run (after 1 s of warm-up)")
    ap.add_argument("--repeats", type=int, default=2, help="runs per encoding, alternated")
    ap.add_argument("--interval-ms", type=float, default=8.0,
                    help="the page moves the slider this often (8 ms: a 125 Hz mouse)")
    ap.add_argument("--chromium", default=shutil.which("chromium") or shutil.which("chromium-browser"))
    ap.add_argument("-o", "--output", default=None, metavar="FILE",
                    help="result file (default benchmarks/results/viewer-fps.json, or viewer-fps-view.json, "
                         "viewer-fps-object.json by --vary; '-': none, stdout only)")
    args = ap.parse_args()
    if args.output is None:
        args.output = result_path(OUTPUTS[args.vary])
    if args.vary == "view" and (args.width is not None or args.height is not None):
        ap.error("--vary view: the frames are the bake's size (the scene's); --width and --height do not apply")
    if args.width is None or args.height is None:
        side = {"lighting": 512, "object": 256}.get(args.vary)
        args.width = args.width if args.width is not None else side
        args.height = args.height if args.height is not None else (args.width if args.vary == "object" else side)
    if args.levels is None:
        args.levels = {"lighting": 6, "object": OBJECT_LEVELS}.get(args.vary)
    prov = provenance()
    if not args.chromium:
        sys.exit("no chromium found (give --chromium PATH)")
    if args.vary == "lighting":
        lighting(args, prov)
    else:
        varied(args, prov)


def lighting(args, prov):
    """The viewer of a lighting bake: the rotation slider (the figures of viewer-fps.json)."""
    from playwright.sync_api import sync_playwright

    import wavlight
    from wavlight.relight.viewer import ENCODINGS, Viewer, preview_terms

    path, fresh = baked(args.width, args.height, args.levels, args.terms)
    transfer = wavlight.Transfer.load(path)
    image = transfer.frame(rotate_y=0.0, terms=args.terms)
    alone = frame_alone(transfer, args.terms)
    result = {"width": transfer.width, "height": transfer.height, "terms": args.terms,
              "texels": f"{1 << transfer.n_levels}x{1 << transfer.n_levels}", "bake_file": path,
              "bake_file_bytes": transfer.file_bytes, "baked_now": fresh, "target_fps": 20,
              "seconds_per_run": args.seconds, "slider_interval_ms": args.interval_ms, "chromium": args.chromium,
              "frame_alone": {"median_ms": round(alone * 1e3, 2), "fps": round(1 / alone, 1)},
              "encode_alone": {}, "runs": [], "encodings": {}}
    for e in ENCODINGS:
        seconds, size = encode_alone(image, e)
        result["encode_alone"][e] = {"median_ms": round(seconds * 1e3, 2), "bytes": size}

    viewer = Viewer(transfer)
    url = viewer.start_background(0)
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=args.chromium, headless=True, args=["--no-sandbox"])
            result["chromium_version"] = browser.version
            plan = [(e, False) for _ in range(args.repeats) for e in ENCODINGS] + [(ENCODINGS[0], True)]
            for encoding, drag in plan:
                page = browser.new_page(viewport={"width": args.width + 420, "height": args.height + 80})
                page.goto(f"{url}&terms={args.terms}&encoding={encoding}&rotate_y=0")
                page.wait_for_function("() => window.viewer && viewer.frames >= 1", timeout=60000)
                run = page.evaluate(ANIMATE, [args.seconds, 1.0, drag, args.interval_ms])
                page.close()
                h = np.array(run["headers"], float) if run["headers"] else np.zeros((0, 4))
                record = {"encoding": encoding, "preview": drag, "fps": round(run["frames"] / run["elapsed"], 2),
                          "frames": run["frames"], "seconds": round(run["elapsed"], 3),
                          "page_fps_samples": run["rates"],
                          "frame_ms_median": round(float(np.median(h[:, 0])), 2) if len(h) else None,
                          "encode_ms_median": round(float(np.median(h[:, 1])), 2) if len(h) else None,
                          "bytes_median": int(np.median(h[:, 2])) if len(h) else None,
                          "terms_used_median": int(np.median(h[:, 3])) if len(h) else None}
                if drag:
                    record["preview_terms"] = preview_terms(args.terms)
                result["runs"].append(record)
                print(f"{encoding}{' (drag preview)' if drag else ''}: {record['fps']} frames/s "
                      f"(page showed {run['rates']}), frame {record['frame_ms_median']} ms, "
                      f"encode {record['encode_ms_median']} ms, {record['bytes_median']} bytes", file=sys.stderr)
            browser.close()
    finally:
        viewer.stop_background()
    for e in ENCODINGS:
        fps = [r["fps"] for r in result["runs"] if r["encoding"] == e and not r["preview"]]
        result["encodings"][e] = {"fps_median": round(statistics.median(fps), 2), "fps_runs": fps}
    preview = [r for r in result["runs"] if r["preview"]]
    result["drag_preview"] = {"encoding": preview[0]["encoding"], "fps": preview[0]["fps"],
                              "terms": preview_terms(args.terms)} if preview else None
    result["meets_target"] = {e: v["fps_median"] >= 20 for e, v in result["encodings"].items()}
    write_result(args.output, result, prov)
    transfer.close()


def view_baked(levels):
    """(transfer, scene, info) of the view bake of benchmarks/relight_view.py's bunny, from its
    cache (cached_view_bake: baked there when missing)."""
    import relight_view

    d = relight_view.turned(relight_view.SCENES[VIEW_SCENE](), VIEW_TURN)
    print("the view bake (benchmarks/relight_view.py's cache; baked when missing) ...", file=sys.stderr, flush=True)
    transfer, info = relight_view.cached_view_bake(d, levels)
    return transfer, relight_view.common.load(d), {
        "scene": f"{VIEW_SCENE} of benchmarks/relight_view.py (turned {VIEW_TURN:g} degrees, {relight_view.ENV})",
        "baked_now": not info["cached"], "bake_wall_seconds": info.get("wall_seconds"),
        "levels": "auto" if levels is None else levels}


def object_baked(width, height, levels):
    """(transfer, scene, info) of the object bake of benchmarks/relight_moving.py's bunny (baked as
    that script bakes it), cached in CACHE (baked again when the file no longer loads, or was made
    from another scene or size)."""
    import relight_moving

    import wavlight
    from wavlight.errors import WavlightError

    relight_moving.needs.fetch("viewer_fps", relight_moving.ENVMAP, "bunny")
    scene = relight_moving.load(relight_moving.bunny_dict())
    os.makedirs(CACHE, exist_ok=True)
    path = os.path.join(CACHE, f"bunny-object-{width}x{height}-n{levels}-s{OBJECT_STATIC_SPP}.wlt")
    info = {"scene": "benchmarks/scenes/bunny_ggx.toml's bunny under rooitou_park_1k (benchmarks/relight_moving.py), "
                     "moved",
            "static_spp": OBJECT_STATIC_SPP, "bake_spp": OBJECT_BAKE_SPP}
    if os.path.exists(path):
        try:
            t = wavlight.Transfer.load(path)
            if t.header.get("vary") == "object" and (t.width, t.height, t.n_levels) == (width, height, levels) \
                    and t.scene.get("content_hash") == scene.content_hash \
                    and (t.header.get("static") or {}).get("spp") == OBJECT_STATIC_SPP:
                return t, scene, dict(info, baked_now=False)
            t.close()
        except WavlightError as e:
            print(f"baking again: {e}", file=sys.stderr)
    print(f"baking {path} ...", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    t = wavlight.bake(scene, path, width=width, height=height, spp=OBJECT_BAKE_SPP, levels=levels, terms=64,
                      priority="area", vary="object", object="bunny", static_spp=OBJECT_STATIC_SPP)
    return t, scene, dict(info, baked_now=True, bake_wall_seconds=round(time.perf_counter() - t0, 2))


def moved(viewer, state, i):
    """The state moved i steps along the run's path: the camera i degrees of azimuth, or the object
    i cm along x and i degrees about +Y."""
    if viewer.varies == "view":
        return dict(state, azimuth=(state["azimuth"] + i) % 360.0)
    x, y, z = state["translate"]
    return dict(state, translate=[x + 0.01 * (i % 50), y, z], rotate_y=(state["rotate_y"] + i) % 360.0)


def viewer_frame_alone(viewer, preview, n=12):
    """Median seconds of Viewer.frame (the frame the server computes) along the path, the first two
    left out; and the last image."""
    from wavlight.relight.viewer import sanitise

    state = dict(sanitise({}, viewer.limits)[0], preview=preview)
    times, image = [], None
    for i in range(n + 2):
        s = moved(viewer, state, i)
        t0 = time.perf_counter()
        image, _ = viewer.frame(s, viewer.detail(s))
        times.append(time.perf_counter() - t0)
    return statistics.median(times[2:]), image


def headed(run):
    """A run's figures from the page: frames/s, the page's own samples, the headers' medians."""
    h = np.array(run["headers"], float) if run["headers"] else np.zeros((0, 5))

    def med(col, digits=2):
        return round(float(np.median(h[:, col])), digits) if len(h) else None
    return {"fps": round(run["frames"] / run["elapsed"], 2), "frames": run["frames"],
            "seconds": round(run["elapsed"], 3), "page_fps_samples": run["rates"],
            "frame_ms_median": med(0), "encode_ms_median": med(1),
            "bytes_median": int(np.median(h[:, 2])) if len(h) else None,
            "pixels_median": int(np.median(h[:, 3])) if len(h) else None,
            "preview_share": round(float(h[:, 4].mean()), 3) if len(h) else None}


def orbit(page, seconds, warmup, interval_ms):
    """Orbit the camera by a drag on the picture: the button held in its middle, the mouse moved
    one pixel along x every interval (back and forth, ORBIT_PIXELS either side) by playwright,
    while the page counts its frames; the page's figures and the moves made."""
    page.evaluate("([s, w]) => { window.__orbit = null; window.__measure(s, w).then((r) => { window.__orbit = r; }); }",
                  [seconds, warmup])
    box = page.locator("#frame").bounding_box()
    cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(cx, cy)
    page.mouse.down()
    t0 = time.monotonic()
    x, step, moves = 0, -1, 0
    try:
        while time.monotonic() - t0 < warmup + seconds + 0.2:
            if abs(x + step) > ORBIT_PIXELS:
                step = -step
            x += step
            page.mouse.move(cx + x, cy)
            moves += 1
            left = t0 + moves * interval_ms / 1e3 - time.monotonic()
            if left > 0:
                time.sleep(left)
        page.wait_for_function("() => window.__orbit !== null", timeout=60000)
        run = page.evaluate("window.__orbit")
    finally:
        page.mouse.up()
    return run, {"mouse_moves": moves, "mouse_moves_per_second": round(moves / (time.monotonic() - t0), 1)}


def varied(args, prov):
    """The viewer of a view bake (the azimuth slider, the orbit drag) or of an object bake (the x
    translation and rotation sliders)."""
    from playwright.sync_api import sync_playwright

    from wavlight.relight.viewer import ENCODINGS, OBJECT_FRAME_SPP, OBJECT_PREVIEW_SPP, Viewer

    if args.vary == "view":
        transfer, scene, info = view_baked(args.levels)
    else:
        transfer, scene, info = object_baked(args.width, args.height, args.levels)
    viewer = Viewer(transfer, scene=scene)
    lim = viewer.limits
    alone, image = {}, None
    for preview in (False, True):
        seconds, img = viewer_frame_alone(viewer, preview)
        image = img if image is None else image
        alone["preview" if preview else "full"] = {"median_ms": round(seconds * 1e3, 2), "fps": round(1 / seconds, 1),
                                                   "width": img.shape[1], "height": img.shape[0]}
    print(f"frame alone: {alone}", file=sys.stderr, flush=True)
    result = {"vary": args.vary, **info, "width": transfer.width, "height": transfer.height,
              "texels": f"{1 << transfer.n_levels}x{1 << transfer.n_levels}", "bake_file": transfer.path,
              "bake_file_bytes": transfer.file_bytes, "seconds_per_run": args.seconds,
              "slider_interval_ms": args.interval_ms, "chromium": args.chromium,
              "frame_alone": alone, "encode_alone": {}, "runs": [], "controls": {}}
    for e in ENCODINGS:
        seconds, size = encode_alone(image, e)
        result["encode_alone"][e] = {"median_ms": round(seconds * 1e3, 2), "bytes": size}
    if args.vary == "view":
        start = {"azimuth": lim.azimuth, "elevation": lim.elevation, "distance": lim.distance, "exposure": 0}
        # (control, lo, hi, step per tick, wrap)
        sliders = [("azimuth", 0.0, 360.0, 1.0, True)]
        result["camera"] = {k: start[k] for k in ("azimuth", "elevation", "distance")}
        result["preview_size"] = [alone["preview"]["width"], alone["preview"]["height"]]
    else:
        start = {"translate": ",".join(f"{x:g}" for x in lim.translate), "rotate_y": lim.rotate_y, "exposure": 0}
        x0 = lim.translate[0]
        sliders = [("translate_x", max(lim.lo[0], x0 - OBJECT_SWEEP), min(lim.hi[0], x0 + OBJECT_SWEEP),
                    max(0.01, lim.step), False),
                   ("rotate_y", 0.0, 360.0, 1.0, True)]
        result.update(frame_spp=OBJECT_FRAME_SPP, preview_spp=OBJECT_PREVIEW_SPP,
                      translate=list(lim.translate), translate_x_sweep=[sliders[0][1], sliders[0][2]])
    query = "&".join(f"{k}={v}" for k, v in start.items())
    # full frames: each control and encoding, alternated, --repeats times; then each control held
    # (the preview); a view bake also the orbit drag on the picture
    plan = [(c, e, False) for c in sliders for _ in range(args.repeats) for e in ENCODINGS]
    plan += [(c, ENCODINGS[0], True) for c in sliders]
    if args.vary == "view":
        plan.append((None, ENCODINGS[0], True))
    url = viewer.start_background(0)
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=args.chromium, headless=True, args=["--no-sandbox"])
            result["chromium_version"] = browser.version
            for control, encoding, drag in plan:
                page = browser.new_page(viewport={"width": max(transfer.width, 384) + 420,
                                                  "height": max(transfer.height, 384) + 80})
                page.goto(f"{url}&{query}&encoding={encoding}")
                page.wait_for_function("() => window.viewer && viewer.frames >= 1", timeout=60000)
                page.evaluate(MEASURE)
                extra = {}
                if control is None:
                    name = "orbit_drag"
                    run, extra = orbit(page, args.seconds, 1.0, args.interval_ms)
                else:
                    name, lo, hi, step, wrap = control
                    run = page.evaluate(SWEEP, [name, args.seconds, 1.0, drag, args.interval_ms, lo, hi, step, wrap])
                errors = page.evaluate("viewer.errors")
                page.close()
                record = {"control": name, "encoding": encoding, "preview": drag, **headed(run), **extra,
                          "page_errors": errors}
                result["runs"].append(record)
                print(f"{name} {encoding}{' (held: preview)' if drag else ''}: {record['fps']} frames/s "
                      f"(page showed {run['rates']}), frame {record['frame_ms_median']} ms, "
                      f"encode {record['encode_ms_median']} ms, {record['bytes_median']} bytes, "
                      f"{record['pixels_median']} pixels", file=sys.stderr, flush=True)
            browser.close()
    finally:
        viewer.stop_background()
    for name in dict.fromkeys(r["control"] for r in result["runs"]):
        runs = [r for r in result["runs"] if r["control"] == name]
        summary = {}
        for e in ENCODINGS:
            fps = [r["fps"] for r in runs if r["encoding"] == e and not r["preview"]]
            if fps:
                summary[e] = {"fps_median": round(statistics.median(fps), 2), "fps_runs": fps}
        held = [r for r in runs if r["preview"]]
        if held:
            summary["preview"] = {"encoding": held[0]["encoding"], "fps": held[0]["fps"]}
        result["controls"][name] = summary
    write_result(args.output, result, prov)
    transfer.close()


if __name__ == "__main__":
    main()
