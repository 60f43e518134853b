"""Animations of a sequence of frames (``wavlight frame --turntable N``, ``--orbit N``).

From the PNG frames written (their display transform, :mod:`wavlight.display`, already applied):

- an **animated PNG** (APNG) through Pillow, always: lossless, so that every frame reads back as
  its PNG bit for bit (a GIF's 256 colours banded the smooth gradients of HDR renders);
- an **MP4** (H.264, yuv420p, through PyAV, whose wheels carry FFmpeg) where PyAV is installed:
  the extra ``video`` (``pip install 'wavlight[video]'``); without it :func:`write` returns
  :data:`NO_MP4_NOTE`, the one line the command prints.

The choice and its measurements: docs/decisions/animated-outputs.md. Both files are written
atomically (:mod:`wavlight.atomic`) and read back (their frame counts) before they replace
anything. Memory: Pillow holds every frame of an APNG until it writes it (as it did for the
GIF); the MP4 reads one frame at a time.
"""
from __future__ import annotations

import os

import numpy as np

from .atomic import atomic_write
from .errors import WavlightError

#: frames per second of both animations (a frame of 40 ms, as the GIF had)
FPS = 25
#: the extra that installs PyAV, for the MP4
VIDEO_EXTRA = "video"
NO_MP4_NOTE = (f"no MP4 written: it needs PyAV, which wavlight's '{VIDEO_EXTRA}' extra installs: "
               f"pip install 'wavlight[{VIDEO_EXTRA}]'")
#: H.264's constant rate factor (x264's scale: 0 lossless, 23 its default; 18 is close to transparent)
MP4_CRF = 18


def has_mp4() -> bool:
    """Whether PyAV (the ``video`` extra) is installed."""
    try:
        import av  # noqa: F401
    except ImportError:
        return False
    return True


def paths(folder, stem: str) -> dict:
    """{"apng": FOLDER/STEM.png, "mp4": FOLDER/STEM.mp4}: the files :func:`write` may make."""
    return {"apng": os.path.join(folder, f"{stem}.png"), "mp4": os.path.join(folder, f"{stem}.mp4")}


def write(frames, folder, stem: str) -> tuple[list, str | None]:
    """Write the animations of the PNG files ``frames`` into ``folder`` (:func:`paths`): (the files
    written, a note or None). The MP4 only where PyAV is installed; else the note names the extra."""
    frames = [os.fspath(f) for f in frames]
    names = paths(folder, stem)
    written = [write_apng(frames, names["apng"])]
    if not has_mp4():
        return written, NO_MP4_NOTE
    written.append(write_mp4(frames, names["mp4"]))
    return written, None


def _rgb(path):
    from PIL import Image

    with Image.open(path) as im:
        return im.convert("RGB")


def write_apng(frames, path) -> str:
    """An animated PNG of the PNG files ``frames`` (Pillow), written atomically and read back."""
    from PIL import Image

    step = 1000 // FPS

    def check(tmp):   # Pillow stores a frame equal to the one before as a longer duration of that one
        with Image.open(tmp) as im:
            n = getattr(im, "n_frames", 1)
            total = 0
            for i in range(n):
                im.seek(i)
                total += im.info.get("duration", step) if n > 1 else step * len(frames)
        return None if total == step * len(frames) else f"{total} ms of {step * len(frames)} read back"

    images = [_rgb(f) for f in frames]
    with atomic_write(path, check=check) as tmp:
        # (Pillow's defaults: each frame kept under the next, drawn over it as it is, and stored as
        # the box in which it differs from the one before: lossless)
        images[0].save(tmp, format="PNG", save_all=True, append_images=images[1:], duration=step, loop=0)
    return path


def write_mp4(frames, path) -> str:
    """An H.264 MP4 (yuv420p, :data:`MP4_CRF`, :data:`FPS`) of the PNG files ``frames`` through PyAV,
    written atomically and read back; odd sizes are padded to even by repeating the last row or
    column (yuv420p halves the chroma). A WavlightError without PyAV."""
    try:
        import av
    except ImportError:
        raise WavlightError(f"{path}: {NO_MP4_NOTE}") from None

    first = np.asarray(_rgb(frames[0]))
    h, w = first.shape[:2]
    even = (h + h % 2, w + w % 2)

    def check(tmp):
        try:
            with av.open(tmp) as container:
                n = sum(1 for _ in container.decode(video=0))
        except av.FFmpegError as e:
            return f"it does not read back: {e}"
        return None if n == len(frames) else f"{n} of {len(frames)} frames read back"

    with atomic_write(path, check=check) as tmp:
        with av.open(tmp, mode="w", format="mp4") as container:
            stream = container.add_stream("libx264", rate=FPS)
            stream.width, stream.height = even[1], even[0]
            stream.pix_fmt = "yuv420p"
            stream.options = {"crf": str(MP4_CRF)}
            for name in frames:
                rgb = np.asarray(_rgb(name))
                if rgb.shape[:2] != (h, w):
                    raise WavlightError(f"{name}: a frame of {rgb.shape[1]}x{rgb.shape[0]} among frames of {w}x{h}")
                if even != (h, w):
                    rgb = np.pad(rgb, ((0, even[0] - h), (0, even[1] - w), (0, 0)), mode="edge")
                for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")):
                    container.mux(packet)
            for packet in stream.encode():
                container.mux(packet)
    return path
