"""SCIP 2.0 encode/decode, checksums, replies and scan frames (pure, no I/O), against the protocol
specification's own examples and by property."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from robot_agent.sensors.errors import ScipChecksumError, ScipError, ScipStatusError
from robot_agent.sensors.scip import (
    TIMESTAMP_MODULUS,
    checksum,
    decode,
    decode_values,
    encode,
    encode_reply,
    encode_values,
    parse_reply,
    ranges_mm_to_m,
    unwrap_timestamp,
)
from robot_agent.sensors.scip_info import (
    URG04LX_PARAMS,
    encode_info_reply,
    parse_parameters,
    parse_state,
    parse_switch_reply,
    parse_versions,
)
from robot_agent.sensors.scip_scan import (
    ScanRequest,
    encode_scan_reply,
    parse_scan_command,
    parse_scan_reply,
    recover_scan_frame,
)

# A URG-04LX's replies as published (Hokuyo's SCIP 2.0 notes): checksums computed by the sensor.
PP_REPLY = (
    b"PP\n00P\nMODL:URG-04LX(Hokuyo Automatic Co.,Ltd.);N\nDMIN:20;4\nDMAX:5600;_\nARES:1024;\\\n"
    b"AMIN:44;7\nAMAX:725;o\nAFRT:384;6\nSCAN:600;e\n\n"
)
VV_REPLY = (
    b"VV\n00P\nVEND:Hokuyo Automatic Co.,Ltd.;[\nPROD:SOKUIKI Sensor URG-04LX;[\n"
    b"FIRM:3.1.00(18/Jan./2007);`\nPROT:SCIP 2.0;N\nSERI:H0614967;V\n\n"
)
II_REPLY = (
    b"II\n00P\nMODL:URG-04LX(Hokuyo Automatic Co.,Ltd.);N\nLASR:OFF;7\n"
    b"SCSP:Initial(600[rpm])<-Default setting by user;A\nMESM:IDLE;:\n"
    b"SBPS:19200[bps]<-Default setting by user;A\nTIME:081615;N\nSTAT:Sensor works well.;8\n\n"
)

scan_data_char = st.integers(0x30, 0x6F)


def test_checksums_of_the_specification() -> None:
    assert chr(checksum(b"00")) == "P" and chr(checksum(b"99")) == "b"
    assert chr(checksum(b"DMIN:20")) == "4" and chr(checksum(b"AFRT:384")) == "6"


def test_encodings_of_the_specification() -> None:
    assert encode(1234, 2) == b"CB" and decode(b"CB") == 1234
    assert encode(5432, 3) == b"1Dh" and decode(b"1Dh") == 5432
    assert encode(16_000_000, 4) == b"m2@0" and decode(b"m2@0") == 16_000_000


@given(st.integers(1, 4).flatmap(lambda n: st.tuples(st.just(n), st.integers(0, (1 << (6 * n)) - 1))))
def test_encode_decode_round_trip(case: tuple[int, int]) -> None:
    chars, value = case
    text = encode(value, chars)
    assert len(text) == chars and all(0x30 <= b <= 0x6F for b in text)
    assert decode(text) == value


@given(st.sampled_from([2, 3, 4]), st.data())
def test_value_runs_round_trip(chars: int, data: st.DataObject) -> None:
    values = data.draw(st.lists(st.integers(0, (1 << (6 * chars)) - 1), max_size=200))
    text = encode_values(values, chars)
    assert len(text) == chars * len(values)
    assert decode_values(text, chars).tolist() == values
    assert [decode(text[i : i + chars]) for i in range(0, len(text), chars)] == values


def test_out_of_range_values_and_characters_are_refused() -> None:
    with pytest.raises(ScipError, match="does not fit in 2"):
        encode(4096, 2)
    with pytest.raises(ScipError, match="cannot be sent in 3"):
        encode_values([0, 1 << 18], 3)
    with pytest.raises(ScipError, match=r"outside '0'\.\.'o'"):
        decode(b"0p")
    with pytest.raises(ScipError, match="character"):
        decode_values(b"00/", 3)
    with pytest.raises(ScipError, match="whole number of 3"):
        decode_values(b"0000", 3)


@given(
    st.lists(st.binary(min_size=1, max_size=64).map(lambda b: bytes(0x30 + x % 64 for x in b)), max_size=8)
)
def test_reply_round_trip_checks_every_line(lines: list[bytes]) -> None:
    block = encode_reply(b"GD0044072501", "00", lines)
    assert block.endswith(b"\n\n")
    reply = parse_reply(block)
    assert reply.echo == b"GD0044072501" and reply.status == "00" and list(reply.lines) == lines


@given(
    st.binary(min_size=1, max_size=64).map(lambda b: bytes(0x30 + x % 64 for x in b)),
    st.integers(0, 63),
    scan_data_char,
)
def test_any_single_changed_character_fails_its_checksum(line: bytes, pos: int, new: int) -> None:
    """A change of one character in 0x30..0x6F shifts the sum by -63..63, never 0 mod 64: always caught."""
    pos %= len(line)
    if line[pos] == new:
        new = 0x30 + (new - 0x30 + 1) % 64
    block = bytearray(encode_reply(b"MD0044072501000", "99", [b"0000", line]))
    head = len(b"MD0044072501000\n99b\n0000?\n")  # echo, status, time stamp line
    assert block[head:].startswith(line)
    block[head + pos] = new
    with pytest.raises(ScipChecksumError, match="checksum does not match"):
        parse_reply(bytes(block))


def test_malformed_replies_say_what_is_wrong() -> None:
    with pytest.raises(ScipError, match="truncated"):
        parse_reply(b"VV\n00P\n")
    with pytest.raises(ScipChecksumError, match="status checksum"):
        parse_reply(b"VV\n00Q\n\n")
    with pytest.raises(ScipError, match="status of 2 characters"):
        parse_reply(b"VV\n0\n\n")


def test_status_codes_become_errors_naming_command_and_code() -> None:
    reply = parse_reply(encode_reply(b"GD0044072501", "10"))
    with pytest.raises(ScipStatusError, match=r"'GD0044072501'.*'10'.*laser is off") as info:
        reply.check("00")
    assert info.value.command == "GD0044072501" and info.value.status == "10"
    with pytest.raises(ScipStatusError, match="hardware trouble"):
        parse_reply(encode_reply(b"MD0044072501000", "55")).check("00")
    assert parse_reply(encode_reply(b"BM", "02")).check("00", "02").status == "02"


def test_published_info_replies_parse() -> None:
    assert parse_parameters(parse_reply(PP_REPLY)) == URG04LX_PARAMS
    v = parse_versions(parse_reply(VV_REPLY))
    assert v.vendor == "Hokuyo Automatic Co.,Ltd." and v.protocol == "SCIP 2.0" and v.serial == "H0614967"
    s = parse_state(parse_reply(II_REPLY))
    assert not s.laser_on and s.measuring_mode == "IDLE" and s.time_ms == 0x081615
    assert s.bit_rate.startswith("19200")
    p = URG04LX_PARAMS
    assert p.range_min_m == 0.02 and p.range_max_m == 5.6 and p.rate_hz == 10.0 and p.beam_count == 682
    assert p.step_angle_rad(384) == 0.0 and p.step_angle_rad(640) == pytest.approx(math.pi / 2)


def test_info_reply_encoding_round_trips() -> None:
    block = encode_info_reply("PP", URG04LX_PARAMS.fields())
    assert block == PP_REPLY.replace(b"\\\n", b"\\\n")  # the emulator sends what the sensor sends
    assert parse_parameters(parse_reply(block)) == URG04LX_PARAMS


def test_scip_switch_replies() -> None:
    assert parse_switch_reply(parse_reply(b"SCIP2.0\n0\n\n")) is True  # from SCIP 1.1
    assert parse_switch_reply(parse_reply(b"SCIP2.0\n0Ee\n\n")) is False  # already SCIP 2.0
    with pytest.raises(ScipStatusError, match="did not switch"):
        parse_switch_reply(parse_reply(encode_reply(b"SCIP2.0", "0D")))


requests = st.builds(
    ScanRequest,
    st.sampled_from(["MD", "MS", "GD", "GS"]),
    st.integers(0, 400),
    st.integers(400, 768),
    st.integers(0, 99),
    st.integers(0, 9),
    st.integers(0, 99),
    st.text("AZaz09 ._+@", max_size=16),
).map(lambda r: r if r.continuous else ScanRequest(r.command, r.start_step, r.end_step, r.cluster, tag=r.tag))


@given(requests)
def test_scan_command_lines_round_trip(request: ScanRequest) -> None:
    line = request.line()
    assert parse_scan_command(line) == (request, "00")
    assert line.startswith(request.echo_prefix())


def test_bad_scan_commands_get_the_specification_status() -> None:
    assert parse_scan_command(b"MD00x4072501000") == (None, "01")
    assert parse_scan_command(b"MD004407x501000") == (None, "02")
    assert parse_scan_command(b"MD00440725x1000") == (None, "03")
    assert parse_scan_command(b"MD0725004401000") == (None, "05")
    assert parse_scan_command(b"MD004407250100x") == (None, "07")
    assert parse_scan_command(b"MD0044") == (None, "0C")
    with pytest.raises(ScipError, match="cluster = 100"):
        ScanRequest("MD", 44, 725, 100)


@given(requests, st.integers(0, TIMESTAMP_MODULUS - 1), st.data())
def test_scan_frames_round_trip(request: ScanRequest, stamp: int, data: st.DataObject) -> None:
    limit = (1 << (6 * request.chars)) - 1
    values = data.draw(
        st.lists(st.integers(0, limit), min_size=request.value_count, max_size=request.value_count)
    )
    block = encode_scan_reply(request, stamp, values, remaining=3 if request.continuous else None)
    lines = block.split(b"\n")
    assert all(len(line) <= 65 for line in lines)  # 64 data characters and the checksum
    frame = parse_scan_reply(parse_reply(block), request)
    assert frame.timestamp_ms == stamp and frame.ranges_mm.tolist() == values
    assert frame.remaining == (3 if request.continuous else 0)


def test_error_codes_are_no_returns() -> None:
    out = ranges_mm_to_m([0, 1, 7, 19, 20, 1234, 5600])
    assert np.isnan(out[:4]).all()
    assert out[4:].tolist() == [0.02, 1.234, 5.6]


def _md(values: list[int], remaining: int) -> bytes:
    return encode_scan_reply(ScanRequest("MD", 44, 725, 1), 1000 + remaining, values, remaining=remaining)


def test_truncated_frames_are_refused_and_the_next_frame_recovered() -> None:
    request = ScanRequest("MD", 44, 725)
    a, b = _md([1000] * 682, 0), _md(list(range(20, 702)), 0)
    for cut in (len(a) // 2, a.index(b"\n", 100) + 1, 17):  # mid-line, at a line end, inside the stamp
        merged = a[:cut] + b
        with pytest.raises(ScipError):
            parse_scan_reply(parse_reply(merged), request)
        frame = recover_scan_frame(merged, request)
        assert frame is not None and frame.ranges_mm.tolist() == list(range(20, 702))
    short = a[: len(a) // 2] + b"\n\n"
    with pytest.raises(ScipError):
        parse_scan_reply(parse_reply(short), request)
    assert recover_scan_frame(short, request) is None


@given(
    st.integers(0, 10 * TIMESTAMP_MODULUS),
    st.integers(-(TIMESTAMP_MODULUS // 2) + 1, TIMESTAMP_MODULUS // 2 - 1),
)
def test_timestamps_unwrap_to_the_nearest_turn(true_ms: int, error_ms: int) -> None:
    assert unwrap_timestamp(true_ms % TIMESTAMP_MODULUS, true_ms + error_ms) == true_ms
