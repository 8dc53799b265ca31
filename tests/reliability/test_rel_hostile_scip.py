"""Fuzzed SCIP 2.0 input (docs/reliability.md): what a broken or hostile serial line can send the URG-04LX
driver's parser. Valid replies (scan frames MD/MS/GD/GS, VV/PP/II information, the SCIP2.0 switch) built
with the module's own encoders are mutated (truncation, byte flips, inserted/duplicated runs, non-ASCII
bytes, spliced tokens) and decoded all the way (reply, scan frame, information fields, a Scan): only
:class:`ScipError` (and :class:`ScipStatusError` for a refused status) may come out.
"""

from __future__ import annotations

import pytest
from hypothesis import strategies as st

from robot_agent.sensors.errors import ScipError, ScipStatusError
from robot_agent.sensors.scip import (
    INFO_COMMANDS,
    SWITCH_COMMAND,
    decode,
    decode_values,
    encode_reply,
    parse_reply,
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
from robot_agent.sensors.urg_scans import scan_from_frame
from tests.reliability.hostiletools import assert_only, fast_examples, mutated_bytes, run_fuzz, soak_examples

OWN = (ScipError, ScipStatusError)

VERSIONS = [
    ("VEND", "Hokuyo"), ("PROD", "URG-04LX"), ("FIRM", "3.4.03"), ("PROT", "SCIP 2.0"), ("SERI", "H1"),
]  # fmt: skip
STATE = [
    ("MODL", "URG-04LX"), ("LASR", "ON"), ("SCSP", "600"), ("MESM", "Normal"), ("SBPS", "115200"),
    ("TIME", "0012AB"), ("STAT", "Sensor works well."),
]  # fmt: skip


@st.composite
def requests(draw: st.DrawFn) -> ScanRequest:
    start = draw(st.integers(0, 760))
    return ScanRequest(
        draw(st.sampled_from(["MD", "MS", "GD", "GS"])),
        start,
        draw(st.integers(start, min(start + 200, 768))),
        draw(st.integers(0, 4)),
        draw(st.integers(0, 9)),
        draw(st.integers(0, 99)),
        draw(st.sampled_from(["", "t1", "abc.DEF_+@"])),
    )


@st.composite
def valid_blocks(draw: st.DrawFn) -> tuple[bytes, ScanRequest | None]:
    """A reply block as a URG-04LX sends it, and the scan request it answers (None for the others)."""
    kind = draw(st.sampled_from(["scan", "scan", "VV", "PP", "II", "switch", "status"]))
    if kind == "scan":
        req = draw(requests())
        values = draw(st.lists(st.integers(0, (1 << (6 * req.chars)) - 1), min_size=req.value_count,
                               max_size=req.value_count))  # fmt: skip
        return encode_scan_reply(req, draw(st.integers(0, 1 << 30)), values), req
    if kind == "switch":
        status = draw(st.sampled_from(["0", "0E", "00"]))
        return (b"SCIP2.0\n0\n\n" if status == "0" else encode_reply(SWITCH_COMMAND, status)), None
    if kind == "status":
        echo = draw(st.sampled_from([b"BM", b"QT", b"RS", b"MD0044072501000"]))
        return encode_reply(echo, draw(st.sampled_from(["00", "02", "10", "0C", "99"]))), None
    fields = {"VV": VERSIONS, "PP": URG04LX_PARAMS.fields(), "II": STATE}[kind]
    return encode_info_reply(kind, fields, draw(st.sampled_from(["", "x"]))), None


def _decode_all(block: bytes, expected: ScanRequest | None) -> None:
    """Everything the driver does with a block it read."""
    reply = parse_reply(block)
    assert reply.command is not None
    if reply.echo.startswith(b"SCIP2.0"):
        parse_switch_reply(reply)
        return
    if reply.command in INFO_COMMANDS:
        reply.fields()
        {"VV": parse_versions, "PP": parse_parameters, "II": parse_state}[reply.command](reply)
        return
    if reply.command not in ("MD", "MS", "GD", "GS") or not reply.lines:  # BM, QT, RS; MD's first "00"
        reply.check("00")
        return
    frame = parse_scan_reply(reply, expected)
    scan = scan_from_frame(frame, URG04LX_PARAMS, 0.0)
    assert scan.beam_count == frame.request.value_count


def _check(case: tuple[tuple[bytes, ScanRequest | None], bytes, bool]) -> None:
    (_valid, expected), block, with_expected = case
    assert_only(OWN, lambda: _decode_all(block, expected if with_expected else None))
    if expected is not None:
        assert_only(OWN, lambda: recover_scan_frame(block, expected))


@st.composite
def mutated_blocks(draw: st.DrawFn) -> tuple[tuple[bytes, ScanRequest | None], bytes, bool]:
    valid = draw(valid_blocks())
    block = draw(mutated_bytes(valid[0]) | st.just(valid[0]))
    return valid, block, draw(st.booleans())


def _check_pieces(case: tuple[bytes, int]) -> None:
    raw, chars = case
    assert_only(OWN, lambda: decode(raw))
    assert_only(OWN, lambda: decode_values(raw, chars))
    assert_only(OWN, lambda: parse_scan_command(raw))


pieces = st.tuples(st.binary(max_size=40) | st.from_regex(rb"\A[MG][DS][0-9]{0,12}(;.{0,20})?\Z"),
                   st.integers(-1, 6))  # fmt: skip


def test_valid_blocks_decode() -> None:
    def check(valid: tuple[bytes, ScanRequest | None]) -> None:
        block, expected = valid
        try:
            _decode_all(block, expected)
        except ScipStatusError:
            assert expected is None  # a refusal: only the status/switch replies may be refused

    run_fuzz(check, valid_blocks(), fast_examples(200))


def test_mutated_replies_raise_only_scip_errors() -> None:
    run_fuzz(_check, mutated_blocks(), fast_examples(400))


def test_random_pieces_raise_only_scip_errors() -> None:
    run_fuzz(_check_pieces, pieces, fast_examples(300))


@pytest.mark.parametrize(
    ("block", "fragment"),
    [
        (b"VV\n\xff\xffn\n\n", "status"),  # non-ASCII status with a matching checksum
        (b"MD0044072501000\n\xc3\xa9\\\n\n", "status"),  # UTF-8 'e-acute' status, checksum '\\'
    ],
)
def test_known_hostile_blocks(block: bytes, fragment: str) -> None:
    err = assert_only(OWN, lambda: _decode_all(block, None))
    assert err is not None and fragment in str(err), err


def test_pp_with_non_ascii_digit_is_a_scip_error() -> None:
    """'²' (latin-1 0xB2) is a digit to str.isdigit() but not to int(): the PP parser must say so."""
    block = encode_info_reply("PP", [(k, "\u00b2" if k == "DMIN" else v) for k, v in URG04LX_PARAMS.fields()])
    err = assert_only(OWN, lambda: _decode_all(block, None))
    assert err is not None and "DMIN" in str(err)


def test_pp_with_a_5000_digit_number_is_a_scip_error() -> None:
    fields = [(k, "9" * 5000 if k == "ARES" else v) for k, v in URG04LX_PARAMS.fields()]
    block = encode_info_reply("PP", fields)
    err = assert_only(OWN, lambda: _decode_all(block, None))
    assert err is not None and "ARES" in str(err)


@pytest.mark.soak
def test_scip_soak() -> None:
    n = soak_examples()
    run_fuzz(_check, mutated_blocks(), n)
    run_fuzz(_check_pieces, pieces, n)
