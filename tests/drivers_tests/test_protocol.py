"""The DAQ wire protocol: CRCs, frame round trips, and a parser that survives anything."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from drivers.protocol import (
    SAMPLE_FORMATS,
    SYNC,
    ChannelInfo,
    DataFrame,
    DeviceInfo,
    FrameParser,
    TextLineParser,
    _frame,
    crc16_ccitt,
    crc32,
    encode_data,
    encode_info,
    frames_to_samples,
)

INFO = DeviceInfo(
    serial_number="SN-000123",
    model="ADXL355-DAQ",
    sample_rate_hz=2000.0,
    sample_format=2,
    samples_per_frame=20,
    channels=(
        ChannelInfo(156.9064, "wheel", "z"),
        ChannelInfo(78.4532, "body", "z"),
        ChannelInfo(19.6133, "other", "x"),
    ),
    firmware=(2, 7),
)


def _check_frame_integrity(raw: bytes) -> None:
    """A frame the parser returned must carry both CRCs right (checked independently)."""
    assert raw[:2] == SYNC
    assert struct.unpack_from("<H", raw, 6)[0] == crc16_ccitt(raw[2:6])
    assert struct.unpack_from("<I", raw, len(raw) - 4)[0] == crc32(raw[2:-4])


def test_crc_check_values():
    # The catalogue check values of CRC-16/CCITT-FALSE and CRC-32/ISO-HDLC.
    assert crc16_ccitt(b"123456789") == 0x29B1
    assert crc32(b"123456789") == 0xCBF43926


def test_the_example_frame_of_protocol_md():
    raw = encode_data(7, 1_000_000, np.array([[1, -1], [256, 2]]), 1)
    assert raw.hex(" ") == (
        "a5 5a 01 01 18 00 9e 4f 07 00 00 00 40 42 0f 00 00 00 00 00 "
        "02 01 02 00 01 00 ff ff 00 01 02 00 ec 86 18 b1"
    )


def test_info_round_trip_and_layout():
    raw = encode_info(INFO)
    assert raw[:2] == b"\xa5\x5a" and raw[2] == 0x02 and raw[3] == 1
    body_len = struct.unpack_from("<H", raw, 4)[0]
    assert body_len == 48 + 12 * 3 and len(raw) == 8 + body_len + 4
    _check_frame_integrity(raw)
    (got,) = FrameParser().feed(raw)
    assert got == INFO
    # calibration: int32 full scale 156.9064 m/s2 -> one count = 156.9064 / 2**31
    assert got.scale(0) == pytest.approx(156.9064 / 2**31, rel=1e-15)


@pytest.mark.parametrize("fmt", sorted(SAMPLE_FORMATS))
def test_data_round_trip_every_format(fmt, rng):
    dt = SAMPLE_FORMATS[fmt]
    if dt.kind == "f":
        samples = rng.normal(0, 50, (17, 5)).astype(dt)
    else:
        info = np.iinfo(dt)
        samples = rng.integers(info.min, info.max, (17, 5), endpoint=True).astype(dt)
    raw = encode_data(4_000_000_000, 2**40 + 5, samples, fmt)
    assert len(raw) == 8 + 16 + samples.nbytes + 4
    _check_frame_integrity(raw)
    (f,) = FrameParser().feed(raw)
    assert (f.seq, f.t_us, f.n_channels, f.n_samples) == (4_000_000_000, 2**40 + 5, 5, 17)
    assert f.samples.dtype == dt
    assert f.samples.tobytes() == samples.tobytes()  # bit for bit, NaN payloads included


def test_byte_by_byte_and_every_split(rng):
    frames = [encode_data(k, 10_000 * k, rng.integers(-3000, 3000, (4, 2)), 1) for k in range(3)]
    stream = b"".join(frames)
    p = FrameParser()
    out = []
    for b in stream:
        out += p.feed(bytes([b]))
    assert [f.seq for f in out] == [0, 1, 2]
    for cut in range(1, len(stream)):
        p = FrameParser()
        got = p.feed(stream[:cut]) + p.feed(stream[cut:])
        assert [f.seq for f in got] == [0, 1, 2]
        assert p.counters.bytes_discarded == 0


def test_resync_after_garbage_and_counts(rng):
    good = [encode_data(k, k, rng.integers(-9, 9, (3, 2)), 1) for k in range(4)]
    garbage = [b"", b"\x00\xff" * 10, SYNC + b"\x01\x01", b"\xa5" * 7]
    stream = b"".join(g + f for g, f in zip(garbage, good, strict=True))
    p = FrameParser()
    out = p.feed(stream)
    assert [f.seq for f in out] == [0, 1, 2, 3]
    assert p.counters.bytes_discarded == sum(len(g) for g in garbage)
    # the garbage before frame 2 and 3 is reported on those frames
    assert [f.skipped_bytes for f in out] == [0, 20, 4, 7]


def test_damaged_frame_dropped_neighbours_kept(rng):
    frames = [encode_data(k, k, rng.integers(-9, 9, (10, 4)), 2) for k in range(5)]
    bad = bytearray(frames[2])
    bad[40] ^= 0x10  # a bit flip in the samples
    p = FrameParser()
    out = p.feed(frames[0] + frames[1] + bytes(bad) + frames[3] + frames[4])
    assert [f.seq for f in out] == [0, 1, 3, 4]
    assert p.counters.crc_errors == 1
    # a corrupted length field is caught by the header CRC without waiting for the body
    hdr = bytearray(frames[2])
    hdr[5] ^= 0x7F
    p = FrameParser()
    out = p.feed(frames[0] + bytes(hdr) + frames[3])
    assert [f.seq for f in out] == [0, 3]
    assert p.counters.header_errors == 1


def test_bytes_lost_before_an_info_answer_count_for_the_next_data_frame(rng):
    """A damaged DATA frame followed by an INFO answer (the host asked again after a
    reconnect) and then good DATA: the next DATA frame still reports the bytes thrown
    away, so the missing frame is blamed on damage, not on the device."""
    frames = [encode_data(k, k, rng.integers(-9, 9, (10, 4)), 2) for k in range(3)]
    bad = bytearray(frames[1])
    bad[30] ^= 0x01
    out = FrameParser().feed(frames[0] + bytes(bad) + encode_info(INFO) + frames[2])
    assert [type(f).__name__ for f in out] == ["DataFrame", "DeviceInfo", "DataFrame"]
    assert out[0].skipped_bytes == 0
    assert out[2].skipped_bytes == len(bad)


def test_frames_to_samples_concatenates_in_order(rng):
    parts = [rng.integers(-100, 100, (6, 3)).astype("<i2") for _ in range(4)]
    frames = FrameParser().feed(b"".join(encode_data(k, 0, s, 1) for k, s in enumerate(parts)))
    assert np.array_equal(frames_to_samples(frames), np.concatenate(parts))


# ------------------------------------------------------------------ property-based
@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(chunks=st.lists(st.binary(max_size=300), max_size=12))
def test_arbitrary_bytes_never_crash_nor_yield_a_bad_frame(chunks):
    p = FrameParser()
    for c in chunks:
        for f in p.feed(c):
            if isinstance(f, DataFrame):
                raw = encode_data(f.seq, f.t_us, f.samples, f.sample_format)
                # re-encoding gives the same bytes, so the parser only accepted a frame
                # whose CRCs were right
                _check_frame_integrity(raw)
                assert f.payload == raw[24:-4]
    c = p.counters
    assert c.bytes_discarded + p.pending_bytes <= c.bytes_received
    assert p.pending_bytes <= 8 + 65535 + 4


_frame_strategy = st.builds(
    lambda seq, t, nch, n, fmt, seed: (
        seq,
        t,
        fmt,
        np.random.default_rng(seed).integers(-(2**15), 2**15, (n, nch)).astype(SAMPLE_FORMATS[fmt]),
    ),
    st.integers(0, 2**32 - 1),
    st.integers(0, 2**64 - 1),
    st.integers(1, 8),
    st.integers(1, 30),
    st.sampled_from([1, 2, 3]),
    st.integers(0, 2**31),
)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    frames=st.lists(_frame_strategy, min_size=1, max_size=6),
    garbage=st.lists(st.binary(max_size=80), min_size=7, max_size=7),
    split=st.integers(1, 64),
)
def test_valid_frames_survive_any_garbage_between_them(frames, garbage, split):
    stream = b""
    for i, (seq, t, fmt, s) in enumerate(frames):
        stream += garbage[i] + encode_data(seq, t, s, fmt)
    stream += garbage[-1]
    p = FrameParser()
    out: list = []
    for k in range(0, len(stream), split):
        out += p.feed(stream[k : k + split])
    got = [f for f in out if isinstance(f, DataFrame)]
    assert [(f.seq, f.t_us) for f in got] == [(seq, t) for seq, t, _, _ in frames]
    for f, (_, _, _, s) in zip(got, frames, strict=True):
        assert f.samples.tobytes() == s.tobytes()


def _feed_in_pieces(stream: bytes, split: int) -> tuple[FrameParser, list]:
    p = FrameParser()
    out: list = []
    for k in range(0, len(stream), split):
        out += p.feed(stream[k : k + split])
    return p, out


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31),
    flips=st.lists(st.tuples(st.integers(0, 10**6), st.integers(1, 255)), min_size=1, max_size=6),
    split=st.integers(1, 300),
)
def test_byte_flips_in_valid_frames_never_yield_a_damaged_frame(seed, flips, split):
    """Random bytes almost never pass a CRC; flipped bytes inside real frames test the
    property that matters: only frames exactly as sent come out, and every frame the
    flips missed still does."""
    rng = np.random.default_rng(seed)
    frames = [encode_data(k, 1000 * k, rng.integers(-(2**15), 2**15, (5, 3)), 1) for k in range(6)]
    stream = bytearray(b"".join(frames))
    for pos, xor in flips:
        stream[pos % len(stream)] ^= xor
    starts = np.cumsum([0, *map(len, frames)])
    intact = [f for f, a in zip(frames, starts, strict=False) if bytes(stream[a : a + len(f)]) == f]
    p, out = _feed_in_pieces(bytes(stream), split)
    got = [encode_data(f.seq, f.t_us, f.samples, f.sample_format) for f in out]
    for raw in got:
        assert raw in frames  # an original frame, byte for byte
        _check_frame_integrity(raw)
    assert got == intact  # a damaged frame never hides an intact neighbour
    c = p.counters
    assert c.frames == len(intact) and c.malformed == 0
    assert c.bytes_discarded + p.pending_bytes == len(stream) - sum(map(len, intact))


def _data_body_is_valid(body: bytes) -> bool:
    """The rules of a DATA body (PROTOCOL.md), checked independently of the parser."""
    if len(body) < 16:
        return False
    nch, fmt, n = body[12], body[13], int.from_bytes(body[14:16], "little")
    size = {1: 2, 2: 4, 3: 4}.get(fmt)
    return (
        size is not None and 1 <= nch <= 64 and 1 <= n <= 4096 and len(body) == 16 + n * nch * size
    )


def _info_body_is_valid(body: bytes) -> bool:
    """The rules of an INFO body (PROTOCOL.md), checked independently of the parser."""
    if len(body) < 48:
        return False
    nch, fmt, spf = body[0], body[1], int.from_bytes(body[2:4], "little")
    (rate,) = struct.unpack_from("<d", body, 4)
    return (
        1 <= nch <= 64
        and fmt in (1, 2, 3)
        and 1 <= spf <= 4096
        and np.isfinite(rate)
        and rate > 0
        and len(body) == 48 + 12 * nch
    )


_BAD_FIELD_VALUES = {
    "n_channels": [0, 65, 255],
    "format": [0, 4, 255],
    "samples": [0, 4097, 65535],
    "rate": [0.0, -1.0, float("nan"), float("inf"), float("-inf")],
    "length": [-12, -4, -1, 1, 4, 12],
}


@st.composite
def _bodies(draw, frame_type: int) -> bytes:
    """Arbitrary bodies: random bytes, bodies that follow the rules, and bodies that break
    exactly one rule (a field out of range, or a length off by a little)."""
    kind = draw(st.sampled_from(["random", "valid", "one rule broken"]))
    if kind == "random":
        return draw(st.binary(max_size=400))
    broken = None
    if kind == "one rule broken":
        rules = ["n_channels", "format", "samples", "length"]
        broken = draw(st.sampled_from(rules + (["rate"] if frame_type == 2 else [])))

    def field(name: str, good: list):
        return draw(st.sampled_from(_BAD_FIELD_VALUES[name] if name == broken else good))

    nch = field("n_channels", [1, 2, 3, 8, 64])
    fmt = field("format", [1, 2, 3])
    if frame_type == 1:
        n = field("samples", [1, 2, 5, 20, 4096])
        size = n * nch * {1: 2, 2: 4, 3: 4}.get(fmt, 2)
        if size > 60_000 and broken != "samples":  # keep the body under 65535 bytes
            n = 60_000 // (size // n)
            size = n * nch * {1: 2, 2: 4, 3: 4}.get(fmt, 2)
        seq, t_us = draw(st.integers(0, 2**32 - 1)), draw(st.integers(0, 2**64 - 1))
        head = struct.pack("<IQBBH", seq, t_us, nch, fmt, n)
    else:
        spf = field("samples", [1, 20, 4096])
        rate = (
            field("rate", [1e-3, 1.0, 2000.0, 1e6])
            if broken == "rate"
            else draw(st.floats(1e-3, 1e6))
        )
        serial, model = draw(st.binary(max_size=16)), draw(st.binary(max_size=16))
        fw = draw(st.tuples(st.integers(0, 255), st.integers(0, 255)))
        head = struct.pack("<BBHd16s16sBBH", nch, fmt, spf, rate, serial, model, *fw, 0)
        size = 12 * nch  # channel records: random bytes (any full scale, role, axis)
    if broken == "length":
        size = max(0, size + draw(st.sampled_from(_BAD_FIELD_VALUES["length"])))
    size = min(size, 60_000)  # a frame body holds at most 65535 bytes
    payload = np.random.default_rng(draw(st.integers(0, 2**32 - 1))).bytes(size)
    return head + payload


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), frame_type=st.sampled_from([1, 2]), splits=st.lists(st.integers(1, 99)))
def test_valid_envelope_around_any_body_decodes_or_counts_malformed(data, frame_type, splits):
    """Both CRCs right, body anything: a DATA or INFO body that follows the rules is
    decoded to exactly its fields; any other is counted as malformed and dropped."""
    body = data.draw(_bodies(frame_type), label="body")
    raw = _frame(frame_type, body)
    cuts = sorted({c % len(raw) for c in splits} - {0})
    p = FrameParser()
    out: list = []
    for a, b in zip([0, *cuts], [*cuts, len(raw)], strict=True):
        out += p.feed(raw[a:b])
    c = p.counters
    assert p.pending_bytes == 0 and c.header_errors == 0 and c.crc_errors == 0
    valid = _data_body_is_valid(body) if frame_type == 1 else _info_body_is_valid(body)
    event(f"type {frame_type} {'valid' if valid else 'malformed'}")
    if not valid:
        assert out == [] and c.malformed == 1 and c.bytes_discarded == len(raw)
        return
    assert c.malformed == 0 and c.bytes_discarded == 0 and len(out) == 1
    (f,) = out
    if frame_type == 1:
        assert isinstance(f, DataFrame)
        assert encode_data(f.seq, f.t_us, f.samples, f.sample_format) == raw
        assert f.samples.shape == (f.n_samples, f.n_channels)
    else:
        assert isinstance(f, DeviceInfo)
        nch, fmt, spf, rate = struct.unpack_from("<BBHd", body)
        assert (f.n_channels, f.sample_format, f.samples_per_frame) == (nch, fmt, spf)
        assert f.sample_rate_hz == rate and f.firmware == (body[44], body[45])
        for i, ch in enumerate(f.channels):
            (fs,) = struct.unpack_from("<d", body, 48 + 12 * i)
            assert ch.full_scale_mps2 == fs or (np.isnan(fs) and np.isnan(ch.full_scale_mps2))
        assert f.serial_number == body[12:28].rstrip(b"\0").decode("ascii", "replace")
        assert f.model == body[28:44].rstrip(b"\0").decode("ascii", "replace")


# ------------------------------------------------------------------ text mode
def test_text_lines_header_partial_lines_and_bad_lines():
    p = TextLineParser()
    b1 = p.feed(b"# comment\nt_us,ax,ay\n1000,0.5,-1.25\n2000,0.75,-1")
    assert p.header == ["ax", "ay"]
    assert b1.t_us.tolist() == [1000] and b1.values.tolist() == [[0.5, -1.25]]
    b2 = p.feed(b".5\n3000,1.0\nbad,line,x\n4000,2,3\n\n")
    assert b2.t_us.tolist() == [2000, 4000]
    assert b2.values.tolist() == [[0.75, -1.5], [2.0, 3.0]]
    assert p.bad_lines == 2  # wrong field count, non-numeric time


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=2000))
def test_text_parser_arbitrary_bytes(data):
    p = TextLineParser()
    b = p.feed(data)
    assert b.values.shape == (b.t_us.size, p.n_channels or 0)
    assert np.all(np.isfinite(b.t_us))
