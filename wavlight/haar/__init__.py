"""Nonstandard 2D Haar wavelets: transform, compression, tripling coefficients, products
(Chen & Gao sec. 4.1-4.4, eq. 13-25; Ng et al. 2003, 2004).

Conventions
-----------
*Images* are functions on the unit square, piecewise constant on a 2^n x 2^n grid,
stored ``image[y, x]`` (y the row; "top" means small y, "left" small x). Every
function here acts on the last two axes; all leading axes are a batch. A colour
image (2^n, 2^n, C) is transformed as ``forward(np.moveaxis(img, -1, 0))``: channels
come first, like any other batch axis.

*Basis* (orthonormal, eq. 13): the scaling function phi = 1 on the unit square and,
for each level 0 <= l < n and node t = (x, y) (0 <= x, y < 2^l, square
[x, x+1] 2^-l x [y, y+1] 2^-l), three wavelets of value +-2^l on that square:
m = 1 horizontal difference (+ on the left half, - on the right), m = 2 vertical
difference (+ top, - bottom), m = 3 diagonal (+ top-left and bottom-right).
Scaling coefficient of a node: F^0_{l,t} = integral of F * 2^l over its square
= 2^l * mass (eq. 17); the root F^0_{0,0} is the integral (eq. 18).

*Dense layout* (in place, Stollnitz et al.): coefficients of a 2^n x 2^n image are a
2^n x 2^n array ``c``; ``c[0, 0]`` is the scaling coefficient and the wavelets of
level l (s = 2^l) sit in three s x s blocks::

    m = 1: c[y, s + x]      m = 2: c[s + y, x]      m = 3: c[s + y, s + x]

A basis index is the flat position ``row * 2^n + col`` (``coeff_index`` /
``coeff_basis``). The top-left 2^k x 2^k block is the transform of the same image
at resolution 2^k, so sets of different resolutions compare by zero padding.

*Sparse* (:class:`SparseHaar`): sorted flat indices and values, (K,) or (K, C);
``to_dense`` gives (2^n, 2^n) or (C, 2^n, 2^n).

*Pyramids* are box masses in the layout of :mod:`wavlight.haar.tree`: node (l, x, y) at
``level_offset(l) + y 2^l + x`` holds 2^-l F^0_{l,t}; many pyramids stack on a
leading axis, ``tree_size(L)`` apart.

Algorithms
----------
*Triple product integral* (Ng et al. 2004, linear time). Of the three cases of the
tripling theorem (sec. 4.2), case 3 pairs two identical wavelets w at node (l, t)
with every coarser function that overlaps them; summed, those coarser functions are
the third image's average over the node's square, X(l,t) = 2^l X^0_{l,t}, the
running sum of its parents' scaling coefficients. Hence

    int G H K = G0 H0 K0 + sum over nodes (l, t) of
                [ sum_m (G^m H^m K(l,t) + G^m K^m H(l,t) + H^m K^m G(l,t))
                  + 2^l sum over permutations (a, b, c) of (1, 2, 3) of G^a H^b K^c ].

Dense: one top-down pass gives every average, O(4^n). Sparse: only nodes where two
sets share a wavelet contribute, and their averages come from one top-down pass over
the distinct nodes on their paths to the root (Ng et al.'s traversal; ``_averages``);
coefficients are found by key in O(1) through a table over the key space where the set
fills at least 1/64 of it (binary search, O(log K), for sparser sets), so the cost is
linear in the K kept coefficients plus those paths' distinct nodes (at most min(C n,
4^n / 3) for C shared wavelets; ``haar_bench.py``). The double product is a dot product.

*Product scaling coefficients* (eq. 23-25). On a node's square Q, G is its average
plus the wavelets inside Q; wavelets integrate to zero over Q and are orthonormal,
so with levels l' >= l (the node's own wavelets included)

    2^-l F^0_{l,t} = G^0_{l,t} H^0_{l,t} + D_{l,t},   D_{l,t} = sum_{l' >= l, t' in t, m} G^m H^m,

which is eq. 25 divided by 2^l, exactly the box sum of G H (tested). D is
accumulated bottom-up (D_{l,t} = own products + the children's D). Sparse inputs
only touch the common wavelets; ``product_scaling_at`` evaluates single nodes with
per-level prefix sums in Morton order, for nodes a sample visits.
On the device (``ProductPyramids``) the pyramid is built as leaf products reduced
bottom-up, which equals eq. 25 level by level and keeps parent = sum of children in
float32, as the warp in ``kernels/warp.h`` expects.
"""
from __future__ import annotations

from .products import double_product_integral, triple_product_integral, tripling
from .pyramids import (
    ProductPyramids,
    product_scaling,
    product_scaling_at,
    scaling_pyramid,
)
from .sparse import SparseHaar, compress_energy, compress_topk
from .transform import (
    MAX_LEVELS,
    coeff_basis,
    coeff_index,
    forward,
    forward_cl,
    inverse,
    texel_values,
    inverse_cl,
    node_scale,
)
from .tree import HaarTree

__all__ = [
    "coeff_index", "coeff_basis", "node_scale", "forward", "inverse", "texel_values", "scaling_pyramid",
    "SparseHaar", "compress_topk", "compress_energy", "tripling", "double_product_integral",
    "triple_product_integral", "product_scaling", "product_scaling_at", "forward_cl", "inverse_cl",
    "ProductPyramids", "HaarTree", "MAX_LEVELS",
]
