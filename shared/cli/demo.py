"""``linemap demo``: the whole system on one machine: a server, a simulated robot, the dashboard.

Starts ``linemap server`` on ``HOST:PORT`` with a SQLite database in ``DIR``, registers a robot and a
signing key, starts ``linemap agent`` patrolling a simulated world until stopped (``--world``: the paper's
room by default, or a kind of the scenario suite: :mod:`shared.cli.demo_world`), prints the dashboard URL
and the operator token, and waits. Ctrl-C (or SIGTERM, or ``--for-s`` seconds) stops the agent, then the
server; ``--png FILE`` first draws the robot's map as the server holds it then over the true walls.
``DIR/demo.json`` records what it made (URL, token, robot id, key files) for scripts and tests.

Each start is fresh: the databases in ``DIR`` are replaced. ``--keep`` resumes the last demo instead: the
same server database, robot (its token is kept in ``DIR/robot.token``), Robot DB and signing key, so the
robot continues its map. The processes are real subprocesses talking HTTP on loopback, exactly as a robot
and a server on two machines would; a server that dies is started again (at most
:data:`SERVER_RESTARTS` times a minute) while the robot rides out the outage, as a robot does anywhere.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Annotated

import httpx
import typer

from shared.cli.demo_world import DEFAULT_WORLD, save_map_png, world_source
from shared.errors import LinemapError
from shared.stopsignals import stop_on_signals

__all__ = ["DemoInfo", "demo_cmd"]

EXAMPLE_KERNEL = Path(__file__).resolve().parents[2] / "docs" / "examples" / "dbscan_1_1_0.py"
ROBOT_NAME = "sim-robot"
#: server restarts allowed within a minute before the demo gives up
SERVER_RESTARTS = 5


@dataclass(frozen=True)
class DemoInfo:
    """What a running demo made (written to ``DIR/demo.json``)."""

    url: str
    operator_token: str
    world: str
    robot_id: int
    robot_name: str
    private_key: str
    public_key: str
    example_kernel: str | None
    example_signature: str | None
    server_pid: int
    agent_pid: int


def _linemap() -> list[str]:
    exe = Path(sys.executable).with_name("linemap")
    return [str(exe)] if exe.is_file() else [sys.executable, "-m", "shared.cli.main"]


def _port_free(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def _tail(path: Path, lines: int = 15) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(no log)"


class _Child:
    """A ``linemap`` subprocess with its output in a log file."""

    def __init__(self, name: str, args: list[str], log: Path, env: dict[str, str] | None = None) -> None:
        """``env``: variables added to this process's environment for the child (secrets go there, not
        into ``args``: a command line is visible to every local user in ``ps``)."""
        self.name, self.log = name, log
        self._out = log.open("ab")
        # Own session: a Ctrl-C at the terminal reaches only the demo, which stops the children in order.
        self.proc = subprocess.Popen(
            [*_linemap(), *args],
            stdout=self._out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            preexec_fn=_die_with_parent,
            env={**os.environ, **env} if env else None,
        )

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout_s: float) -> int:
        """SIGINT, then SIGKILL after ``timeout_s``; the exit code."""
        if self.alive():
            self.proc.send_signal(signal.SIGINT)
        try:
            code = self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait()
        self._out.close()
        return code


def _die_with_parent() -> None:
    """In the child before exec (Linux): SIGTERM it if the demo itself dies, even by SIGKILL, so no
    server or agent outlives it. Elsewhere a no-op."""
    if sys.platform.startswith("linux"):
        import ctypes

        pr_set_pdeathsig = 1
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, signal.SIGTERM)


def _wait_healthy(base: str, server: _Child, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if not server.alive():
            raise LinemapError(
                f"the server exited at start (code {server.proc.returncode}):\n{_tail(server.log)}"
            )
        try:
            if httpx.get(f"{base}/healthz", timeout=2.0).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise LinemapError(
        f"the server did not answer on {base}/healthz within {timeout_s:.0f} s:\n{_tail(server.log)}"
    )


def _setup(base: str, op_token: str, directory: Path) -> tuple[int, str, str, str, str | None, str | None]:
    """Register the robot and a signing key; pre-sign the example kernel. Returns (robot id, robot token,
    private key file, public key, example kernel file, its signature)."""
    from shared.cli.kernelfile import describe_kernel_file
    from shared.signing import generate_keypair, load_private_key, sha256_hex, sign_digest

    pair = generate_keypair()
    key_file = directory / "signing.pem"
    fd = os.open(key_file, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(pair.private_pem)
    (directory / "signing.pub").write_text(pair.public_b64 + "\n", encoding="utf-8")
    with httpx.Client(base_url=f"{base}/api/v1", headers={"Authorization": f"Bearer {op_token}"}) as api:
        r = api.post("/robots", json={"name": ROBOT_NAME})
        if r.status_code != 201:
            raise LinemapError(f"could not register the demo robot: HTTP {r.status_code} {r.text[:300]}")
        robot = r.json()
        r = api.post("/keys", json={"name": "demo", "public_key": pair.public_b64})
        if r.status_code not in (201, 409):
            raise LinemapError(
                f"could not register the demo signing key: HTTP {r.status_code} {r.text[:300]}"
            )
    example = signature = None
    kernels = directory / "kernels"
    # every example kernel artifact, signed, ready to upload (docs/examples: a new version of a built-in
    # kernel, and a kernel of a new name)
    for source in sorted(EXAMPLE_KERNEL.parent.glob("*.py")):
        kernels.mkdir(exist_ok=True)
        copy = kernels / source.name
        shutil.copyfile(source, copy)
        signed = sign_digest(load_private_key(pair.private_pem), sha256_hex(copy.read_bytes()))
        copy.with_suffix(".sig").write_text(signed + "\n", encoding="utf-8")
        declared = describe_kernel_file(source)["parameters"]  # the upload's optional `parameters`
        copy.with_suffix(".params.json").write_text(json.dumps(declared, indent=2) + "\n", encoding="utf-8")
        if source == EXAMPLE_KERNEL:
            example, signature = str(copy), signed
    return int(robot["id"]), str(robot["token"]), str(key_file), pair.public_b64, example, signature


def _save_robot_token(directory: Path, token: str) -> None:
    fd = os.open(directory / "robot.token", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(token + "\n")


def _resume(directory: Path, world: str) -> tuple[int, str, str, str, str | None, str | None] | None:
    """What ``--keep`` continues: the last demo's robot id, robot token, key files and example kernel;
    ``None`` when ``directory`` holds no demo at all (a fresh start). :class:`LinemapError` when it holds
    a server database but not what resuming needs, or the last demo patrolled another world."""
    info_file, token_file = directory / "demo.json", directory / "robot.token"
    if not info_file.is_file() or not token_file.is_file():
        if not (directory / "server.db").exists():
            return None
        missing = "demo.json" if not info_file.is_file() else "robot.token"
        raise LinemapError(
            f"--keep: {directory} holds a server database but no {missing}, which resuming needs (a demo "
            "from before resuming was possible): run without --keep to start fresh"
        )
    try:
        info = json.loads(info_file.read_text(encoding="utf-8"))
        token = token_file.read_text(encoding="utf-8").strip()
        last = (int(info["robot_id"]), str(info["private_key"]), str(info["public_key"]))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise LinemapError(f"--keep: cannot read the last demo from {info_file}: {exc}") from None
    if info.get("world") != world:
        raise LinemapError(
            f"--keep: the last demo in {directory} patrolled world {info.get('world')!r}, not {world!r}: "
            "pass the same --world, or run without --keep to start fresh"
        )
    robot_id, key_file, public_key = last
    return robot_id, token, key_file, public_key, info.get("example_kernel"), info.get("example_signature")


def demo_cmd(
    directory: Annotated[
        Path, typer.Option("--dir", help="Where the demo keeps its databases, keys and logs.")
    ] = Path(".demo"),
    host: Annotated[str, typer.Option(help="Address the server listens on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=1, max=65535, help="The server's TCP port.")] = 8000,
    keep: Annotated[
        bool, typer.Option(help="Reuse the databases of the last demo instead of starting fresh.")
    ] = False,
    laps: Annotated[int, typer.Option(min=0, help="Patrols of the simulated world (0: until stopped).")] = 0,
    world: Annotated[
        str,
        typer.Option(
            help="The world the robot patrols: room (the paper's Fig. 8 room), a kind of the scenario suite "
            "(see `linemap bench worlds --list`) or a world file (.json/.toml)."
        ),
    ] = DEFAULT_WORLD,
    for_s: Annotated[
        float | None,
        typer.Option("--for-s", min=1.0, help="Stop by itself after this many seconds (default: Ctrl-C)."),
    ] = None,
    png: Annotated[
        Path | None,
        typer.Option(help="On stopping, draw the robot's map over the world's true walls to this PNG."),
    ] = None,
    loop_closure: Annotated[
        bool,
        typer.Option(
            "--loop-closure/--no-loop-closure",
            help="The robot closes loops with a keyframe pose graph (docs/loopclosure.md).",
        ),
    ] = False,
) -> None:
    """Run a server and a simulated robot, print the dashboard's URL and operator token, wait for Ctrl-C."""
    source = world_source(world)
    if png is not None and (png.suffix.lower() != ".png" or not png.resolve().parent.is_dir()):
        raise LinemapError(f"--png {png}: expected a .png file in an existing folder")
    if not _port_free(host, port):
        raise LinemapError(f"port {port} on {host} is in use: stop what runs there or pass --port")
    directory.mkdir(parents=True, exist_ok=True)
    resume = _resume(directory, world) if keep else None
    if not keep:
        # the demo's own files only: a folder the user named may hold other things (their own logs)
        for pattern in ("server.db*", "robot.db*", "server.log", "agent.log", "demo.json*", "robot.token"):
            for old in directory.glob(pattern):
                old.unlink()
    db = directory / "server.db"
    base = f"http://{host}:{port}"
    token = subprocess.run(
        [*_linemap(), "server", "--db", str(db), "token", "create", "--name", "demo"],
        capture_output=True,
        text=True,
        check=False,
    )
    if token.returncode != 0:
        raise LinemapError(
            f"could not create the operator token: {token.stderr.strip() or token.stdout.strip()}"
        )
    op_token = token.stdout.strip().splitlines()[-1]

    stop = threading.Event()
    stop_on_signals(stop)
    server_args = ["server", "--db", str(db), "--host", host, "--port", str(port)]
    server = _Child("server", server_args, directory / "server.log")
    agent: _Child | None = None
    code = 0
    try:
        _wait_healthy(base, server)
        if resume is None:
            robot_id, robot_token, key_file, public_key, example, signature = _setup(
                base, op_token, directory
            )
            _save_robot_token(directory, robot_token)
        else:
            robot_id, robot_token, key_file, public_key, example, signature = resume
            typer.echo(f"linemap demo: resuming the last demo's robot (id {robot_id}) and map", err=True)
        agent = _Child(
            "agent",
            [
                "agent",
                "--source", source,
                "--laps", str(laps),
                "--server", base,
                "--robot-id", str(robot_id),
                "--db", str(directory / "robot.db"),
                "--trust-key", public_key,
                *(["--loop-closure"] if loop_closure else []),
            ],
            directory / "agent.log",
            env={"LINEMAP_ROBOT_TOKEN": robot_token},  # not on the command line: ps shows that to all
        )  # fmt: skip
        info = DemoInfo(
            f"{base}/", op_token, world, robot_id, ROBOT_NAME, key_file, public_key, example, signature,
            server.proc.pid, agent.proc.pid,
        )  # fmt: skip
        _banner(info, directory)
        # after the banner (scripts that wait for demo.json find the banner printed)
        _write_info(info, directory)
        deadline = None if for_s is None else time.monotonic() + for_s
        restarts: list[float] = []
        while not stop.wait(0.5):
            if deadline is not None and time.monotonic() >= deadline:
                typer.echo(f"linemap demo: {for_s:g} s are up", err=True)
                stop.set()
            if not agent.alive():
                typer.echo(
                    f"linemap demo: the agent stopped (code {agent.proc.returncode}); "
                    f"its log ends:\n{_tail(agent.log)}",
                    err=True,
                )
                code = 1
                stop.set()
            elif not server.alive() and not stop.is_set():
                now = time.monotonic()
                restarts = [t for t in restarts if now - t < 60.0] + [now]
                why = (
                    f"the server stopped (code {server.proc.returncode}); its log ends:\n{_tail(server.log)}"
                )
                if len(restarts) > SERVER_RESTARTS:
                    typer.echo(
                        f"linemap demo: {why}\n{SERVER_RESTARTS} restarts in a minute: giving up", err=True
                    )
                    code = 1
                    stop.set()
                    continue
                typer.echo(f"linemap demo: {why}\nrestarting it; the robot rides out the outage", err=True)
                server.stop(1.0)
                server = _Child("server", server_args, directory / "server.log")
                try:
                    _wait_healthy(base, server)
                except LinemapError as exc:
                    typer.echo(f"linemap demo: {exc}", err=True)
                    continue
                info = replace(info, server_pid=server.proc.pid)
                _write_info(info, directory)
        if png is not None and server.alive():
            summary = save_map_png(base, op_token, robot_id, world, png)
            typer.echo(f"linemap demo: the robot's map ({summary}) drawn to {png}", err=True)
    finally:
        typer.echo("linemap demo: stopping the robot agent and the server ...", err=True)
        if agent is not None:
            agent.stop(60.0)
        server.stop(20.0)
    typer.echo("linemap demo: stopped", err=True)
    if code:
        raise typer.Exit(code)


def _write_info(info: DemoInfo, directory: Path) -> None:
    """``DIR/demo.json``, atomically (never read half-written)."""
    partial = directory / "demo.json.partial"
    partial.write_text(json.dumps(asdict(info), indent=2) + "\n", encoding="utf-8")
    partial.replace(directory / "demo.json")


def _banner(info: DemoInfo, directory: Path) -> None:
    from rich.console import Console
    from rich.panel import Panel

    lines = [
        f"Dashboard:      [bold cyan]{info.url}[/]",
        f"Operator token: [bold]{info.operator_token}[/]   (paste it at the login)",
        f"Robot:          {info.robot_name} (id {info.robot_id}), patrolling the simulated world "
        f"'{info.world}' at 10 Hz",
        f"Signing key:    {info.private_key}  (trusted by the robot)",
    ]
    if info.example_kernel:
        lines.append(
            f"Example kernels: {Path(info.example_kernel).parent}/*.py, each with its signature (.sig) and "
            "parameter schema (.params.json) (upload them on the Kernels page)"
        )
    lines.append(f"Logs:           {directory / 'server.log'}, {directory / 'agent.log'}")
    lines.append("Stop with Ctrl-C.")
    Console(highlight=False).print(Panel("\n".join(lines), title="linemap demo", expand=False))
    sys.stdout.flush()
