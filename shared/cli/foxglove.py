"""``linemap foxglove``: a robot's live map from a linemap server, on a Foxglove WebSocket server
(:mod:`shared.foxbridge`; docs/foxglove.md). Needs the optional extra: ``pip install 'linemap[foxglove]'``."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Annotated

import typer

from shared.errors import LinemapError

__all__ = ["foxglove_cmd"]


def _read_token(token: str | None, token_file: Path | None) -> str | None:
    if token_file is None:
        return token
    try:
        lines = token_file.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise LinemapError(f"cannot read the token file {token_file}: {exc.strerror}") from None
    text = lines[0].strip() if lines else ""
    if not text:
        raise LinemapError(f"the token file {token_file} has no token on its first line")
    return text


def foxglove_cmd(
    server: Annotated[
        str, typer.Option(envvar="LINEMAP_SERVER", help="The linemap server's URL, e.g. http://host:8000.")
    ],
    robot: Annotated[int, typer.Option(min=1, help="The id of the robot whose map to show.")],
    token: Annotated[
        str | None,
        typer.Option(
            envvar="LINEMAP_TOKEN",
            help="An operator token or the robot's own (prefer the environment variable or --token-file: "
            "a command line is visible to every local user).",
        ),
    ] = None,
    token_file: Annotated[
        Path | None, typer.Option(help="Read the token from this file (its first line).")
    ] = None,
    host: Annotated[str, typer.Option(help="Address the Foxglove WebSocket server binds to.")] = "127.0.0.1",
    port: Annotated[
        int, typer.Option(min=0, max=65535, help="Port of the Foxglove WebSocket server (0: any free one).")
    ] = 8765,
    trajectory: Annotated[
        int, typer.Option(min=0, help="Trajectory poses to keep and draw (the newest).")
    ] = 5000,
    centroids: Annotated[
        bool, typer.Option("--centroids/--no-centroids", help="Publish the cluster centroids too.")
    ] = True,
) -> None:
    """Bridge a robot's live map to Foxglove: open ws://HOST:PORT in Foxglove (topics /linemap/walls,
    /linemap/pose, /linemap/tf, /linemap/trajectory, /linemap/centroids)."""
    from shared.foxbridge.bridge import FoxgloveBridge, require_foxglove
    from shared.foxbridge.sse import MapEventStream

    require_foxglove()
    if not server.startswith(("http://", "https://")):
        raise LinemapError(f"--server {server!r}: expected an http:// or https:// URL")
    secret = _read_token(token, token_file)
    stream = MapEventStream(server, robot, secret, trajectory=trajectory)
    stop = threading.Event()
    with FoxgloveBridge(host, port, centroids=centroids) as bridge:
        typer.echo(f"Foxglove WebSocket server on ws://{host}:{bridge.port} (robot {robot} from {server})")
        try:
            bridge.follow(stream, stop, keep=trajectory)
        except KeyboardInterrupt:
            typer.echo("stopped")
