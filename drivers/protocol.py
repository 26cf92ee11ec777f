"""The fielddiag DAQ wire protocol: frame encoding, CRCs and a streaming parser. No I/O.

The byte-by-byte description is in ``drivers/PROTOCOL.md``; this module is its reference
implementation. Every frame is::

    A5 5A | type u8 | version u8 | body length u16 | header CRC-16 | body | CRC-32

little-endian, the header CRC-16/CCITT-FALSE over bytes 2..5 and the frame CRC-32
(ISO-HDLC, as :func:`zlib.crc32`) over bytes 2 .. end of body. Two frame types exist:
``INFO`` (the device describes itself) and ``DATA`` (a block of samples). The host sends
ASCII command lines (``INFO``, ``START``, ``STOP``).

:class:`FrameParser` is fed arbitrary byte chunks and returns whole, CRC-checked frames;
it re-synchronises after garbage and counts what it threw away. :class:`TextLineParser`
does the same for the text mode (``t_us,ch0,ch1,...`` lines).
"""

from __future__ import annotations

import binascii
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

SYNC = b"\xa5\x5a"
PROTOCOL_VERSION = 1
TYPE_DATA = 0x01
TYPE_INFO = 0x02

HEADER_LEN = 8
CRC_LEN = 4
DATA_HEADER_LEN = 16
INFO_FIXED_LEN = 48
INFO_CHANNEL_LEN = 12
MAX_CHANNELS = 64
MAX_SAMPLES_PER_FRAME = 4096

#: Sample format code -> numpy dtype (little-endian) of one sample.
SAMPLE_FORMATS: dict[int, np.dtype] = {
    1: np.dtype("<i2"),
    2: np.dtype("<i4"),
    3: np.dtype("<f4"),
}
FORMAT_NAMES = {1: "int16", 2: "int32", 3: "float32"}
FORMAT_CODES = {v: k for k, v in FORMAT_NAMES.items()}

#: Channel role code (INFO frame) -> fielddiag channel role.
ROLE_CODES = {0: "other", 1: "wheel", 2: "body", 3: "acceleration", 4: "force", 5: "displacement"}
ROLE_NUMBERS = {v: k for k, v in ROLE_CODES.items()}

CMD_INFO = b"INFO\n"
CMD_START = b"START\n"
CMD_STOP = b"STOP\n"

_HDR_CHECK = struct.Struct("<BBHH")
_HDR_TAIL = struct.Struct("<BBH")
_DATA_HDR = struct.Struct("<IQBBH")
_INFO_FIXED = struct.Struct("<BBHd16s16sBBH")
_INFO_CH = struct.Struct("<dBBH")
_CRC32 = struct.Struct("<I")


def crc16_ccitt(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final XOR)."""
    return binascii.crc_hqx(data, 0xFFFF)


def crc32(data: bytes) -> int:
    """CRC-32/ISO-HDLC (the zlib/Ethernet CRC-32)."""
    return zlib.crc32(data) & 0xFFFFFFFF


def _frame(frame_type: int, body: bytes) -> bytes:
    if len(body) > 0xFFFF:
        raise ValueError(f"frame body of {len(body)} bytes exceeds 65535")
    tail = _HDR_TAIL.pack(frame_type, PROTOCOL_VERSION, len(body))
    head = SYNC + tail + struct.pack("<H", crc16_ccitt(tail))
    return head + body + _CRC32.pack(crc32(head[2:] + body))


# ---------------------------------------------------------------------------------- frames
@dataclass(frozen=True)
class ChannelInfo:
    """One channel as the device describes it in its INFO frame."""

    full_scale_mps2: float
    role: str = "other"
    axis: str = "z"


@dataclass(frozen=True)
class DeviceInfo:
    """The device-info handshake (INFO frame).

    Parameters
    ----------
    serial_number, model : str
        Up to 16 ASCII characters each.
    sample_rate_hz : float
        Nominal sample rate on the device clock.
    sample_format : int
        Key of :data:`SAMPLE_FORMATS`.
    samples_per_frame : int
        Samples per channel in every DATA frame of a run (constant).
    channels : tuple of ChannelInfo
        Per channel: full scale (the physical value of raw ``2**(bits-1)`` for integer
        formats; float32 samples are already m/s2), role, axis.
    firmware : tuple of int
        (major, minor).
    """

    serial_number: str
    model: str
    sample_rate_hz: float
    sample_format: int
    samples_per_frame: int
    channels: tuple[ChannelInfo, ...]
    firmware: tuple[int, int] = (1, 0)

    @property
    def n_channels(self) -> int:
        return len(self.channels)

    @property
    def dtype(self) -> np.dtype:
        return SAMPLE_FORMATS[self.sample_format]

    def scale(self, channel: int) -> float:
        """Calibration factor raw count -> m/s2 of ``channel``."""
        fs = self.channels[channel].full_scale_mps2
        if self.sample_format == 3:
            return 1.0
        bits = 8 * self.dtype.itemsize
        return fs / float(2 ** (bits - 1))

    def to_dict(self) -> dict:
        return {
            "serial_number": self.serial_number,
            "model": self.model,
            "sample_rate_hz": self.sample_rate_hz,
            "sample_format": FORMAT_NAMES[self.sample_format],
            "samples_per_frame": self.samples_per_frame,
            "firmware": f"{self.firmware[0]}.{self.firmware[1]}",
            "channels": [
                {"full_scale_mps2": c.full_scale_mps2, "role": c.role, "axis": c.axis}
                for c in self.channels
            ],
        }


@dataclass(frozen=True)
class DataFrame:
    """A DATA frame that passed both CRCs. ``payload`` holds the raw interleaved samples."""

    seq: int
    t_us: int
    n_channels: int
    sample_format: int
    n_samples: int
    payload: bytes
    skipped_bytes: int = 0  # bytes discarded (garbage, damaged frames) since the last DATA frame

    @property
    def samples(self) -> np.ndarray:
        """Samples as an (n_samples, n_channels) array of the device's dtype."""
        dt = SAMPLE_FORMATS[self.sample_format]
        return np.frombuffer(self.payload, dtype=dt).reshape(self.n_samples, self.n_channels)


def encode_info(info: DeviceInfo) -> bytes:
    """The INFO frame of ``info``."""
    if not 1 <= info.n_channels <= MAX_CHANNELS:
        raise ValueError(f"1..{MAX_CHANNELS} channels, not {info.n_channels}")
    body = _INFO_FIXED.pack(
        info.n_channels,
        info.sample_format,
        info.samples_per_frame,
        float(info.sample_rate_hz),
        info.serial_number.encode("ascii")[:16],
        info.model.encode("ascii")[:16],
        info.firmware[0],
        info.firmware[1],
        0,
    )
    for c in info.channels:
        body += _INFO_CH.pack(
            float(c.full_scale_mps2), ROLE_NUMBERS.get(c.role, 0), ord(c.axis[:1] or " "), 0
        )
    return _frame(TYPE_INFO, body)


def encode_data(seq: int, t_us: int, samples: np.ndarray, sample_format: int) -> bytes:
    """The DATA frame of ``samples`` ((n_samples, n_channels), cast to the format's dtype)."""
    arr = np.asarray(samples)
    if arr.ndim != 2:
        raise ValueError("samples must be (n_samples, n_channels)")
    n, nch = arr.shape
    dt = SAMPLE_FORMATS[sample_format]
    payload = np.ascontiguousarray(arr, dtype=dt).tobytes()
    head = _DATA_HDR.pack(seq & 0xFFFFFFFF, t_us & 0xFFFFFFFFFFFFFFFF, nch, sample_format, n)
    return _frame(TYPE_DATA, head + payload)


def _decode_info(body: bytes) -> DeviceInfo | None:
    if len(body) < INFO_FIXED_LEN:
        return None
    nch, fmt, spf, rate, sn, model, fw_major, fw_minor, _ = _INFO_FIXED.unpack_from(body, 0)
    if (
        not 1 <= nch <= MAX_CHANNELS
        or fmt not in SAMPLE_FORMATS
        or not 1 <= spf <= MAX_SAMPLES_PER_FRAME
        or not (rate > 0 and np.isfinite(rate))
        or len(body) != INFO_FIXED_LEN + INFO_CHANNEL_LEN * nch
    ):
        return None
    chans = []
    for i in range(nch):
        fs, role, axis, _ = _INFO_CH.unpack_from(body, INFO_FIXED_LEN + INFO_CHANNEL_LEN * i)
        chans.append(
            ChannelInfo(float(fs), ROLE_CODES.get(role, "other"), chr(axis).strip() or "z")
        )
    return DeviceInfo(
        serial_number=sn.rstrip(b"\0").decode("ascii", "replace"),
        model=model.rstrip(b"\0").decode("ascii", "replace"),
        sample_rate_hz=float(rate),
        sample_format=fmt,
        samples_per_frame=spf,
        channels=tuple(chans),
        firmware=(fw_major, fw_minor),
    )


def _decode_data(body: bytes, skipped: int = 0) -> DataFrame | None:
    if len(body) < DATA_HEADER_LEN:
        return None
    seq, t_us, nch, fmt, n = _DATA_HDR.unpack_from(body, 0)
    dt = SAMPLE_FORMATS.get(fmt)
    if (
        dt is None
        or not 1 <= nch <= MAX_CHANNELS
        or not 1 <= n <= MAX_SAMPLES_PER_FRAME
        or len(body) != DATA_HEADER_LEN + n * nch * dt.itemsize
    ):
        return None
    return DataFrame(seq, t_us, nch, fmt, n, body[DATA_HEADER_LEN:], skipped)


# ---------------------------------------------------------------------------------- parser
@dataclass
class ParserCounters:
    """What a :class:`FrameParser` saw. All counts since creation."""

    frames: int = 0
    bytes_received: int = 0
    bytes_discarded: int = 0
    header_errors: int = 0  # sync word found, header CRC-16 wrong (garbage or a hit header)
    crc_errors: int = 0  # header fine, frame CRC-32 wrong: a damaged frame, dropped
    malformed: int = 0  # CRCs fine but the body contradicts itself (a device bug)


class FrameParser:
    """Streaming parser: feed it bytes as they come, get whole CRC-checked frames back.

    Garbage between frames is skipped (counted in ``counters.bytes_discarded``). When a
    header or frame CRC fails, the parser moves one byte past that sync word and searches
    again, so a damaged frame never hides the good frames after it. Bytes that may still
    become a frame are kept until the next :meth:`feed`.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.counters = ParserCounters()
        self._discarded_at_frame = 0

    @property
    def pending_bytes(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[DataFrame | DeviceInfo]:
        """Add received bytes; return the frames completed by them, in order."""
        c = self.counters
        c.bytes_received += len(data)
        buf = self._buf
        buf += data
        out: list[DataFrame | DeviceInfo] = []
        pos = 0
        nbuf = len(buf)
        find = buf.find
        while True:
            i = find(SYNC, pos)
            if i < 0:
                keep = 1 if nbuf > pos and buf[-1] == 0xA5 else 0
                c.bytes_discarded += nbuf - keep - pos
                pos = nbuf - keep
                break
            c.bytes_discarded += i - pos
            pos = i
            if nbuf - i < HEADER_LEN:
                break
            ftype, ver, length, hcrc = _HDR_CHECK.unpack_from(buf, i + 2)
            if (
                binascii.crc_hqx(buf[i + 2 : i + 6], 0xFFFF) != hcrc
                or ver != PROTOCOL_VERSION
                or ftype not in (TYPE_DATA, TYPE_INFO)
            ):
                c.header_errors += 1
                c.bytes_discarded += 1
                pos = i + 1
                continue
            end = i + HEADER_LEN + length + CRC_LEN
            if nbuf < end:
                break
            body_end = end - CRC_LEN
            if zlib.crc32(buf[i + 2 : body_end]) != _CRC32.unpack_from(buf, body_end)[0]:
                c.crc_errors += 1
                c.bytes_discarded += 1
                pos = i + 1
                continue
            body = bytes(buf[i + HEADER_LEN : body_end])
            if ftype == TYPE_DATA:
                frame = _decode_data(body, c.bytes_discarded - self._discarded_at_frame)
            else:
                frame = _decode_info(body)
            if frame is None:
                c.malformed += 1
                c.bytes_discarded += end - i
            else:
                c.frames += 1
                out.append(frame)
                if ftype == TYPE_DATA:
                    # bytes lost before an INFO answer still count for the next DATA frame
                    self._discarded_at_frame = c.bytes_discarded
            pos = end
        if pos:
            del buf[:pos]
        return out


def frames_to_samples(frames: list[DataFrame]) -> np.ndarray:
    """Concatenate the samples of frames with one shape and format into (n, n_channels)."""
    if not frames:
        return np.zeros((0, 0))
    f0 = frames[0]
    dt = SAMPLE_FORMATS[f0.sample_format]
    raw = b"".join(f.payload for f in frames)
    return np.frombuffer(raw, dtype=dt).reshape(-1, f0.n_channels)


# ---------------------------------------------------------------------------- text mode
@dataclass
class TextBatch:
    """Lines parsed by :class:`TextLineParser`: device times and values."""

    t_us: np.ndarray
    values: np.ndarray
    header: list[str] | None = None
    bad_lines: int = 0
    bytes_discarded: int = 0


@dataclass
class TextLineParser:
    """Parse ``t_us,ch0,ch1,...`` lines (text mode) from a byte stream.

    The first valid numeric line fixes the channel count; later lines with another field
    count, a non-number, or longer than ``max_line`` bytes are counted in ``bad_lines`` and
    dropped. Empty lines and lines starting with ``#`` are ignored. A first line made of
    names (``t_us,ax,ay``) is taken as a header naming the channels.
    """

    max_line: int = 512
    n_channels: int | None = None
    header: list[str] | None = None
    bad_lines: int = 0
    bytes_discarded: int = 0
    lines: int = 0
    _buf: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes) -> TextBatch:
        """Add received bytes; return the complete lines they finished."""
        self._buf += data
        *complete, rest = self._buf.split(b"\n")
        if len(rest) > self.max_line:
            self.bad_lines += 1
            self.bytes_discarded += len(rest)
            rest = b""
        self._buf = bytearray(rest)
        times: list[int] = []
        rows: list[list[float]] = []
        for raw in complete:
            line = raw.strip()
            if not line or line.startswith(b"#"):
                continue
            parts = line.split(b",")
            try:
                t = int(parts[0])
                vals = [float(p) for p in parts[1:]]
            except ValueError:
                if self.header is None and self.lines == 0 and self.n_channels is None:
                    names = [p.strip().decode("ascii", "replace") for p in parts[1:]]
                    if names and all(names):
                        self.header = names
                        self.n_channels = len(names)
                        continue
                self.bad_lines += 1
                self.bytes_discarded += len(raw) + 1
                continue
            if self.n_channels is None:
                if not vals:
                    self.bad_lines += 1
                    continue
                self.n_channels = len(vals)
            if len(vals) != self.n_channels or t < 0 or len(line) > self.max_line:
                self.bad_lines += 1
                self.bytes_discarded += len(raw) + 1
                continue
            self.lines += 1
            times.append(t)
            rows.append(vals)
        nch = self.n_channels or 0
        values = np.array(rows, dtype="f8").reshape(len(rows), nch)
        return TextBatch(
            np.array(times, dtype="i8"), values, self.header, self.bad_lines, self.bytes_discarded
        )
