"""Dynamic lighting from precomputed transfer (Chen & Gao sec. 2, eq. 6-8): the camera, objects
and materials stay fixed, the lighting varies. The bake (:mod:`.bake`) stores each pixel's
transfer T1 = f_r cos V on the lat-long square in Haar coefficients (:mod:`.store`, the file
format); a frame (:mod:`.transfer`) projects the new lighting T2 = L on the same texels
(:mod:`.lighting`), keeps its K most important coefficients and takes the sparse product
(:mod:`.frame`, kernels/relight.cl). A bake that varies the view (:mod:`.view_bake`) stores
T1 = L V cos per point of a surface cache instead, and its frames (:class:`.view_frames.ViewFrames`)
take the product with the BRDF for any camera (kernels/relight_view.cl).

    import wavlight
    transfer = wavlight.bake("scenes/spot_ggx.toml", output="spot.wlt")   # wavlight.relight.bakes.bake
    image = transfer.frame(rotate_y=120, terms=256)
    again = wavlight.relight.Transfer.load("spot.wlt")
"""
from .transfer import Transfer

__all__ = ["Transfer"]   # the bake itself: wavlight.bake (wavlight.relight.bakes.bake)
