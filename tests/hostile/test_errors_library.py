"""Bad arguments to the library's public helpers (haar, distributions, product, warp,
strategies) raise ArgumentError: one line that names the function and the argument, a
WavlightError (the CLI's one-line errors) and a ValueError (for existing callers)."""
from __future__ import annotations

import re

import numpy as np
import pytest

from wavlight import bsdfs, haar, strategies, warp
from wavlight.haar import tree as haar_tree
from wavlight.strategies import product
from wavlight.errors import ArgumentError, WavlightError

C8 = haar.forward(np.random.default_rng(1).random((8, 8)))        # dense coefficients, n = 3
SP = haar.compress_topk(C8, 5)                                     # sparse, n = 3
SP2 = haar.SparseHaar(2, [0, 1], np.ones((2, 2)))                  # 2 channels
SP3 = haar.SparseHaar(2, [0, 1], np.ones((2, 3)))                  # 3 channels
TREE = haar_tree.build_reference(np.random.default_rng(2).random((2, 4, 4)))   # 2 trees, n = 2
U8 = np.random.default_rng(3).random((8, 2))
N3 = np.tile([0.0, 0.0, 1.0], (4, 1))
PRODUCT_ARGS = dict(tree=TREE, n_levels=2, env=None, axis=N3, n=N3, kappa=np.zeros(4),
                    levels=np.full(4, 2), shape=np.zeros(4, int), u=np.full((4, 2), 0.5))


def product_twin(fn=product.sample_reference, points="u", **changes):
    args = {**PRODUCT_ARGS, **changes}
    args[points] = args.pop("u")
    return fn(**args)


CASES = [
    # ---------------------------------------------------------------- haar: layout
    ("coeff_index n_levels", lambda: haar.coeff_index(0, 0, 0, 1, -1),
     r"haar\.coeff_index: n_levels must be between 0 and 31"),
    ("coeff_index float", lambda: haar.coeff_index(1.5, 0, 0, 1, 3), r"haar\.coeff_index: level must be integers"),
    ("coeff_index m", lambda: haar.coeff_index(1, 0, 0, 4, 3), r"haar\.coeff_index: m must be 0"),
    ("coeff_index level", lambda: haar.coeff_index(3, 0, 0, 1, 3),
     r"haar\.coeff_index: a wavelet's level must be in \[0, 3\), got 3"),
    ("coeff_index x", lambda: haar.coeff_index(1, 2, 0, 1, 3), r"haar\.coeff_index: a wavelet's x and y"),
    ("coeff_index broadcast", lambda: haar.coeff_index([1, 1], [0, 0, 0], 0, 1, 3),
     r"haar\.coeff_index: shapes do not broadcast"),
    ("coeff_basis index", lambda: haar.coeff_basis(64, 3), r"haar\.coeff_basis: index must be in \[0, 64\), got 64"),
    ("coeff_basis n_levels", lambda: haar.coeff_basis(0, 2.0), r"haar\.coeff_basis: n_levels must be an integer"),
    ("node_scale", lambda: haar.node_scale(40), r"haar\.node_scale: n_levels must be between 0 and 31, got 40"),
    # ---------------------------------------------------------------- haar: transform
    ("forward shape", lambda: haar.forward(np.zeros((300, 200))),
     r"haar\.forward: images must be \(\.\.\., 2\^n, 2\^n\) arrays, got shape \(300, 200\)"),
    ("forward side", lambda: haar.forward(np.zeros((6, 6))), r"haar\.forward: images .* got shape \(6, 6\)"),
    ("forward 1d", lambda: haar.forward(np.zeros(8)), r"haar\.forward: images .* got shape \(8,\)"),
    ("forward dtype", lambda: haar.forward(np.ones((2, 2), complex)),
     r"haar\.forward: images must be an array of real numbers"),
    ("forward str", lambda: haar.forward("abc"), r"haar\.forward: images must be an array of real numbers"),
    ("forward ragged", lambda: haar.forward([[1.0, 2.0], [3.0]]), r"haar\.forward: images must be an array of numbers"),
    ("forward nan", lambda: haar.forward(np.full((2, 2), np.nan)),
     r"haar\.forward: images must be finite, got NaN or Inf in 4 of 4"),
    ("inverse shape", lambda: haar.inverse(np.zeros((3, 3))), r"haar\.inverse: coeffs must be \(\.\.\., 2\^n, 2\^n\)"),
    ("inverse None", lambda: haar.inverse(None), r"haar\.inverse: coeffs must be an array of real numbers"),
    # ---------------------------------------------------------------- haar: sparse sets, compression
    ("SparseHaar n_levels", lambda: haar.SparseHaar(-1, [0], [1.0]),
     r"haar\.SparseHaar: n_levels must be between 0 and 31"),
    ("SparseHaar index dtype", lambda: haar.SparseHaar(2, [0.5], [1.0]), r"haar\.SparseHaar: index must be integers"),
    ("SparseHaar index range", lambda: haar.SparseHaar(2, [16], [1.0]),
     r"haar\.SparseHaar: index must be in \[0, 16\), got 16"),
    ("SparseHaar duplicate", lambda: haar.SparseHaar(2, [1, 1], [1.0, 2.0]),
     r"haar\.SparseHaar: index 1 appears more than once"),
    ("SparseHaar value shape", lambda: haar.SparseHaar(2, [0, 1], [1.0]),
     r"haar\.SparseHaar: value must be \(K,\) or \(K, C\) for K = 2"),
    ("SparseHaar value nan", lambda: haar.SparseHaar(2, [0], [np.nan]), r"haar\.SparseHaar: value must be finite"),
    ("from_dense 4d", lambda: haar.SparseHaar.from_dense(np.zeros((1, 1, 4, 4))),
     r"haar\.SparseHaar\.from_dense: coeffs must be one set"),
    ("from_dense keep range", lambda: haar.SparseHaar.from_dense(C8, [100]),
     r"haar\.SparseHaar\.from_dense: keep must be in \[0, 64\), got 100"),
    ("from_dense keep float", lambda: haar.SparseHaar.from_dense(C8, [1.5]),
     r"haar\.SparseHaar\.from_dense: keep must be integers"),
    ("from_dense keep mask", lambda: haar.SparseHaar.from_dense(C8, np.ones(5, bool)),
     r"haar\.SparseHaar\.from_dense: a boolean keep must have one entry per coefficient \(64\)"),
    ("compress_topk k 0", lambda: haar.compress_topk(C8, 0), r"haar\.compress_topk: k must be at least 1, got 0"),
    ("compress_topk k float", lambda: haar.compress_topk(C8, 2.5),
     r"haar\.compress_topk: k must be an integer, got 2\.5"),
    ("compress_topk k bool", lambda: haar.compress_topk(C8, True),
     r"haar\.compress_topk: k must be an integer, got True"),
    ("compress_topk coeffs", lambda: haar.compress_topk(np.zeros((1, 1, 2, 2)), 1),
     r"haar\.compress_topk: coeffs must be one set"),
    ("compress_topk nan", lambda: haar.compress_topk(np.full((2, 2), np.nan), 2),
     r"haar\.compress_topk: coeffs must be finite"),
    ("compress_energy 1.5", lambda: haar.compress_energy(C8, 1.5),
     r"haar\.compress_energy: fraction must be a finite number in \[0, 1\], got 1\.5"),
    ("compress_energy nan", lambda: haar.compress_energy(C8, float("nan")),
     r"haar\.compress_energy: fraction must be a finite number in \[0, 1\], got nan"),
    ("compress_energy str", lambda: haar.compress_energy(C8, "0.5"),
     r"haar\.compress_energy: fraction must be a number, got '0\.5'"),
    ("compress_energy inf", lambda: haar.compress_energy(np.full((2, 2), np.inf), 0.5),
     r"haar\.compress_energy: coeffs must be finite"),
    # ---------------------------------------------------------------- haar: tripling, products
    ("tripling range", lambda: haar.tripling(100, 0, 0, 2), r"haar\.tripling: i must be in \[0, 16\), got 100"),
    ("tripling negative", lambda: haar.tripling(0, -1, 0, 2), r"haar\.tripling: j must be in \[0, 16\), got -1"),
    ("tripling float", lambda: haar.tripling(0, 0, 1.5, 2), r"haar\.tripling: k must be integers"),
    ("tripling broadcast", lambda: haar.tripling([1, 2], [1, 2, 3], 0, 2),
     r"haar\.tripling: shapes do not broadcast: i \(2,\), j \(3,\), k \(\)"),
    ("tripling n_levels", lambda: haar.tripling(0, 0, 0, None),
     r"haar\.tripling: n_levels must be an integer, got None"),
    ("double shape", lambda: haar.double_product_integral(C8, np.zeros((3, 3))),
     r"haar\.double_product_integral: H must be \(\.\.\., 2\^n, 2\^n\)"),
    ("double batch", lambda: haar.double_product_integral(np.zeros((2, 4, 4)), np.zeros((3, 4, 4))),
     r"haar\.double_product_integral: batch shapes do not broadcast: G \(2, 4, 4\), H \(3, 4, 4\)"),
    ("double None", lambda: haar.double_product_integral(None, C8),
     r"haar\.double_product_integral: G must be an array of real numbers"),
    ("double channels", lambda: haar.double_product_integral(SP2, SP3),
     r"haar\.double_product_integral: sparse sets have different channel counts \[2, 3\]"),
    ("triple shape", lambda: haar.triple_product_integral(C8, C8, np.zeros((3, 3))),
     r"haar\.triple_product_integral: K must be"),
    ("triple batch", lambda: haar.triple_product_integral(np.zeros((2, 4, 4)), np.zeros((3, 4, 4)), C8),
     r"haar\.triple_product_integral: batch shapes do not broadcast"),
    ("triple channels", lambda: haar.triple_product_integral(SP2, SP3, SP3),
     r"haar\.triple_product_integral: sparse sets have different channel counts"),
    ("scaling_pyramid levels", lambda: haar.scaling_pyramid(C8, 5),
     r"haar\.scaling_pyramid: levels must be between 0 and 3, got 5"),
    ("scaling_pyramid levels float", lambda: haar.scaling_pyramid(C8, 1.5),
     r"haar\.scaling_pyramid: levels must be an integer, got 1\.5"),
    ("scaling_pyramid sparse levels", lambda: haar.scaling_pyramid(SP, -1),
     r"haar\.scaling_pyramid: levels must be between 0 and 3, got -1"),
    ("scaling_pyramid shape", lambda: haar.scaling_pyramid(np.zeros((6, 6))),
     r"haar\.scaling_pyramid: coeffs must be \(\.\.\., 2\^n, 2\^n\)"),
    ("product_scaling levels", lambda: haar.product_scaling(C8, C8, 9),
     r"haar\.product_scaling: levels must be between 0 and 3, got 9"),
    ("product_scaling batch", lambda: haar.product_scaling(np.zeros((2, 8, 8)), np.zeros((3, 8, 8))),
     r"haar\.product_scaling: batch shapes do not broadcast"),
    ("product_scaling shape", lambda: haar.product_scaling(C8, np.zeros((6, 6))),
     r"haar\.product_scaling: H must be \(\.\.\., 2\^n, 2\^n\)"),
    ("product_scaling channels", lambda: haar.product_scaling(SP2, SP3),
     r"haar\.product_scaling: sparse sets have different channel counts"),
    ("product_scaling_at level", lambda: haar.product_scaling_at(SP, SP, 5, 0, 0),
     r"haar\.product_scaling_at: level must be in \[0, 3\], got 5"),
    ("product_scaling_at x", lambda: haar.product_scaling_at(SP, SP, 1, 7, 0),
     r"haar\.product_scaling_at: x and y must be in \[0, 2\^level\)"),
    ("product_scaling_at float", lambda: haar.product_scaling_at(SP, SP, 1.5, 0, 0),
     r"haar\.product_scaling_at: level must be integers"),
    ("product_scaling_at broadcast", lambda: haar.product_scaling_at(SP, SP, [1, 1], [0, 1, 0], 0),
     r"haar\.product_scaling_at: shapes do not broadcast"),
    ("product_scaling_at dense", lambda: haar.product_scaling_at(np.zeros((6, 6)), SP, 1, 0, 0),
     r"haar\.product_scaling_at: G must be \(\.\.\., 2\^n, 2\^n\)"),
    ("product_scaling_at 4d", lambda: haar.product_scaling_at(np.zeros((1, 1, 4, 4)), SP, 1, 0, 0),
     r"haar\.product_scaling_at: G must be one set"),
    ("forward_cl 1d", lambda: haar.forward_cl(np.ones(4)),
     r"haar\.forward_cl: images must be \(\.\.\., 2\^n, 2\^n\), got shape \(4,\)"),
    ("forward_cl side", lambda: haar.forward_cl(np.ones((3, 6, 6))),
     r"haar\.forward_cl: images must be \(\.\.\., 2\^n, 2\^n\)"),
    ("forward_cl str", lambda: haar.forward_cl("abc"), r"haar\.forward_cl: images must be an array of real numbers"),
    ("ProductPyramids G channels", lambda: haar.ProductPyramids(np.ones((2, 8, 8)), 2),
     r"haar\.ProductPyramids: G must be one single-channel coefficient set"),
    ("ProductPyramids h_levels", lambda: haar.ProductPyramids(C8, -1),
     r"haar\.ProductPyramids: h_levels must be between 0 and 31, got -1"),
    ("ProductPyramids h_levels float", lambda: haar.ProductPyramids(C8, 2.5),
     r"haar\.ProductPyramids: h_levels must be an integer"),
    ("ProductPyramids levels", lambda: haar.ProductPyramids(C8, 2, levels=4),
     r"haar\.ProductPyramids: levels must be between 0 and 3, got 4"),
    # ---------------------------------------------------------------- distributions
    ("leaf_levels 6", lambda: haar_tree.leaf_levels(6),
     r"haar\.tree\.leaf_levels: tree images must be 2\^n x 2\^n, got side 6"),
    ("leaf_levels str", lambda: haar_tree.leaf_levels("8"), r"haar\.tree\.leaf_levels: .* got side '8'"),
    ("build_reference 1d", lambda: haar_tree.build_reference(np.zeros(4)),
     r"haar\.tree\.build_reference: leaves must be \(T, 2\^n, 2\^n\) or \(2\^n, 2\^n\), got shape \(4,\)"),
    ("build_reference 4d", lambda: haar_tree.build_reference(np.zeros((1, 1, 4, 4))),
     r"haar\.tree\.build_reference: leaves must be .* got shape \(1, 1, 4, 4\)"),
    ("build_reference non-square", lambda: haar_tree.build_reference(np.zeros((4, 8))),
     r"haar\.tree\.build_reference: leaves must be .* got shape \(4, 8\)"),
    ("build_reference negative", lambda: haar_tree.build_reference(-np.ones((4, 4))),
     r"haar\.tree\.build_reference: tree leaves must be finite and non-negative"),
    ("build_reference str", lambda: haar_tree.build_reference([["a"]]),
     r"haar\.tree\.build_reference: leaves must be an array of real numbers"),
    ("sample_reference n_levels", lambda: haar_tree.sample_reference(TREE, 3, U8, 4),
     r"haar\.tree\.sample_reference: tree must hold whole pyramids of tree_size\(3\) = 85 nodes"),
    ("sample_reference spt 0", lambda: haar_tree.sample_reference(TREE, 2, U8, 0),
     r"haar\.tree\.sample_reference: samples_per_tree must be at least 1, got 0"),
    ("sample_reference spt small", lambda: haar_tree.sample_reference(TREE, 2, U8, 1),
     r"haar\.tree\.sample_reference: 8 points at 1 per tree need 8 trees, tree holds 2"),
    ("sample_reference u", lambda: haar_tree.sample_reference(TREE, 2, np.zeros((8, 3)), 4),
     r"haar\.tree\.sample_reference: u must be \(N, 2\), got shape \(8, 3\)"),
    ("pdf_reference spt small", lambda: haar_tree.pdf_reference(TREE, 2, U8, 1),
     r"haar\.tree\.pdf_reference: 8 points at 1 per tree need 8 trees"),
    ("pdf_reference n_levels", lambda: haar_tree.pdf_reference(TREE, -1, U8, 4),
     r"haar\.tree\.pdf_reference: n_levels must be between 0 and 30, got -1"),
    ("HaarTree 1d", lambda: haar_tree.HaarTree(np.ones(4)),
     r"haar\.tree\.HaarTree: leaves must be \(T, 2\^n, 2\^n\) or \(2\^n, 2\^n\), got shape \(4,\)"),
    ("HaarTree 4d", lambda: haar_tree.HaarTree(np.ones((1, 1, 4, 4))),
     r"haar\.tree\.HaarTree: leaves must be .* got shape \(1, 1, 4, 4\)"),
    ("HaarTree empty", lambda: haar_tree.HaarTree(np.ones((0, 4, 4))),
     r"haar\.tree\.HaarTree: leaves must hold at least one image"),
    ("HaarTree negative", lambda: haar_tree.HaarTree(-np.ones((4, 4))),
     r"haar\.tree\.HaarTree: tree leaves must be finite and non-negative"),
    ("HaarTree None", lambda: haar_tree.HaarTree(None),
     r"haar\.tree\.HaarTree: leaves must be an array of real numbers"),
    # ---------------------------------------------------------------- product
    ("centre_angles level", lambda: product.centre_angles(0, 0, 20),
     r"strategies\.product\.centre_angles: level must be between 0 and 14, got 20"),
    ("centre_angles x", lambda: product.centre_angles(5, 0, 2),
     r"strategies\.product\.centre_angles: x must be in \[0, 4\), got 5"),
    ("lobe_shape kind", lambda: product.lobe_shape(7, 0.1),
     r"strategies\.product\.lobe_shape: kind must be one of 0 \(lambert\), 1 \(phong\), 2 \(ggx\), 3 \(plastic\), got 7"),
    ("lobe_kappa kind str", lambda: product.lobe_kappa("ggx", 0.1),
     r"strategies\.product\.lobe_kappa: kind must be one of .* got 'ggx'"),
    ("lobe_kappa ggx 0", lambda: product.lobe_kappa(bsdfs.GGX, 0.0),
     r"strategies\.product\.lobe_kappa: param \(ggx or plastic alpha\) must be positive"),
    ("lobe_kappa ggx nan", lambda: product.lobe_kappa(bsdfs.GGX, float("nan")),
     r"strategies\.product\.lobe_kappa: param must be a finite number >= 0, got nan"),
    ("lobe_kappa phong negative", lambda: product.lobe_kappa(bsdfs.PHONG, -5.0),
     r"strategies\.product\.lobe_kappa: param must be a finite number >= 0, got -5"),
    ("product_levels kappa nan", lambda: product.product_levels(float("nan"), 8),
     r"strategies\.product\.product_levels: kappa must be a finite number >= 0, got nan"),
    ("product_levels kappa inf", lambda: product.product_levels(float("inf"), 8),
     r"strategies\.product\.product_levels: kappa must be a finite number >= 0, got inf"),
    ("product_levels tree_levels", lambda: product.product_levels(10.0, -1),
     r"strategies\.product\.product_levels: tree_levels must be at least 0, got -1"),
    ("product_levels override", lambda: product.product_levels(10.0, 8, 2.7),
     r"strategies\.product\.product_levels: override must be an integer, got 2\.7"),
    ("sample_reference tree", lambda: product_twin(n_levels=3),
     r"strategies\.product\.sample_reference: tree must be \(tree_size\(n\),\) or \(T, tree_size\(n\)\) with tree_size\(3\) = 85"),
    ("sample_reference u", lambda: product_twin(u=np.zeros((4, 3))),
     r"strategies\.product\.sample_reference: u must be \(N, 2\), got shape \(4, 3\)"),
    ("sample_reference axis", lambda: product_twin(axis=N3[:3]),
     r"strategies\.product\.sample_reference: axis must be \(4, 3\) like u, got shape \(3, 3\)"),
    ("sample_reference kappa", lambda: product_twin(kappa=0.0),
     r"strategies\.product\.sample_reference: kappa must be \(4,\) like u, got shape \(\)"),
    ("sample_reference levels", lambda: product_twin(levels=np.full(4, -1)),
     r"strategies\.product\.sample_reference: levels must be non-negative"),
    ("sample_reference levels float", lambda: product_twin(levels=np.full(4, 2.0)),
     r"strategies\.product\.sample_reference: levels must be integers"),
    ("sample_reference tree_index", lambda: product_twin(tree_index=np.full(4, 2)),
     r"strategies\.product\.sample_reference: tree_index must be in \[0, 2\), got 2"),
    ("pdf_reference tree_index shape", lambda: product_twin(product.pdf_reference, "uv", tree_index=np.zeros(3, int)),
     r"strategies\.product\.pdf_reference: tree_index must be one index or \(4,\)"),
    # ---------------------------------------------------------------- warp
    ("uniform_hemisphere shape", lambda: warp.square_to_uniform_hemisphere(np.zeros((4, 3))),
     r"warp\.square_to_uniform_hemisphere: u must be \(N, 2\), got shape \(4, 3\)"),
    ("uniform_hemisphere range", lambda: warp.square_to_uniform_hemisphere(np.array([[2.0, 0.5]])),
     r"warp\.square_to_uniform_hemisphere: u must lie in \[0, 1\]\^2"),
    ("uniform_hemisphere nan", lambda: warp.square_to_uniform_hemisphere(np.array([[np.nan, 0.5]])),
     r"warp\.square_to_uniform_hemisphere: u must lie in \[0, 1\]\^2 \(no NaN\)"),
    ("uniform_hemisphere_pdf", lambda: warp.square_to_uniform_hemisphere_pdf(np.zeros(3)),
     r"warp\.square_to_uniform_hemisphere_pdf: d must be \(N, 3\), got shape \(3,\)"),
    ("cosine_hemisphere range", lambda: warp.square_to_cosine_hemisphere(np.array([[0.5, -0.1]])),
     r"warp\.square_to_cosine_hemisphere: u must lie in \[0, 1\]\^2"),
    ("cosine_hemisphere_pdf", lambda: warp.square_to_cosine_hemisphere_pdf(np.zeros((4, 2))),
     r"warp\.square_to_cosine_hemisphere_pdf: d must be \(N, 3\), got shape \(4, 2\)"),
    ("frame", lambda: warp.frame(np.array([0.0, 0.0, 1.0])), r"warp\.frame: n must be \(N, 3\), got shape \(3,\)"),
    ("to_local", lambda: warp.to_local(N3, N3[:3], N3, N3), r"warp\.to_local: s must be \(4, 3\), got shape \(3, 3\)"),
    ("to_world", lambda: warp.to_world(np.zeros((4, 2)), N3, N3, N3),
     r"warp\.to_world: v must be \(N, 3\), got shape \(4, 2\)"),
    # ---------------------------------------------------------------- strategies
    ("make options", lambda: strategies.make("mis", levels=3),
     r"strategies\.make: strategy 'mis' has no option 'levels' \(options: light_levels\)"),
    ("make no options", lambda: strategies.make("uniform", levels=3),
     r"strategies\.make: strategy 'uniform' has no option 'levels' \(options: none\)"),
    ("make list", lambda: strategies.make(["mis"]), r"strategies\.make: unknown strategy \['mis'\]"),
    ("LightStrategy levels", lambda: strategies.LightStrategy(levels=0),
     r"strategies\.LightStrategy: levels must be between 1 and 11, got 0"),
    ("LightStrategy levels float", lambda: strategies.make("light", levels=2.7),
     r"strategies\.LightStrategy: levels must be an integer, got 2\.7"),
    ("MisStrategy light_levels", lambda: strategies.make("mis", light_levels=-1),
     r"strategies\.MisStrategy: light_levels must be between 1 and 11, got -1"),
    ("MisCompensatedStrategy light_levels", lambda: strategies.make("mis_comp", light_levels="4"),
     r"strategies\.MisCompensatedStrategy: light_levels must be an integer, got '4'"),
    ("WaveletStrategy slots 3", lambda: strategies.make("wavelet", slots=3),
     r"strategies\.WaveletStrategy: slots must be 2 \| 4, got 3"),
    ("WaveletStrategy slots 4 without candidates", lambda: strategies.make("wavelet", slots=4, candidates=0),
     r"strategies\.WaveletStrategy: slots must be 2, or 4 with candidates \(the MIS pair has 2\), got 4"),
    ("WaveletStrategy levels", lambda: strategies.make("wavelet", levels=-2),
     r"strategies\.WaveletStrategy: levels must be between 0 and 11, got -2"),
    ("WaveletStrategy light_levels", lambda: strategies.make("wavelet", light_levels=0),
     r"strategies\.WaveletStrategy: light_levels must be between 1 and 11, got 0"),
    ("WaveletStrategy compensated_kinds str", lambda: strategies.make("wavelet", compensated_kinds="lambert"),
     r"strategies\.WaveletStrategy: compensated_kinds must be a tuple of bsdf kinds"),
    ("WaveletStrategy compensated_kinds int", lambda: strategies.make("wavelet", compensated_kinds=5),
     r"strategies\.WaveletStrategy: compensated_kinds must be .* got 5"),
    ("SirStrategy candidates", lambda: strategies.make("sir", candidates=2.7),
     r"strategies\.SirStrategy: candidates must be an integer, got 2\.7"),
    ("SirStrategy samples", lambda: strategies.make("sir", samples=0),
     r"strategies\.SirStrategy: samples must be between 1 and 1024, got 0"),
    ("SirStrategy source", lambda: strategies.make("sir", source="sky"),
     r"strategies\.SirStrategy: source must be one of light \| bsdf, got 'sky'"),
    ("SirStrategy light_levels", lambda: strategies.make("sir", light_levels=0),
     r"strategies\.SirStrategy: light_levels must be between 1 and 11, got 0"),
    ("StructuredStrategy strata", lambda: strategies.make("structured", strata=5000),
     r"strategies\.StructuredStrategy: strata must be between 1 and 1024, got 5000"),
    ("StructuredStrategy mode", lambda: strategies.make("structured", mode="points"),
     r"strategies\.StructuredStrategy: mode must be one of stratified \| preintegrated, got 'points'"),
    ("StructuredStrategy samples", lambda: strategies.make("structured", samples="x"),
     r"strategies\.StructuredStrategy: samples must be 'strata' or an integer, got 'x'"),
    ("StructuredStrategy levels", lambda: strategies.make("structured", levels=0),
     r"strategies\.StructuredStrategy: levels must be at least 1, got 0"),
]


def check_one_line(fn, match):
    with pytest.raises(ArgumentError, match=match) as info:
        fn()
    message = str(info.value)
    assert "\n" not in message and message.strip() == message and len(message) < 300, message
    assert isinstance(info.value, WavlightError) and isinstance(info.value, ValueError)
    return message


@pytest.mark.parametrize("fn,match", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_argument_is_one_line_argument_error(fn, match):
    check_one_line(fn, match)


def test_unknown_strategy_lists_the_known_names():
    for name in ("bogus", None, "MIS"):
        message = check_one_line(lambda: strategies.make(name), r"^strategies\.make: unknown strategy ")
        listed = re.search(r"\((.*)\)$", message).group(1).split(" | ")
        assert listed == list(strategies.REGISTRY), message


def test_argument_error_is_a_value_error_and_a_wavlight_error():
    """Existing ``except ValueError`` callers (and the CLI's WavlightError handler) keep working."""
    assert issubclass(ArgumentError, ValueError) and issubclass(ArgumentError, WavlightError)
    with pytest.raises(ValueError):
        haar.forward(np.zeros((6, 6)))
    with pytest.raises(WavlightError):
        strategies.make("bogus")


def test_messages_never_print_arrays():
    big = np.zeros((40, 40, 40, 3))
    message = check_one_line(lambda: strategies.make("wavelet", compensated_kinds=big), r"got an array of shape")
    assert "0." not in message


def test_valid_edge_cases_unchanged():
    """Inputs that were valid keep their results (the checks only refuse)."""
    assert len(haar.compress_energy(C8, 0.0)) == 1                          # fraction 0: the scaling coefficient
    assert len(haar.compress_topk(C8, 5000)) == 64                          # k beyond the set keeps all
    assert product.product_levels(200.0, 8, -3) == 0                       # overrides clamp to [0, tree levels]
    assert product.product_levels(200.0, 8, 20) == 8
    assert product.lobe_kappa(bsdfs.LAMBERT, None) == 0.0                  # lambert's param is not read
    mask = np.zeros((8, 8), bool)
    mask[0, :3] = True                                                      # a 2-D boolean mask, as before
    np.testing.assert_array_equal(haar.SparseHaar.from_dense(C8, mask).index, [0, 1, 2])
    assert len(haar.SparseHaar(2, [], [])) == 0                             # an empty set
    np.testing.assert_array_equal(haar.coeff_index(5, 9, 9, 0, 3), 0)        # m = 0 ignores level, x, y
    empty_u = np.zeros((0, 2))
    uv, pdf = haar_tree.sample_reference(TREE, 2, empty_u, 0)           # no points, len(u) per tree
    assert uv.shape == (0, 2) and pdf.shape == (0,)
    coeffs, pyr = haar.forward_cl(np.zeros((0, 4, 4)))                      # no images: no device work
    assert coeffs.shape == (0, 4, 4) and pyr.shape == (0, 21)
    assert isinstance(strategies.make("structured", samples="strata"), strategies.Strategy)
    st = strategies.make("light", levels=11)                                # deeper than small maps: cut when used
    assert st.override == 11


# ============================================================================= checks that need the device
def test_haar_tree_sample_and_pdf_arguments(device):
    tree = haar_tree.HaarTree(np.random.default_rng(4).random((2, 4, 4)))
    for fn, arg in ((tree.sample, "u"), (tree.pdf, "uv")):
        where = re.escape(f"haar.tree.HaarTree.{fn.__name__}")
        check_one_line(lambda: fn(np.zeros((8, 3))), rf"{where}: {arg} must be \(N, 2\), got shape \(8, 3\)")
        check_one_line(lambda: fn(np.zeros(7)), rf"{where}: {arg} must be \(N, 2\), got shape \(7,\)")
        check_one_line(lambda: fn("abc"), rf"{where}: {arg} must be an array of real numbers")
        check_one_line(lambda: fn(U8, 0), rf"{where}: samples_per_tree must be at least 1, got 0")
        check_one_line(lambda: fn(U8, 2.5), rf"{where}: samples_per_tree must be an integer, got 2\.5")
        # a tree per sample beyond the buffer's trees would be read out of bounds by the kernel
        check_one_line(lambda: fn(U8, 1), rf"{where}: 8 points at 1 per tree need 8 trees, this HaarTree holds 2")
    uv, pdf = tree.sample(U8, 4)                                             # valid: unchanged
    assert uv.shape == (8, 2) and np.all(pdf > 0)


def test_product_pyramids_arguments(device):
    pp = haar.ProductPyramids(C8, 2)
    check_one_line(lambda: pp(np.zeros((3, 8, 8))),
                   r"haar\.ProductPyramids: H must be \(T, 4, 4\) or \(4, 4\), got shape \(3, 8, 8\)")
    check_one_line(lambda: pp(np.full((1, 4, 4), np.nan)), r"haar\.ProductPyramids: H must be finite")
    check_one_line(lambda: pp("abc"), r"haar\.ProductPyramids: H must be an array of real numbers")
    check_one_line(lambda: haar.ProductPyramids(C8, 2, work_group=0),
                   r"haar\.ProductPyramids: work_group must be between 1 and ")
    # the smallest leaf level whose two 4^P-float work arrays exceed this device's local memory
    too_deep = next(p for p in range(1, 32) if 8 * 4 ** p > device.device.local_mem_size)
    check_one_line(lambda: haar.ProductPyramids(C8, too_deep),
                   rf"haar\.ProductPyramids: product trees of leaf level {too_deep} do not fit")
    assert pp(np.zeros((4, 4))).shape == (1, haar_tree.tree_size(2))
