"""``linemap agent``: run the robot daemon (map, keep the Robot DB, follow the server's control messages)."""

from __future__ import annotations

import logging
import threading
import tomllib
from pathlib import Path
from typing import Annotated, Any

import typer

from shared.errors import LinemapError
from shared.slam import LoopClosureSettings, OnlineGraphMapper
from shared.stopsignals import stop_on_signals

__all__ = ["agent_cmd"]

log = logging.getLogger(__name__)


def _loop_settings(option: bool | None, in_file: object, file: Path | None) -> LoopClosureSettings | None:
    """Loop closure from the option, else the file's ``loop_closure``: true / false, or a table of
    :class:`shared.slam.LoopClosureSettings` fields (``search_radius_m``, ``min_inlier_share``, ...)."""
    if option is not None:
        return LoopClosureSettings() if option else None
    if isinstance(in_file, bool):
        return LoopClosureSettings() if in_file else None
    if isinstance(in_file, dict):
        return LoopClosureSettings.parse(in_file)
    raise LinemapError(f"{file}: loop_closure = {in_file!r}: expected true, false or a table of settings")


def _file_settings(path: Path | None) -> dict[str, Any]:
    if path is None:
        return {}
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise LinemapError(f"agent file {path}: {exc}") from None
    allowed = {
        "server",
        "robot_id",
        "token",
        "source",
        "db",
        "rate",
        "trust_keys",
        "allow_unsigned",
        "config",
        "laps",
        "encoders",
        "retry_base",
        "retry_cap",
        "max_retry_after",
        "error_clear",
        "loop_closure",
        "continue_map",
    }
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise LinemapError(f"agent file {path}: unknown keys {unknown}; expected some of {sorted(allowed)}")
    return data


def _flag(value: Any, path: Path | None, key: str) -> bool:
    """A true / false setting from the agent file's ``key``."""
    if not isinstance(value, bool):
        raise LinemapError(f"agent file {path}: {key} = {value!r}: expected true or false")
    return value


def _retry_base(value: Any, path: Path | None) -> float:
    """``retry_base`` from the agent file: a number of seconds in [0.001, 60]."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0.001 <= value <= 60:
        raise LinemapError(f"agent file {path}: retry_base = {value!r}: expected seconds in [0.001, 60]")
    return float(value)


def _seconds(value: Any, path: Path | None, key: str, low: float, high: float) -> float:
    """A number of seconds in ``[low, high]`` from the agent file's ``key``."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
        raise LinemapError(f"agent file {path}: {key} = {value!r}: expected seconds in [{low:g}, {high:g}]")
    return float(value)


def _key_text(value: str) -> str:
    """A trusted key given inline (base64 or PEM) or as a file holding one."""
    path = Path(value)
    if len(value) < 200 and path.is_file():
        return path.read_text(encoding="utf-8").strip()
    return value


def agent_cmd(
    server: Annotated[
        str | None,
        typer.Option(
            envvar="LINEMAP_SERVER",
            help="Server URL, e.g. http://host:8000; several processes of one server separated by commas "
            "(the agent moves to the next when one does not answer).",
        ),
    ] = None,
    robot_id: Annotated[
        int | None, typer.Option(envvar="LINEMAP_ROBOT_ID", help="This robot's id on the server.")
    ] = None,
    token: Annotated[
        str | None, typer.Option(envvar="LINEMAP_ROBOT_TOKEN", help="This robot's token.")
    ] = None,
    source: Annotated[
        str | None,
        typer.Option(help="sim | sim:WORLD_FILE | sim:KIND (a suite world) | a log file | urg:/dev/ttyACM0"),
    ] = None,
    encoders: Annotated[
        str | None,
        typer.Option(help="With urg:: the wheel-encoder bridge's serial device, e.g. /dev/ttyUSB0."),
    ] = None,
    db: Annotated[Path | None, typer.Option(help="Robot DB file (SQLite).")] = None,
    rate: Annotated[
        float | None,
        typer.Option(
            min=0, help="Steps per second (default: the log's own time stamps, 10 for sim; 0 = flat out)."
        ),
    ] = None,
    trust_key: Annotated[
        list[str] | None,
        typer.Option(help="Trusted Ed25519 public key (base64, PEM, or a file); repeatable."),
    ] = None,
    allow_unsigned: Annotated[
        bool, typer.Option(help="DEVELOPMENT ONLY: accept kernels without a valid signature.")
    ] = False,
    config: Annotated[
        Path | None, typer.Option(help="Initial pipeline configuration (XML control message, JSON or TOML).")
    ] = None,
    file: Annotated[
        Path | None, typer.Option("--file", help="TOML file with any of these settings (options win).")
    ] = None,
    max_steps: Annotated[int | None, typer.Option(min=1, help="Stop after this many steps.")] = None,
    laps: Annotated[
        int | None,
        typer.Option(
            min=0, help="Simulated source: drive the path out and back this many times (0 = until stopped)."
        ),
    ] = None,
    exit_at_end: Annotated[
        bool, typer.Option(help="Exit when the source ends (default: keep serving).")
    ] = False,
    retry_base: Annotated[
        float | None,
        typer.Option(
            min=0.001,
            max=60,
            help="First retry delay after a network fault, s (doubles per failure up to --retry-cap, full "
            "jitter) [0.5].",
        ),
    ] = None,
    retry_cap: Annotated[
        float | None,
        typer.Option(
            min=0.001,
            max=3600,
            help="Longest retry delay after network faults, s (a server's Retry-After may ask more) [30].",
        ),
    ] = None,
    max_retry_after: Annotated[
        float | None,
        typer.Option(
            min=0,
            max=3600,
            help="Longest Retry-After honoured, s (a longer one is capped; inf, negatives, garbage ignored) "
            "[60].",
        ),
    ] = None,
    error_clear: Annotated[
        float | None,
        typer.Option(
            min=0,
            max=86400,
            help="last_error is cleared once this long passed without a new error and a status reached the "
            "server, s [60].",
        ),
    ] = None,
    loop_closure: Annotated[
        bool | None,
        typer.Option(
            "--loop-closure/--no-loop-closure",
            help="Close loops with a keyframe pose graph; the map is drawn again from its poses [off].",
        ),
    ] = None,
    continue_map: Annotated[
        bool,
        typer.Option(
            "--continue-map",
            help="A new Robot DB continues the map the server holds for this robot (same map, next "
            "version, from its last pose) instead of starting a new one; a Robot DB with a map of its own "
            "goes on with that.",
        ),
    ] = False,
) -> None:
    """Map from SOURCE and follow the server: apply control messages between steps, hot-swap verified
    kernels, upload every map version (kept in the Robot DB until the server has it)."""
    from robot_agent.agent import Agent, AgentSettings
    from robot_agent.link import server_urls
    from shared.control import load_config

    f = _file_settings(file)
    src = source or f.get("source") or "sim"
    keys = [_key_text(k) for k in (trust_key or f.get("trust_keys") or [])]
    given = server or f.get("server")
    if given is not None and not isinstance(given, str | list):
        raise LinemapError(f"agent file {file}: server = {given!r}: expected a URL or a list of URLs")
    urls = server_urls(given) if given else ()
    rid = robot_id if robot_id is not None else f.get("robot_id")
    tok = token or f.get("token")
    if urls and (rid is None or not tok):
        raise LinemapError("--server needs --robot-id and --token (from POST /api/v1/robots)")
    cfg_path = config or (Path(f["config"]) if f.get("config") else None)
    settings = AgentSettings(
        source=src,
        db_path=db or Path(f.get("db", "robot.db")),
        server_urls=urls,
        robot_id=int(rid or 0),
        token=str(tok or ""),
        rate_hz=rate if rate is not None else f.get("rate"),
        trusted_keys=tuple(keys),
        allow_unsigned=allow_unsigned or bool(f.get("allow_unsigned", False)),
        config=load_config(cfg_path) if cfg_path else None,
        max_steps=max_steps,
        stay=not exit_at_end,
        laps=laps if laps is not None else int(f.get("laps", 1)),
        encoders=encoders or f.get("encoders"),
        retry_base_s=retry_base if retry_base is not None else _retry_base(f.get("retry_base", 0.5), file),
        retry_cap_s=retry_cap
        if retry_cap is not None
        else _seconds(f.get("retry_cap", 30.0), file, "retry_cap", 0.001, 3600),
        max_retry_after_s=max_retry_after
        if max_retry_after is not None
        else _seconds(f.get("max_retry_after", 60.0), file, "max_retry_after", 0, 3600),
        error_clear_s=error_clear
        if error_clear is not None
        else _seconds(f.get("error_clear", 60.0), file, "error_clear", 0, 86400),
        loop_closure=_loop_settings(loop_closure, f.get("loop_closure", False), file),
        continue_map=continue_map or _flag(f.get("continue_map", False), file, "continue_map"),
    )
    if settings.retry_cap_s < settings.retry_base_s:
        raise LinemapError(
            f"retry cap {settings.retry_cap_s:g} s is below the first retry delay "
            f"{settings.retry_base_s:g} s: expected --retry-cap >= --retry-base"
        )
    if settings.allow_unsigned:
        typer.echo("WARNING: --allow-unsigned: kernels without a valid signature will run", err=True)
    agent = Agent(settings)
    stop = threading.Event()
    stop_on_signals(stop)
    where = f"server {', '.join(urls)} as robot {rid}" if urls else "no server"
    typer.echo(f"linemap agent: source {src}, Robot DB {settings.db_path}, {where}", err=True)
    if agent.continued:
        typer.echo(f"linemap agent: {agent.continued}", err=True)
    agent.run(stop)
    closed = (
        f", {agent.pipeline.closures} loop closures, map redrawn {agent.pipeline.rebuilds} times"
        if isinstance(agent.pipeline, OnlineGraphMapper)
        else ""
    )
    typer.echo(f"linemap agent: stopped after {agent.stats.steps} steps{closed}", err=True)
