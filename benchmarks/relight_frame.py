"""A relit frame's time at 512 x 512: the bunny of benchmarks/scenes/bunny_ggx.toml baked at 64 x 64 texels
(levels 6; the bake of benchmarks/relight_bake.py, from the cache in /tmp/relight-bench/, made
here if it is not there), colour, for K in --terms: --warmup frames, then --frames frames at
rotations 7.3 degrees apart (no two alike), median of each part of Transfer.frame_timed:
lighting_seconds (projection of the turned map onto the texels and its Haar transform),
terms_seconds (selection of the K terms), product_seconds (the sparse product on the device, times
the albedo), assembly_seconds (the background where camera samples missed, the copy back; before
docs/decisions/relight-preview-frames.md, the albedo too). frames/s = 1 /
frame_seconds; the target (>= 60 frames/s at K = 256) counts the frame computation, lighting +
terms + product: compute frames/s = 1 / that sum (the median of the per-frame sums).

Timing: waits for the 1-minute load average to fall below --wait-load (default 1.0, polling
every 60 s for --wait-minutes, default 40), then runs anyway; the load is in the provenance.

    python benchmarks/relight_frame.py [--size 512] [--levels 6] [--spp 16] [--terms 64,256,1024]
        [--frames 20] [--warmup 3] [--env MAP] [--wait-load 1.0] [--wait-minutes 40] [-o FILE]

The figures in benchmarks/results/relight_frame.json come from

    python benchmarks/relight_frame.py --wait-minutes 8
"""
from __future__ import annotations

import os
import statistics
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import relight_common as rc  # noqa: E402

SCENE = rc.BAKE_SCENE
PARTS = ("lighting_seconds", "terms_seconds", "product_seconds", "assembly_seconds", "frame_seconds")


def main():
    ap = rc.parser(__doc__)
    rc.add_bake_arguments(ap)
    ap.add_argument("--terms", default="64,256,1024", help="the K to time, comma-separated")
    ap.add_argument("--frames", type=int, default=20, help="timed frames per K")
    ap.add_argument("--warmup", type=int, default=3, help="untimed frames per K before them")
    ap.add_argument("--env", default=None, help="frames under this map (a name in envmaps/) instead of the baked one")
    args = rc.parse(ap, "relight_frame", 40)
    d = rc.scene_dict(SCENE)
    # the bake first (minutes if it is not cached), then the wait, then the frames
    transfer, info = rc.cached_bake(d, args.size, args.spp, levels=args.levels, terms=256, priority="area")
    started = rc.begin(args)
    env = transfer.environment(rc.envmap(args.env)) if args.env else None
    rows = []
    for k in [int(x) for x in args.terms.split(",") if x]:
        for i in range(args.warmup):
            transfer.frame_timed(env, 3.1 * i, 1.0, k)
        stats = [transfer.frame_timed(env, 7.3 * (i + 1), 1.0, k)[1] for i in range(args.frames)]
        med = {p: statistics.median(s[p] for s in stats) for p in PARTS}
        compute = statistics.median(s["lighting_seconds"] + s["terms_seconds"] + s["product_seconds"] for s in stats)
        rows.append({"K": k, "terms": stats[0]["terms"], "entries_read": stats[0]["entries_read"], **med,
                     "compute_seconds": compute, "frames_per_second": 1.0 / med["frame_seconds"],
                     "compute_frames_per_second": 1.0 / compute,
                     "frame_seconds_min": min(s["frame_seconds"] for s in stats),
                     "frame_seconds_max": max(s["frame_seconds"] for s in stats),
                     "bytes_read": int(stats[0]["entries_read"] * (transfer.block ** 2 * transfer.bits // 8 + 4))})
    at = {r["K"]: r for r in rows}
    target = None
    if 256 in at:
        target = {"K": 256, "compute_frames_per_second": at[256]["compute_frames_per_second"],
                  "frames_per_second": at[256]["frames_per_second"], "target": 60,
                  "met": bool(at[256]["compute_frames_per_second"] >= 60)}
    print(f"frames {args.size}x{args.size}, {1 << transfer.n_levels}x{1 << transfer.n_levels} texels, colour, "
          f"median of {args.frames} after {args.warmup} warm-ups (ms)")
    shown = [{**{k: v for k, v in r.items() if not k.endswith("_seconds") and k != "compute_seconds"},
              **{p.replace("_seconds", "_ms"): 1e3 * r[p] for p in PARTS + ("compute_seconds",)}} for r in rows]
    print(rc.table(shown, ["K", "entries_read", "lighting_ms", "terms_ms", "product_ms", "assembly_ms", "frame_ms",
                           "compute_ms", "frames_per_second", "compute_frames_per_second"],
                   {c: "{:.2f}" for c in ("lighting_ms", "terms_ms", "product_ms", "assembly_ms", "frame_ms",
                                          "compute_ms", "frames_per_second", "compute_frames_per_second")}))
    if target:
        print(f"K = 256: {target['compute_frames_per_second']:.1f} frames/s of computation (lighting + terms + product), "
              f"{target['frames_per_second']:.1f} whole frames/s; target >= 60: {'met' if target['met'] else 'NOT met'}")
    rc.finish(args.output, {"scene": SCENE, "size": args.size, "levels": transfer.n_levels, "bake_spp": args.spp,
                            "env": args.env, "frames": args.frames, "warmup": args.warmup,
                            "bake": {"path": info["path"], "cached": info["cached"], "file_bytes": transfer.file_bytes,
                                     "entries": transfer.entries, "bake_seconds": transfer.measured.get("bake_seconds")},
                            "rows": rows, "target": target}, started)


if __name__ == "__main__":
    main()
