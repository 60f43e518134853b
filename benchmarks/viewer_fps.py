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

    python benchmarks/viewer_fps.py                  # -> benchmarks/results/viewer-fps.json
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
from provenance import add_output_argument, provenance, write_result  # noqa: E402

ROOT = os.path.dirname(HERE)
SCENE = os.path.join(ROOT, "scenes", "bunny_ggx.toml")
CACHE = "/tmp/wavlight-viewer-bench"

ANIMATE = """([seconds, warmup, drag, interval]) => new Promise((done) => {
  const slider = document.getElementById('rotate_y');
  if (drag) slider.dispatchEvent(new PointerEvent('pointerdown', {bubbles: true}));
  const headers = [], rates = [];
  const log = (h) => headers.push([h.frame_ms, h.encode_ms, h.bytes, h.terms_used]);
  let r = 0;
  const timer = setInterval(() => { r = (r + 1) % 360; slider.value = r;
                                    slider.dispatchEvent(new Event('input', {bubbles: true})); }, interval);
  setTimeout(() => {
    const f0 = viewer.frames, t0 = performance.now();
    let last = viewer.last;
    const watch = setInterval(() => { if (viewer.last !== last) { last = viewer.last; log(last); } }, 10);
    const sample = setInterval(() => rates.push(parseFloat(document.getElementById('fps').textContent)), 1000);
    setTimeout(() => {
      const frames = viewer.frames - f0, elapsed = (performance.now() - t0) / 1000;
      [timer, watch, sample].forEach(clearInterval);
      done({frames, elapsed, rates, headers});
    }, seconds * 1000);
  }, warmup * 1000);
})"""


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


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--height", type=int, default=512)
    ap.add_argument("--levels", type=int, default=6)
    ap.add_argument("--terms", type=int, default=256)
    ap.add_argument("--seconds", type=float, default=5.0, help="measured per run (after 1 s of warm-up)")
    ap.add_argument("--repeats", type=int, default=2, help="runs per encoding, alternated")
    ap.add_argument("--interval-ms", type=float, default=8.0,
                    help="the page moves the slider this often (8 ms: a 125 Hz mouse)")
    ap.add_argument("--chromium", default=shutil.which("chromium") or shutil.which("chromium-browser"))
    add_output_argument(ap, "viewer-fps")
    args = ap.parse_args()
    prov = provenance()

    from playwright.sync_api import sync_playwright

    import wavlight
    from wavlight.relight.viewer import ENCODINGS, Viewer, preview_terms

    if not args.chromium:
        sys.exit("no chromium found (give --chromium PATH)")
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
                page.goto(f"{url}?terms={args.terms}&encoding={encoding}&rotate_y=0")
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


if __name__ == "__main__":
    main()
