"""An :class:`~robot_agent.uploader.Uploader` for tests: the given link and Robot DB, an empty status, no
wall times, fresh events and error report (what the agent would pass in)."""

from __future__ import annotations

import threading
from typing import Any

from robot_agent.health import ErrorReport
from robot_agent.link import ServerLink
from robot_agent.store import RobotDB
from robot_agent.uploader import Uploader
from shared.protocol import RobotStatus

__all__ = ["bare_uploader"]


def bare_uploader(link: ServerLink, db: RobotDB, robot_id: int, **settings: Any) -> Uploader:
    """An uploader of ``db`` over ``link``; ``settings`` are the Uploader's keyword settings."""
    return Uploader(
        link,
        db,
        lambda: RobotStatus(),
        lambda _v: None,
        threading.Event(),
        threading.Event(),
        ErrorReport(60.0),
        robot_id=robot_id,
        **settings,
    )
