"""The kernel supply rules of robot_agent.control, in-process: the anti-rollback floor holds for every
combination of operations within a message and across messages unless the operator overrides it
explicitly (``below-floor="allow"``), built-in versions and last fallbacks cannot be deleted, and a failed
kernel always has a fallback."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.control import (
    Prepared,
    apply_message,
    choices,
    fallback_choice,
    kernels_run,
    pin_versions,
    refuse_deletions,
    refuse_downgrades,
    registered,
)
from shared.control import parse_message
from shared.errors import LinemapError
from shared.kernels import REGISTRY, Kernel, Stage
from shared.kernels.noise.dbscan import Dbscan
from shared.kernels.versions import parse_version
from shared.pipeline import KernelChoice, PipelineConfig

SHA = "ab" * 32
VERSIONS = ["1.0.0", "1.1.0", "1.2.0", "1.3.0"]  # 1.0.0 is the built-in one


def msg(body: str) -> Any:
    return parse_message(f"<xml><message>{body}</message></xml>".encode())


def op(kind: str, version: str, override: bool = False, name: str = "dbscan") -> str:
    sha = f' sha256="{SHA}"' if kind in ("install", "update") else ""
    below = ' below-floor="allow"' if override else ""
    return f'<kernel-{kind} stage="noise-removal" name="{name}" version="{version}"{sha}{below}/>'


def _register(cls: type[Kernel[Any]]) -> None:
    REGISTRY.register(cls)


def _downloaded(version: str) -> type[Kernel[Any]]:
    return type(
        f"Dbscan_{version.replace('.', '_')}", (Dbscan,), {"version": version, "__module__": __name__}
    )


@pytest.fixture
def downloaded() -> Iterator[dict[str, type[Kernel[Any]]]]:
    """Downloaded dbscan versions 1.1.0 .. 1.3.0 (registered on demand by apply_message)."""
    classes = {v: _downloaded(v) for v in VERSIONS[1:]}
    yield classes
    for v in classes:
        REGISTRY.unregister(Stage.NOISE_REMOVAL, "dbscan", v)


# --- the floor: one rule for every path ------------------------------------------------------------


@pytest.mark.parametrize("kind", ["install", "update", "rollback"])
def test_every_operation_below_the_floor_needs_the_override(kind: str) -> None:
    floors = {("noise-removal", "dbscan"): "1.2.0"}
    why = refuse_downgrades(msg(op(kind, "1.1.0")), floors)
    assert why is not None and "1.1.0 is lower than 1.2.0" in why and 'below-floor="allow"' in why
    assert refuse_downgrades(msg(op(kind, "1.1.0") + op("rollback", "1.1.0", True)), floors) is None


def test_install_plus_plain_rollback_is_refused() -> None:
    floors = {("noise-removal", "dbscan"): "1.2.0"}
    why = refuse_downgrades(msg(op("install", "1.1.0") + op("rollback", "1.1.0")), floors)
    assert why is not None and why.startswith("<kernel-install> noise-removal/dbscan 1.1.0")


def test_the_override_covers_only_the_version_it_names() -> None:
    floors = {("noise-removal", "dbscan"): "1.2.0"}
    why = refuse_downgrades(msg(op("install", "1.0.5") + op("rollback", "1.1.0", True)), floors)
    assert why is not None and "1.0.5 is lower than 1.2.0" in why


def test_below_floor_is_only_an_attribute_of_rollback() -> None:
    with pytest.raises(LinemapError, match="unknown attribute 'below-floor'"):
        msg(op("install", "1.1.0", True))
    with pytest.raises(LinemapError, match='expected below-floor="allow"'):
        msg(op("rollback", "1.1.0").replace("/>", ' below-floor="yes"/>'))


OPS = st.lists(
    st.tuples(
        st.sampled_from(["install", "update", "rollback", "delete", "select"]),
        st.sampled_from(VERSIONS),
        st.booleans(),
    ),
    min_size=1,
    max_size=4,
)


def _xml(ops: list[tuple[str, str, bool]]) -> str:
    out = []
    for kind, version, override in ops:
        if kind == "select":
            out.append(f"<noise-removal><dbscan><version>{version}</version></dbscan></noise-removal>")
        else:
            out.append(op(kind, version, override and kind == "rollback"))
    return "".join(out)


@settings(max_examples=300, deadline=None)
@given(st.lists(OPS, min_size=1, max_size=6))
def test_no_sequence_of_messages_runs_below_the_floor_without_the_override(
    messages: list[list[tuple[str, str, bool]]],
) -> None:
    """A simulated robot applies random messages with apply_message; whatever it ends up running, a version
    below the floor in force was only ever put in force by a message overriding it for that version."""
    classes = {v: _downloaded(v) for v in VERSIONS[1:]}
    config = pin_versions(PipelineConfig())
    floors: dict[tuple[str, str], str] = {}
    start = Prepared(
        0, msg(op("update", "1.2.0")), classes={("noise-removal", "dbscan", "1.2.0"): classes["1.2.0"]}
    )
    config = apply_message(start, config, _register, REGISTRY.unregister, lambda c: None, floors)
    for key, version in ((k[:2], k[2]) for k in kernels_run(config)):
        floors[key] = version  # running (and floor) 1.2.0; 1.0.0 built in, 1.1.0 and 1.3.0 downloadable
    try:
        for seq, ops in enumerate(messages, 1):
            try:
                message = msg(_xml(ops))
            except LinemapError:
                continue  # e.g. two <noise-removal> elements: the parser refuses it, nothing changes
            prepared = Prepared(seq, message)
            for kind, version, _ in ops:
                if kind in ("install", "update") and version in classes and version != "1.2.0":
                    prepared.classes[("noise-removal", "dbscan", version)] = classes[version]
            floor = floors.get(("noise-removal", "dbscan"), "0.0.0")
            before = {c.version for c in choices(config, Stage.NOISE_REMOVAL)}
            try:
                config = apply_message(
                    prepared, config, _register, REGISTRY.unregister, lambda c: None, floors
                )
            except LinemapError:
                continue
            overridden = {v for k, v, o in ops if k == "rollback" and o}
            for c in choices(config, Stage.NOISE_REMOVAL):
                assert c.version is not None
                if parse_version(c.version) < parse_version(floor) and c.version not in before:
                    assert c.version in overridden, (ops, c.version, floor)
            for key3 in kernels_run(config):
                old = floors.get(key3[:2])
                if old is None or parse_version(key3[2]) > parse_version(old):
                    floors[key3[:2]] = key3[2]
    finally:
        for v in VERSIONS[1:]:
            REGISTRY.unregister(Stage.NOISE_REMOVAL, "dbscan", v)


# --- deletions and fallbacks -----------------------------------------------------------------------


def _running(version: str) -> PipelineConfig:
    base = pin_versions(PipelineConfig())
    return base.model_copy(update={"noise_removal": (KernelChoice(name="dbscan", version=version),)})


def test_the_built_in_fallback_of_the_kernel_in_service_cannot_be_deleted(downloaded: Any) -> None:
    REGISTRY.register(downloaded["1.1.0"])
    why = refuse_deletions(msg(op("delete", "1.0.0")).operations, _running("1.1.0"), registered())
    assert why is not None and "built-in version cannot be deleted" in why and "dbscan 1.1.0" in why


def test_the_last_downloaded_fallback_cannot_be_deleted() -> None:
    reg = [("noise-removal", "mine", "1.0.0", False), ("noise-removal", "mine", "2.0.0", False)]
    config = pin_versions(PipelineConfig()).model_copy(
        update={"noise_removal": (KernelChoice(name="mine", version="2.0.0"),)}
    )
    why = refuse_deletions(msg(op("delete", "1.0.0", name="mine")).operations, config, reg)
    assert why is not None and "last fallback of noise-removal/mine 2.0.0" in why
    reg.append(("noise-removal", "mine", "1.5.0", False))
    assert refuse_deletions(msg(op("delete", "1.0.0", name="mine")).operations, config, reg) is None
    both = msg(op("delete", "1.0.0", name="mine") + op("delete", "1.5.0", name="mine")).operations
    assert "last fallback" in (refuse_deletions(both, config, reg) or "")


def test_apply_message_refuses_the_delete_and_changes_nothing(downloaded: Any) -> None:
    current = pin_versions(PipelineConfig())
    built: list[PipelineConfig] = []
    install = Prepared(
        1, msg(op("update", "1.1.0")), classes={("noise-removal", "dbscan", "1.1.0"): downloaded["1.1.0"]}
    )
    current = apply_message(install, current, _register, REGISTRY.unregister, built.append)
    with pytest.raises(LinemapError, match="built-in version cannot be deleted"):
        apply_message(
            Prepared(2, msg(op("delete", "1.0.0"))),
            current,
            _register,
            REGISTRY.unregister,
            built.append,
        )
    assert REGISTRY.get(Stage.NOISE_REMOVAL, "dbscan", "1.0.0") is Dbscan


@given(
    st.sampled_from([s for s in Stage]),
    st.text(alphabet="abcdefgh-", min_size=1, max_size=8).filter(lambda n: n[0] != "-" and n[-1] != "-"),
)
def test_every_failed_kernel_has_a_fallback(stage: Stage, name: str) -> None:
    pick = fallback_choice(stage, name, "9.9.9", None, registered())
    assert pick is not None
    REGISTRY.get(stage, *pick)  # registered


def test_fallback_prefers_the_version_it_replaced_then_a_built_in() -> None:
    reg = [("noise-removal", "dbscan", "1.0.0", True), ("noise-removal", "dbscan", "1.1.0", False)]
    assert fallback_choice(Stage.NOISE_REMOVAL, "dbscan", "1.2.0", _running("1.1.0"), reg) == (
        "dbscan",
        "1.1.0",
    )
    assert fallback_choice(Stage.NOISE_REMOVAL, "dbscan", "1.2.0", None, reg) == ("dbscan", "1.0.0")
    only_new = [("noise-removal", "mine", "1.0.0", False), ("noise-removal", "dbscan", "1.0.0", True)]
    assert fallback_choice(Stage.NOISE_REMOVAL, "mine", "1.0.0", None, only_new) == ("dbscan", "1.0.0")
