"""Camera frame messages (``<prefix>/camera/frame``): one binary payload per stereo frame.

Layout (docs/CAMERA_FRAMES.md)::

    b"TFCF" | uint32 little endian H | H bytes of UTF-8 JSON header | image bytes | xyz bytes

The header names the capture stamp, the left camera's intrinsics, and how the two raw buffers
that follow are laid out: the rectified left image (``bgr8`` or ``bgra8``, row major, no padding)
and the XYZ point-cloud image (float32 or float16, 3 or 4 channels, metres or millimetres,
``camera`` frame) covering a rectangle ``roi`` of the left image at its own resolution (a bridge
may send it at half resolution, or only around the ball). The payload's length must be exactly
the header's plus both buffers'.

:func:`parse_frame` never raises: it returns a :class:`Frame` whose arrays are read-only views
into the payload (no copy), or a :class:`FrameRejection` naming one of
:data:`FRAME_REJECT_REASONS`. :func:`frame_buffer` builds a payload whose image and XYZ views the
sender fills in place (one copy per frame).
"""

from __future__ import annotations

import json
import struct
from typing import Any, NamedTuple

import numpy as np

from thinkfast.contract.detection import finite_number

MAGIC = b"TFCF"
FORMAT = "thinkfast-camera-frame"
VERSION = 1
PREFIX = struct.Struct("<4sI")
MAX_HEADER = 16384  # bytes
IMAGE_ENCODINGS = {"bgr8": 3, "bgra8": 4}
XYZ_DTYPES = {"float32": np.dtype("<f4"), "float16": np.dtype("<f2")}
XYZ_UNITS = {"m": 1.0, "mm": 1e-3}
FRAME_REJECT_REASONS = (
    "not_bytes", "too_short", "too_large", "bad_magic", "bad_header", "bad_version", "bad_stamp",
    "bad_seq", "bad_size", "bad_intrinsics", "bad_image", "bad_xyz", "bad_length",
)  # fmt: skip


class Frame(NamedTuple):
    """One decoded frame (arrays are read-only views into the payload).

    Attributes:
        stamp: capture time [s since the Unix epoch].
        seq: sender's frame counter, or None.
        width, height: left image size [px].
        fx, fy, cx, cy: rectified left camera intrinsics [px] (pixel centres at integers).
        image: left image, shape (height, width, 3 or 4), uint8, BGR(A).
        xyz: point-cloud image, shape (h, w, 3 or 4), float32 or float16, in ``xyz_unit`` units,
            ``camera`` frame (x forward, y left, z up); non-finite where there is no depth.
        xyz_roi: rectangle of the left image that ``xyz`` covers: (x, y, w, h) [px].
        xyz_scale: metres per ``xyz`` unit (1.0 or 0.001).
    """

    stamp: float
    seq: int | None
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    image: np.ndarray
    xyz: np.ndarray
    xyz_roi: tuple[int, int, int, int]
    xyz_scale: float


class FrameRejection(NamedTuple):
    """A refused frame payload: ``reason`` in :data:`FRAME_REJECT_REASONS`, ``detail`` for logs."""

    reason: str
    detail: str = ""


def _int(v: Any) -> int | None:
    return v if isinstance(v, int) and not isinstance(v, bool) else None


def _image_layout(h: dict, width: int, height: int) -> tuple[int, int] | str:
    """(channels, bytes) of the image block, or a problem."""
    img = h.get("image")
    if not isinstance(img, dict):
        return "image: expected an object"
    ch = IMAGE_ENCODINGS.get(img.get("encoding")) if isinstance(img.get("encoding"), str) else None
    if ch is None:
        return f"image.encoding {img.get('encoding')!r} not in {', '.join(IMAGE_ENCODINGS)}"
    n = _int(img.get("bytes"))
    if n != width * height * ch:
        return f"image.bytes {img.get('bytes')!r} != {width * height * ch}"
    return ch, n


def _xyz_layout(h: dict, width: int, height: int) -> tuple | str:
    """(dtype, channels, w, h, roi, scale, bytes) of the XYZ block, or a problem."""
    x = h.get("xyz")
    if not isinstance(x, dict):
        return "xyz: expected an object"
    dt = x.get("dtype", "float32")
    if not isinstance(dt, str) or dt not in XYZ_DTYPES:
        return f"xyz.dtype {dt!r} not in {', '.join(XYZ_DTYPES)}"
    ch = _int(x.get("channels", 3))
    if ch not in (3, 4):
        return f"xyz.channels {x.get('channels')!r} not 3 or 4"
    unit = x.get("unit", "m")
    if not isinstance(unit, str) or unit not in XYZ_UNITS:
        return f"xyz.unit {unit!r} not in m, mm"
    if x.get("frame", "camera") != "camera":
        return f"xyz.frame {x.get('frame')!r} is not camera"
    roi = x.get("roi", [0, 0, width, height])
    if not isinstance(roi, list) or len(roi) != 4 or any(_int(v) is None for v in roi):
        return f"xyz.roi {roi!r}: expected 4 integers"
    rx, ry, rw, rh = roi
    if rx < 0 or ry < 0 or rw < 1 or rh < 1 or rx + rw > width or ry + rh > height:
        return f"xyz.roi {roi!r} outside the {width}x{height} image"
    w, hh = _int(x.get("width", rw)), _int(x.get("height", rh))
    if w is None or hh is None or not (1 <= w <= rw and 1 <= hh <= rh):
        return f"xyz.width/height {x.get('width')!r}x{x.get('height')!r} not in 1..roi size"
    n = _int(x.get("bytes"))
    want = w * hh * ch * XYZ_DTYPES[dt].itemsize
    if n != want:
        return f"xyz.bytes {x.get('bytes')!r} != {want}"
    return XYZ_DTYPES[dt], ch, w, hh, (rx, ry, rw, rh), XYZ_UNITS[unit], n


def _check_header(h: Any) -> tuple | FrameRejection:
    """Header fields and buffer layouts, or the first problem."""
    if not isinstance(h, dict):
        return FrameRejection("bad_header", f"not an object: {type(h).__name__}")
    if h.get("format", FORMAT) != FORMAT or h.get("version") != VERSION:
        return FrameRejection("bad_version", f"{h.get('format')!r} v{h.get('version')!r}")
    stamp = finite_number(h.get("stamp"))
    if stamp is None or stamp < 0.0:
        return FrameRejection("bad_stamp", repr(h.get("stamp"))[:80])
    seq = h.get("seq")
    if seq is not None and (_int(seq) is None or not 0 <= seq < 2**63):
        return FrameRejection("bad_seq", repr(seq)[:80])
    width, height = _int(h.get("width")), _int(h.get("height"))
    if width is None or height is None or not (1 <= width <= 16384 and 1 <= height <= 16384):
        return FrameRejection("bad_size", f"{h.get('width')!r}x{h.get('height')!r}")
    k = h.get("intrinsics")
    names = ("fx", "fy", "cx", "cy")
    k = [finite_number(k.get(n)) for n in names] if isinstance(k, dict) else [None]
    if any(v is None for v in k) or k[0] <= 0.0 or k[1] <= 0.0:
        return FrameRejection("bad_intrinsics", repr(h.get("intrinsics"))[:80])
    img = _image_layout(h, width, height)
    if isinstance(img, str):
        return FrameRejection("bad_image", img)
    xyz = _xyz_layout(h, width, height)
    if isinstance(xyz, str):
        return FrameRejection("bad_xyz", xyz)
    return stamp, seq, width, height, k, img, xyz


def parse_frame(payload: Any, max_bytes: int = 64 << 20) -> Frame | FrameRejection:
    """Decode one frame payload without copying its buffers.

    Args:
        payload: ``bytes`` or ``bytearray`` (kept alive by the returned views).
        max_bytes: largest payload accepted.

    Returns:
        A :class:`Frame`, or a :class:`FrameRejection` naming the first problem. Never raises.
    """
    if not isinstance(payload, bytes | bytearray):
        return FrameRejection("not_bytes", type(payload).__name__)
    size = len(payload)
    if size > max_bytes:
        return FrameRejection("too_large", f"{size} bytes > {max_bytes}")
    if size < PREFIX.size:
        return FrameRejection("too_short", f"{size} bytes")
    magic, hlen = PREFIX.unpack_from(payload, 0)
    if magic != MAGIC:
        return FrameRejection("bad_magic", repr(magic))
    if hlen > MAX_HEADER or PREFIX.size + hlen > size:
        return FrameRejection("bad_header", f"header length {hlen} in a {size}-byte payload")
    try:
        h = json.loads(bytes(payload[PREFIX.size : PREFIX.size + hlen]).decode("utf-8"))
    except Exception as exc:  # UnicodeDecodeError, JSONDecodeError, RecursionError ...
        return FrameRejection("bad_header", type(exc).__name__)
    layout = _check_header(h)
    if isinstance(layout, FrameRejection):
        return layout
    stamp, seq, width, height, k, (ch, img_bytes), xyz = layout
    dtype, xch, xw, xh, roi, scale, xyz_bytes = xyz
    start = PREFIX.size + hlen
    if size != start + img_bytes + xyz_bytes:
        return FrameRejection(
            "bad_length", f"{size} bytes, header says {start + img_bytes + xyz_bytes}"
        )
    image = np.frombuffer(payload, np.uint8, img_bytes, start).reshape(height, width, ch)
    cloud = np.frombuffer(payload, dtype, xw * xh * xch, start + img_bytes).reshape(xh, xw, xch)
    image.flags.writeable = cloud.flags.writeable = False
    return Frame(stamp, seq, width, height, *k, image, cloud, roi, scale)


class FrameBuffer(NamedTuple):
    """A frame payload under construction: fill ``image`` and ``xyz`` in place, send ``payload``."""

    payload: bytearray
    image: np.ndarray
    xyz: np.ndarray


def frame_buffer(
    stamp: float,
    intrinsics: tuple[float, float, float, float],
    size: tuple[int, int],
    seq: int | None = None,
    image_encoding: str = "bgr8",
    xyz_dtype: str = "float32",
    xyz_channels: int = 3,
    xyz_size: tuple[int, int] | None = None,
    xyz_roi: tuple[int, int, int, int] | None = None,
    xyz_unit: str = "m",
) -> FrameBuffer:
    """Allocate a frame payload and writable views of its image and XYZ blocks.

    Args:
        stamp: capture time [s since the Unix epoch].
        intrinsics: (fx, fy, cx, cy) of the rectified left image [px].
        size: left image (width, height) [px].
        seq: frame counter, or None.
        image_encoding: ``"bgr8"`` or ``"bgra8"``.
        xyz_dtype: ``"float32"`` or ``"float16"``.
        xyz_channels: 3 (x, y, z) or 4 (ZED's XYZ plus an unused channel).
        xyz_size: XYZ image (width, height) [px]; default the ROI's size.
        xyz_roi: (x, y, w, h) of the left image the XYZ image covers; default the whole image.
        xyz_unit: ``"m"`` or ``"mm"``.

    Raises:
        ValueError: a layout :func:`parse_frame` would refuse.
    """
    if image_encoding not in IMAGE_ENCODINGS or xyz_dtype not in XYZ_DTYPES:
        raise ValueError(f"unsupported encoding {image_encoding!r} or dtype {xyz_dtype!r}")
    width, height = size
    roi = tuple(xyz_roi) if xyz_roi is not None else (0, 0, width, height)
    xw, xh = xyz_size if xyz_size is not None else roi[2:]
    ch = IMAGE_ENCODINGS[image_encoding]
    dtype = XYZ_DTYPES[xyz_dtype]
    header = {
        "format": FORMAT,
        "version": VERSION,
        "stamp": float(stamp),
        "seq": seq,
        "width": width,
        "height": height,
        "intrinsics": dict(zip(("fx", "fy", "cx", "cy"), map(float, intrinsics), strict=True)),
        "image": {"encoding": image_encoding, "bytes": width * height * ch},
        "xyz": {
            "dtype": xyz_dtype,
            "channels": xyz_channels,
            "unit": xyz_unit,
            "frame": "camera",
            "roi": list(roi),
            "width": xw,
            "height": xh,
            "bytes": xw * xh * xyz_channels * dtype.itemsize,
        },
    }
    if seq is None:
        del header["seq"]
    text = json.dumps(header, separators=(",", ":")).encode("utf-8")
    start = PREFIX.size + len(text)
    n_img, n_xyz = header["image"]["bytes"], header["xyz"]["bytes"]
    buf = bytearray(start + n_img + n_xyz)
    PREFIX.pack_into(buf, 0, MAGIC, len(text))
    buf[PREFIX.size : start] = text
    check = _check_header(json.loads(text))
    if isinstance(check, FrameRejection):
        raise ValueError(f"invalid frame layout: {check.reason}: {check.detail}")
    image = np.frombuffer(buf, np.uint8, n_img, start).reshape(height, width, ch)
    xyz = np.frombuffer(buf, dtype, xw * xh * xyz_channels, start + n_img).reshape(
        xh, xw, xyz_channels
    )
    return FrameBuffer(buf, image, xyz)


def encode_frame(
    stamp: float,
    intrinsics: tuple[float, float, float, float],
    image: np.ndarray,
    xyz: np.ndarray,
    seq: int | None = None,
    xyz_roi: tuple[int, int, int, int] | None = None,
    xyz_unit: str = "m",
) -> bytes:
    """A frame payload from a BGR(A) image (H, W, 3|4) uint8 and an XYZ image (h, w, 3|4) float.

    Raises:
        ValueError: unsupported dtype, channel count or ROI.
    """
    image = np.asarray(image)
    xyz = np.asarray(xyz)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"image must be (H, W, 3|4) uint8, got {image.shape} {image.dtype}")
    names = {np.dtype(np.float32): "float32", np.dtype(np.float16): "float16"}
    if xyz.ndim != 3 or xyz.dtype not in names:
        raise ValueError(f"xyz must be (h, w, 3|4) float32/float16, got {xyz.shape} {xyz.dtype}")
    fb = frame_buffer(
        stamp,
        intrinsics,
        (image.shape[1], image.shape[0]),
        seq,
        "bgr8" if image.shape[2] == 3 else "bgra8",
        names[xyz.dtype],
        xyz.shape[2],
        (xyz.shape[1], xyz.shape[0]),
        xyz_roi,
        xyz_unit,
    )
    fb.image[...] = image
    fb.xyz[...] = xyz
    return bytes(fb.payload)
