"""A link naming several server processes (robot_agent/link.py): the URLs are checked when given, and a call
that meets a process that cannot answer (no response, 502, 503, 504) moves the next calls to the next
process of the list, round robin; other answers (a 4xx, a 500) do not. In-process transport here; the
same through real server processes and a real agent killed under it:
tests/reliability/test_rel_failover_processes.py."""

from __future__ import annotations

import httpx
import pytest
from hypothesis import given
from hypothesis import strategies as st

from robot_agent.errors import LinkError
from robot_agent.link import ServerLink, server_urls

A, B, C = "http://a.example:8000", "http://b.example:8000", "https://c.example/linemap"


def test_server_urls_split_trim_and_keep_order() -> None:
    assert server_urls(f" {A}/ ,{B},{A}") == (A, B)
    assert server_urls([C + "/"]) == (C,)


@pytest.mark.parametrize(
    ("text", "named"),
    [
        ("", "no server URL"),
        (" , ", "no server URL"),
        ("a.example:8000", "'a.example:8000'"),
        ("ftp://a.example", "'ftp://a.example'"),
        ("http://", "'http://'"),
        ("http://a.example:99999", "port"),
        ("http://a.example:80x", "port"),
        ("http://a.example/?x=1", "'http://a.example/?x=1'"),
        (f"{A},nonsense", "'nonsense'"),
    ],
)
def test_a_bad_server_url_is_named(text: str, named: str) -> None:
    with pytest.raises(LinkError) as err:
        server_urls(text)
    assert named in str(err.value)


hosts = st.from_regex(r"[a-z][a-z0-9-]{0,20}(\.[a-z]{2,6}){0,2}", fullmatch=True)


@given(st.lists(st.tuples(st.sampled_from(["http", "https"]), hosts, st.integers(1, 65535)), min_size=1))
def test_any_list_of_urls_round_trips(parts: list[tuple[str, str, int]]) -> None:
    urls = [f"{scheme}://{host}:{port}" for scheme, host, port in parts]
    got = server_urls(",".join(urls))
    assert got == tuple(dict.fromkeys(urls))
    assert server_urls(got) == got


def _link(answers: dict[str, int | None], seen: list[str], urls: str = f"{A},{B},{C}") -> ServerLink:
    """A link whose servers answer ``answers[host]`` (None: no answer at all) to every call."""

    def handle(request: httpx.Request) -> httpx.Response:
        seen.append(request.url.host)
        status = answers[request.url.host]
        if status is None:
            raise httpx.ConnectError("connection refused", request=request)
        return httpx.Response(status, json={"messages": []} if status == 200 else {"detail": "no"})

    return ServerLink(urls, 1, "t", transport=httpx.MockTransport(handle))


@pytest.mark.parametrize("failure", [None, 502, 503, 504])
def test_a_process_that_cannot_answer_moves_the_link_to_the_next(failure: int | None) -> None:
    seen: list[str] = []
    link = _link({"a.example": failure, "b.example": 200, "c.example": 200}, seen)
    with pytest.raises(LinkError):
        link.poll(0, 0.0)
    assert link.base_url == B
    assert link.poll(0, 0.0) == []
    assert seen == ["a.example", "b.example"]


def test_the_link_goes_round_the_list() -> None:
    seen: list[str] = []
    link = _link({"a.example": None, "b.example": None, "c.example": None}, seen)
    for _ in range(4):
        with pytest.raises(LinkError):
            link.poll(0, 0.0)
    assert seen == ["a.example", "b.example", "c.example", "a.example"]


@pytest.mark.parametrize("status", [400, 401, 404, 500])
def test_an_answer_of_the_api_keeps_the_link_where_it_is(status: int) -> None:
    seen: list[str] = []
    link = _link({"a.example": status, "b.example": 200, "c.example": 200}, seen)
    with pytest.raises(LinkError):
        link.poll(0, 0.0)
    assert link.base_url == A


def test_one_server_stays_the_one() -> None:
    seen: list[str] = []
    link = _link({"a.example": None}, seen, urls=A)
    for _ in range(2):
        with pytest.raises(LinkError):
            link.poll(0, 0.0)
    assert link.base_url == A and seen == ["a.example", "a.example"]
