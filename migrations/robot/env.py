"""Alembic environment of the Robot DB (run by ``robot_agent.store`` on open, or ``alembic -n robot``)."""

from __future__ import annotations

from alembic import context
from sqlalchemy import create_engine, pool

from robot_agent.models import RobotBase

config = context.config
target_metadata = RobotBase.metadata


def _url() -> str:
    given = config.attributes.get("url") or context.get_x_argument(as_dictionary=True).get("db")
    if not given:
        raise SystemExit("give the Robot DB: alembic -n robot -x db=sqlite:///robot.db upgrade head")
    return str(given) if "://" in str(given) else f"sqlite:///{given}"


def run_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        context.configure(connection=connection, target_metadata=target_metadata, render_as_batch=True)
        with context.begin_transaction():
            context.run_migrations()
        return
    engine = create_engine(_url(), poolclass=pool.NullPool)
    with engine.connect() as conn:
        context.configure(connection=conn, target_metadata=target_metadata, render_as_batch=True)
        with context.begin_transaction():
            context.run_migrations()
    engine.dispose()


if context.is_offline_mode():
    context.configure(url=_url(), target_metadata=target_metadata, literal_binds=True, render_as_batch=True)
    with context.begin_transaction():
        context.run_migrations()
else:
    run_online()
