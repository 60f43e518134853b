"""Writing images: linear float (.exr, .hdr, .pfm) or display 8-bit (.png), atomically, with metadata.

A PNG holds the display transform of the pixels (:mod:`wavlight.display`: exposure, tone curve,
sRGB), by default clamped to [0, 1] and sRGB-encoded; linear outputs hold the radiance itself,
and a transform other than the identity for outputs that are all linear is refused
(:func:`check_display`): it would be silently dropped.

Metadata (:func:`provenance`: strategy, spp, seed, the scene's content hash, wavlight's version)
goes into EXR headers as string attributes and into PNG files as tEXt chunks, each named
``wavlight:KEY`` (OpenImageIO writes both; :func:`read_metadata` reads them back), with
``Software`` = ``wavlight VERSION``. .hdr and .pfm hold none (their headers have no place for it).

Negative pixels (an unbiased estimator's shadowed pixels at low spp can average below 0:
the wavelet strategy's control variate) are kept by .exr and .pfm, written as 0 to .hdr,
whose RGBE encoding has no sign (it turned -0.5 into 1.5), and clamped to 0 in .png.

The file appears complete and readable or not at all (:mod:`wavlight.atomic`): pixels go to a
temporary file in the same folder, which is read back (a full disk can leave an empty or cut
file while the writer reports success) and renamed over the target only then.

Memory: the pixels are checked, converted (sRGB, 8-bit; RGBE's clamp at 0) and written in
strips of rows of about :data:`STRIP_BYTES` (OpenImageIO's scanline interface), so that
writing costs a few MiB beyond the image itself whatever its size (the whole-image
conversion for PNG cost about 50 bytes per pixel: 13 GB at 16384 x 16384).
:func:`render_bytes` states what a render of a size needs, :func:`check_memory` refuses
one that will not fit.
"""
from __future__ import annotations

import os

import numpy as np

from . import display
from .atomic import atomic_files
from .display import srgb_encode  # noqa: F401  (wavlight.imageio.srgb_encode, as before)
from .errors import ArgumentError, WavlightError, shown

LINEAR = (".exr", ".hdr", ".pfm")
DISPLAY = (".png",)
FORMATS = LINEAR + DISPLAY

#: The largest image save_image writes: renders are at most 16384 a side (wavlight.scene.MAX_SIDE);
#: a larger array (np.broadcast_to makes one of 10^10 pixels in no memory) would fill the disk.
MAX_WRITE_SIDE = 65536
MAX_WRITE_PIXELS = 1 << 30
#: Pixels converted and written per call (rows of at most this many bytes of float32 RGB).
STRIP_BYTES = 1 << 22
#: Bytes per pixel of `wavlight render`, measured (benchmarks/probe_memory.py: 34.4 at 16384 x
#: 16384 for PNG and EXR alike): render_full's film (the image and its standard error, float32
#: RGB each: 24), the CLI's check for NaN / Inf pixels (np.isfinite, its negation and .any: 7)
#: and the tiles in flight. Writing adds a few MiB whatever the size (strips).
RENDER_BYTES_PER_PIXEL = 36
#: What a process needs besides the film: Python, numpy, OpenCL, the scene (measured: 140 MB
#: for the sky alone, ~300 MB with the default scene's geometry).
RENDER_BASE_BYTES = 400 << 20


def render_bytes(width: int, height: int) -> int:
    """Peak memory (bytes) of ``wavlight render`` at width x height: RENDER_BYTES_PER_PIXEL per
    pixel plus RENDER_BASE_BYTES (measured by benchmarks/probe_memory.py: the output format
    no longer matters, strips are written)."""
    return int(width) * int(height) * RENDER_BYTES_PER_PIXEL + RENDER_BASE_BYTES


def available_bytes() -> int | None:
    """Memory the system can give a process now (MemAvailable; None where unknown)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, OSError, ValueError):
        return None


def _gb(n: int) -> str:
    return f"{n / 1e9:.1f} GB" if n >= 1e8 else f"{n / 1e6:.0f} MB"


def check_memory(what: str, width: int, height: int, copies: int = 1) -> int:
    """A one-line WavlightError when ``copies`` renders of width x height (:func:`render_bytes`)
    need more memory than the system has available now; else the bytes they need."""
    need = render_bytes(width, height) * copies
    have = available_bytes()
    if have is not None and need > have:
        raise WavlightError(f"{what}: a {width}x{height} render needs about {_gb(need)} of memory "
                            f"({RENDER_BYTES_PER_PIXEL} bytes per pixel{f' x {copies}' if copies > 1 else ''}); "
                            f"{_gb(have)} is available")
    return need


# ----------------------------------------------------------------------------- inputs and outputs
def same_file(a, b) -> bool:
    """Whether paths a and b name the same file: the same absolute path, the same file after
    symbolic links, or the same inode (hard links)."""
    a, b = os.fspath(a), os.fspath(b)
    if os.path.abspath(a) == os.path.abspath(b) or os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        sa, sb = os.stat(a), os.stat(b)
    except (OSError, ValueError):
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)


def scene_files(scene_path) -> list:
    """The files a scene file reads: itself, its environment map and its meshes (absolute paths,
    relative ones resolved against the scene's folder and ``data:`` names as load_scene does). For a scene that
    load_scene accepted; anything unreadable is skipped (a Scene built in Python: [])."""
    import tomllib

    if not isinstance(scene_path, (str, os.PathLike)):
        return []
    scene_path = os.path.abspath(os.fspath(scene_path))
    files = [scene_path]
    try:
        with open(scene_path, "rb") as fh:
            doc = tomllib.load(fh)
    except (OSError, ValueError, RecursionError):
        return files
    from .data import resolve

    base = os.path.dirname(scene_path)
    env = doc.get("environment")
    named = [env.get("file")] if isinstance(env, dict) else []
    objects = doc.get("objects")
    named += [o.get("mesh") for o in (objects if isinstance(objects, list) else []) if isinstance(o, dict)]
    for name in named:
        if isinstance(name, str):
            try:   # a "data:NAME" asset where it is, or would be, without fetching it
                files.append(resolve(name, base, download=False))
            except WavlightError:
                pass
    return files


def check_not_input(outputs, inputs) -> None:
    """A one-line WavlightError, before anything is rendered, when an output path names one of
    the run's inputs (the scene, its map or a mesh; an experiment's spec or reference): the
    write would replace it."""
    inputs = [i for i in inputs if i is not None]
    for out in outputs:
        if out is None:
            continue
        for inp in inputs:
            if same_file(out, inp):
                raise WavlightError(f"{out}: is an input of this run ({inp}); writing it would replace that "
                                    "file: choose another output")


def save_image(path: str, image: np.ndarray, exposure: float = display.EXPOSURE.default,
               tonemap: str = display.TONEMAP.default, metadata: dict | None = None) -> None:
    """Write an (H, W, 3) float image; the format follows the extension (.exr .hdr .pfm .png).
    ``exposure`` and ``tonemap``: a PNG's display transform (:mod:`wavlight.display`; refused
    for a linear output unless the identity); ``metadata``: key -> value (text or numbers) written
    as ``wavlight:KEY`` into an EXR's or a PNG's header (:func:`provenance` makes it)."""
    save_images([(path, image)], exposure, tonemap, metadata)


def save_images(outputs, exposure: float = display.EXPOSURE.default, tonemap: str = display.TONEMAP.default,
                metadata: dict | None = None) -> None:
    """Write several (path, image) pairs all or nothing (:func:`wavlight.atomic.atomic_files`):
    every image is checked, then written to its temporary file and read back, and the
    temporaries are renamed over the targets only once all are written (an error in any leaves
    none of them written). The display transform applies to the PNG outputs among them (linear
    ones are written linear); the metadata goes into every EXR and PNG."""
    try:
        pairs = list(outputs)
        if not all(isinstance(p, (tuple, list)) and len(p) == 2 for p in pairs):
            raise TypeError
    except TypeError:
        raise ArgumentError(f"save_images: outputs must be (path, image) pairs, got {shown(outputs)}") from None
    outputs = [(_path(path), image) for path, image in pairs]
    exposure, tonemap = display.check(exposure, tonemap, "save_image")
    if outputs:
        check_display([path for path, _ in outputs], exposure, tonemap)
    attributes = _attributes(metadata)
    for n, (path, _) in enumerate(outputs):
        if any(same_file(path, other) for other, _ in outputs[:n]):
            raise ArgumentError(f"{path}: named twice among the outputs")
    checked = [(path, _check_target(path, image)) for path, image in outputs]   # before any file exists
    checks = [_readable(os.path.splitext(path)[1].lower(), *image.shape[:2]) for path, image in checked]
    with atomic_files([path for path, _ in checked], checks) as temps:
        for (path, image), tmp in zip(checked, temps):
            _write_pixels(path, tmp, image, exposure, tonemap, attributes)


def check_display(paths, exposure: float = display.EXPOSURE.default, tonemap: str = display.TONEMAP.default,
                  what: str = "--exposure and --tonemap") -> None:
    """A one-line ArgumentError when the exposure or the tone curve is not allowed (their records),
    or a display transform other than the identity is asked for outputs that are all linear
    (.exr .hdr .pfm): they hold the radiance itself, and the
    transform would be silently dropped. Called before any work (the commands) and by
    :func:`save_images`."""
    paths = [os.fspath(p) for p in paths]
    exposure, tonemap = display.check(exposure, tonemap, what)
    if display.is_identity(exposure, tonemap) or not paths:
        return
    if all(os.path.splitext(p)[1].lower() in LINEAR for p in paths):
        raise ArgumentError(f"{paths[0]}: {what} set how a display output (.png) shows the image; "
                            f"{os.path.splitext(paths[0])[1] or 'this output'} is written linear, untouched "
                            "(write a .png, or leave them out)")


#: the metadata keys :func:`provenance` writes, in order
PROVENANCE_KEYS = ("strategy", "spp", "seed", "scene_hash", "version")
#: the prefix of wavlight's attributes in an EXR header and of its PNG tEXt keywords
METADATA_PREFIX = "wavlight:"


def provenance(strategy, spp, seed, scene_hash, **more) -> dict:
    """The metadata of a rendered image (:data:`PROVENANCE_KEYS`): how it was made (strategy, spp,
    seed: None where it does not apply), the scene's content hash
    (:attr:`wavlight.scene.Scene.content_hash`) and wavlight's version; ``more`` adds keys."""
    from .version import __version__

    found = {"strategy": strategy, "spp": spp, "seed": seed, "scene_hash": scene_hash, "version": __version__,
             **more}
    return {k: v for k, v in found.items() if v is not None}


def _attributes(metadata) -> list:
    """[(name, text)] of a metadata dict, checked: keys of letters, digits and ``_`` (at most 60),
    values text, integers, finite numbers or booleans (at most 2000 characters as text)."""
    if metadata is None:
        return []
    if not isinstance(metadata, dict):
        raise ArgumentError(f"save_image: metadata must be a dict of key -> value, got {shown(metadata)}")
    found = []
    for key, value in metadata.items():
        if not (isinstance(key, str) and 0 < len(key) <= 60 and key.replace("_", "a").isascii()
                and key.replace("_", "a").isalnum()):
            raise ArgumentError(f"save_image: metadata keys must be names of letters, digits and _, got {shown(key)}")
        if isinstance(value, (bool, np.bool_)):
            text = "true" if value else "false"
        elif isinstance(value, (int, np.integer, str)):
            text = str(value)
        elif isinstance(value, (float, np.floating)) and np.isfinite(value):
            text = repr(float(value))
        else:
            raise ArgumentError(f"save_image: metadata {key} must be text or a finite number, got {shown(value)}")
        if len(text) > 2000 or "\0" in text:
            raise ArgumentError(f"save_image: metadata {key} must be at most 2000 characters of text")
        found.append((METADATA_PREFIX + key, text))
    return found


def read_metadata(path) -> dict:
    """The ``wavlight:`` metadata of an EXR or PNG file written by :func:`save_image` (key -> text;
    {} for a file without any, or a format that holds none), read by OpenImageIO."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(os.fspath(path))
    if inp is None:
        raise WavlightError(f"{path}: cannot read image ({_first_line(oiio.geterror())})")
    try:
        return {a.name[len(METADATA_PREFIX):]: str(a.value) for a in inp.spec().extra_attribs
                if a.name.startswith(METADATA_PREFIX)}
    finally:
        inp.close()


def _path(path) -> str:
    """An output path as a str, or a one-line ArgumentError (None, a number, bytes, "", a NUL)."""
    p = os.fspath(path) if isinstance(path, (str, os.PathLike)) else None
    if not isinstance(p, str) or not p or "\0" in p:
        raise ArgumentError(f"save_image: the path must be a file name (str or os.PathLike), got {shown(path)}")
    return p


def _check_pixels(path: str, image) -> np.ndarray:
    """image as an (H, W, 3) array of real numbers (not copied), or a one-line error."""
    if isinstance(image, np.ndarray):
        a = image
    else:
        try:
            a = np.asarray(image)
        except (TypeError, ValueError, MemoryError):
            raise ArgumentError(f"{path}: expected an (H, W, 3) image of numbers, got {shown(image)}") from None
    if a.dtype.kind not in "biuf":
        raise ArgumentError(f"{path}: expected an (H, W, 3) image of real numbers, got {shown(image)}")
    if a.ndim != 3 or a.shape[2] != 3:
        raise WavlightError(f"{path}: expected an (H, W, 3) image, got shape {a.shape}")
    if a.shape[0] < 1 or a.shape[1] < 1:
        raise WavlightError(f"{path}: expected an (H, W, 3) image, got an empty one of shape {a.shape}")
    if a.shape[0] > MAX_WRITE_SIDE or a.shape[1] > MAX_WRITE_SIDE or a.shape[0] * a.shape[1] > MAX_WRITE_PIXELS:
        raise WavlightError(f"{path}: an image of {a.shape[1]}x{a.shape[0]} pixels is too large to write (at most "
                            f"{MAX_WRITE_SIDE} a side and {MAX_WRITE_PIXELS} pixels, "
                            f"{MAX_WRITE_PIXELS * 12 >> 30} GiB as float RGB)")
    return a


def _rows(height: int, width: int):
    """Strips [y0, y1) of about STRIP_BYTES of float32 RGB."""
    step = max(1, STRIP_BYTES // (width * 12))
    return [(y, min(y + step, height)) for y in range(0, height, step)]


def _strip(image: np.ndarray, y0: int, y1: int, ext: str, exposure: float = 0.0,
           tonemap: str = "clamp") -> np.ndarray:
    """Rows y0..y1-1 as the pixels the format gets (contiguous)."""
    # contiguous and aligned: OpenImageIO refuses an unaligned buffer ("buffer is wrong size"), as
    # numpy gives for an array unpickled from a byte offset (a dask worker's image, at some sizes)
    px = np.require(image[y0:y1], np.float32, ["C_CONTIGUOUS", "ALIGNED"])
    if ext in DISPLAY:
        return display.encode8(px, exposure, tonemap)
    if ext == ".hdr":   # RGBE has no sign
        return np.maximum(px, np.float32(0.0))
    return px


def _check_target(path: str, image) -> np.ndarray:
    """Check the image and the target before any file exists: a known extension, (H, W, 3)
    finite pixels within float32, an existing folder. Returns the pixels (not copied)."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise WavlightError(f"{path}: unsupported output format {ext or '(none)'!r} "
                            f"(use {', '.join(FORMATS)})")
    image = _check_pixels(path, image)
    for y0, y1 in _rows(*image.shape[:2]):   # a strip at a time (no whole-image mask)
        part = image[y0:y1]
        if part.dtype.kind == "f" and not np.isfinite(part).all():
            raise WavlightError(f"{path}: refusing to write an image with NaN or Inf pixels")
        if part.dtype != np.float32 and part.size and np.abs(part).max() > np.finfo(np.float32).max:
            raise WavlightError(f"{path}: refusing to write an image with values beyond float32's range "
                                "(they would become Inf)")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise WavlightError(f"{path}: folder {folder} does not exist")
    if os.path.isdir(path):
        raise WavlightError(f"{path}: is a folder")
    return image


def _write_pixels(path: str, tmp: str, image: np.ndarray, exposure: float = 0.0, tonemap: str = "clamp",
                  attributes=()) -> None:
    """Write the checked pixels of ``path`` into the file ``tmp``, with the attributes (name,
    text) in an EXR's or PNG's header (a WavlightError naming ``path`` where the writer reports a
    failure)."""
    import OpenImageIO as oiio

    ext = os.path.splitext(path)[1].lower()
    height, width = image.shape[:2]
    strips = _rows(height, width)
    out = oiio.ImageOutput.create(tmp)
    if out is None:
        raise WavlightError(f"{path}: cannot create writer ({oiio.geterror().strip()})")
    spec = oiio.ImageSpec(width, height, 3, oiio.UINT8 if ext in DISPLAY else oiio.FLOAT)
    if attributes and ext in (".exr", ".png"):
        from .version import __version__

        spec.attribute("Software", f"wavlight {__version__}")
        if ext in DISPLAY:   # how the PNG shows the radiance
            attributes = [*attributes, (METADATA_PREFIX + "exposure", repr(float(exposure))),
                          (METADATA_PREFIX + "tonemap", tonemap)]
        for name, text in attributes:
            spec.attribute(name, text)
    ok = out.open(tmp, spec)
    err = "" if ok else out.geterror()
    if ok and len(strips) == 1:
        ok = out.write_image(_strip(image, 0, height, ext, exposure, tonemap))
        # a writer may report a failed write (a full disk) only in its error text, while
        # write_image and close return True (OpenImageIO's PNG writer does): both count
        err = out.geterror()
    elif ok:
        for y0, y1 in strips:
            ok = out.write_scanlines(y0, y1, 0, _strip(image, y0, y1, ext, exposure, tonemap))
            err = out.geterror()
            if not ok or err:
                break
    ok = out.close() and ok
    err = (err + " " + out.geterror()).strip().replace(tmp, path)   # the target's name, not the temporary's
    if not ok or err:
        raise WavlightError(f"{path}: write failed ({_first_line(err)})")


def _readable(ext: str, height: int, width: int):
    """A check for :func:`wavlight.atomic.atomic_files`: the written file reads back as a
    width x height image to its end. OpenImageIO's PNG and HDR writers can return success with
    nothing or a part written (a full disk): PNG's chunks and checksums are read to its end
    (Pillow, without decoding), a PFM's size is exact, HDR and EXR read their last row."""
    def check(tmp):
        if ext == ".png":
            from PIL import Image

            try:
                with Image.open(tmp) as im:
                    size = im.size
                    im.verify()
            except Exception as e:   # Pillow raises many kinds (SyntaxError for a bad chunk)
                return f"it does not read back: {_first_line(str(e) or type(e).__name__)}"
            return None if size == (width, height) else f"it reads back as {size[0]}x{size[1]}"
        if ext == ".pfm":
            with open(tmp, "rb") as fh:
                head = [fh.readline() for _ in range(3)]
            want = sum(len(line) for line in head) + width * height * 12
            got = os.path.getsize(tmp)
            return None if got == want else f"{got} bytes written of {want}"
        import OpenImageIO as oiio

        inp = oiio.ImageInput.open(tmp)
        if inp is None:
            return f"it does not read back: {_first_line(oiio.geterror())}"
        try:
            spec = inp.spec()
            if (spec.width, spec.height) != (width, height):
                return f"it reads back as {spec.width}x{spec.height}"
            row = inp.read_scanline(height - 1, 0, oiio.FLOAT)
            err = inp.geterror()
            return f"it does not read back: {_first_line(err)}" if row is None or err else None
        finally:
            inp.close()
    return check


def _first_line(err: str) -> str:
    line = err.splitlines()[0].strip() if err.strip() else "unknown error"
    return line if len(line) <= 200 else line[:197] + "..."
