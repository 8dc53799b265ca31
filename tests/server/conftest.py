"""The shared live servers (one per database backend); see :mod:`tests.server.live`."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.server.live import BACKENDS, Live, start_live


@pytest.fixture(scope="session", params=BACKENDS)
def live(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    """The shared server of a backend. Waiters re-read the database only every 30 s, so a long-poll or
    stream that answers at once proves the in-process wake-up works."""
    tmp = tmp_path_factory.mktemp(f"server-{request.param}")
    yield from start_live(request.param, tmp, poll_recheck_s=30.0, max_body_bytes=256 * 1024)
