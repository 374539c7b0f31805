"""Frame messages and box messages: layouts round trip; every malformed payload is named, never
raises."""

import json
import struct

import numpy as np
import pytest

from thinkfast.perception.boxes import Box, Boxes, BoxRejection, parse_boxes, pick_box, same_frame
from thinkfast.perception.frame import (
    FRAME_REJECT_REASONS,
    MAGIC,
    Frame,
    FrameRejection,
    encode_frame,
    frame_buffer,
    parse_frame,
)

K = (532.0, 531.5, 639.2, 359.8)


def _images(w=64, h=48, ch=3, xyz_shape=None, dtype=np.float32, seed=0):
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (h, w, ch), dtype=np.uint8)
    xyz = rng.normal(3.0, 1.0, xyz_shape or (h, w, 3)).astype(dtype)
    xyz[0, 0] = np.nan
    return img, xyz


def _header_and_body(payload: bytes) -> tuple[dict, bytes]:
    n = struct.unpack_from("<I", payload, 4)[0]
    return json.loads(payload[8 : 8 + n]), payload[8 + n :]


def _with_header(payload: bytes, **changes) -> bytes:
    h, body = _header_and_body(payload)
    for k, v in changes.items():
        if v is None:
            h.pop(k, None)
        else:
            h[k] = v
    text = json.dumps(h).encode()
    return MAGIC + struct.pack("<I", len(text)) + text + body


@pytest.mark.parametrize(
    ("ch", "dtype", "xyz_shape", "roi", "unit"),
    [
        (3, np.float32, None, None, "m"),
        (4, np.float16, (24, 32, 4), None, "mm"),  # ZED's XYZ at half resolution, millimetres
        (3, np.float32, (10, 20, 3), (30, 8, 20, 10), "m"),  # a region around the ball
    ],
)
def test_frames_round_trip_without_copying(ch, dtype, xyz_shape, roi, unit):
    img, xyz = _images(ch=ch, xyz_shape=xyz_shape, dtype=dtype)
    payload = encode_frame(1763800000.25, K, img, xyz, seq=17, xyz_roi=roi, xyz_unit=unit)
    f = parse_frame(payload)
    assert isinstance(f, Frame), f
    assert (f.stamp, f.seq, f.width, f.height) == (1763800000.25, 17, 64, 48)
    assert (f.fx, f.fy, f.cx, f.cy) == K
    np.testing.assert_array_equal(f.image, img)
    np.testing.assert_array_equal(f.xyz, xyz)
    assert f.xyz_roi == (roi or (0, 0, 64, 48))
    assert f.xyz_scale == (1e-3 if unit == "mm" else 1.0)
    assert not f.image.flags.writeable and not f.xyz.flags.writeable
    assert np.shares_memory(f.image, np.frombuffer(payload, np.uint8))


def test_a_frame_buffer_is_filled_in_place_and_parses_back():
    fb = frame_buffer(5.0, K, (40, 30), None, "bgr8", "float16", 3, (20, 15), (0, 0, 40, 30))
    fb.image[...] = 7
    fb.xyz[...] = 2.5
    f = parse_frame(bytes(fb.payload))
    assert isinstance(f, Frame) and f.seq is None
    assert (f.image == 7).all() and (f.xyz == 2.5).all() and f.xyz.dtype == np.float16


def test_frame_buffer_refuses_layouts_the_parser_would_refuse():
    with pytest.raises(ValueError):
        frame_buffer(1.0, K, (40, 30), xyz_roi=(30, 0, 20, 30))  # ROI beyond the image
    with pytest.raises(ValueError):
        frame_buffer(1.0, K, (40, 30), image_encoding="rgb565")


def _valid() -> bytes:
    img, xyz = _images()
    return encode_frame(100.0, K, img, xyz, seq=3)


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"", "too_short"),
        (b"TFCF", "too_short"),
        (b"XXXX" + b"\0" * 40, "bad_magic"),
        (MAGIC + struct.pack("<I", 10**6) + b"{}", "bad_header"),  # header beyond the payload
        (MAGIC + struct.pack("<I", 4) + b"\xff\xfe{}", "bad_header"),  # not UTF-8
        (MAGIC + struct.pack("<I", 5) + b"[1,2]", "bad_header"),  # not an object
        (MAGIC + struct.pack("<I", 2) + b"{x", "bad_header"),  # not JSON
    ],
)
def test_broken_envelopes_are_named(payload, reason):
    assert parse_frame(payload) == FrameRejection(reason, parse_frame(payload).detail)


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({"version": 2}, "bad_version"),
        ({"format": "other"}, "bad_version"),
        ({"stamp": None}, "bad_stamp"),
        ({"stamp": "now"}, "bad_stamp"),
        ({"stamp": -1.0}, "bad_stamp"),
        ({"seq": -1}, "bad_seq"),
        ({"seq": True}, "bad_seq"),
        ({"width": 0}, "bad_size"),
        ({"height": 2.5}, "bad_size"),
        ({"intrinsics": {"fx": 0.0, "fy": 1.0, "cx": 0.0, "cy": 0.0}}, "bad_intrinsics"),
        ({"intrinsics": [532, 532, 320, 240]}, "bad_intrinsics"),
        ({"image": {"encoding": "rgb8", "bytes": 9216}}, "bad_image"),
        ({"image": {"encoding": "bgr8", "bytes": 9215}}, "bad_image"),
        ({"xyz": {"dtype": "float64", "bytes": 36864}}, "bad_xyz"),
        ({"xyz": {"dtype": "float32", "channels": 2, "bytes": 24576}}, "bad_xyz"),
        ({"xyz": {"dtype": "float32", "roi": [60, 0, 10, 48], "bytes": 5760}}, "bad_xyz"),
        ({"xyz": {"dtype": "float32", "frame": "base", "bytes": 36864}}, "bad_xyz"),
        ({"xyz": {"dtype": "float32", "unit": "inch", "bytes": 36864}}, "bad_xyz"),
        ({"xyz": {"dtype": "float32", "bytes": 36860}}, "bad_xyz"),
    ],
)
def test_each_bad_header_field_is_named(changes, reason):
    got = parse_frame(_with_header(_valid(), **changes))
    assert isinstance(got, FrameRejection) and got.reason == reason, got


def test_truncated_or_padded_buffers_are_bad_length_at_every_cut():
    good = _valid()
    h, body = _header_and_body(good)
    head = len(good) - len(body)
    for cut in range(head, len(good), 997):
        assert parse_frame(good[:cut]).reason == "bad_length", cut
    assert parse_frame(good + b"\0").reason == "bad_length"
    assert parse_frame(good, max_bytes=len(good) - 1).reason == "too_large"


def test_random_and_mutated_bytes_never_raise_and_are_counted_by_known_reasons():
    rng = np.random.default_rng(7)
    good = bytearray(_valid())
    reasons = set()
    for i in range(3000):
        if i % 3 == 0:
            p = rng.integers(0, 256, rng.integers(0, 300), dtype=np.uint8).tobytes()
        else:  # flip bytes in the header region of a valid frame
            p = bytearray(good)
            for k in rng.integers(0, 300, rng.integers(1, 6)):
                p[int(k)] = int(rng.integers(0, 256))
            p = bytes(p)
        got = parse_frame(p)
        assert isinstance(got, Frame | FrameRejection)
        if isinstance(got, FrameRejection):
            assert got.reason in FRAME_REJECT_REASONS
            reasons.add(got.reason)
    assert {"too_short", "bad_magic", "bad_header"} <= reasons
    assert parse_frame("text").reason == "not_bytes"


def test_boxes_parse_match_and_pick():
    msg = {
        "stamp": 12.5,
        "seq": 4,
        "boxes": [
            {"xyxy": [10, 20, 30, 44], "score": 0.4, "label": "sports ball"},
            {"xyxy": [100, 20, 130, 44], "score": 0.9, "label": "person"},
            {"xyxy": [50.5, 60, 70, 80]},
        ],
    }
    b = parse_boxes(json.dumps(msg).encode())
    assert isinstance(b, Boxes) and (b.stamp, b.seq, len(b.boxes)) == (12.5, 4, 3)
    assert pick_box(b, 0.3) == Box(50.5, 60, 70, 80, 1.0, "")  # no score: 1
    assert pick_box(b, 0.3, "sports ball") == Box(10, 20, 30, 44, 0.4, "sports ball")
    assert pick_box(b, 0.5, "sports ball") is None
    assert same_frame(12.5, 4, 12.5, 4) and not same_frame(12.5, 4, 12.5, 5)
    assert same_frame(12.5, None, 12.50001, 9) and not same_frame(12.5, None, 12.52, None)


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"\xff", "not_utf8"),
        (b"{", "not_json"),
        (b"[]", "not_object"),
        (b'{"boxes": []}', "bad_stamp"),
        (b'{"stamp": 1, "seq": -2, "boxes": []}', "bad_seq"),
        (b'{"stamp": 1}', "bad_boxes"),
        (b'{"stamp": 1, "boxes": [{"xyxy": [5, 5, 4, 9]}]}', "bad_boxes"),  # x1 < x0
        (b'{"stamp": 1, "boxes": [{"xyxy": [1, 2, 3, 4], "score": 1.5}]}', "bad_boxes"),
        (b'{"stamp": 1, "boxes": [{"xyxy": [1, 2, NaN, 4]}]}', "bad_boxes"),
        (b" " * 70000, "too_large"),
    ],
)
def test_bad_box_messages_are_named(payload, reason):
    got = parse_boxes(payload)
    assert isinstance(got, BoxRejection) and got.reason == reason, got
