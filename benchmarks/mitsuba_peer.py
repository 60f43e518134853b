#!/usr/bin/env python3
"""Render a wavlight scene TOML with Mitsuba 3's ``direct`` integrator and print timings as JSON.

A peer reference for wavlight benchmarks: it reads the scene file itself (``tomllib``; wavlight
only resolves ``data:NAME`` files), builds the equivalent Mitsuba scene with ``mi.load_dict`` on the ``llvm_ad_rgb`` variant
(CPU), renders it and prints one JSON object on stdout. The same object, with the run's
provenance (benchmarks/provenance.py; the OpenCL platform is asked of a separate process, so
that PoCL's LLVM is not loaded beside Dr.Jit's), goes to the result file
benchmarks/results/mitsuba_peer.json unless -o names another ("-": none, as
benchmarks/render_bench.py --mitsuba runs it).

Usage:
    python benchmarks/mitsuba_peer.py SCENE.toml [--spp N] [--width W] [--height H]
                                      [--strategy mis|light|bsdf] [--out IMAGE.exr] [-o FILE]
    python benchmarks/mitsuba_peer.py --designer-glb [--spp N] [--seeds S] [--width W] [--height H] [-o FILE]
Command-line values override ``[render]``; ``seed`` comes from ``[render]`` (default 0).
The figures in benchmarks/results/mitsuba_peer.json come from
    python benchmarks/mitsuba_peer.py benchmarks/scenes/bunny_ggx.toml --spp 16 --width 512 --height 512 --strategy mis

--designer-glb: issue 38's acceptance, agreement rather than timing. The GLB a designer makes with
trimesh (tests/support/assets_util.write_designer_glb: a plastic floor with an sRGB stripes
texture, a gold metal sphere, a red plastic sphere, both low-poly with per-vertex normals), named
in a scene with no material (assets_util.designer_scene), under an indoor map
(st_fagans_interior_512) and a sun map (rooitou_park_1k); wavlight (``mis``, S x N spp) against
Mitsuba 3 (wavlight.evaluation.peers: roughconductor with material none, roughplastic with
nonlinear false, int_ior 1.5, ext_ior 1, the texture as a bilinear sRGB bitmap, vertex normals
with face_normals false; S seeds of N spp). Per part (peers.part_agreement, the pixels whose four
corners see that part): the relative bias with its standard error and z, and the relMSE (the
reference's own noise removed) over the reference's own noise. The acceptance: |bias| < 1.5% and
relMSE within 3x the reference's noise. A control ("control_mitsuba_face_normals") gives Mitsuba
face normals instead (the scene's corner normals dropped): the comparison must see the difference. This mode imports wavlight; the result goes to
benchmarks/results/mitsuba_peer_glb.json unless -o names another. Its figures come from
    python benchmarks/mitsuba_peer.py --designer-glb --spp 256 --seeds 4 --width 128 --height 96

Setup (Debian 12, Python 3.11):
    apt-get install -y libllvm19 && pip install mitsuba     # mitsuba 3.9.1, drjit 1.5.0
    export DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so   # optional, see below
Dr.Jit finds libLLVM.so.19.1 on its own here; the variable just makes the choice explicit.

Mapping (see docs/scene-format.md of wavlight):
  strategy    mis -> direct(emitter_samples=1, bsdf_samples=1); light -> (1, 0); bsdf -> (0, 1).
              Other wavlight strategies have no Mitsuba equivalent: "mis" is used and reported.
  camera      perspective, fov_axis='y', look_at(eye, target, up); hdrfilm + box rfilter;
              independent sampler.
  environment envmap(filename, scale, to_world = rotate(+Y, rotate_y)). `procedural = "sky"` is not
              supported: the script prints {"skipped": true, ...} and exits with status 0.
  objects     .ply/.obj -> Mitsuba ply/obj; other formats, spheres (trimesh icosphere) and quads are
              written as temporary PLYs. to_world = translate @ rotate @ scale. face_normals as the
              object's key (default false: Mitsuba's vertex normals, the file's or its own).
  materials   lambert -> twosided(diffuse); ggx -> twosided(roughconductor, ggx, material='none');
              plastic -> twosided(roughplastic, ggx, alpha, int_ior = ior, ext_ior = 1, nonlinear = false);
              phong -> approximated by ggx with alpha = sqrt(2 / (exponent + 2)) (no phong in Mitsuba 3),
              listed under "approximated_materials".

Environment orientation (checked with Mitsuba 3.9.1): Mitsuba's envmap uses u = atan2(d.x, -d.z)/2pi,
v = acos(d.y)/pi, exactly wavlight's formula. A 64x32 probe map with coloured 3x3 blocks at the texels
wavlight assigns to +X, -Z, +Z and (0, 1, 0.3) returned each block's colour from Envmap.eval in that
direction; with to_world = rotate(+Y, 90) the +X block was seen from world -Z, as the spec requires.
A render looking towards (1, 0.5, -1) showed the +X block on the right half and -Z on the left, both
below the centre: no mirroring, row 0 at the top. So no extra rotation is applied. Remaining
difference: Mitsuba interpolates the map bilinearly, wavlight looks it up per texel (nearest).

Timing: setup_seconds = mi.load_dict; jit_seconds = a 1-spp warm-up render; render_seconds = the
timed render at full spp incl. dr.eval + dr.sync_thread. The render kernel does not depend on spp or
seed ("render_kernels_compiled" checks that it is 0) but does on resolution, strategy and scene; Dr.Jit
caches compiled kernels in ~/.drjit, so jit_seconds is ~0.2 s on a cold cache and a few ms after
("jit_kernels" says which). Mitsuba logs to fd 1, so it is redirected to stderr; stdout carries only
the JSON line.
"""
import argparse
import dataclasses
import json
import math
import os
import sys
import tempfile
import time
import tomllib

import drjit as dr
import mitsuba as mi
import numpy as np

VARIANT = "llvm_ad_rgb"
STRATEGIES = {"mis": (1, 1), "light": (1, 0), "bsdf": (0, 1)}  # (emitter_samples, bsdf_samples)


def vec3(x):
    """A scalar (uniform) or a 3-list as a float array of 3."""
    return np.full(3, float(x)) if np.isscalar(x) else np.asarray(x, float).reshape(3)


def object_transform(obj):
    """Per-object to_world: scale, then rotate [ax, ay, az, deg], then translate."""
    rot = obj.get("rotate", [0.0, 1.0, 0.0, 0.0])
    return (mi.ScalarTransform4f()
            .translate(vec3(obj.get("translate", 0.0)).tolist())
            .rotate(list(map(float, rot[:3])), float(rot[3]))
            .scale(vec3(obj.get("scale", 1.0)).tolist()))


def quad_mesh(center, normal, size):
    """Two triangles spanning t1 = normalize(Y x n) (+X if n || Y) and t2 = n x t1."""
    import trimesh
    n = vec3(normal) / np.linalg.norm(normal)
    t1 = np.cross([0.0, 1.0, 0.0], n)
    t1 = np.array([1.0, 0.0, 0.0]) if np.linalg.norm(t1) < 1e-8 else t1 / np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    s1, s2 = (float(size), float(size)) if np.isscalar(size) else map(float, size)
    c, a, b = vec3(center), 0.5 * s1 * t1, 0.5 * s2 * t2
    verts = [c - a - b, c + a - b, c + a + b, c - a + b]
    # t1 x t2 = n, so counter-clockwise in (t1, t2) gives a winding whose normal is +n.
    return trimesh.Trimesh(verts, [[0, 1, 2], [0, 2, 3]], process=False)


def input_path(value, base, kind):
    """The file a scene value names: ``data:NAME`` through wavlight.data (fetched on first use, or
    read from WAVLIGHT_DATA), else a path relative to the scene's folder."""
    if not str(value).startswith("data:"):
        return os.path.normpath(os.path.join(base, value))
    import wavlight.data

    try:
        return wavlight.data.resolve(str(value), kind=kind)
    except wavlight.WavlightError as e:
        sys.exit(f"mitsuba_peer: {e}")


def shape_dict(obj, base, tmpdir, idx):
    """Mitsuba shape dict (without BSDF) for one [[objects]] entry."""
    import trimesh
    mesh = None
    if "mesh" in obj:
        path = input_path(obj["mesh"], base, "mesh")
        ext = os.path.splitext(path)[1].lower()
        if ext in (".ply", ".obj"):
            d = {"type": ext[1:], "filename": path}
        else:
            mesh = trimesh.load(path, force="mesh")
    elif obj.get("shape") == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=int(obj.get("subdivisions", 5)),
                                          radius=float(obj["radius"]))
        mesh.apply_translation(vec3(obj["center"]))
    elif obj.get("shape") == "quad":
        mesh = quad_mesh(obj["center"], obj["normal"], obj["size"])
    else:
        raise ValueError(f"object {idx}: needs mesh = ... or shape = sphere|quad")
    if mesh is not None:
        path = os.path.join(tmpdir, f"object_{idx}.ply")
        trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(path)  # geometry only
        d = {"type": "ply", "filename": path}
    d.update(face_normals=bool(obj.get("face_normals", False)), to_world=object_transform(obj))
    return d


def bsdf_dict(name, mat):
    """(Mitsuba BSDF dict, approximated?) for one [materials.NAME] table."""
    kind = mat.get("type", "lambert")
    albedo = {"type": "rgb", "value": vec3(mat.get("albedo", 0.5)).tolist()}
    if kind == "lambert":
        return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": albedo}}, False
    if kind == "plastic":   # the same BSDF (docs/decisions/plastic-material.md)
        return {"type": "twosided", "bsdf": {"type": "roughplastic", "distribution": "ggx",
                "alpha": float(mat.get("alpha", 0.1)), "int_ior": float(mat.get("ior", 1.5)), "ext_ior": 1.0,
                "nonlinear": False, "diffuse_reflectance": albedo}}, False
    if kind == "ggx":
        alpha = float(mat.get("roughness", 0.1))
    elif kind == "phong":
        alpha = math.sqrt(2.0 / (float(mat.get("exponent", 100.0)) + 2.0))
    else:
        raise ValueError(f"material {name!r}: unknown type {kind!r}")
    return {"type": "twosided", "bsdf": {"type": "roughconductor", "distribution": "ggx",
            "alpha": alpha, "material": "none", "specular_reflectance": albedo}}, kind == "phong"


def build_scene(cfg, base, width, height, spp, strategy, tmpdir):
    """Return (scene dict, approximated material names) for a parsed scene TOML."""
    em_samples, bsdf_samples = STRATEGIES[strategy]
    cam = cfg["camera"]
    scene = {
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": em_samples, "bsdf_samples": bsdf_samples},
        "sensor": {
            "type": "perspective", "fov_axis": "y", "fov": float(cam.get("fov_y", 35.0)),
            "to_world": mi.ScalarTransform4f().look_at(origin=vec3(cam["eye"]).tolist(),
                                                       target=vec3(cam["target"]).tolist(),
                                                       up=vec3(cam.get("up", [0, 1, 0])).tolist()),
            "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": spp},
        },
    }
    env = cfg.get("environment")
    if env:
        scene["environment"] = {
            "type": "envmap", "filename": input_path(env["file"], base, "environment map"),
            "scale": float(env.get("scale", 1.0)),
            "to_world": mi.ScalarTransform4f().rotate([0.0, 1.0, 0.0], float(env.get("rotate_y", 0.0)))}
    approximated = []
    for name, mat in cfg.get("materials", {}).items():
        scene[f"mat_{name}"], approx = bsdf_dict(name, mat)
        if approx:
            approximated.append(name)
    for i, obj in enumerate(cfg.get("objects", [])):
        shape = shape_dict(obj, base, tmpdir, i)
        if "material" in obj:
            shape["bsdf"] = {"type": "ref", "id": f"mat_{obj['material']}"}
        else:
            shape["bsdf"], _ = bsdf_dict("<default>", {"type": "lambert"})
        scene[f"object_{i}"] = shape
    return scene, approximated


def jit_stats():
    """Summarise Dr.Jit's kernel history since the last call (and clear it)."""
    kernels = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
    disk = sum(bool(k.get("cache_disk")) for k in kernels)
    memory = sum(bool(k.get("cache_hit")) for k in kernels) - disk
    return {"launched": len(kernels), "compiled": len(kernels) - disk - memory,
            "disk_cache": disk, "memory_cache": memory}


def timed_render(scene, spp, seed):
    t0 = time.perf_counter()
    img = mi.render(scene, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    return img, time.perf_counter() - t0


GLB_MAPS = {"indoor": "data:st_fagans_interior_512", "sun": "data:rooitou_park_1k"}


def designer_glb(args, prov):
    """--designer-glb: the designer's GLB per part against Mitsuba 3, under each map of GLB_MAPS."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    sys.path.insert(0, os.path.join(root, "tests", "support"))
    import needs
    from assets_util import designer_scene, write_designer_glb
    from provenance import write_result

    needs.fetch("mitsuba_peer", *(m.split(":", 1)[1] for m in GLB_MAPS.values()))
    import wavlight
    from wavlight.evaluation import peers

    if not peers.available():
        sys.exit("mitsuba_peer: Mitsuba 3 (llvm_ad_rgb) is not available: pip install 'wavlight[peers]'")
    width, height, spp, seeds = args.width or 128, args.height or 96, args.spp or 256, args.seeds
    result = {"renderer": "mitsuba3", "case": "designer_glb", "width": width, "height": height,
              "wavlight_spp": spp * seeds, "mitsuba_spp": f"{seeds} x {spp}", "maps": {}}
    with tempfile.TemporaryDirectory(prefix="mitsuba_peer_") as folder:
        glb = write_designer_glb(os.path.join(folder, "designer.glb"))
        for label, env in GLB_MAPS.items():
            scene = wavlight.load_dict(designer_scene(glb, env, width, height))
            t0 = time.perf_counter()
            ours = wavlight.render_full(scene, spp=spp * seeds, strategy="mis", seed=3)
            t1 = time.perf_counter()
            runs = np.stack([peers.render_mitsuba(scene, "mis", spp=spp, seed=50 + s).image for s in range(seeds)])
            t2 = time.perf_counter()
            parts = {}
            for name, r in peers.part_agreement(scene, ours, runs).items():
                part = name.rsplit(":", 1)[-1]
                r = {k: (np.round(v, 5).tolist() if isinstance(v, (list, float)) else v) for k, v in r.items()}
                r["bias_z"] = np.round(r["bias_z"], 2).tolist()
                r["accepted"] = bool(max(map(abs, r["bias"])) < 0.015 and r["relmse_ratio"] < 3.0)
                parts[part] = r
                print(f"{label} {part} ({r['type']}, {r['pixels']} pixels): bias {r['bias']} +- {r['bias_se']} "
                      f"(z {r['bias_z']}), relMSE / reference noise {r['relmse_ratio']}", file=sys.stderr, flush=True)
            # the control: Mitsuba given face normals (the scene's corner normals dropped), wavlight smooth
            flat = dataclasses.replace(scene, normal_faces=None)
            runs = np.stack([peers.render_mitsuba(flat, "mis", spp=spp, seed=50 + s).image for s in range(seeds)])
            control = {name.rsplit(":", 1)[-1]: {"bias": np.round(r["bias"], 5).tolist(),
                                                 "bias_z": np.round(r["bias_z"], 2).tolist(),
                                                 "relmse_ratio": round(r["relmse_ratio"], 3)}
                       for name, r in peers.part_agreement(scene, ours, runs).items()}
            result["maps"][label] = {"environment": env, "wavlight_seconds": round(t1 - t0, 2),
                                     "mitsuba_seconds": round(t2 - t1, 2), "parts": parts,
                                     "control_mitsuba_face_normals": control}
    result["accepted"] = all(p["accepted"] for m in result["maps"].values() for p in m["parts"].values())
    result["mitsuba_version"] = mi.__version__
    print(json.dumps(result))
    write_result(args.output, result, prov)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?")
    ap.add_argument("--designer-glb", action="store_true",
                    help="issue 38's GLB per part against Mitsuba 3 (agreement, not timing)")
    ap.add_argument("--seeds", type=int, default=4, help="--designer-glb: Mitsuba's seeds (wavlight: spp x seeds)")
    ap.add_argument("--spp", type=int)
    ap.add_argument("--width", type=int)
    ap.add_argument("--height", type=int)
    ap.add_argument("--strategy", choices=sorted(STRATEGIES))
    ap.add_argument("--out", help="write the image (e.g. .exr) with mi.util.write_bitmap")
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from provenance import add_output_argument, provenance, result_path, write_result

    add_output_argument(ap, "mitsuba_peer")
    args = ap.parse_args()
    if args.designer_glb:
        if args.scene or args.strategy or args.out:
            ap.error("--designer-glb takes no SCENE, --strategy or --out")
        if args.output == result_path("mitsuba_peer"):
            args.output = result_path("mitsuba_peer_glb")
        designer_glb(args, provenance() if args.output != "-" else None)
        return
    if not args.scene:
        ap.error("a SCENE.toml is needed (or --designer-glb)")
    prov = provenance(opencl="subprocess") if args.output != "-" else None

    with open(args.scene, "rb") as f:
        cfg = tomllib.load(f)
    base = os.path.dirname(os.path.abspath(args.scene))
    render = cfg.get("render", {})
    width = args.width or int(render.get("width", 256))
    height = args.height or int(render.get("height", 256))
    spp = args.spp or int(render.get("spp", 16))
    seed = int(render.get("seed", 0))
    strategy, note = args.strategy or render.get("strategy", "mis"), None
    if strategy not in STRATEGIES:
        note = f"strategy {strategy!r} has no Mitsuba equivalent; used 'mis'"
        print(f"mitsuba_peer: {note}", file=sys.stderr)
        strategy = "mis"
    # Mitsuba's logger writes to the process's stdout (fd 1); keep fd 1 for the JSON line only.
    json_out = os.fdopen(os.dup(1), "w")
    sys.stdout.flush()
    os.dup2(2, 1)
    result = {"renderer": "mitsuba3", "scene": args.scene}
    env = cfg.get("environment", {})
    if "file" not in env and env.get("procedural"):
        reason = f"procedural environment {env['procedural']!r} is not supported"
        print(f"mitsuba_peer: skipping {args.scene}: {reason}", file=sys.stderr)
        result.update(skipped=True, reason=reason)
        print(json.dumps(result), file=json_out)
        write_result(args.output, result, prov)
        return

    mi.set_variant(VARIANT)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    with tempfile.TemporaryDirectory(prefix="mitsuba_peer_") as tmpdir:
        t0 = time.perf_counter()
        scene_dict, approximated = build_scene(cfg, base, width, height, spp, strategy, tmpdir)
        prep = time.perf_counter() - t0
        t0 = time.perf_counter()
        scene = mi.load_dict(scene_dict)
        setup = time.perf_counter() - t0
    jit_stats()  # drop kernels launched while loading (e.g. envmap / mesh preprocessing)
    _, jit = timed_render(scene, 1, seed)  # warm-up: the LLVM backend JIT-compiles here
    jit_kernels = jit_stats()
    img, seconds = timed_render(scene, spp, seed)
    render_kernels = jit_stats()

    result.update({
        "variant": VARIANT, "mitsuba_version": mi.__version__, "drjit_version": dr.__version__,
        "threads": dr.thread_count(), "strategy": strategy, "spp": spp, "width": width,
        "height": height, "seed": seed, "prep_seconds": prep, "setup_seconds": setup,
        "jit_seconds": jit, "jit_kernels": jit_kernels, "render_seconds": seconds,
        "render_kernels_compiled": render_kernels["compiled"],
        "samples_per_second": width * height * spp / seconds,
        "approximated_materials": approximated,
    })
    if note:
        result["note"] = note
    if args.out:
        mi.util.write_bitmap(args.out, img)
        result["out"] = args.out
    print(json.dumps(result), file=json_out)
    json_out.flush()
    write_result(args.output, result, prov)


if __name__ == "__main__":
    main()
