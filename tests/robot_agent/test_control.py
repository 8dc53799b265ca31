"""Anti-rollback floors in robot_agent/control.py (docs/design.md §9: a robot never runs a version lower than
one it has already run for the same name unless the operator overrides it with <kernel-rollback
below-floor="allow">): the rule itself and apply_message refusing before it builds anything, without
processes. The floors' record in the Robot DB (kept across restarts, only ever raised, backfilled by the
migration) is in tests/robot_agent/test_store.py, more supply rules of control.py in
tests/robot_agent/test_control_supply.py, the same rule against a real server and agent in
tests/reliability/test_rel_supply_live.py."""

from __future__ import annotations

import pytest

from robot_agent.control import Prepared, apply_message, kernels_run, pin_versions, refuse_downgrades
from shared.control import parse_message
from shared.errors import LinemapError
from shared.pipeline import KernelChoice, PipelineConfig

SHA = "ab" * 32
FLOOR = {("noise-removal", "dbscan"): "1.2.0"}


def msg(body: str) -> bytes:
    return f"<xml><message>{body}</message></xml>".encode()


def op(kind: str, version: str, override: bool = False) -> str:
    sha = f' sha256="{SHA}"' if kind in ("install", "update") else ""
    below = ' below-floor="allow"' if override else ""
    return f'<kernel-{kind} stage="noise-removal" name="dbscan" version="{version}"{sha}{below}/>'


def running(version: str) -> PipelineConfig:
    """The default pipeline, pinned, with dbscan at ``version`` (built without registry checks)."""
    base = pin_versions(PipelineConfig())
    return base.model_copy(update={"noise_removal": (KernelChoice(name="dbscan", version=version),)})


@pytest.mark.parametrize("kind", ["install", "update"])
def test_install_or_update_below_the_floor_is_refused_naming_both_versions(kind: str) -> None:
    why = refuse_downgrades(parse_message(msg(op(kind, "1.1.0"))), FLOOR)
    assert why == (
        f"<kernel-{kind}> noise-removal/dbscan 1.1.0: version 1.1.0 is lower than 1.2.0, which this robot"
        " has already run (rollback attack?); to go back to 1.1.0 on purpose send"
        ' <kernel-rollback stage="noise-removal" name="dbscan" version="1.1.0" below-floor="allow"/>'
        " (an operator override, recorded in the server's audit log)"
    )


@pytest.mark.parametrize("version", ["1.2.0", "1.2.1", "2.0.0"])
def test_the_floor_itself_and_higher_versions_pass(version: str) -> None:
    assert refuse_downgrades(parse_message(msg(op("update", version))), FLOOR) is None


def test_other_kernels_and_unknown_floors_pass() -> None:
    other = '<kernel-update stage="clustering" name="kmeans" version="0.1.0" sha256="' + SHA + '"/>'
    assert refuse_downgrades(parse_message(msg(other)), FLOOR) is None
    assert refuse_downgrades(parse_message(msg(op("update", "0.0.1"))), {}) is None


def test_only_an_overriding_rollback_may_go_below_and_may_bring_its_version() -> None:
    plain = refuse_downgrades(parse_message(msg(op("rollback", "1.0.0"))), FLOOR) or ""
    assert plain.startswith("<kernel-rollback> noise-removal/dbscan 1.0.0") and 'below-floor="allow"' in plain
    assert refuse_downgrades(parse_message(msg(op("rollback", "1.0.0", True))), FLOOR) is None
    both = parse_message(msg(op("install", "1.1.0") + op("rollback", "1.1.0", True)))
    assert refuse_downgrades(both, FLOOR) is None
    # install plus a plain rollback (no override) is refused like the replay alone
    assert "1.1.0 is lower" in (
        refuse_downgrades(parse_message(msg(op("install", "1.1.0") + op("rollback", "1.1.0"))), FLOOR) or ""
    )
    # ... and the override covers only the version it names
    mixed = parse_message(msg(op("install", "1.0.5") + op("rollback", "1.1.0", True)))
    assert "1.0.5 is lower than 1.2.0" in (refuse_downgrades(mixed, FLOOR) or "")


def test_a_configuration_may_not_newly_select_a_version_below_the_floor() -> None:
    chosen = parse_message(msg("<noise-removal><dbscan><version>1.0.0</version></dbscan></noise-removal>"))
    new = running("1.0.0")
    why = refuse_downgrades(chosen, FLOOR, running("1.2.0"), new)
    assert why is not None and why.startswith("<noise-removal> noise-removal/dbscan 1.0.0: version 1.0.0")
    # Already running it (after an explicit rollback): other settings may change without a new rollback.
    mode_only = parse_message(msg("<mode>offline</mode>"))
    assert refuse_downgrades(mode_only, FLOOR, running("1.0.0"), new) is None


def test_apply_message_refuses_before_building_anything() -> None:
    current = pin_versions(PipelineConfig())  # built-in dbscan 1.0.0
    built: list[PipelineConfig] = []
    prepared = Prepared(7, parse_message(msg(op("update", "1.0.0"))))
    with pytest.raises(LinemapError, match=r"1\.0\.0 is lower than 1\.2\.0.*rollback attack\?"):
        apply_message(prepared, current, lambda c: None, lambda *k: None, built.append, floors=FLOOR)
    assert built == []
    rollback = Prepared(8, parse_message(msg(op("rollback", "1.0.0", True))))
    config = apply_message(rollback, current, lambda c: None, lambda *k: None, built.append, floors=FLOOR)
    assert built == [config] and ("noise-removal", "dbscan", "1.0.0") in kernels_run(config)
