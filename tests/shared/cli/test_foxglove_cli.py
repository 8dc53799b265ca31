"""`linemap foxglove`'s own checks before it connects (the bridge itself: tests/shared/foxbridge/): a URL
that is not http(s), a token file that cannot be read or holds no token."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from shared.cli.main import app
from shared.errors import LinemapError


def _run(*args: str) -> BaseException | None:
    result = CliRunner().invoke(app, ["foxglove", *args], env={"LINEMAP_TOKEN": ""})
    return result.exception


def test_a_server_that_is_not_an_http_url_is_named() -> None:
    exc = _run("--server", "ftp://host:8000", "--robot", "1")
    assert isinstance(exc, LinemapError)
    assert str(exc) == "--server 'ftp://host:8000': expected an http:// or https:// URL"


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "cannot read the token file {path}: No such file or directory"),
        ("", "the token file {path} has no token on its first line"),
        ("\nsecret\n", "the token file {path} has no token on its first line"),
    ],
)
def test_a_token_file_without_a_token_is_named(tmp_path: Path, content: str | None, message: str) -> None:
    path = tmp_path / "token"
    if content is not None:
        path.write_text(content)
    exc = _run("--server", "http://127.0.0.1:9", "--robot", "1", "--token-file", str(path))
    assert isinstance(exc, LinemapError)
    assert str(exc) == message.format(path=path)
