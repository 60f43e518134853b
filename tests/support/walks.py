"""Launching the renderer's product walk (kernels/product.cl ``product_sample_points``) from the
tests: one call that uploads a batch of shading points and reads back their samples."""
from __future__ import annotations

import numpy as np


def product_kernel_samples(tree, env, n_levels, normals, views, material, mat_kappa, mat_depth, mat_shape,
                           mat_tree, u, shapes, n_trees=1):
    """uv (N, 2) on the square and pdf (N,) from the product walk kernel, for shading points with
    world normals and view directions (N, 3), material ids (N,) into the per-material tables
    (lobe concentration, product depth, lobe shape, light tree) and uniforms u (N, 2 or 4: u.xy
    draws the sample, as in the renderer). ``tree`` is a HaarTree of n_trees light trees of
    depth n_levels; ``shapes`` the LOBE_SHAPES bit set the program is built for."""
    from wavlight import cl

    count = len(normals)
    q = cl.thread_queue()
    n4, w4, u4 = (np.zeros((count, 4), np.float32) for _ in range(3))
    n4[:, :3], w4[:, :3] = normals, views
    u = np.asarray(u, np.float32)
    u4[:, :u.shape[1]] = u
    uv_buf, pdf_buf = cl.empty(8 * count), cl.empty(4 * count)
    prog = cl.program("product.cl", N_LEVELS=n_levels, PRODUCT_LEVELS=int(np.max(mat_depth)), LOBE_SHAPES=shapes,
                      PRODUCT_TREES=n_trees)
    coded = (np.asarray(mat_depth) + 256 * np.asarray(mat_shape) + 65536 * np.asarray(mat_tree)).astype(np.int32)
    cl.kernel(prog, "product_sample_points")(
        q, (cl.items(count, cl.LANES),), (cl.WORK_GROUP,), tree.buffer,
        cl.to_device(env.map_from_world.astype(np.float32).ravel()), np.uint32(count), cl.to_device(n4),
        cl.to_device(w4), cl.to_device(np.asarray(material, np.int32)),
        cl.to_device(np.asarray(mat_kappa, np.float32)), cl.to_device(coded), cl.to_device(u4), np.uint32(4),
        uv_buf, pdf_buf)
    return cl.read(uv_buf, (2, count), np.float32, q).T, cl.read(pdf_buf, (count,), np.float32, q)
