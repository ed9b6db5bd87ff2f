"""Image I/O through OpenImageIO, and colour-space conversion through colour-science.

Maps are painted images: read as sRGB-encoded (8/16-bit PNG, TIFF, JPEG) and
converted to linear; EXR/HDR inputs are already linear.  Renders are written
as linear EXR (half or float) and sRGB-encoded 8-bit PNG, always atomically.
"""

from __future__ import annotations

import errno
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import atomic_path, no_space
from .errors import ForestError

MAX_IMAGE_BYTES = 512 * 1024 * 1024
MAX_IMAGE_PIXELS = 16384 * 16384
#: Largest decoded image (float32, every channel) a read may allocate: width × height × channels × 4 bytes,
#: checked from the header before decoding.  A small file can hold a huge image (a 1 MB PNG of
#: 16384×16000 RGBA decodes to 4 GiB); the job service reads uploads with a far smaller limit, and every
#: read refuses, from the header too, an image whose decoded size is more than the process's memory room.
MAX_DECODED_BYTES = MAX_IMAGE_PIXELS * 4 * 4
LINEAR_FORMATS = (".exr", ".hdr", ".pfm")


def _oiio():
    import OpenImageIO as oiio

    return oiio


def _first_line(*texts: str) -> str:
    """The first non-empty line of the first text that has one, without OpenImageIO's format prefixes."""
    for text in texts:
        for line in str(text or "").splitlines():
            line = line.strip()
            for prefix in ("libpng error: ", "PNG read error: ", "JPEG error: ", "Error: "):
                line = line.removeprefix(prefix)
            if line and line != "PNG library error":
                return line
    return ""


def _memory_short(decoded: int) -> str:
    """Where ``decoded`` bytes do not fit the memory this process may still allocate
    (:func:`forest.preflight.memory_room`: ``$FOREST_MEMORY_GB``, else the available memory and every cgroup
    limit): ``36.0 MiB decoded, more than the 12.0 MiB of memory available`` (with the cgroup limit that binds);
    else ``""`` (it fits, or the room cannot be read)."""
    from .preflight import format_bytes, memory_room

    room = memory_room()
    if room is None or decoded <= room.bytes:
        return ""
    text = f"{format_bytes(decoded)} decoded, more than the {format_bytes(room.bytes)} of memory available"
    if room.cgroup is not None:
        text += f" (cgroup limit of {format_bytes(room.cgroup.limit)} on {room.cgroup.path})"
    return text


def read_image(
    path: str | Path,
    *,
    what: str = "image",
    max_bytes: int = MAX_IMAGE_BYTES,
    max_pixels: int = MAX_IMAGE_PIXELS,
    max_decoded_bytes: int = MAX_DECODED_BYTES,
    unassociated: bool = False,
) -> np.ndarray:
    """Read an image as float32 ``(H, W, C)`` with the file's own encoding (no conversion).

    8/16-bit integer images are normalised to [0, 1].  Raises :class:`ForestError`
    naming the file for a missing, oversized, unreadable, truncated or
    non-finite image, in one line: what the decoding libraries print on stderr
    (libpng, libjpeg, OpenEXR through OpenImageIO) is captured and folded into
    that line, and OpenImageIO's pending errors are collected so that none is
    printed later.  A decoder that reports an error after returning pixels (a
    truncated JPEG, filled with grey) counts as a failure.  With
    ``unassociated``, RGBA colour comes back as stored (straight alpha) instead
    of OpenImageIO's default of multiplying it by alpha on read.  ``max_pixels``
    and ``max_decoded_bytes`` (:data:`MAX_DECODED_BYTES`) are checked from the
    file's header, before anything is decoded, and so is the memory: an image
    whose decoded size is more than this process may still allocate
    (:func:`forest.preflight.memory_room`, cgroup limits included) is refused
    naming both sizes, rather than decoded until the kernel kills the process.
    """
    from .runtime import captured_stderr

    path = Path(path)
    if path.is_dir():
        raise ForestError(f"{path}: {what} is a folder, not an image file")
    if not path.is_file():
        raise ForestError(f"{path}: {what} {'is not a regular file' if path.exists() else 'not found'}")
    size = path.stat().st_size
    if size == 0:
        raise ForestError(f"{path}: {what} is empty")
    if size > max_bytes:
        raise ForestError(f"{path}: {what} is {size / 2**20:.0f} MiB, over the {max_bytes / 2**20:.0f} MiB limit")
    if not os.access(path, os.R_OK):
        raise ForestError(f"{path}: cannot read {what}: permission denied")
    oiio = _oiio()
    problem = ""
    data = None
    spec = None
    with captured_stderr() as noise:
        if unassociated:
            config = oiio.ImageSpec()
            config.attribute("oiio:UnassociatedAlpha", 1)
            inp = oiio.ImageInput.open(str(path), config)
        else:
            inp = oiio.ImageInput.open(str(path))
        if inp is None:
            problem = _first_line(oiio.geterror()) or "not an image file OpenImageIO can read"
        else:
            spec = inp.spec()
            if spec.width * spec.height > max_pixels:
                inp.close()
                del inp
                raise ForestError(f"{path}: {what} is {spec.width}x{spec.height}, over the {max_pixels} pixel limit")
            decoded = spec.width * spec.height * spec.nchannels * 4
            if decoded > max_decoded_bytes:
                inp.close()
                del inp
                raise ForestError(
                    f"{path}: {what} is {spec.width}x{spec.height} with {spec.nchannels} channels, "
                    f"{decoded / 2**20:.0f} MiB decoded, over the {max_decoded_bytes / 2**20:.0f} MiB limit"
                )
            short = _memory_short(decoded)
            if short:
                inp.close()
                del inp
                raise ForestError(
                    f"{path}: {what} is {spec.width}x{spec.height} with {spec.nchannels} channels, {short}"
                )
            data = inp.read_image(0, 0, 0, spec.nchannels, "float")
            error = inp.geterror()
            if data is None or not hasattr(data, "shape") or error:
                problem = _first_line(error) or "corrupt or truncated data"
                data = None
            inp.close()
            del inp
        oiio.geterror()  # clear the global error too: OpenImageIO prints unretrieved errors at exit
    if data is None:
        detail = _first_line(problem, *noise) or "unknown format"
        for quoted in (f' ("{path}")', f" ({path})", f' "{path}"', str(path)):  # the line names the file already
            detail = detail.replace(quoted, "")
        detail = re.sub(r"^EXR Error\s*:\s*", "", detail).strip(" :") or "unknown format"
        raise ForestError(f"{path}: cannot read {what}: {detail}")
    assert spec is not None
    data = np.asarray(data, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
    if not np.isfinite(data).all():
        bad = int((~np.isfinite(data)).sum())
        raise ForestError(f"{path}: {what} contains NaN or infinite values ({bad:,} of {data.size:,})")
    return data


def is_linear_file(path: str | Path) -> bool:
    """Whether ``path``'s suffix names a linear-light format (EXR, HDR, PFM) rather than an sRGB-encoded one."""
    return Path(path).suffix.lower() in LINEAR_FORMATS


#: The encoded value below which IEC 61966-2-1 decodes linearly: the encoding of its linear knee 0.0031308 on the
#: linear piece, 0.0031308 × 12.92 = 0.040449936 (the standard rounds it to 0.04045), as colour-science's
#: ``eotf_sRGB`` takes it.
SRGB_KNEE = 0.0031308 * 12.92


def srgb_to_linear(a: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding, V ≤ knee: V / 12.92, else ((V + 0.055) / 1.055)^2.4, of V clipped to [0, 1].

    The same float64 arithmetic and knee (:data:`SRGB_KNEE`) as colour-science's ``eotf_sRGB``, so the same
    float32 values (tested), without its domain-range handling: about 4× faster on a painted map, which
    every scatter and scene load decodes.
    """
    v = np.clip(np.asarray(a, np.float64), 0.0, 1.0)
    return np.where(v <= SRGB_KNEE, v / 12.92, ((v + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(a: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB encoding (colour-science's ``eotf_inverse_sRGB``)."""
    import colour

    return np.asarray(colour.models.eotf_inverse_sRGB(np.clip(a, 0.0, 1.0)), dtype=np.float32)


def read_map_rgb(path: str | Path, *, what: str = "map") -> np.ndarray:
    """Read a painted map as linear RGB float32 ``(H, W, 3)``."""
    img = read_image(path, what=what)
    rgb = to_rgb(img)
    return rgb if is_linear_file(path) else srgb_to_linear(rgb)


def read_map_grey(path: str | Path, *, what: str = "map", linearise: bool = False) -> np.ndarray:
    """Read a painted map as one float32 channel ``(H, W)`` in the file's encoding.

    Grey maps (presence, density, height) are used as painted: a mid-grey
    painted value means one half, so no sRGB decoding unless asked.
    """
    img = read_image(path, what=what)
    if img.shape[2] >= 3:
        g = img[..., :3].mean(axis=2)
    else:
        g = img[..., 0]
    if linearise and not is_linear_file(path):
        g = srgb_to_linear(g)
    return g.astype(np.float32)


def to_rgb(img: np.ndarray) -> np.ndarray:
    """The first three channels of an ``(H, W, C)`` image; grey (C = 1 or 2) repeated to RGB."""
    c = img.shape[2]
    if c == 1 or c == 2:
        return np.repeat(img[..., :1], 3, axis=2)
    return img[..., :3]


def _set_attributes(spec, attributes: dict | None) -> None:
    """Header metadata in sorted order; no timestamps, so files are byte-identical.

    Booleans are written as 0/1, ints and floats as themselves, a 4×4 array as
    a matrix (OpenEXR ``m44f``, stored in the order given), any other float
    array or tuple of floats as ``float[n]`` (e.g. ``chromaticities``), the rest
    as strings.
    """
    oiio = _oiio()
    for key, value in sorted((attributes or {}).items()):
        if isinstance(value, (bool, np.bool_)):
            value = int(value)
        if isinstance(value, (int, np.integer)):
            spec.attribute(key, int(value))
        elif isinstance(value, (float, np.floating)):
            spec.attribute(key, float(value))
        elif isinstance(value, (np.ndarray, tuple)) and np.asarray(value).dtype.kind == "f":
            arr = np.asarray(value, dtype=np.float32)
            floats = tuple(float(v) for v in arr.ravel())
            if arr.shape == (4, 4):
                spec.attribute(key, oiio.TypeMatrix, floats)
            else:
                spec.attribute(key, oiio.TypeDesc(f"float[{len(floats)}]"), floats)
        else:
            spec.attribute(key, str(value))


#: What OpenImageIO's writers say, through ``geterror()`` alone, when a write was cut short (its other messages, such
#: as a TIFF's optional Exif block it could not add, leave a valid file).
SHORT_WRITE = re.compile(r"write error|could only write|failed to write|file output failed", re.IGNORECASE)


def _write_failed(path: Path, tmp: Path, err: str) -> ForestError:
    """One line for an image write that failed: the storage's own reason where the folder has no space left
    (OpenImageIO's message names the temporary file, not the output), else the writer's first line."""
    reason = (err or "write failed").strip().splitlines()[0].replace(str(tmp), str(path))
    if no_space(tmp.parent):
        reason = os.strerror(errno.ENOSPC)
    return ForestError(f"{path}: cannot write: {reason}")


def _finish(out: Any, path: Path, tmp: Path) -> None:
    """Close an OpenImageIO writer and raise a one-line :class:`ForestError` if any write failed.

    OpenImageIO reports a short write (a full disk, a quota, a file size limit) only through ``geterror()`` —
    ``write_image`` and ``close`` still return True — and would leave a truncated file behind the atomic rename.
    """
    out.close()
    err = out.geterror()
    if err and (SHORT_WRITE.search(err) or no_space(tmp.parent)):
        raise _write_failed(path, tmp, err)


def write_image(path: str | Path, pixels: np.ndarray, *, attributes: dict | None = None, half: bool = True) -> Path:
    """Write ``pixels`` ``(H, W, C)`` atomically.

    EXR receives linear values (half float unless ``half=False``) and any
    ``attributes`` as header metadata; PNG/JPEG/TIFF receive sRGB-encoded 8-bit
    values converted from linear.  Single-channel data (depth, ids) goes to EXR
    as float with channel name ``Z`` or ``Y``.
    """
    oiio = _oiio()
    path = Path(path)
    pixels = np.asarray(pixels, dtype=np.float32)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    h, w, c = pixels.shape
    ext = path.suffix.lower()
    if ext == ".exr":
        fmt = oiio.HALF if half else oiio.FLOAT
        data = pixels
    elif ext in (".png", ".jpg", ".jpeg", ".tif", ".tiff"):
        fmt = oiio.UINT8
        rgb = pixels.copy()
        rgb[..., : min(c, 3)] = linear_to_srgb(rgb[..., : min(c, 3)])
        data = np.round(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8)
    else:
        raise ForestError(f"{path}: unsupported image format {ext or '(none)'}; use .exr or .png")
    spec = oiio.ImageSpec(w, h, c, fmt)
    if c == 1:
        spec.channelnames = ("Y",)
    elif c == 4:
        spec.channelnames = ("R", "G", "B", "A")
        spec.alpha_channel = 3
    if ext == ".exr":
        spec.attribute("compression", "zip")
    if ext in (".exr", ".tif", ".tiff"):
        spec.attribute("DateTime", "")  # OpenEXR and TIFF output otherwise stamp the time: not byte-identical
    if ext == ".png":
        spec.attribute("png:compressionLevel", 6)
    _set_attributes(spec, attributes)
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise ForestError(f"{path}: cannot write image: {oiio.geterror()}")
        try:
            if not out.open(str(tmp), spec):
                raise ForestError(f"{path}: cannot write image: {out.geterror()}")
            if not out.write_image(np.ascontiguousarray(data)):
                raise _write_failed(path, tmp, out.geterror())
        except BaseException:
            out.close()
            raise
        _finish(out, path, tmp)
    return path


def write_multilayer_exr(path: str | Path, layers: dict[str, np.ndarray], *, attributes: dict | None = None) -> Path:
    """Write several named layers (``{"": rgb, "depth": z, …}``) into one float EXR, atomically."""
    channels: dict[str, np.ndarray] = {}
    for layer, arr in layers.items():
        arr = np.asarray(arr, dtype=np.float32)
        if arr.ndim == 2:
            arr = arr[..., None]
        base = (
            ("R", "G", "B", "A")[: arr.shape[2]]
            if arr.shape[2] in (3, 4)
            else (("Z",) if arr.shape[2] == 1 else tuple(f"c{i}" for i in range(arr.shape[2])))
        )
        for i, b in enumerate(base):
            channels[f"{layer}.{b}" if layer else b] = arr[..., i]
    return write_exr_channels(path, channels, attributes=attributes)


def write_exr_channels(
    path: str | Path,
    channels: dict[str, np.ndarray],
    *,
    attributes: dict | None = None,
    half: frozenset[str] | set[str] = frozenset(),
    compression: str = "zip",
) -> Path:
    """Write named ``(H, W)`` channels (``{"R": …, "depth.Z": …, "CryptoObject00.R": …}``) to one EXR, atomically.

    Channels are float32 except those named in ``half``.  Lossless
    ``compression`` (OpenEXR's ``zip`` by default; ``zip:1`` is the fastest zlib
    level), no time stamp and sorted header attributes (see
    :func:`_set_attributes`), so the same pixels and attributes give a
    byte-identical file.  An ``A`` channel is flagged as the image's alpha.
    """
    oiio = _oiio()
    path = Path(path)
    if not channels:
        raise ValueError("write_exr_channels needs at least one channel")
    names = list(channels)
    planes = [np.asarray(channels[n], dtype=np.float32) for n in names]
    shape = planes[0].shape
    if len(shape) != 2 or any(p.shape != shape for p in planes):
        raise ValueError(f"every channel must be one (H, W) plane of the same size: {[p.shape for p in planes]}")
    h, w = shape
    data = np.stack(planes, axis=2)
    spec = oiio.ImageSpec(w, h, len(names), oiio.FLOAT)
    spec.channelnames = tuple(names)
    spec.channelformats = tuple(oiio.TypeDesc(oiio.HALF if n in half else oiio.FLOAT) for n in names)
    if "A" in names:
        spec.alpha_channel = names.index("A")
    spec.attribute("compression", compression)
    spec.attribute("DateTime", "")  # no time stamp: byte-identical files
    _set_attributes(spec, attributes)
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec) or not out.write_image(np.ascontiguousarray(data)):
            raise _write_failed(path, tmp, (out.geterror() if out is not None else "") or oiio.geterror())
        _finish(out, path, tmp)
    return path


def read_exr_channels(path: str | Path, *, what: str = "EXR") -> tuple[dict[str, np.ndarray], dict[str, object]]:
    """Every channel of an EXR as float32 ``(H, W)`` planes by name, and its header attributes.

    Matrices come back as 4×4 float64 arrays in the file's order, float arrays
    as tuples.  Raises :class:`ForestError` for a missing or unreadable file.
    """
    path = Path(path)
    if not path.is_file():
        raise ForestError(f"{path}: {what} not found")
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ForestError(f"{path}: cannot read {what}: {oiio.geterror() or 'unknown format'}")
    try:
        spec = inp.spec()
        data = inp.read_image(0, 0, 0, spec.nchannels, "float")
        if data is None or not hasattr(data, "shape"):
            raise ForestError(f"{path}: cannot read {what}: {inp.geterror() or 'corrupt data'}")
        data = np.asarray(data, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
        attrs: dict[str, object] = {}
        for a in spec.extra_attribs:
            value = a.value
            if str(a.type) in ("matrix", "matrix44"):
                value = np.asarray(value, dtype=np.float64).reshape(4, 4)
            attrs[a.name] = value
    finally:
        inp.close()
    return {name: data[..., i] for i, name in enumerate(spec.channelnames)}, attrs


def write_encoded_image(path: str | Path, pixels: np.ndarray, *, attributes: dict | None = None) -> Path:
    """Write already display-encoded ``uint8``/``uint16`` pixels ``(H, W, C)`` to a PNG/TIFF as they are, atomically.

    Unlike :func:`write_image` nothing is converted: the values are the code
    values a view transform produced (:func:`forest.imaging.to_display`).
    """
    oiio = _oiio()
    path = Path(path)
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"write_encoded_image takes uint8 or uint16 pixels, not {pixels.dtype}")
    ext = path.suffix.lower()
    if ext not in (".png", ".tif", ".tiff"):
        raise ForestError(f"{path}: unsupported format {ext or '(none)'} for a display image; use .png")
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, oiio.UINT8 if pixels.dtype == np.uint8 else oiio.UINT16)
    if c == 4:
        spec.channelnames = ("R", "G", "B", "A")
        spec.alpha_channel = 3
    if ext == ".png":
        spec.attribute("png:compressionLevel", 6)
    spec.attribute("oiio:ColorSpace", "srgb_rec709_display")
    _set_attributes(spec, attributes)
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec) or not out.write_image(np.ascontiguousarray(pixels)):
            raise _write_failed(path, tmp, (out.geterror() if out is not None else "") or oiio.geterror())
        _finish(out, path, tmp)
    return path


def resample(img: np.ndarray, height: int, width: int) -> np.ndarray:
    """Area-average / bilinear resize of a float image with OpenImageIO's ImageBufAlgo."""
    oiio = _oiio()
    img = np.asarray(img, dtype=np.float32)
    if img.ndim == 2:
        img = img[..., None]
    src = oiio.ImageBuf(np.ascontiguousarray(img))
    dst = oiio.ImageBufAlgo.resize(src, roi=oiio.ROI(0, width, 0, height, 0, 1, 0, img.shape[2]))
    return np.asarray(dst.get_pixels(oiio.FLOAT), dtype=np.float32).reshape(height, width, img.shape[2])


os.environ.setdefault("OPENIMAGEIO_THREADS", "2")
