"""The view frame's walk against its own texel sum: per bunny of benchmarks/relight_view.py (its
view bakes, cached in /tmp/relight-bench/view-bakes), --points cache points on the bunny facing
the camera of relight_view.py, B = <T1, f_r> by the walk (:func:`wavlight.relight.view_walk.product_reference`,
the kernel's numpy twin) at each refine and mass against the same walk refined down to every
texel (refine --truth-refine, mass 0: the midpoint rule at texel size). The relative L2 over
the points and the nodes visited per point show what the walk's stopping rule costs and buys;
the frame's error against ``mis`` is relight_view.py's.

    python benchmarks/view_walk.py [--scenes bunny_ggx,bunny_ggx05] [--points 1500]
        [--settings 0.15:0,0.08:0,0.04:0,0.02:0,0.15:0.01,0.2:0.01,0.25:0.01,0.2:0.003,0.15:0.03] [-o FILE]

The figures in benchmarks/results/view_walk.json come from the defaults.
"""
from __future__ import annotations

import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import relight_common as common  # noqa: E402
import relight_view  # noqa: E402


def main():
    ap = common.parser(__doc__)
    ap.add_argument("--scenes", default="bunny_ggx,bunny_ggx05")
    ap.add_argument("--points", type=int, default=1500, help="cache points on the bunny per scene")
    ap.add_argument("--settings",
                    default="0.15:0,0.08:0,0.04:0,0.02:0,0.15:0.01,0.2:0.01,0.25:0.01,0.2:0.003,0.15:0.03",
                    help="REFINE:MASS pairs of the walk")
    ap.add_argument("--truth-refine", type=float, default=0.003, help="the reference walk's refine (mass 0)")
    ap.add_argument("--turn", type=float, default=40.0, help="degrees the eye turns about the target")
    args = common.parse(ap, "view_walk", 0.0)
    started = common.begin(args)
    from wavlight.relight import view_frames, view_walk

    rows, scenes = [], {}
    for name in [s for s in args.scenes.split(",") if s]:
        d = relight_view.turned(relight_view.SCENES[name](), args.turn)
        tr, _ = relight_view.cached_view_bake(d, None)
        frames = view_frames.ViewFrames(tr, common.load(d))
        eye = frames.scene.camera.eye
        floor = frames.scene.face_material[-1]
        facing = np.einsum("ij,ij->i", frames.normal, eye - frames.position) > 0
        candidates = np.flatnonzero((frames.material != floor) & facing)
        points = np.sort(np.random.default_rng(1).choice(candidates, min(args.points, len(candidates)), replace=False))
        items = frames._point_items(points, eye)
        s = tr._s
        walk = lambda refine, mass: view_walk.product_reference(  # noqa: E731
            s["offsets"], s["entry_scale"], s["entry_data"], tr.n_levels, *items, refine=refine, mass=mass)
        truth, truth_nodes = walk(args.truth_refine, 0.0)
        scenes[name] = {"points": len(points), "n_levels": tr.n_levels,
                        "truth_nodes_per_point": float(truth_nodes.mean())}
        for spec in [x for x in args.settings.split(",") if x]:
            refine, mass = (float(x) for x in spec.split(":"))
            B, nodes = walk(refine, mass)
            err = float(np.sqrt(((B - truth) ** 2).sum() / (truth ** 2).sum()))
            rows.append({"scene": name, "refine": refine, "mass": mass, "error": err,
                         "nodes_per_point": float(nodes.mean())})
            print(f"{name:12s} refine {refine:<6g} mass {mass:<6g} error {err:.4f} nodes/point {nodes.mean():7.0f}",
                  flush=True)
        tr.close()
    data = {"turn": args.turn, "truth_refine": args.truth_refine, "scenes": scenes, "rows": common.rounded(rows)}
    print(common.finish(args.output, data, started))


if __name__ == "__main__":
    main()
