"""What a base-colour texture costs the renderer: the shade_rays kernel and whole renders of one
GLB (a floor with a stripes texture of --texels² texels, a metal sphere; made with trimesh in a
temporary folder), rays pixel-major as the renderer's passes order them, textured (-DTEXTURES=1:
the barycentric upload, the texture coordinates and four texel gathers per hit) against the same
scene with its textures dropped (-DTEXTURES=0), alternating launch by launch and render by render
and keeping each one's best (and the launches' median) time: a shared machine's speed drifts
between runs; the load average is recorded. Prints one JSON object and writes it, with the run's
provenance (benchmarks/provenance.py), to benchmarks/results/texture_cost.json (-o FILE another,
"-" none).

    python benchmarks/texture_cost.py [--texels 1024] [--rays 262144] [--repeat 30] [--size 256] [--spp 16]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import tempfile
import time

import numpy as np


def write_glb(path, texels):
    import PIL.Image
    import trimesh
    from trimesh.visual.material import PBRMaterial
    from trimesh.visual.texture import TextureVisuals

    img = np.zeros((texels, texels, 3), np.uint8)
    img[:, 0::2] = (200, 40, 40)
    img[:, 1::2] = (230, 230, 230)
    floor = trimesh.Trimesh([[-2, 0, -2], [2, 0, -2], [2, 0, 2], [-2, 0, 2]], [[0, 2, 1], [0, 3, 2]], process=False)
    floor.visual = TextureVisuals(uv=np.array([[0, 0], [2, 0], [2, 2], [0, 2]], float), material=PBRMaterial(
        name="floor", baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=1.0, roughnessFactor=0.7,
        baseColorTexture=PIL.Image.fromarray(img)))
    gold = trimesh.creation.icosphere(3, 0.5)
    gold.visual = TextureVisuals(material=PBRMaterial(name="gold", baseColorFactor=[1.0, 0.78, 0.34, 1.0],
                                                      metallicFactor=1.0, roughnessFactor=0.3))
    scene = trimesh.Scene()
    scene.add_geometry(floor, node_name="floor")
    scene.add_geometry(gold, node_name="gold", transform=trimesh.transformations.translation_matrix([-0.7, 0.5, 0]))
    with open(path, "wb") as fh:
        fh.write(scene.export(file_type="glb"))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--texels", type=int, default=1024)
    ap.add_argument("--rays", type=int, default=1 << 18)
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--strategy", default="mis")
    ap.add_argument("--env", default="data:rooitou_park_512")
    from provenance import add_output_argument, provenance, write_result

    add_output_argument(ap, "texture_cost")
    args = ap.parse_args()
    prov = provenance()

    import wavlight
    from wavlight import camera, strategies
    from wavlight.raytrace import RayTracer
    from wavlight.shading import KernelShader

    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "asset.glb")
        write_glb(path, args.texels)
        textured = wavlight.load_asset(path, args.env, args.size, args.size)
    plain = dataclasses.replace(textured, textures=[], vertex_uv=None,
                                materials=[dataclasses.replace(m, texture=-1) for m in textured.materials])
    assert textured.textured and not plain.textured
    tracer = RayTracer(textured.vertices, textured.faces)
    rng = np.random.default_rng(1)
    n = args.rays   # pixel-major, four samples per pixel, as the renderer's passes order them
    pixel = np.arange(n) // 4 % (args.size * args.size)
    o, d = camera.camera_rays(textured, pixel % args.size, pixel // args.size, rng.random((n, 2)), args.size,
                              args.size)
    prim, t, bu, bv = tracer.intersect_uv(o, d)
    bary = np.stack([bu, bv], 1)
    u = rng.random((n, 4), dtype=np.float32)
    shaders = {}
    for name, scene in (("textured", textured), ("untextured", plain)):
        strat = strategies.make(args.strategy)
        strat.prepare(scene.environment, scene.materials)
        shaders[name] = KernelShader(scene, strat, tracer)
    launch = {k: [] for k in shaders}
    for _ in range(args.repeat):   # alternating launch by launch
        for name, shader in shaders.items():
            t0 = time.perf_counter()
            shader.shade_rays(textured.camera.eye, d, prim, t, u, bary)
            launch[name].append(time.perf_counter() - t0)
    render = {k: [] for k in shaders}
    for _ in range(max(2, args.repeat // 4)):
        for name, scene in (("textured", textured), ("untextured", plain)):
            r = wavlight.render_full(scene, spp=args.spp, strategy=args.strategy)
            render[name].append(r.stats["render_seconds"])
    out = {"texels": args.texels, "rays": n, "hit_fraction": round(float((prim >= 0).mean()), 3),
           "strategy": args.strategy, "size": args.size, "spp": args.spp, "load_average": os.getloadavg()[0],
           "shade_rays_best_seconds": {k: round(min(v), 5) for k, v in launch.items()},
           "shade_rays_median_seconds": {k: round(float(np.median(v)), 5) for k, v in launch.items()},
           "render_best_seconds": {k: round(min(v), 4) for k, v in render.items()}}
    out["shade_rays_ratio"] = round(out["shade_rays_best_seconds"]["textured"]
                                    / out["shade_rays_best_seconds"]["untextured"], 3)
    out["render_ratio"] = round(out["render_best_seconds"]["textured"] / out["render_best_seconds"]["untextured"], 3)
    print(json.dumps(out, indent=1))
    write_result(args.output, out, prov)


if __name__ == "__main__":
    main()
