"""Encoder bridge protocol: line parser/formatter round trip, checksum, bad lines, counter and clock wrap,
the line splitter, the bridge-to-host clock map and the decoder's rules (restart, implausible jumps)."""

from __future__ import annotations

import math
import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from robot_agent.errors import AgentError
from robot_agent.sensors import encoders
from robot_agent.sensors.encoders import (
    MAX_LINE_BYTES,
    BridgeInfo,
    ClockSync,
    EncoderDecoder,
    EncoderLine,
    EncoderProtocolError,
    LineSplitter,
    checksum,
    format_line,
    parse_line,
    tick_delta,
    wrap_int32,
)
from shared.odometry import MINES_ROVER

U32 = 2**32
I32 = st.integers(-(2**31), 2**31 - 1)
encoder_lines = st.builds(EncoderLine, st.integers(0, U32 - 1), I32, I32)
positive = st.floats(min_value=5e-324, allow_nan=False, allow_infinity=False)
firmware = st.from_regex(re.compile(r"[!-)+-~]{1,32}"), fullmatch=True)
infos = st.builds(BridgeInfo, positive, positive, positive, firmware)
records = st.one_of(encoder_lines, infos)


@given(records, st.booleans())
def test_format_then_parse_round_trips(record: EncoderLine | BridgeInfo, with_checksum: bool) -> None:
    line = format_line(record, with_checksum=with_checksum)
    assert line.endswith(b"\n") and len(line) - 1 <= MAX_LINE_BYTES
    assert parse_line(line) == record
    assert parse_line(line.rstrip(b"\n") + b"\r\n") == record
    if with_checksum:
        assert parse_line(line, require_checksum=True) == record
    else:
        with pytest.raises(EncoderProtocolError, match="expected a '\\*HH' checksum") as err:
            parse_line(line, require_checksum=True)
        assert err.value.kind == "missing checksum"


@given(records, st.data())
def test_a_changed_byte_in_a_checksummed_line_is_caught(
    record: EncoderLine | BridgeInfo, data: st.DataObject
) -> None:
    line = format_line(record).rstrip(b"\n")
    pos = data.draw(st.integers(0, len(line) - 1))
    byte = data.draw(st.integers(0, 255).filter(lambda b: b != line[pos]))
    garbled = line[:pos] + bytes([byte]) + line[pos + 1 :]
    try:
        parsed = parse_line(garbled, require_checksum=True)
    except EncoderProtocolError:
        return
    assert parsed == record  # only a hex digit's case may change and still parse


@given(st.binary(max_size=200))
def test_any_bytes_parse_or_raise_the_protocol_error(data: bytes) -> None:
    error: EncoderProtocolError | None = None
    try:
        parse_line(data)
    except EncoderProtocolError as exc:  # anything else escapes and fails the test
        error = exc
    assert error is None or (error.kind and str(error))


def test_known_lines_and_checksum() -> None:
    assert format_line(EncoderLine(123456, -20, 31)) == b"E 123456 -20 31*4F\n"  # the docstring's example
    assert format_line(BridgeInfo(2000, 154, 330, "uno-bridge-1.0")) == b"I 2000 154 330 uno-bridge-1.0*0F\n"
    assert checksum(b"E 1 2 3") == ord("E") ^ ord("1") ^ ord("2") ^ ord("3") ^ ord(" ")  # 3 spaces
    assert parse_line(b"E 123456 -20 31*4f") == EncoderLine(123456, -20, 31)
    assert parse_line(b"  E  7   -1 2  ") == EncoderLine(7, -1, 2)
    assert parse_line(b"I 2000 154.0 1.5e3 fw") == BridgeInfo(2000.0, 154.0, 1500.0, "fw")
    assert parse_line(b"") is None and parse_line(b"   \r\n") is None
    assert parse_line(b"# booting, battery 12.1 V *junk") is None
    drive = BridgeInfo(2000, 154, 330, "fw").to_drive()
    assert drive.metres_per_tick == pytest.approx(MINES_ROVER.metres_per_tick)
    assert drive.tread_m == pytest.approx(0.330)


@pytest.mark.parametrize(
    ("line", "kind", "says"),
    [
        (b"E 1 2 3*4E", "bad checksum", "does not match"),
        (b"E 1 2 3*G1", "bad checksum", "two hex digits"),
        (b"E 1 2 3*", "bad checksum", "two hex digits"),
        (b"E 1 2", "field count", "expected 'E <t_ms> <left_ticks> <right_ticks>'"),
        (b"E 1 2 3 4", "field count", "expected 'E"),
        (b"E 1.5 2 3", "bad number", "t_ms = '1.5'"),
        (b"E -1 2 3", "bad number", "t_ms = '-1'"),
        (b"E 1 +2 3", "bad number", "left_ticks = '+2'"),
        (b"E 1 2 3_0", "bad number", "right_ticks = '3_0'"),
        (b"E 4294967296 0 0", "out of range", "expected an integer in 0..4294967295"),
        (b"E 0 2147483648 0", "out of range", "left_ticks = 2147483648"),
        (b"I 2000 154 0 fw", "out of range", "tread_mm = 0.0: expected a positive number"),
        (b"I 2000 154 330", "field count", "expected 'I <ticks_per_rev>"),
        (b"I 2000 1e999 330 fw", "out of range", "wheel_diameter_mm = inf"),
        (b"I 2000 -154 330 fw", "bad number", "wheel_diameter_mm = '-154'"),
        (b"X 1 2 3", "unknown record", "expected an 'E', 'I' or '#' line"),
        (b"E 1 2\x003", "bad byte", "0x00"),
        ("E 1 2 ³".encode(), "bad byte", "0xC2"),
        (b"E " + b"1" * 200, "too long", f"expected at most {MAX_LINE_BYTES}"),
        (b"E 1*2 3*" + b"%02X" % checksum(b"E 1*2 3"), "bad field", "'*' inside"),
    ],
)
def test_bad_lines_say_what_is_wrong(line: bytes, kind: str, says: str) -> None:
    with pytest.raises(EncoderProtocolError, match=re.escape(says)) as err:
        parse_line(line)
    assert err.value.kind == kind
    assert isinstance(err.value, AgentError)


def test_public_names_are_exported() -> None:
    for name in encoders.__all__:
        assert hasattr(encoders, name), name


@given(I32, st.integers(-(2**31) + 1, 2**31 - 1))
def test_counter_wrap_gives_the_true_change(start: int, change: int) -> None:
    assert tick_delta(wrap_int32(start + change), start) == change
    assert -(2**31) <= wrap_int32(start + change) < 2**31


@given(st.lists(st.binary(max_size=40).map(lambda b: b.replace(b"\n", b"")), max_size=20), st.data())
def test_splitter_finds_the_same_lines_however_the_stream_is_cut(
    lines: list[bytes], data: st.DataObject
) -> None:
    stream = b"".join(line + b"\n" for line in lines) + b"partial"
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
    splitter = LineSplitter()
    out: list[bytes] = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        out += splitter.feed(stream[a:b])
    assert out == lines


def test_splitter_cuts_overlong_lines_so_the_parser_rejects_them() -> None:
    splitter = LineSplitter()
    lines = splitter.feed(b"E 1 2 3\n" + b"9" * 5000)
    lines += splitter.feed(b"9" * 5000 + b"\nE 2 2 3\n")
    assert lines[0] == b"E 1 2 3" and lines[2] == b"E 2 2 3"
    assert len(lines[1]) == MAX_LINE_BYTES + 1
    with pytest.raises(EncoderProtocolError) as err:
        parse_line(lines[1])
    assert err.value.kind == "too long"


@given(
    st.floats(-1e6, 1e6),
    st.lists(st.tuples(st.integers(1, 100), st.floats(0.0, 0.05)), min_size=1, max_size=50),
)
def test_clock_stamps_lie_between_latch_and_arrival(offset: float, steps: list[tuple[int, float]]) -> None:
    # a bridge clock without drift; each line arrives 0..50 ms after its latch, in order
    sync = ClockSync()
    device_s, last, arrival = 0.0, -math.inf, -math.inf
    for dt_ms, delay in steps:
        device_s += dt_ms / 1000.0
        true_s = device_s + offset
        arrival = max(arrival, true_s + delay)
        stamp = sync.update(device_s, arrival)
        assert true_s - 1e-9 <= stamp <= arrival + 1e-9
        assert stamp >= last - 1e-9
        last = stamp


def test_clock_follows_the_least_delayed_line_and_a_slow_bridge_clock() -> None:
    sync = ClockSync(max_drift=1e-3)
    assert sync.update(0.0, 10.050) == pytest.approx(10.050)  # first guess: no delay
    assert sync.update(0.1, 10.101) == pytest.approx(10.101)  # a faster line lowers the offset at once
    assert sync.update(0.2, 10.300) == pytest.approx(10.201, abs=2e-4)  # a slower one cannot raise it
    # except at max_drift: a bridge clock 500 ppm slow is followed over 100 s of arrivals
    for k in range(1, 1001):
        stamp = sync.update(0.2 + 0.1 * k, 10.201 + 0.1 * k * (1 + 5e-4))
    assert stamp == pytest.approx(10.201 + 100.0 * (1 + 5e-4), abs=1e-3)


def decode(lines: list[bytes], **kw: object) -> tuple[EncoderDecoder, list[encoders.OdometryReading]]:
    decoder = EncoderDecoder(MINES_ROVER, **kw)  # type: ignore[arg-type]
    out = [decoder.feed_line(line, 100.0 + 0.01 * i) for i, line in enumerate(lines)]
    return decoder, [r for r in out if isinstance(r, encoders.OdometryReading)]


def test_decoder_unwraps_counters_and_clock() -> None:
    t0, l0, r0 = U32 - 20, 2**31 - 30, -(2**31) + 30
    lines = [
        format_line(EncoderLine((t0 + 10 * k) % U32, wrap_int32(l0 + 25 * k), wrap_int32(r0 - 25 * k)))
        for k in range(5)
    ]
    decoder, readings = decode(lines)
    assert [(r.left_ticks, r.right_ticks) for r in readings] == [(25 * k, -25 * k) for k in range(5)]
    assert [r.device_ms for r in readings] == [(t0 + 10 * k) % U32 for k in range(5)]
    assert decoder.stats.malformed == 0 and decoder.stats.resets == 0
    # turning in place: 100 ticks per wheel in opposite directions, about the axle's midpoint
    expected = 2 * 100 * MINES_ROVER.metres_per_tick / MINES_ROVER.tread_m
    assert readings[-1].pose.theta_rad == pytest.approx(-expected)
    assert math.hypot(readings[-1].pose.x_m, readings[-1].pose.y_m) < 1e-12
    stamps = [r.stamp_s for r in readings]
    assert stamps == sorted(set(stamps))


def e(t_ms: int, left: int, right: int | None = None) -> bytes:
    return format_line(EncoderLine(t_ms, left, left if right is None else right))


def test_decoder_skips_and_counts_what_it_cannot_use() -> None:
    lines = [
        e(1000, 0, 0),
        b"E 1010 5 5*00",  # bad checksum
        e(1010, 5, 5),
        e(1010, 9, 9),  # time did not advance
        b"#comment",
        format_line(BridgeInfo(2000, 154, 330, "fw")),
        e(1020, 100_000, 10),  # 24 m in 10 ms: implausible
        e(1030, 15, 15),
        e(500, 7, 7),  # time went back: the bridge restarted
        e(510, 17, 17),
    ]
    decoder, readings = decode(lines)
    assert [(r.left_ticks, r.right_ticks) for r in readings] == [(0, 0), (5, 5), (15, 15), (15, 15), (25, 25)]
    s = decoder.stats
    assert s.lines == len(lines) and s.readings == 5 and s.resets == 1
    assert s.malformed == 3
    assert s.reasons == {"bad checksum": 1, "time not advancing": 1, "implausible jump": 1}
    assert s.info == BridgeInfo(2000, 154, 330, "fw")
    assert [r.stamp_s for r in readings] == sorted({r.stamp_s for r in readings})


def test_three_implausible_jumps_in_a_row_make_a_new_baseline() -> None:
    decoder, readings = decode(
        [e(0, 0), e(10, 10**6), e(20, 10**6 + 10), e(30, 10**6 + 20), e(40, 10**6 + 30)]
    )
    assert [r.left_ticks for r in readings] == [0, 0, 10]
    assert decoder.stats.reasons == {"implausible jump": 2} and decoder.stats.resets == 1
    _, unchecked = decode([e(0, 0), e(10, 10**6)], max_wheel_speed_mps=None)
    assert [r.left_ticks for r in unchecked] == [0, 10**6]


def test_once_the_bridge_sends_checksums_a_line_without_one_is_refused() -> None:
    # "E 5 6 7*12" whose '*' was hit by noise reads as a valid unchecked line "E 5 6 7812"
    decoder, readings = decode(
        [format_line(EncoderLine(0, 0, 0)), b"E 10 6 7812", b"E 20 6 7*" + b"%02X" % checksum(b"E 20 6 7")]
    )
    assert [(r.left_ticks, r.right_ticks) for r in readings] == [(0, 0), (6, 7)]
    assert decoder.stats.reasons == {"missing checksum": 1}
    _, plain = decode([format_line(EncoderLine(0, 0, 0), with_checksum=False), b"E 10 6 7"])
    assert [(r.left_ticks, r.right_ticks) for r in plain] == [(0, 0), (6, 7)]
