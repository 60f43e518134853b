"""The viewer's tools for a designer, timed: a map sent from the page (POST /upload: streamed to
the viewer's temporary folder, read and checked as any map, added to the list) until its answer,
per map file; and the PNG of the picture shown (asked for over the websocket) until it arrives,
per size of bake. Each subject alternates with the others within a repeat; the medians are written
to benchmarks/results/viewer_upload.json with the provenance (the load average included: on a
shared 2-core machine a load above 1 slows every figure).

    python benchmarks/viewer_upload.py [--repeats 5] [--sizes 64,256]
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import struct
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from provenance import add_output_argument, provenance, write_result  # noqa: E402

ROOT = os.path.dirname(HERE)
SCENE = os.path.join(ROOT, "scenes", "spot_ggx.toml")
MAPS = ("debevec_grace_256x128.hdr", "st_fagans_interior_1k.hdr", "rooitou_park_1k.hdr")


async def one_upload(v, path) -> float:
    import aiohttp

    with open(path, "rb") as f:
        body = f.read()
    async with aiohttp.ClientSession() as client:
        t0 = time.perf_counter()
        async with client.post(v.address + "upload", params={"token": v.token, "name": os.path.basename(path)},
                               data=body) as r:
            data = await r.json()
        seconds = time.perf_counter() - t0
    if "index" not in data:
        raise SystemExit(f"{path}: refused: {data}")
    return seconds


async def one_png(v) -> float:
    import aiohttp

    async with aiohttp.ClientSession() as client, client.ws_connect(v.socket_url) as ws:
        await ws.send_json({"type": "state", "exposure": 0.5, "tonemap": "aces"})
        while True:   # the first frame
            msg = await ws.receive(timeout=60)
            if msg.type == aiohttp.WSMsgType.BINARY:
                n = struct.unpack("<I", msg.data[:4])[0]
                await ws.send_json({"type": "drawn", "seq": json.loads(msg.data[4:4 + n])["seq"]})
                break
        t0 = time.perf_counter()
        await ws.send_json({"type": "png"})
        while True:
            msg = await ws.receive(timeout=60)
            if msg.type == aiohttp.WSMsgType.BINARY:
                n = struct.unpack("<I", msg.data[:4])[0]
                if json.loads(msg.data[4:4 + n])["type"] == "png":
                    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--sizes", default="64,256", help="bake sizes (width = height) whose PNG is timed")
    add_output_argument(ap, "viewer_upload")
    args = ap.parse_args()
    prov = provenance()
    import wavlight
    from wavlight.data import resolve
    from wavlight.relight.viewer import Viewer

    maps = [resolve("data:" + os.path.splitext(m)[0], kind="environment map", download=False) for m in MAPS]
    sizes = [int(s) for s in args.sizes.split(",")]
    folder = tempfile.mkdtemp(prefix="wavlight-bench-")
    viewers = {}
    try:
        for size in sizes:
            path = os.path.join(folder, f"spot-{size}.wlt")
            transfer = wavlight.bake(SCENE, output=path, width=size, height=size, spp=4, levels=5, terms=256,
                                     priority="transfer")
            viewers[size] = Viewer(transfer, max_upload_bytes=1 << 28)
            viewers[size].start_background(0)
        upload = {os.path.basename(m): [] for m in maps}
        pngs = {str(s): [] for s in sizes}
        v = viewers[sizes[0]]
        for _ in range(args.repeats):   # the subjects alternate within each repeat
            for m in maps:
                upload[os.path.basename(m)].append(asyncio.run(one_upload(v, m)))
            for s in sizes:
                pngs[str(s)].append(asyncio.run(one_png(viewers[s])))
    finally:
        for v in viewers.values():
            v.stop_background()
            v.transfer.close()
    result = {"repeats": args.repeats,
              "upload_seconds_median": {k: round(statistics.median(x), 4) for k, x in upload.items()},
              "upload_bytes": {os.path.basename(m): os.path.getsize(m) for m in maps},
              "png_seconds_median": {k: round(statistics.median(x), 4) for k, x in pngs.items()},
              "upload_seconds": upload, "png_seconds": pngs}
    print(json.dumps({k: result[k] for k in ("upload_seconds_median", "png_seconds_median")}))
    write_result(args.output, result, prov)


if __name__ == "__main__":
    main()
