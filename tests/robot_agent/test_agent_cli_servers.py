"""``linemap agent`` as a user runs it, with bad server settings: each is named in one line on stderr, exit
status 2, no traceback, and no Robot DB made. Error text holding square brackets is printed as text (the
CLI's error printer once read it as markup and crashed with a traceback)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.shared.cli.test_cli import linemap


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (
            ["--server", "ftp://robots.example"],
            "server URL 'ftp://robots.example': expected http(s)://host[:port][/path]",
        ),
        (["--server", "http://a.example:8000,a.example"], "server URL 'a.example'"),
        (["--server", "http://a.example:70000"], "the port is not a number in 1..65535"),
    ],
)
def test_a_bad_server_list_is_named(tmp_path: Path, args: list[str], said: str) -> None:
    out = linemap("agent", *args, "--robot-id", "1", "--token", "t", "--db", str(tmp_path / "r.db"))
    assert out.returncode == 2, out.stderr
    assert said in out.stderr and "Traceback" not in out.stderr
    assert not (tmp_path / "r.db").exists()


@pytest.mark.parametrize(
    ("toml", "said"),
    [
        ("server = 5\n", "server = 5: expected a URL or a list of URLs"),
        ('server = ["http://a.example", "gopher://b"]\n', "server URL 'gopher://b'"),
    ],
)
def test_a_bad_server_in_the_agent_file_is_named(tmp_path: Path, toml: str, said: str) -> None:
    file = tmp_path / "agent.toml"
    file.write_text(toml + 'robot_id = 1\ntoken = "t"\n', encoding="utf-8")
    out = linemap("agent", "--file", str(file), "--db", str(tmp_path / "r.db"))
    assert out.returncode == 2, out.stderr
    assert said in out.stderr and "Traceback" not in out.stderr


@pytest.mark.parametrize(
    ("args", "toml", "said"),
    [
        (["--retry-base", "2", "--retry-cap", "1"], "", "retry cap 1 s is below the first retry delay 2 s"),
        ([], "retry_cap = 0\n", "retry_cap = 0: expected seconds in [0.001, 3600]"),
        ([], 'retry_cap = "soon"\n', "retry_cap = 'soon'"),
    ],
)
def test_a_bad_retry_cap_is_named(tmp_path: Path, args: list[str], toml: str, said: str) -> None:
    file = tmp_path / "agent.toml"
    file.write_text(toml, encoding="utf-8")
    out = linemap("agent", "--file", str(file), *args, "--db", str(tmp_path / "r.db"))
    assert out.returncode == 2, out.stderr
    assert said in out.stderr and "Traceback" not in out.stderr
    assert not (tmp_path / "r.db").exists()
