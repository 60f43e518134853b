"""Maps sent from the viewer's page (a file picker or a file dropped on it): an HTTP POST of the
file's bytes, streamed to disk within :data:`MAX_UPLOAD_BYTES`, into a folder of the viewer's own
(:func:`tempfile.mkdtemp`, removed when the viewer stops) under a name the server makes
(``map-N`` and the extension, one of :data:`MAP_EXTENSIONS`): nothing the page sends names a path.
The page's file name is only shown (:func:`shown_name`: its last component, without control
characters, at most :data:`MAX_NAME_CHARS` characters). Reading the file is the viewer's (the
environment loading of any map: :func:`wavlight.envmap.read_image` and
:class:`wavlight.envmap.Environment`); what is refused here (:class:`Refused`: an HTTP status and
one line) is what is refused before a byte is kept: a declared or a streamed size beyond the
bound (413), an extension that is not a map's (415), an empty file (400), a full folder (409).

    uploads = Uploads()             # limit=MAX_UPLOAD_BYTES
    uploads.open()                  # the viewer starts
    path, name = await uploads.receive(request)   # or raises Refused
    ...                             # read the map; then os.unlink(path)
    uploads.close()                 # the viewer stops: the folder and anything left in it removed
"""
from __future__ import annotations

import os
import shutil
import tempfile
import unicodedata

#: the largest map the page may send, bytes (a 8k x 4k float EXR is about 200 MiB uncompressed)
MAX_UPLOAD_BYTES = 256 << 20
#: the file names a map may have (what wavlight.envmap.read_image reads through OpenImageIO; 8-bit
#: images are decoded from sRGB with a warning)
MAP_EXTENSIONS = (".hdr", ".exr", ".pfm", ".png", ".jpg", ".jpeg", ".tif", ".tiff")
#: the most maps a viewer takes from its pages (each is kept in memory)
MAX_UPLOADED_MAPS = 32
#: a shown file name is cut to this many characters
MAX_NAME_CHARS = 120
#: bytes read from the request and written at a time
CHUNK_BYTES = 1 << 16


class Refused(Exception):
    """An upload refused: ``status`` (HTTP) and a one-line ``message`` for the page."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status, self.message = status, message


def shown_name(raw) -> str:
    """The page's file name as the viewer shows it: its last component (after ``/`` or ``\\``),
    control and format characters removed, at most MAX_NAME_CHARS characters; "map" where
    nothing is left."""
    text = str(raw or "").replace("\\", "/").rsplit("/", 1)[-1]
    text = "".join(c for c in text if unicodedata.category(c)[0] != "C").strip()
    text = text[:MAX_NAME_CHARS]
    return text if text not in ("", ".", "..") else "map"


def extension(name: str) -> str:
    """The map extension of ``name`` (lower case), or :class:`Refused` (415)."""
    ext = os.path.splitext(name)[1].lower()
    if ext not in MAP_EXTENSIONS:
        raise Refused(415, f"{name}: not an environment map's file name (use {', '.join(MAP_EXTENSIONS)})")
    return ext


def size_text(n: int) -> str:
    return f"{n / (1 << 20):.0f} MiB" if n >= 1 << 20 else f"{n} bytes"


class Uploads:
    """The folder of one viewer's uploads and their bound (module docstring)."""

    def __init__(self, limit: int = MAX_UPLOAD_BYTES):
        if isinstance(limit, bool) or not isinstance(limit, int) or limit < 1:
            raise ValueError(f"the upload limit must be a positive number of bytes, got {limit!r}")
        self.limit = limit
        self.folder = None
        self.count = 0

    def open(self) -> str:
        """Make the folder (once); its path."""
        if self.folder is None:
            self.folder = tempfile.mkdtemp(prefix="wavlight-view-")
        return self.folder

    def close(self) -> None:
        """Remove the folder and anything in it."""
        folder, self.folder = self.folder, None
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)

    async def receive(self, request, name: str):
        """(path, shown name) of the map in ``request``'s body (an aiohttp request), written to a
        new file of the folder, at most ``limit`` bytes; :class:`Refused` otherwise (and nothing
        left on disk)."""
        name = shown_name(name)
        ext = extension(name)
        if self.folder is None:
            raise Refused(503, "the viewer is stopping")
        declared = request.content_length
        if declared is not None and declared > self.limit:
            raise Refused(413, f"{name}: {size_text(declared)} (a map may have at most {size_text(self.limit)})")
        self.count += 1
        path = os.path.join(self.folder, f"map-{self.count}{ext}")
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
        fd = os.open(path, flags, 0o600)
        size = 0
        try:
            with os.fdopen(fd, "wb") as out:
                async for chunk in request.content.iter_chunked(CHUNK_BYTES):
                    size += len(chunk)
                    if size > self.limit:
                        raise Refused(413, f"{name}: more than {size_text(self.limit)} (a map may have at most "
                                           f"{size_text(self.limit)})")
                    out.write(chunk)
            if size == 0:
                raise Refused(400, f"{name}: an empty file")
        except BaseException:
            try:
                os.unlink(path)
            except OSError:
                pass
            raise
        return path, name
