"""The bake file: a header and the transfer's Haar coefficients by column in blocks of pixels,
compressed and quantized (Ng et al. 2003's layout), so that a frame reads only the columns of
the lighting terms it keeps.

Layout (little-endian)::

    MAGIC (16 bytes)  header length (uint64)  header (UTF-8 JSON)  padding to 64 bytes
    sections, each 64-byte aligned, in the order and at the offsets the header lists:
      environment   float32 (h, w, 3)   the scene's map, scaled (frames default to it)
      albedo        float32 (H, W, 3)   the pixel's albedo a_p
      background_pixel  uint32 (M,)     the pixels some of whose S camera samples miss
      background_mask   uint64 (M,)     bit s set where sample s misses
      background_dir    float32 (M, S, 3)  the samples' directions
      rms           float32 (4^n,)      root-mean-square of each coefficient over the image
      offsets       int32 (4^n, B)      the entry of coefficient c in block b, or -1 where the block
                                        keeps none (blocks row-major, BLOCK x BLOCK pixels each); a
                                        frame reads the rows of its K coefficients
      entry_scale   float32 (E,)        each entry's scale: value = scale x q (entries by coefficient,
                                        then block: a coefficient's entries lie together)
      entry_data    int8 | int16 (E, BLOCK^2)  the quantized coefficients q of the block's pixels
    and, for a bake that varies one object:
      static        float32 (H, W, 3)   the scene without the object, converged (unbiased)
      static_stderr float32 (H, W, 3)   its standard error
      product_leaves float16 (H W, 4^m) each pixel's T1 x L (luminance) on 2^m x 2^m texels
    and, for a bake that varies the view (``vary = "view"``, :mod:`.view`; its entries hold the
    three channels of a block's BLOCK^2 surface points, channel-major, and ``albedo`` is (P, 3)
    per point):
      view_position float32 (P, 3)    the surface cache's points, in blocks of BLOCK^2
      view_normal   float32 (P, 3)    their normals
      view_material int32 (P,)        their material
      view_face_k   int32 (F,)        the lattice subdivisions of each scene face
      view_face_base int64 (F,)       each face's first lattice entry
      view_lattice  int32 (E,)        the cache point at each lattice entry
    and, for a lighting bake of a scene with plastic (``coat`` true in the header): plastic's
    coat, whose transfer the albedo does not multiply (f cos = coat + albedo x base,
    docs/decisions/plastic-in-the-bake.md), stored for the blocks that see plastic alone, as
    the transfer is:
      coat_blocks   int32 (C,)          the blocks that hold a coat (increasing; C <= blocks)
      coat_offsets  int32 (4^n, C)      the entry of coefficient c in coat block j, or -1
      coat_entry_scale float32 (D,)     each coat entry's scale
      coat_entry_data  int8 | int16 (D, BLOCK^2)  the quantized coat coefficients

The header records the format and its version, wavlight's version, the scene (file, content
hash), camera, image size, camera samples, texel levels n, block size, bits, what was chosen
and measured (compression, terms, errors), and per section its offset, dtype, shape and CRC-32.
The header carries its own CRC-32 (``header_crc32``, of its JSON text without that key:
:func:`header_checksum`), so that a field no section describes (the default rotation, the
terms) cannot change unnoticed. Loading (:func:`read`) reads the file whole into memory, once
(a memory map would end the process with SIGBUS where the file is truncated or written over
while frames read it: docs/decisions/bake-file-mapping.md), and checks the magic, the version,
the header's checksum and the file's length (truncation), then every field, section shape,
offset, dtype, CRC-32 (corruption) and index against each other (:func:`validate`), before any
frame reads them.

Compression, per block: coefficient columns in decreasing energy (sum over the block's pixels
of c^2), the scaling coefficient first, until the energy left out is at most tolerance^2 of the
block's (:func:`compress_block`); the frame's error under a held-out lighting is measured and
recorded. Quantization: a scale per (column, block), max |c| / (2^(bits-1) - 1),
and stochastic rounding (dithering; unbiased), at 8 or 16 bits.
"""
from __future__ import annotations

import json
import math
import os
import stat
import tempfile
import zlib
from typing import NamedTuple

import numpy as np

from ..atomic import TEMPORARY_PREFIX, atomic_write, check_room, check_target, size_is, temporary
from ..envmap import MAX_RADIANCE, MAX_TEXELS
from ..errors import WavlightError, file_problem, shown
from ..scene import MAX_ALBEDO, MAX_SIDE
from ..version import __version__
from .lighting import MAX_LEVELS, MAX_TERMS, PRIORITIES

MAGIC = b"WAVLIGHT-XFER\x00\x01\n"   # 16 bytes
#: 2: the header holds its own checksum (``header_crc32``); 3: plastic's coat (COAT_SECTIONS)
FORMAT_VERSION = 3
ALIGN = 64
#: pixels per side of a block (an entry's row: BLOCK^2 pixels, or a view bake's 3 BLOCK^2 values)
BLOCK = 16
#: camera samples per pixel at most: the bits of a background mask (uint64)
MAX_SPP = 64
#: the factors a bake varies
VARIES = ("lighting", "object", "view")
#: a header's length at most, in bytes
MAX_HEADER = 1 << 24
PIXEL_SECTIONS = ("environment", "albedo", "background_pixel", "background_mask", "background_dir", "rms")
SECTIONS = PIXEL_SECTIONS + ("offsets", "entry_scale", "entry_data")
#: the sections of a bake that varies one object (``vary = "object"``): the scene without it,
#: converged (``static``, its standard error), and each pixel's product T1 x L on coarse texels
OBJECT_SECTIONS = ("static", "static_stderr", "product_leaves")
#: the sections of a bake that varies the view (``vary = "view"``): the surface cache and the
#: lattice that finds a hit's cache points (:mod:`wavlight.relight.surface_cache`)
VIEW_SECTIONS = ("view_position", "view_normal", "view_material", "view_face_k", "view_face_base", "view_lattice")
#: the sections of plastic's coat (a lighting bake whose header says ``coat``: true): its blocks,
#: their index and entries, as offsets, entry_scale and entry_data are the transfer's
COAT_SECTIONS = ("coat_blocks", "coat_offsets", "coat_entry_scale", "coat_entry_data")
#: each section's dtype as the file names it (little-endian): the only names a file may give,
#: looked up (never parsed); entry_data's by the bits
SECTION_DTYPES = {"environment": "<f4", "albedo": "<f4", "background_pixel": "<u4", "background_mask": "<u8",
                  "background_dir": "<f4", "rms": "<f4", "offsets": "<i4", "entry_scale": "<f4",
                  "static": "<f4", "static_stderr": "<f4", "product_leaves": "<f2",
                  "view_position": "<f4", "view_normal": "<f4", "view_material": "<i4", "view_face_k": "<i4",
                  "view_face_base": "<i8", "view_lattice": "<i4",
                  "coat_blocks": "<i4", "coat_offsets": "<i4", "coat_entry_scale": "<f4"}
ENTRY_DTYPES = {8: "|i1", 16: "<i2"}
_DTYPES = {name: np.dtype(name) for name in {*SECTION_DTYPES.values(), *ENTRY_DTYPES.values()}}
#: a surface cache's face has at most this many subdivisions k (its lattice: (k + 1)(k + 2) / 2 points)
MAX_FACE_K = 1 << 16
#: a cache point's normal is of unit length within this
NORMAL_TOLERANCE = 1e-3
#: the entries of this many megabytes are reordered from block order into column order at once
REORDER_CHUNK_BYTES = 64 << 20
#: a bake file is read in pieces of this many bytes
READ_CHUNK_BYTES = 64 << 20


def lattice_size(k):
    """Points of a triangle's lattice of k subdivisions (a view bake's surface cache):
    (k + 1)(k + 2) / 2."""
    k = np.asarray(k, np.int64)
    return (k + 1) * (k + 2) // 2


def quantize(values: np.ndarray, bits: int, rng: np.random.Generator):
    """(scales (C,), q (C, P) int8 | int16) for rows of values (C, P): scale = max |v| / qmax,
    q = floor(v / scale + uniform) (stochastic rounding: E[q scale] = v)."""
    qmax = (1 << (bits - 1)) - 1
    peak = np.abs(values).max(axis=1)
    scale = np.where(peak > 0, peak / qmax, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(scale[:, None] > 0, values / np.where(scale > 0, scale, 1.0)[:, None], 0.0)
    q = np.clip(np.floor(x + rng.random(values.shape, dtype=np.float32)), -qmax, qmax)
    return scale.astype(np.float32), q.astype(np.int8 if bits == 8 else np.int16)


def compress_block(coeffs: np.ndarray, held_out: np.ndarray, tolerance: float, bits: int, rng):
    """Compress one block: coeffs (P, 4^n) float32 (the block's pixels' Haar coefficients) and
    held_out (4^n, 3) the held-out lighting's coefficients (times N^2, :mod:`.frame`).

    Columns are kept in decreasing energy (sum over the block's pixels of c^2), the scaling
    coefficient first, until the energy left out is at most tolerance^2 of the block's (in an
    orthonormal basis, the transfer's relative L2 error over the block); the frame under the
    held-out lighting measures what that costs a frame.
    Returns (columns (E,) int64, scales (E,) float32, data (E, P) int8 | int16, error2, norm2):
    the kept columns, their quantized values, the squared held-out frame error of the block and
    the squared norm of its exact held-out frame (to sum over blocks)."""
    c = np.asarray(coeffs, np.float32)
    energy = np.einsum("pc,pc->c", c, c, dtype=np.float64)
    total = float(energy.sum())
    dtype = np.int8 if bits == 8 else np.int16
    if total <= 0:
        return np.zeros(0, np.int64), np.zeros(0, np.float32), np.zeros((0, c.shape[0]), dtype), 0.0, 0.0
    order = np.argsort(-energy, kind="stable")
    order = np.concatenate([[0], order[order != 0]]) if energy[0] > 0 else order   # the block's mean first
    left = total - np.cumsum(energy[order])          # energy left out after keeping the first k + 1
    keep = int(np.searchsorted(-left, -(tolerance ** 2) * total, side="left")) + 1
    keep = min(max(keep, 1), int(np.count_nonzero(energy)))
    cols = np.sort(order[:keep])
    scales, q = quantize(c[:, cols].T, bits, rng)
    lum = held_out.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])
    exact = c.astype(np.float64) @ lum
    approx = (q.astype(np.float64) * scales[:, None].astype(np.float64)).T @ lum[cols]
    diff = approx - exact
    return cols, scales, q, float(diff @ diff), float(exact @ exact)


def check_output(path, known_bytes: int) -> None:
    """Before a bake's work: a one-line WavlightError when ``path`` cannot be written
    (:func:`wavlight.atomic.check_target`: a folder, no folder, a read-only file) or its folder
    has less room than ``known_bytes``, the sections whose sizes are known before the bake."""
    check_target(path, "a bake file")
    check_room(path, known_bytes)


def header_of(scene) -> dict:
    """The header's opening that every bake writes: the format and its version, wavlight's
    version, the scene (its file, None for a dict, and content hash) and its camera."""

    cam = scene.camera
    return {"format": "wavlight-transfer", "version": FORMAT_VERSION, "wavlight": __version__,
            "scene": {"path": None if scene.path == "<dict>" else os.path.abspath(scene.path),
                      "content_hash": scene.content_hash},
            "camera": {"eye": cam.eye.tolist(), "target": cam.target.tolist(), "up": cam.up.tolist(),
                       "fov_y": float(cam.fov_y)}}


class TransferWriter:
    """Collects blocks (in any order) into a scratch file, then writes the bake file in column
    order (:meth:`finish`), atomically (:func:`wavlight.atomic.atomic_write`).
    ``row``: the values of one entry (default BLOCK^2, one per pixel; a view bake's entries hold
    three channels of BLOCK^2 points). ``output``: the bake file to be written, beside which the
    scratch file is made (named as :func:`wavlight.atomic.temporary` names it, so that the next
    write there removes the scratch a killed bake left); None: in the system's temporary folder."""

    def __init__(self, n_levels: int, block: int, bits: int, row: int | None = None, output=None):
        self.n_levels, self.block, self.bits = n_levels, block, bits
        self.row = int(block ** 2 if row is None else row)
        self.dtype = _DTYPES[ENTRY_DTYPES[bits]]
        self.output = None if output is None else os.fspath(output)
        try:
            fd, self._tmp = (temporary(self.output, ".entries") if self.output is not None
                             else tempfile.mkstemp(prefix=TEMPORARY_PREFIX, suffix=".entries"))
        except OSError as e:
            raise WavlightError(f"{self.output or tempfile.gettempdir()}: cannot write ({e.strerror or e})") from None
        self._fh = os.fdopen(fd, "wb")
        self._columns, self._blocks, self._scales = [], [], []
        self.entries = 0
        #: a second writer of plastic's coat (COAT_SECTIONS), set by a bake of a scene with plastic
        self.coat = None

    def add(self, block_id: int, columns, scales, data):
        data = np.ascontiguousarray(data, self.dtype)
        if data.shape != (len(columns), self.row):
            raise ValueError(f"block data must be ({len(columns)}, {self.row}), got {data.shape}")
        try:
            self._fh.write(data.tobytes())
        except OSError as e:   # a full disk, while the bake is under way
            raise WavlightError(f"{self.output or self._tmp}: cannot write ({e.strerror or e})") from None
        self._columns.append(np.asarray(columns, np.int64))
        self._blocks.append(np.full(len(columns), block_id, np.uint32))
        self._scales.append(np.asarray(scales, np.float32))
        self.entries += len(columns)

    def close(self):
        if self.coat is not None:
            self.coat.close()
        if not self._fh.closed:
            try:
                self._fh.close()
            except OSError:   # the buffered rest did not fit: the scratch goes anyway
                pass
        if os.path.exists(self._tmp):
            os.unlink(self._tmp)

    def _flushed(self, path: str) -> None:
        try:
            self._fh.flush()
            self._fh.close()
        except OSError as e:
            raise WavlightError(f"{self.output or path}: cannot write ({e.strerror or e})") from None

    def _index(self, n_blocks: int, blocks_of=None):
        """(order, offsets (4^n, B), scales): the entries by column then block, the offset table
        and their scales; ``blocks_of``: the blocks the table's columns are (default 0 .. n_blocks - 1)."""
        side2 = 1 << (2 * self.n_levels)
        columns = np.concatenate(self._columns) if self._columns else np.zeros(0, np.int64)
        blocks = np.concatenate(self._blocks) if self._blocks else np.zeros(0, np.uint32)
        scales = np.concatenate(self._scales) if self._scales else np.zeros(0, np.float32)
        if blocks_of is not None:
            blocks = np.searchsorted(blocks_of, blocks)
        order = np.lexsort((blocks, columns))                 # by column, then block
        offsets = np.full((side2, n_blocks), -1, np.int32)
        offsets[columns[order], blocks[order]] = np.arange(len(order), dtype=np.int32)
        return order, offsets, scales[order]

    def finish(self, path: str, header: dict, arrays: dict):
        """Write the file: ``header`` (JSON-able) completed with the sections, ``arrays`` the
        PIXEL_SECTIONS (and, with a coat writer, COAT_SECTIONS from it)."""
        self._flushed(path)
        n_blocks = int(header["blocks"][0]) * int(header["blocks"][1])
        order, offsets, scales = self._index(n_blocks)
        row = self.row * self.dtype.itemsize
        extra = tuple(k for k in OBJECT_SECTIONS + VIEW_SECTIONS if k in arrays)
        sections = {**{k: arrays[k] for k in PIXEL_SECTIONS + extra}, "offsets": offsets,
                    "entry_scale": scales}
        streams = {"entry_data": (self, order)}
        if self.coat is not None:
            coat = self.coat
            coat._flushed(path)
            coat_blocks = np.unique(np.concatenate(coat._blocks)) if coat._blocks else np.zeros(0, np.uint32)
            c_order, c_offsets, c_scales = coat._index(len(coat_blocks), coat_blocks)
            sections.update(coat_blocks=coat_blocks, coat_offsets=c_offsets, coat_entry_scale=c_scales)
            streams["coat_entry_data"] = (coat, c_order)
            extra = extra + COAT_SECTIONS
        sections = {k: np.ascontiguousarray(a, _DTYPES[SECTION_DTYPES[k]]) for k, a in sections.items()}
        meta, offset = {}, 0
        names = SECTIONS + extra
        for name in names:
            if name in streams:
                rows = len(streams[name][1])
                nbytes, dtype, shape = rows * row, ENTRY_DTYPES[self.bits], [rows, self.row]
            else:
                a = sections[name]
                nbytes, dtype, shape = a.nbytes, SECTION_DTYPES[name], list(a.shape)
            meta[name] = {"offset": offset, "dtype": dtype, "shape": shape, "bytes": nbytes}
            offset += -(-nbytes // ALIGN) * ALIGN
        # the header goes last into its reserved space: the CRCs are known only then
        header = dict(header, sections=meta)
        widest = 0xFFFFFFFF   # the header's room, with its numbers at their widest
        sizer = json.dumps({**header, "sections": {k: {**v, "crc32": widest} for k, v in meta.items()},
                            "data_offset": widest, "file_bytes": 1 << 62, "header_crc32": widest})
        head_room = -(-(len(MAGIC) + 8 + len(sizer) + 256) // ALIGN) * ALIGN
        try:
            with atomic_write(path, check=size_is(head_room + offset)) as tmp, open(tmp, "wb") as out:
                out.write(b"\0" * head_room)
                for name in names:
                    crc = 0
                    if name in streams:
                        writer, rows = streams[name]
                        source = np.memmap(writer._tmp, writer.dtype, "r", shape=(writer.entries, writer.row)) \
                            if writer.entries else np.zeros((0, writer.row), writer.dtype)
                        step = max(1, REORDER_CHUNK_BYTES // row)
                        for i in range(0, len(rows), step):   # chunks, not entries
                            chunk = np.ascontiguousarray(source[rows[i:i + step]]).tobytes()
                            crc = zlib.crc32(chunk, crc)
                            out.write(chunk)
                        del source
                    else:
                        chunk = sections[name].tobytes()
                        crc = zlib.crc32(chunk)
                        out.write(chunk)
                    meta[name]["crc32"] = crc
                    out.write(b"\0" * (-meta[name]["bytes"] % ALIGN))
                header["sections"] = meta
                header["data_offset"] = head_room
                header["file_bytes"] = head_room + offset
                header["header_crc32"] = header_checksum(header)
                text = json.dumps(header).encode()
                if len(MAGIC) + 8 + len(text) > head_room:
                    raise WavlightError("relight: the bake file's header outgrew its space")
                out.seek(0)
                out.write(MAGIC + np.uint64(len(text)).tobytes() + text)
        finally:
            self.close()
        return header


def header_checksum(header: dict) -> int:
    """The CRC-32 of a header's JSON text without its ``header_crc32`` key: what the file records
    there."""
    return zlib.crc32(json.dumps({k: v for k, v in header.items() if k != "header_crc32"}).encode())


class BakeFile(NamedTuple):
    """A bake file read whole and checked (:func:`read`): its header, its sections (read-only
    arrays, views of ``data``), the file's bytes before the sections (magic, header, padding)
    and the sections' bytes (uint8)."""

    header: dict
    sections: dict
    head: bytes
    data: np.ndarray


def _integer(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _open(path: str):
    """The file ``path`` open for reading and its stat; a one-line WavlightError for what is not
    a regular file (a FIFO is opened without waiting for a writer, then refused)."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except (OSError, ValueError):
        problem = file_problem(path)
        raise WavlightError(f"{path}: {'no such bake file' if problem in (None, 'no such file') else problem}") \
            from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        raise WavlightError(f"{path}: {file_problem(path) or 'is not a regular file'}")
    return os.fdopen(fd, "rb"), st


def _header(path: str, fh, size: int):
    """(header, the file's bytes up to its end) after checking the magic, the version, the
    header's checksum and the file's length."""
    try:
        start = fh.read(len(MAGIC) + 8)
        if len(start) < len(MAGIC) + 8 or start[:len(MAGIC)] != MAGIC:
            raise WavlightError(f"{path}: not a wavlight bake file")
        length = int.from_bytes(start[len(MAGIC):], "little")
        if length > min(size - len(start), MAX_HEADER):
            raise WavlightError(f"{path}: the bake file's header is damaged (its length)")
        text = fh.read(length)
        header = json.loads(text.decode("utf-8"))
        if not isinstance(header, dict) or header.get("format") != "wavlight-transfer":
            raise WavlightError(f"{path}: not a wavlight bake file")
        version = header.get("version")
        if version != FORMAT_VERSION or not _integer(version):
            raise WavlightError(f"{path}: bake file format version {shown(version)}; this wavlight reads version "
                                f"{FORMAT_VERSION} (bake the scene again)")
        if not _integer(header.get("header_crc32")) or header["header_crc32"] != header_checksum(header):
            raise WavlightError(f"{path}: the bake file's header is damaged (it fails its checksum)")
    except OSError as e:
        raise WavlightError(f"{path}: cannot read ({e.strerror or e})") from None
    except (UnicodeDecodeError, ValueError, RecursionError):   # not JSON, or nested beyond Python's stack
        raise WavlightError(f"{path}: the bake file's header is damaged (not JSON)") from None
    if header.get("file_bytes") != size:
        raise WavlightError(f"{path}: the bake file is truncated or extended ({size} bytes, its header says "
                            f"{shown(header.get('file_bytes'))})")
    return header, start + text


def read_header(path) -> dict:
    """The header of a bake file, after checking its magic, version, checksum and length (not its
    sections: :func:`read`); a one-line WavlightError naming the file otherwise."""
    path = os.fspath(path)
    fh, st = _open(path)
    with fh:
        return _header(path, fh, st.st_size)[0]


def read(path, verify: bool = True) -> BakeFile:
    """A bake file read whole into memory and checked: the magic, the version, the header's
    checksum and the file's length (:func:`read_header`), then the header against the sections
    and their contents (:func:`validate`; the CRC-32 of every section with ``verify``). Nothing
    stays mapped: a file truncated or written over later does not touch the arrays
    (docs/decisions/bake-file-mapping.md). A one-line WavlightError naming the file otherwise,
    also where the file changes while it is read."""
    path = os.fspath(path)
    fh, st = _open(path)
    with fh:
        header, start = _header(path, fh, st.st_size)
        base = header.get("data_offset")
        if not _integer(base) or not len(start) <= base <= st.st_size or base % ALIGN:
            raise WavlightError(f"{path}: the bake file's header is damaged: data_offset must be a multiple of "
                                f"{ALIGN} from the header's end ({len(start)}) to the file's ({st.st_size}), got "
                                f"{shown(base)}")
        try:
            head = start + fh.read(base - len(start))
            data = np.empty(st.st_size - base, np.uint8)
            view, done = memoryview(data), 0
            while done < len(data):   # pieces, not bytes
                got = fh.readinto(view[done:done + READ_CHUNK_BYTES])
                if not got:
                    break
                done += got
            after = os.fstat(fh.fileno())
        except OSError as e:
            raise WavlightError(f"{path}: cannot read ({e.strerror or e})") from None
    if len(head) != base or done != len(data) or (after.st_size, after.st_mtime_ns) != (st.st_size, st.st_mtime_ns):
        raise WavlightError(f"{path}: the bake file changed while it was read")
    data.flags.writeable = False
    return BakeFile(header, validate(path, header, data, verify), head, data)


def validate(path: str, header: dict, data: np.ndarray, verify: bool = True) -> dict:
    """The sections of a bake file as read-only arrays over ``data`` (uint8: the file's bytes from
    the header's ``data_offset`` on), after checking the header against them and their contents,
    so that every kernel's index arithmetic is in range and no frame sums a NaN; a one-line
    WavlightError naming the file and what is wrong otherwise. Checked, in order:

    - the fields: vary (lighting, object or view); width and height (1..MAX_SIDE); spp
      (1..MAX_SPP: the bits of a background mask); n_levels (1..MAX_LEVELS); block (BLOCK);
      bits (8 or 16); terms (1..MAX_TERMS); priority; environment_rotate_y (finite); blocks (two
      integers); the scene (its path a string without NUL or null, its content hash a string);
      the camera (eye, target and up three finite numbers each, fov_y in (0, 180)); measured (an
      object, if there); an object bake's object (index >= 0, a finite centre, a finite radius
      > 0) and product_levels (1..n_levels);
    - the sections: exactly those of the bake's kind, in the format's order, each with the dtype
      SECTION_DTYPES names (entry_data: ENTRY_DTYPES[bits]; a name is looked up, never parsed), a
      shape of the format's rank, bytes = elements x item size, and the offset the layout gives
      (each 64-byte aligned after the one before: no gaps, no overlaps, the last ending where the
      file does);
    - the shapes against the fields (the counts kernels take their strides from): environment
      (h, w, 3), at most MAX_TEXELS texels; albedo (height, width, 3), a view bake's (P, 3);
      blocks the image's in BLOCK x BLOCK blocks, a view bake's [ceil(P / BLOCK^2), 1];
      background_mask (M,) and background_dir (M, spp, 3) beside background_pixel (M,); rms
      (4^n,); offsets (4^n, blocks); entry_scale (E,) beside entry_data (E, BLOCK^2), a view
      bake's (E, 3 BLOCK^2); static and static_stderr (height, width, 3); product_leaves
      (height width, 4^product_levels); view_position and view_normal (P, 3), view_material (P,),
      view_face_k and view_face_base (F,); with ``coat`` (true only on a lighting bake):
      coat_offsets (4^n, C) beside coat_blocks (C,), coat_entry_scale (D,) beside
      coat_entry_data (D, BLOCK^2);
    - with ``verify``, each section's CRC-32;
    - the contents: the environment finite, >= 0, at most MAX_RADIANCE and not black everywhere
      (its frames would be black); albedo, rms and entry_scale finite and >= 0, the albedo at most
      MAX_ALBEDO (the scene format's); background pixels
      increasing and below width x height, each mask non-zero and without bits at or past spp,
      the directions finite; offsets -1 or the entries in order, each entry once (so that every
      entry index is below E); static finite, static_stderr finite and >= 0, product_leaves
      finite; view positions finite, normals of unit length (within NORMAL_TOLERANCE),
      materials >= 0 (the scene's count: :class:`wavlight.relight.view_frames.ViewFrames`), each face's
      subdivisions in 1..MAX_FACE_K, its first lattice entry the sum of the lattice sizes before
      it, the lattice as long as their sum and its cache points below P; coat_blocks increasing
      and below the blocks, coat_entry_scale finite and >= 0, coat_offsets -1 or the coat
      entries in order, each once.
    """
    def damaged(what):
        return WavlightError(f"{path}: the bake file's header is damaged: {what}")

    def contents(what):
        return WavlightError(f"{path}: the bake file is damaged: {what}")

    def integer(name, lo, hi, where=header, label=None):
        value = where.get(name) if isinstance(where, dict) else None
        if not _integer(value) or not lo <= value <= hi:
            raise damaged(f"{label or name} must be an integer in [{lo}, {hi}], got {shown(value)}")
        return value

    def point(value):
        return isinstance(value, list) and len(value) == 3 and all(_finite(x) for x in value)

    # -- the fields
    vary = header.get("vary")
    if vary not in VARIES:
        raise damaged(f"vary must be one of {', '.join(VARIES)}, got {shown(vary)}")
    width, height = integer("width", 1, MAX_SIDE), integer("height", 1, MAX_SIDE)
    spp = integer("spp", 1, MAX_SPP)
    n = integer("n_levels", 1, MAX_LEVELS)
    if header.get("block") != BLOCK or not _integer(header.get("block")):
        raise damaged(f"block must be {BLOCK} (pixels per side of a block), got {shown(header.get('block'))}")
    bits = header.get("bits")
    if not _integer(bits) or bits not in ENTRY_DTYPES:
        raise damaged(f"bits must be 8 or 16, got {shown(bits)}")
    integer("terms", 1, MAX_TERMS)
    if header.get("priority") not in PRIORITIES:
        raise damaged(f"priority must be one of {', '.join(PRIORITIES)}, got {shown(header.get('priority'))}")
    if not _finite(header.get("environment_rotate_y")):
        given = shown(header["environment_rotate_y"]) if "environment_rotate_y" in header else "none"
        raise damaged(f"environment_rotate_y must be a finite number of degrees, got {given}")
    scene = header.get("scene")
    if (not isinstance(scene, dict) or not isinstance(scene.get("content_hash"), str)
            or not (scene.get("path") is None or isinstance(scene.get("path"), str))
            or "\0" in (scene.get("path") or "")):
        raise damaged(f"scene must hold a path (a file name, or null) and a content hash, got {shown(scene)}")
    camera = header.get("camera")
    if (not isinstance(camera, dict) or not all(point(camera.get(k)) for k in ("eye", "target", "up"))
            or not _finite(camera.get("fov_y")) or not 0 < camera["fov_y"] < 180):
        raise damaged(f"camera must hold eye, target and up (three finite numbers each) and fov_y, got "
                      f"{shown(camera)}")
    if not isinstance(header.get("measured", {}), dict):
        raise damaged(f"measured must be an object, got {shown(header.get('measured'))}")
    blocks = header.get("blocks")
    if not isinstance(blocks, list) or len(blocks) != 2 or not all(_integer(b) for b in blocks):
        raise damaged(f"blocks must be two integers, got {shown(blocks)}")
    names = SECTIONS
    if vary == "object":
        ob = header.get("object")
        if (not isinstance(ob, dict) or not _integer(ob.get("index")) or ob["index"] < 0 or not point(ob.get("center"))
                or not _finite(ob.get("radius")) or not ob["radius"] > 0):
            raise damaged(f"object must hold an index, a finite center and a radius > 0, got {shown(ob)}")
        m = integer("product_levels", 1, n)
        names = SECTIONS + OBJECT_SECTIONS
    elif vary == "view":
        names = SECTIONS + VIEW_SECTIONS
    coat = header.get("coat", False)
    if not isinstance(coat, bool) or (coat and vary != "lighting"):
        raise damaged(f"coat must be true or false, and true only where the bake varies the lighting, got {shown(coat)}")
    if coat:
        names = names + COAT_SECTIONS
    metas = header.get("sections")
    if not isinstance(metas, dict) or set(metas) != set(names):
        given = set(metas) if isinstance(metas, dict) else set()
        missing, unknown = [k for k in names if k not in given], sorted(str(k) for k in given - set(names))
        raise damaged(f"a bake that varies the {vary} has the sections {', '.join(names)}"
                      + (f"; missing {', '.join(missing)}" if missing else "")
                      + (f"; unknown {', '.join(unknown)}" if unknown else ""))

    # -- the sections: dtypes, shapes, sizes, the layout
    ranks = {"environment": 3, "albedo": 2 if vary == "view" else 3, "background_dir": 3, "offsets": 2,
             "entry_data": 2, "static": 3, "static_stderr": 3, "product_leaves": 2, "view_position": 2,
             "view_normal": 2, "coat_offsets": 2, "coat_entry_data": 2}
    s, offset = {}, 0
    for name in names:   # sections, not elements
        meta = metas[name]
        if not isinstance(meta, dict):
            raise damaged(f"section {name} must be an object, got {shown(meta)}")
        entry = name in ("entry_data", "coat_entry_data")
        dtype = ENTRY_DTYPES[bits] if entry else SECTION_DTYPES[name]
        if meta.get("dtype") != dtype:
            raise damaged(f"section {name}: dtype {shown(meta.get('dtype'))}; the format's is {dtype}"
                          + (f" (bits {bits})" if entry else ""))
        shape = meta.get("shape")
        rank = ranks.get(name, 1)
        if not isinstance(shape, list) or len(shape) != rank or not all(_integer(x) and x >= 0 for x in shape):
            raise damaged(f"section {name}: its shape must be {rank} integers >= 0, got {shown(shape)}")
        nbytes = math.prod(shape) * _DTYPES[dtype].itemsize
        if meta.get("bytes") != nbytes or not _integer(meta.get("crc32")):
            raise damaged(f"section {name}: {shown(meta.get('bytes'))} bytes for shape {shape} of {dtype}, or no "
                          "crc32")
        if meta.get("offset") != offset or offset + nbytes > len(data):
            raise damaged(f"section {name}: offset {shown(meta.get('offset'))}, where the layout puts it at "
                          f"{offset} (of {len(data)} bytes)")
        s[name] = np.frombuffer(data, _DTYPES[dtype], math.prod(shape), offset).reshape(shape)
        offset += -(-nbytes // ALIGN) * ALIGN
    if offset != len(data):
        raise damaged(f"the sections end at byte {offset} of the {len(data)} after the header")

    def expect(name, shape, why):
        if s[name].shape != tuple(shape):
            raise damaged(f"{why}, but {name} is {tuple(s[name].shape)} (not {tuple(shape)})")

    env = s["environment"].shape
    if env[2] != 3 or env[0] < 1 or env[1] < 1 or env[0] * env[1] > MAX_TEXELS:
        raise damaged(f"environment is {env}: an (h, w, 3) map of at most {MAX_TEXELS} texels")
    side2 = 1 << (2 * n)
    if vary == "view":
        points = s["view_position"].shape[0]
        rows, expected_blocks = 3 * BLOCK * BLOCK, [-(-points // (BLOCK * BLOCK)), 1]
        expect("albedo", (points, 3), f"view_position holds {points} cache points")
        expect("view_normal", (points, 3), f"view_position holds {points} cache points")
        expect("view_material", (points,), f"view_position holds {points} cache points")
        expect("view_face_base", s["view_face_k"].shape, f"view_face_k holds {len(s['view_face_k'])} faces")
        if blocks != expected_blocks or points < 1:
            raise damaged(f"blocks is {blocks}; {points} cache points fill {expected_blocks} blocks")
    else:
        rows, expected_blocks = BLOCK * BLOCK, [-(-width // BLOCK), -(-height // BLOCK)]
        expect("albedo", (height, width, 3), f"width x height is {width} x {height}")
        if blocks != expected_blocks:
            raise damaged(f"blocks is {blocks}; an image of width x height {width} x {height} has "
                          f"{expected_blocks[0]} x {expected_blocks[1]} blocks of {BLOCK}")
    background = s["background_pixel"].shape[0]
    expect("background_mask", (background,), f"background_pixel holds {background} pixels")
    expect("background_dir", (background, spp, 3), f"spp is {spp} and background_pixel holds {background} pixels")
    expect("rms", (side2,), f"n_levels is {n} (4^n coefficients)")
    expect("offsets", (side2, blocks[0] * blocks[1]), f"n_levels is {n} and blocks {blocks}")
    entries = s["entry_scale"].shape[0]
    expect("entry_data", (entries, rows), f"entry_scale holds {entries} entries of {rows} values")
    if vary == "object":
        expect("static", (height, width, 3), f"width x height is {width} x {height}")
        expect("static_stderr", (height, width, 3), f"width x height is {width} x {height}")
        expect("product_leaves", (width * height, 1 << (2 * m)), f"product_levels is {m}")
    if coat:
        holders = s["coat_blocks"].shape[0]
        expect("coat_offsets", (side2, holders), f"n_levels is {n} and coat_blocks holds {holders} blocks")
        coat_entries = s["coat_entry_scale"].shape[0]
        expect("coat_entry_data", (coat_entries, rows), f"coat_entry_scale holds {coat_entries} entries of {rows} "
                                                        "values")

    # -- the checksums
    if verify:
        for name in names:   # sections, not elements
            meta, crc = metas[name], 0
            for i in range(meta["offset"], meta["offset"] + meta["bytes"], 1 << 26):   # pieces, not bytes
                crc = zlib.crc32(data[i:min(i + (1 << 26), meta["offset"] + meta["bytes"])], crc)
            if crc != meta["crc32"]:
                raise WavlightError(f"{path}: the bake file is damaged (section {name} fails its checksum)")

    # -- the contents
    def finite(name, lo=None):
        a = s[name]
        if not np.all(np.isfinite(a)):
            raise contents(f"{name} holds NaN or Inf")
        if lo is not None and a.size and a.min() < lo:
            raise contents(f"{name} holds values below {lo:g}")

    finite("environment", 0.0)
    if s["environment"].size and s["environment"].max() > MAX_RADIANCE:
        raise contents(f"environment holds radiance above {MAX_RADIANCE:g}")
    if not np.any(s["environment"] > 0):
        raise WavlightError(f"{path}: the bake file's environment map is black everywhere; its frames would be black")
    for name in ("albedo", "rms", "entry_scale"):   # sections, not elements
        finite(name, 0.0)
    if s["albedo"].size and s["albedo"].max() > MAX_ALBEDO:
        raise contents(f"albedo holds values above {MAX_ALBEDO:g} (a scene's albedo at most)")
    finite("background_dir")
    pixel, mask = s["background_pixel"].astype(np.int64), s["background_mask"]
    limit = width * height if vary != "view" else 0
    if background and (np.any(np.diff(pixel) <= 0) or pixel[0] < 0 or pixel[-1] >= limit):
        raise contents(f"background_pixel must be increasing pixels below {limit}")
    if background and (np.any(mask == 0) or (spp < 64 and np.any(mask >> np.uint64(spp)))):
        raise contents(f"background_mask must mark at least one of the {spp} samples and no other")
    flat = s["offsets"].reshape(-1)
    kept = flat[flat >= 0]
    if np.any(flat < -1) or len(kept) != entries or not np.array_equal(kept, np.arange(entries, dtype=kept.dtype)):
        raise contents("the index (offsets) must hold -1 or each entry once, in order")
    if coat:
        held = s["coat_blocks"].astype(np.int64)
        if len(held) and (np.any(np.diff(held) <= 0) or held[0] < 0 or held[-1] >= blocks[0] * blocks[1]):
            raise contents(f"coat_blocks must be increasing blocks below {blocks[0] * blocks[1]}")
        finite("coat_entry_scale", 0.0)
        flat = s["coat_offsets"].reshape(-1)
        kept = flat[flat >= 0]
        if (np.any(flat < -1) or len(kept) != s["coat_entry_scale"].shape[0]
                or not np.array_equal(kept, np.arange(len(kept), dtype=kept.dtype))):
            raise contents("the coat's index (coat_offsets) must hold -1 or each coat entry once, in order")
    if vary == "object":
        finite("static")
        finite("static_stderr", 0.0)
        finite("product_leaves")
    if vary == "view":
        finite("view_position")
        finite("view_normal")
        length = np.linalg.norm(s["view_normal"].astype(np.float64), axis=1)
        if np.any(np.abs(length - 1.0) > NORMAL_TOLERANCE):
            raise contents("view_normal holds normals not of unit length")
        if s["view_material"].size and s["view_material"].min() < 0:
            raise contents("view_material holds negative materials")
        k = s["view_face_k"].astype(np.int64)
        if k.size and (k.min() < 1 or k.max() > MAX_FACE_K):
            raise contents(f"view_face_k must hold subdivisions in [1, {MAX_FACE_K}]")
        sizes = lattice_size(k)
        base = np.concatenate([[0], np.cumsum(sizes)[:-1]]) if k.size else np.zeros(0, np.int64)
        if not np.array_equal(s["view_face_base"], base):
            raise contents("view_face_base must hold each face's first lattice entry (the sum of the lattices before)")
        lattice = s["view_lattice"]
        if len(lattice) != int(sizes.sum()) or (len(lattice) and (lattice.min() < 0 or lattice.max() >= points)):
            raise contents(f"view_lattice must hold {int(sizes.sum())} cache points below {points}")
    return s
