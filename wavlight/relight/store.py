"""The bake file: a header and the transfer's Haar coefficients by column in blocks of pixels,
compressed and quantized (Ng et al. 2003's layout), memory-mapped so that a frame reads only
the columns of the lighting terms it keeps.

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

The header records the format and its version, wavlight's version, the scene (file, content
hash), camera, image size, camera samples, texel levels n, block size, bits, what was chosen
and measured (compression, terms, errors), and per section its offset, dtype, shape and CRC-32.
Loading checks the magic, the version, the sizes against the file's length (truncation), the
CRC-32 of every section (corruption) and the entries' ranges, before any frame reads them.

Compression, per block: coefficient columns in decreasing energy (sum over the block's pixels
of c^2), the scaling coefficient first, until the energy left out is at most tolerance^2 of the
block's (:func:`compress_block`); the frame's error under a held-out lighting is measured and
recorded. Quantization: a scale per (column, block), max |c| / (2^(bits-1) - 1),
and stochastic rounding (dithering; unbiased), at 8 or 16 bits.
"""
from __future__ import annotations

import json
import os
import tempfile
import zlib

import numpy as np

from ..atomic import TEMPORARY_PREFIX, atomic_write, check_room, check_target, size_is, temporary
from ..errors import WavlightError
from ..version import __version__

MAGIC = b"WAVLIGHT-XFER\x00\x01\n"   # 16 bytes
FORMAT_VERSION = 1
ALIGN = 64
PIXEL_SECTIONS = ("environment", "albedo", "background_pixel", "background_mask", "background_dir", "rms")
SECTIONS = PIXEL_SECTIONS + ("offsets", "entry_scale", "entry_data")
#: the sections of a bake that varies one object (``vary = "object"``): the scene without it,
#: converged (``static``, its standard error), and each pixel's product T1 x L on coarse texels
OBJECT_SECTIONS = ("static", "static_stderr", "product_leaves")
#: the sections of a bake that varies the view (``vary = "view"``): the surface cache and the
#: lattice that finds a hit's cache points (:mod:`wavlight.relight.view`)
VIEW_SECTIONS = ("view_position", "view_normal", "view_material", "view_face_k", "view_face_base", "view_lattice")
#: the entries of this many megabytes are reordered from block order into column order at once
REORDER_CHUNK_BYTES = 64 << 20


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
        self.dtype = np.dtype(np.int8 if bits == 8 else np.int16)
        self.output = None if output is None else os.fspath(output)
        try:
            fd, self._tmp = (temporary(self.output, ".entries") if self.output is not None
                             else tempfile.mkstemp(prefix=TEMPORARY_PREFIX, suffix=".entries"))
        except OSError as e:
            raise WavlightError(f"{self.output or tempfile.gettempdir()}: cannot write ({e.strerror or e})") from None
        self._fh = os.fdopen(fd, "wb")
        self._columns, self._blocks, self._scales = [], [], []
        self.entries = 0

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
        if not self._fh.closed:
            try:
                self._fh.close()
            except OSError:   # the buffered rest did not fit: the scratch goes anyway
                pass
        if os.path.exists(self._tmp):
            os.unlink(self._tmp)

    def finish(self, path: str, header: dict, arrays: dict):
        """Write the file: ``header`` (JSON-able) completed with the sections, ``arrays`` the
        PIXEL_SECTIONS."""
        try:
            self._fh.flush()
            self._fh.close()
        except OSError as e:
            raise WavlightError(f"{self.output or path}: cannot write ({e.strerror or e})") from None
        side2 = 1 << (2 * self.n_levels)
        columns = np.concatenate(self._columns) if self._columns else np.zeros(0, np.int64)
        blocks = np.concatenate(self._blocks) if self._blocks else np.zeros(0, np.uint32)
        scales = np.concatenate(self._scales) if self._scales else np.zeros(0, np.float32)
        order = np.lexsort((blocks, columns))                 # by column, then block
        n_blocks = int(header["blocks"][0]) * int(header["blocks"][1])
        offsets = np.full((side2, n_blocks), -1, np.int32)
        offsets[columns[order], blocks[order]] = np.arange(len(order), dtype=np.int32)
        row = self.row * self.dtype.itemsize
        extra = tuple(k for k in OBJECT_SECTIONS + VIEW_SECTIONS if k in arrays)
        sections = {**{k: np.ascontiguousarray(arrays[k]) for k in PIXEL_SECTIONS + extra},
                    "offsets": offsets, "entry_scale": scales[order]}
        meta, offset = {}, 0
        names = SECTIONS + extra
        for name in names:
            if name == "entry_data":
                nbytes, dtype, shape = len(order) * row, self.dtype.str, [len(order), self.row]
            else:
                a = sections[name]
                nbytes, dtype, shape = a.nbytes, a.dtype.str, list(a.shape)
            meta[name] = {"offset": offset, "dtype": dtype, "shape": shape, "bytes": nbytes}
            offset += -(-nbytes // ALIGN) * ALIGN
        # the header goes last into its reserved space: the CRCs are known only then
        header = dict(header, sections=meta)
        sizer = json.dumps({**header, "sections": {k: {**v, "crc32": 0} for k, v in meta.items()}})
        head_room = -(-(len(MAGIC) + 8 + len(sizer) + 256) // ALIGN) * ALIGN
        try:
            with atomic_write(path, check=size_is(head_room + offset)) as tmp, open(tmp, "wb") as out:
                out.write(b"\0" * head_room)
                source = np.memmap(self._tmp, self.dtype, "r", shape=(self.entries, self.row)) \
                    if self.entries else np.zeros((0, self.row), self.dtype)
                for name in names:
                    crc = 0
                    if name == "entry_data":
                        step = max(1, REORDER_CHUNK_BYTES // row)
                        for i in range(0, len(order), step):   # chunks, not entries
                            chunk = np.ascontiguousarray(source[order[i:i + step]]).tobytes()
                            crc = zlib.crc32(chunk, crc)
                            out.write(chunk)
                    else:
                        chunk = sections[name].tobytes()
                        crc = zlib.crc32(chunk)
                        out.write(chunk)
                    meta[name]["crc32"] = crc
                    out.write(b"\0" * (-meta[name]["bytes"] % ALIGN))
                del source
                header["sections"] = meta
                header["data_offset"] = head_room
                header["file_bytes"] = head_room + offset
                text = json.dumps(header).encode()
                if len(MAGIC) + 8 + len(text) > head_room:
                    raise WavlightError("relight: the bake file's header outgrew its space")
                out.seek(0)
                out.write(MAGIC + np.uint64(len(text)).tobytes() + text)
        finally:
            self.close()
        return header


def read_header(path: str) -> dict:
    """The header of a bake file, after checking its magic, version and length; a one-line
    WavlightError naming the file otherwise."""
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as fh:
            start = fh.read(len(MAGIC) + 8)
            if len(start) < len(MAGIC) + 8 or start[:len(MAGIC)] != MAGIC:
                raise WavlightError(f"{path}: not a wavlight bake file")
            length = int(np.frombuffer(start[len(MAGIC):], np.uint64)[0])
            if length > min(size, 1 << 24):
                raise WavlightError(f"{path}: the bake file's header is damaged")
            header = json.loads(fh.read(length).decode("utf-8"))
    except OSError as e:
        raise WavlightError(f"{path}: cannot read ({e.strerror or e})") from None
    except (UnicodeDecodeError, json.JSONDecodeError, ValueError):
        raise WavlightError(f"{path}: the bake file's header is damaged") from None
    if not isinstance(header, dict) or header.get("format") != "wavlight-transfer":
        raise WavlightError(f"{path}: not a wavlight bake file")
    if header.get("version") != FORMAT_VERSION:
        raise WavlightError(f"{path}: bake file format version {header.get('version')!r}; this wavlight reads "
                            f"version {FORMAT_VERSION} (bake the scene again)")
    if header.get("file_bytes") != size:
        raise WavlightError(f"{path}: the bake file is truncated or extended ({size} bytes, its header says "
                            f"{header.get('file_bytes')})")
    return header


def open_sections(path: str, header: dict, verify: bool = True) -> dict:
    """The sections of a bake file as read-only memory maps, checked (CRC-32 with ``verify``,
    shapes, entry ranges)."""
    base = header["data_offset"]
    out = {}
    for name in SECTIONS + tuple(k for k in OBJECT_SECTIONS + VIEW_SECTIONS if k in header["sections"]):
        m = header["sections"].get(name)
        try:
            dtype, shape, offset = np.dtype(m["dtype"]), tuple(int(x) for x in m["shape"]), int(m["offset"])
        except (TypeError, KeyError, ValueError):
            raise WavlightError(f"{path}: the bake file's header is damaged (section {name})") from None
        count = int(np.prod(shape))
        if count * dtype.itemsize != m.get("bytes") or base + offset + m["bytes"] > header["file_bytes"]:
            raise WavlightError(f"{path}: the bake file's header is damaged (section {name})")
        a = np.memmap(path, dtype, "r", offset=base + offset, shape=shape) if count else np.zeros(shape, dtype)
        if verify:
            crc = 0
            flat = a.reshape(-1).view(np.uint8) if count else np.zeros(0, np.uint8)
            for i in range(0, flat.size, 1 << 26):
                crc = zlib.crc32(flat[i:i + (1 << 26)], crc)
            if crc != m.get("crc32"):
                raise WavlightError(f"{path}: the bake file is damaged (section {name} fails its checksum)")
        out[name] = a
    side2 = 1 << (2 * int(header["n_levels"]))
    n_blocks = int(header["blocks"][0]) * int(header["blocks"][1])
    offsets, entries = out["offsets"], len(out["entry_scale"])
    if (offsets.shape != (side2, n_blocks) or out["entry_data"].shape[0] != entries
            or (offsets.size and (int(offsets.min()) < -1 or int(offsets.max()) >= entries))
            or not np.all(np.isfinite(out["entry_scale"]))):
        raise WavlightError(f"{path}: the bake file's index is damaged")
    return out
