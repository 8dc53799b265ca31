"""The ``linemap`` console command, run as a user runs it (a real subprocess of the installed script)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from shared.cli.render import kernel_markdown
from shared.kernels import REGISTRY

ROOT = Path(__file__).resolve().parents[3]


def linemap(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("linemap", path=str(Path(sys.executable).parent))
    assert exe is not None, "the linemap console script is installed next to the interpreter"
    return subprocess.run([exe, *args], capture_output=True, text=True, timeout=600, check=False, cwd=cwd)


def test_kernels_json_lists_every_kernel_with_schema() -> None:
    out = linemap("kernels", "--json")
    assert out.returncode == 0, out.stderr
    catalogue = json.loads(out.stdout)
    names = {(k["stage"], k["name"]) for k in catalogue}
    assert ("noise-removal", "dbscan") in names and ("scan-matching", "icp") in names
    assert all(k["parameters"]["type"] == "object" for k in catalogue)


def test_readme_catalogue_matches_the_registry() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert kernel_markdown(REGISTRY.list()) in readme, (
        "README's kernel catalogue is stale: paste the output of `linemap kernels --markdown`"
    )


def test_bad_option_is_a_clear_error_not_a_traceback() -> None:
    out = linemap("bench", "kernels", "--runs", "1")
    assert out.returncode == 2
    assert "Traceback" not in out.stderr and "--runs" in out.stderr


@pytest.mark.slow
def test_bench_writes_json_figures(tmp_path: Path) -> None:
    target = tmp_path / "bench.json"
    out = linemap("bench", "kernels", "--runs", "5", "--json", str(target))
    assert out.returncode == 0, out.stderr
    figures = json.loads(target.read_text())
    step = figures["online_step"]
    assert step["median_ms"] > 0 and step["p99_ms"] >= step["median_ms"] and step["baseline_median_ms"] > 0
    assert "noise-removal/dbscan" in figures["kernels"]
    assert figures["quality"]["dbscan_keep_identical_to_sklearn"]["value"] is True
    assert "online_step" in out.stdout


def test_unwritable_json_path_is_reported(tmp_path: Path) -> None:
    out = linemap("bench", "kernels", "--runs", "5", "--json", str(tmp_path / "missing-dir" / "x.json"))
    assert out.returncode == 2
    assert "cannot write" in out.stderr and "Traceback" not in out.stderr


def _raise_from_ctrl_c() -> None:
    """What numba raises when Ctrl-C arrives inside a compiled function: a SystemError chained to it."""
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt as ctrl_c:
        raise SystemError("CPUDispatcher(<function f>) returned a result with an exception set") from ctrl_c


def test_ctrl_c_inside_compiled_code_is_an_interruption_not_a_bug(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from shared.cli import main as cli_main

    monkeypatch.setattr(cli_main, "app", _raise_from_ctrl_c)
    with pytest.raises(SystemExit) as caught:
        cli_main.main()
    assert caught.value.code == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "internal error" not in err


def test_an_unexpected_failure_is_still_called_a_bug(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from shared.cli import main as cli_main

    def broken() -> None:
        raise SystemError("returned a result with an exception set")

    monkeypatch.setattr(cli_main, "app", broken)
    with pytest.raises(SystemExit) as caught:
        cli_main.main()
    assert caught.value.code == 3
    assert "internal error: SystemError" in capsys.readouterr().err
