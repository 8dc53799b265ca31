"""``linemap kernels --describe FILE``: the parameter schema of the one kernel a module file defines."""

from __future__ import annotations

from pathlib import Path

import pytest

from shared.cli.kernelfile import describe_kernel_file
from shared.errors import LinemapError

EXAMPLES = Path(__file__).parents[3] / "docs" / "examples"


def test_the_examples_describe_themselves() -> None:
    info = describe_kernel_file(EXAMPLES / "radius_outlier.py")
    assert (info["stage"], info["name"], info["version"]) == ("noise-removal", "radius-outlier", "1.0.0")
    props = info["parameters"]["properties"]
    assert props["radius_m"]["maximum"] == 5.0 and props["radius_m"]["unit"] == "m"
    assert info["parameters"]["additionalProperties"] is False
    assert describe_kernel_file(EXAMPLES / "dbscan_1_1_0.py")["version"] == "1.1.0"


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("VALUE = 1\n", "expected one kernel class defined in it, found 0"),
        ("raise RuntimeError('broken on import')\n", "importing it failed: RuntimeError: broken on import"),
        (
            "from shared.kernels.noise.dbscan import Dbscan\n"
            "class A(Dbscan):\n    version = '2.0.0'\n"
            "class B(Dbscan):\n    version = '2.0.1'\n",
            "found 2 (A, B)",
        ),
    ],
)
def test_a_file_without_exactly_one_kernel_is_refused(tmp_path: Path, text: str, needle: str) -> None:
    path = tmp_path / "mine.py"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(LinemapError, match=None) as info:
        describe_kernel_file(path)
    assert needle in str(info.value)


def test_a_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(LinemapError, match="no such file"):
        describe_kernel_file(tmp_path / "nope.py")
