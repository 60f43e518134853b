"""Haar machinery timings (numpy, wavlight/haar/): the double and triple product integrals
(sec. 4.2, Ng et al. 2004) against the number of coefficients, to show how their cost grows.

Dense: three random (2^n x 2^n) coefficient sets, n = 5..10 (4^n coefficients each).
Sparse: each set compressed to its K largest coefficients (compress_topk) of one 1024 x 1024
random image with a power-law spectrum (as real maps have), K = 10^3 .. 10^6. The module
notes (wavlight/haar/__init__.py) give the sparse cost as linear in K plus the distinct nodes
on the shared wavelets' paths to the root (coefficients found by key through a table,
averages in one top-down pass).
Reports seconds (best of 3), nanoseconds per coefficient and, for the sparse triple product,
the wavelets two of the sets share (their number grows faster than K: three top-K sets of
one image size overlap more as K nears 4^n) and the time per kept coefficient plus shared
wavelet.
Prints one JSON object and writes it with the run's provenance (benchmarks/provenance.py)
to benchmarks/results/haar_bench.json (-o FILE another, "-" none). The figures there come
from the default command:

    python benchmarks/haar_bench.py [--max-level 10] [-o FILE]
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np


def best_of(fn, repeat=3):
    fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def power_law_image(rng, n):
    """A random 2^n x 2^n image whose spectrum falls as 1/f (positive, like a light probe)."""
    side = 1 << n
    f = np.fft.fftfreq(side)
    amp = 1.0 / np.maximum(np.hypot(*np.meshgrid(f, f)), 1.0 / side)
    field = np.fft.ifft2(amp * np.exp(2j * np.pi * rng.random((side, side)))).real
    return np.exp(3 * field / field.std())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--max-level", type=int, default=10)
    from provenance import add_output_argument, provenance, write_result

    add_output_argument(ap, "haar_bench")
    args = ap.parse_args()
    prov = provenance()
    from wavlight import haar
    from wavlight.haar.sparse import common_nodes, Keyed

    rng = np.random.default_rng(3)
    out = {"dense": {}, "sparse": {}}
    for n in range(5, args.max_level + 1):
        g, h, k = (rng.standard_normal((1 << n, 1 << n)) for _ in range(3))
        t3 = best_of(lambda: haar.triple_product_integral(g, h, k))
        t2 = best_of(lambda: haar.double_product_integral(g, h))
        c = 4 ** n
        out["dense"][str(n)] = {"coefficients": c, "triple_seconds": round(t3, 6), "double_seconds": round(t2, 6),
                                "triple_ns_per_coefficient": round(1e9 * t3 / c, 2),
                                "double_ns_per_coefficient": round(1e9 * t2 / c, 2)}
    n = args.max_level
    dense = [haar.forward(power_law_image(rng, n)) for _ in range(3)]
    for kept in (10 ** 3, 10 ** 4, 10 ** 5, 3 * 10 ** 5, 10 ** 6):
        if kept > 4 ** n:
            break
        g, h, k = (haar.compress_topk(d, kept) for d in dense)
        t3 = best_of(lambda: haar.triple_product_integral(g, h, k))
        t2 = best_of(lambda: haar.double_product_integral(g, h))
        # the wavelets two sets share (case 3 needs the third set's average at each)
        c = [Keyed(s, n) for s in (g, h, k)]
        common = sum(len(common_nodes(a, b)[0]) for a, b in ((c[0], c[1]), (c[0], c[2]), (c[1], c[2])))
        out["sparse"][str(kept)] = {"levels": n, "common_wavelets": common,
                                    "triple_seconds": round(t3, 6), "double_seconds": round(t2, 6),
                                    "triple_ns_per_coefficient": round(1e9 * t3 / kept, 2),
                                    "triple_ns_per_coefficient_and_common_wavelet": round(
                                        1e9 * t3 / (3 * kept + common), 2),
                                    "double_ns_per_coefficient": round(1e9 * t2 / kept, 2)}
    print(json.dumps(out, indent=1))
    write_result(args.output, out, prov)


if __name__ == "__main__":
    main()
