"""The Robot DB as the agent uses it: each method is one transaction, so what belongs together commits
together (a step's map version, walls, pose and outbox entry; a message's outcome and the configuration it
put in force). SQLite in WAL mode with ``synchronous=FULL``: a committed step survives kill -9 and power
loss.

The Robot DB is one SQLite file (:mod:`robot_agent.store_db`: opening, migrations, transactions, meta);
its map and outbox tables are :mod:`robot_agent.store_map`, its control-message and kernel tables
:mod:`robot_agent.store_control`, its mapping state and scan journal :mod:`robot_agent.store_resume`, the
server's map taken over by a new Robot DB :mod:`robot_agent.store_adopt`.
:class:`RobotDB` joins them; the records the agent passes in and gets
back are importable from here too.
"""

from __future__ import annotations

from robot_agent.store_adopt import AdoptTables, HeldMap
from robot_agent.store_control import ControlTables, Ran
from robot_agent.store_db import MIGRATIONS_DIR
from robot_agent.store_map import MapTables, PendingUpload, StepRecord
from robot_agent.store_resume import ResumeTables, SavedState

__all__ = ["MIGRATIONS_DIR", "HeldMap", "PendingUpload", "Ran", "RobotDB", "SavedState", "StepRecord"]


class RobotDB(MapTables, ControlTables, ResumeTables, AdoptTables):
    """The Robot DB at ``path`` (created and migrated to the newest schema on open)."""
