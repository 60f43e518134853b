"""Hashes of images of every strategy at fixed seeds on two scenes, and of render --json's keys.

A refactor that is meant to keep behaviour must keep these. The result, with the run's
provenance (benchmarks/provenance.py: commit, CPU, OpenCL platform, command), goes to
benchmarks/results/image_hashes.json unless -o names another file ("-": none); --compare
compares two such files (exit status 1 if any image or key list differs):

    python benchmarks/image_hashes.py [-o FILE]
    python benchmarks/image_hashes.py --compare A B

The hashes in benchmarks/results/image_hashes.json come from the default command.
"""
import argparse, hashlib, json, os, subprocess, sys, tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SCENES = {"default": os.path.join(ROOT, "scenes", "default.toml"),
          "bunny_ggx": os.path.join(HERE, "scenes", "bunny_ggx.toml")}   # fetched data: wavlight.data
STRATEGIES = ("uniform", "cosine", "bsdf", "light", "mis", "mis_comp", "wavelet", "sir", "structured")
VARIANTS = {"wavelet-m0": dict(strategy="wavelet", wavelet_candidates=0),
            "wavelet-16x2": dict(strategy="wavelet", wavelet_candidates=16, wavelet_slots=2),
            "wavelet-8x4-nocv": dict(strategy="wavelet", wavelet_candidates=8, wavelet_slots=4,
                                     wavelet_control_variate=False),
            "mis-stratified": dict(strategy="mis", sampler="stratified"),
            "light-l5": dict(strategy="light", light_levels=5),
            "sir-64x2": dict(strategy="sir", sir_candidates=64, sir_samples=2),
            "structured-pre": dict(strategy="structured", structured_mode="preintegrated", structured_strata=8)}


def digest(a):
    return hashlib.sha256(np.ascontiguousarray(a, np.float32).tobytes()).hexdigest()[:16]


def main():
    import wavlight
    sys.path.insert(0, HERE)
    from provenance import add_output_argument, provenance, write_result

    p = argparse.ArgumentParser()
    add_output_argument(p, "image_hashes")
    p.add_argument("--compare", nargs=2)
    a = p.parse_args()
    if a.compare:
        x, y = (json.load(open(f)) for f in a.compare)
        bad = [k for k in sorted(set(x["hashes"]) | set(y["hashes"])) if x["hashes"].get(k) != y["hashes"].get(k)]
        keys = x["json_keys"] == y["json_keys"]
        print(f"{len(x['hashes'])} / {len(y['hashes'])} images, {len(bad)} differ: {bad}; json keys equal: {keys}")
        sys.exit(1 if bad or not keys else 0)
    prov = provenance()
    hashes, keys = {}, {}
    for sname, path in SCENES.items():
        if not os.path.exists(path):
            continue
        try:
            scene = wavlight.load_scene(path)
        except Exception as e:
            print("skip", sname, e)
            continue
        runs = {s: dict(strategy=s) for s in STRATEGIES} | (VARIANTS if sname == "default" else {})
        for label, opts in runs.items():
            r = wavlight.render_full(scene, spp=4, width=48, height=36, seed=3, **opts)
            hashes[f"{sname}/{label}"] = digest(r.image) + "/" + digest(r.stderr)
            print(sname, label, hashes[f"{sname}/{label}"], flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for s in STRATEGIES:
            out = subprocess.run(["wavlight", "render", SCENES["default"], "-o", os.path.join(tmp, "x.exr"),
                                  "--spp", "2", "--width", "16", "--height", "12", "--strategy", s, "--json"],
                                 capture_output=True, text=True, check=True)
            keys[s] = sorted(json.loads(out.stdout))
    write_result(a.output, {"hashes": hashes, "json_keys": keys}, prov)


if __name__ == "__main__":
    main()
