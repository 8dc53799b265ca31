"""``linemap demo --world``: the paper's room, any kind of the scenario suite, or a world file; a bad value
is refused before anything starts, naming it and listing the kinds. ``--for-s`` and ``--png`` end the demo
by themselves with a picture of the robot's map."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest

from shared.cli.demo_world import DEFAULT_WORLD, true_walls, world_names, world_source
from shared.errors import LinemapError
from shared.sim import default_world, save_world
from shared.sim.worlds import KINDS, build_scene

LINEMAP = str(Path(sys.executable).parent / "linemap")


def test_every_suite_kind_is_a_demo_world() -> None:
    assert world_names() == ["room", *KINDS]
    assert world_source(DEFAULT_WORLD) == "sim"  # the default stays the paper's room
    for kind in KINDS:
        assert world_source(kind) == f"sim:{kind}"


def test_a_world_file_is_a_demo_world(tmp_path: Path) -> None:
    path = tmp_path / "mine.toml"
    save_world(default_world(), path)
    assert world_source(str(path)) == f"sim:{path.resolve()}"
    assert true_walls(str(path), 0.0).shape == default_world().walls.shape
    with pytest.raises(LinemapError, match="no such world file"):
        world_source(str(tmp_path / "missing.json"))


@pytest.mark.parametrize("bad", ["corridor", "Room", "", "people_across"])
def test_an_unknown_world_names_itself_and_lists_the_kinds(bad: str) -> None:
    with pytest.raises(LinemapError) as err:
        world_source(bad)
    text = str(err.value)
    assert f"--world {bad!r}" in text
    assert all(name in text for name in world_names())


def test_the_true_walls_are_the_scenes_at_that_time() -> None:
    scene = build_scene("door-opens", 0)
    late = 10_000.0
    assert (true_walls("door-opens", late) == scene.truth(late)[0].walls).all()
    assert (true_walls("room", 0.0) == default_world().walls).all()


def test_the_demo_refuses_a_bad_world_before_starting(tmp_path: Path) -> None:
    r = subprocess.run(
        [LINEMAP, "demo", "--world", "atrium", "--dir", str(tmp_path / "d")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and "'atrium'" in r.stderr and "corridor-long" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "d" / "server.db").exists()


def test_the_demo_patrols_a_suite_world_and_draws_its_map(tmp_path: Path) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    png = tmp_path / "map.png"
    args = ["--world", "glass-black", "--for-s", "10", "--png", str(png), "--port", str(port)]
    r = subprocess.run(
        [LINEMAP, "demo", "--dir", str(tmp_path / "d"), *args], capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert "patrolling the simulated world" in r.stdout and "'glass-black'" in r.stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and f"drawn to {png}" in r.stderr
    assert "source sim:glass-black" in (tmp_path / "d" / "agent.log").read_text()
