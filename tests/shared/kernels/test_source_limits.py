"""Static checks of untrusted kernel source (shared.kernels.source_limits in-process, and
shared.kernels.source_check in its limited child process): every input gives an answer, never an
exception, and pathological nesting is refused with a reason that says what is expected."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.errors import KernelRejected
from robot_agent.kernels.loading import load_kernel_class
from shared.errors import KernelSourceError
from shared.kernels import Stage
from shared.kernels.source_check import check_source_bounded
from shared.kernels.source_limits import MAX_DEPTH, source_problem

TOKENS = st.sampled_from(
    [
        "(",
        ")",
        "[",
        "]",
        "{",
        "}",
        "+",
        "-",
        "not ",
        "lambda:",
        "if",
        "else",
        "1",
        "x",
        "=",
        "\n",
        " ",
        "\t",
        ":",
        ",",
        ".",
        "'",
        '"',
        "\\",
        "#",
        "*",
        "**",
        "@",
        "def ",
        "f'{",
    ]
)


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.binary(max_size=200), st.lists(TOKENS, max_size=200).map(lambda t: "".join(t).encode())))
def test_every_source_gets_an_answer_never_an_exception(source: bytes) -> None:
    out = source_problem(source)
    assert out["ok"] is True or (isinstance(out["reason"], str) and out["reason"])


@pytest.mark.parametrize(
    ("source", "needle"),
    [
        ("x = " + "+".join(["1"] * 200_000), "too complex to parse"),
        ("x = " + "-" * 200_000 + "1", "too complex to parse"),
        ("x = f" + "()" * 200_000, "too complex to parse"),
        ("x = " + "(" * 100_000 + "1" + ")" * 100_000, "too many nested parentheses"),
        ("x = " + "+".join(["1"] * (MAX_DEPTH * 2)), "nested too deeply"),
        ("x = 1\x00", "NUL byte"),
        ("def broken(:\n", "not valid Python: line 1"),
    ],
)
def test_pathological_source_is_refused_by_the_bounded_check(source: str, needle: str) -> None:
    with pytest.raises(KernelSourceError, match=needle) as info:
        check_source_bounded(source.encode())
    assert "expected" in info.value.reason or "not valid Python" in info.value.reason


def test_ordinary_source_and_string_multiplication_pass() -> None:
    check_source_bounded(b"x = 'a' * 10 ** 10\ny = [1, -2, 3] * 1000\n\ndef f(a):\n    return (a + 1) * 2\n")


def test_a_check_over_its_limits_is_refused_not_waited_for() -> None:
    source = ("x = " + "<".join(["1"] * 100_000)).encode()  # parses, but slowly and with ~100 MB
    with pytest.raises(KernelSourceError, match="too complex to parse"):
        check_source_bounded(source, timeout_s=0.2)
    with pytest.raises(KernelSourceError, match="too complex to parse"):
        check_source_bounded(source, memory_mb=40)


@pytest.mark.parametrize(
    "source", ["x = " + "+".join(["1"] * 200_000), "x = " + "-" * 200_000 + "1", "x = " + "((" * 50_000]
)
def test_the_agent_loader_refuses_it_and_lives(source: str) -> None:
    with pytest.raises(KernelRejected, match="import failed"):
        load_kernel_class(source.encode(), Stage.NOISE_REMOVAL, "deep", "1.0.0")


def test_the_agent_dry_run_refuses_it_in_its_child() -> None:
    from robot_agent.kernels.dryrun import dry_run

    for source in ("x = " + "+".join(["1"] * 200_000), "x = " + "-" * 200_000 + "1"):
        with pytest.raises(KernelRejected, match=r"dry run: import failed: (RecursionError|MemoryError)"):
            dry_run(source.encode(), Stage.NOISE_REMOVAL, "deep", "1.0.0", None, [], 10.0)
