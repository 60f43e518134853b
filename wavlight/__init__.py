"""wavlight: direct environment lighting with Haar wavelet product importance sampling.

    import wavlight
    scene = wavlight.load_scene("scenes/default.toml")
    image = wavlight.render(scene, spp=16, strategy="mis")   # float32 (H, W, 3)
    wavlight.save_image("default.exr", image)
"""
from .errors import SceneError, WavlightError
from .imageio import save_image
from .integrator import RenderResult, render, render_full
from .scene import STRATEGIES, Scene, load_scene

__version__ = "0.1.0"
__all__ = ["load_scene", "render", "render_full", "save_image", "Scene", "RenderResult",
           "WavlightError", "SceneError", "STRATEGIES", "__version__"]
