"""Verified kernel loading for the robot agent: digest, signature, import, dry run.

Each kernel here is a small module source written as a string, signed with :mod:`shared.signing` like an
operator would, and checked to be accepted or refused with the right reason. After every test the global
kernel registry holds exactly what it held before, and no failed load leaves a module behind. The dry-run
tests assert behaviour only: the hanging kernel relies on the budget kill, with small budgets.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from robot_agent.errors import AgentError, KernelRejected
from robot_agent.kernels.artifact import verify_artifact
from robot_agent.kernels.conformance import check_conformance
from robot_agent.kernels.dryrun import DryRunReport, dry_run
from robot_agent.kernels.loading import load_kernel_class, module_name
from shared.errors import LinemapError, UnknownKernelError
from shared.kernels import REGISTRY, Lines, NoiseRemovalKernel, Stage
from shared.kernels.conformance import check_result
from shared.pipeline.probe import stage_inputs as _stage_inputs
from shared.signing import (
    KeyPair,
    generate_keypair,
    load_private_key,
    load_public_key,
    sha256_hex,
    sign_digest,
)
from shared.sim import default_world, simulate_scan
from shared.types import Pose2D, Scan

# ------------------------------------------------------------------------------------ kernel sources
HEADER = """\
from __future__ import annotations

import numpy as np

from shared.kernels import KernelParams, NoiseRemovalKernel, NoiseResult, param, register


class KeepAllParams(KernelParams):
    margin_m: float = param(0.0, description="Unused margin", unit="m", ge=0.0, le=1.0)


"""

KEEP_ALL_CLASS = '''\
class KeepAll(NoiseRemovalKernel[KeepAllParams]):
    """Keeps every finite point."""

    name = "{name}"
    version = "{version}"
    Params = KeepAllParams

    def apply(self, points):
{body}
'''

GOOD_BODY = """\
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        keep = np.all(np.isfinite(pts), axis=1)
        out = pts[keep].copy()
        labels = np.zeros(len(out), dtype=np.intp)
        for arr in (keep, out, labels):
            arr.setflags(write=False)
        return NoiseResult(keep, out, labels)"""

RAISES_BODY = """\
        raise ValueError("kaboom")"""

HANGS_BODY = """\
        while True:
            pass"""

HOG_BODY = """\
        blocks = []
        while True:
            blocks.append(np.ones(1 << 20))  # 8 MB, written"""

GARBAGE_BODY = """\
        return NoiseResult(np.ones(3, dtype=bool), np.full((2, 3), np.nan), np.zeros(7, dtype=np.intp))"""


def kernel_source(
    body: str = GOOD_BODY,
    *,
    name: str = "keep-all",
    version: str = "1.0.0",
    decorate: str = "",
    after: str = "",
) -> bytes:
    """A noise-removal kernel module; ``decorate`` goes above the class, ``after`` below it."""
    cls = KEEP_ALL_CLASS.format(name=name, version=version, body=body)
    return (HEADER + decorate + cls + after).encode()


GOOD = kernel_source()

# --------------------------------------------------------------------------------------------- fixtures


@pytest.fixture(autouse=True)
def registry_and_modules_unchanged() -> Iterator[None]:
    """Every test leaves the global registry as it found it; loaded kernel modules are dropped after."""
    before = {(i.stage, i.name, i.version): i.cls for i in REGISTRY}
    modules = {m for m in sys.modules if m.startswith("linemap_kernel_")}
    yield
    assert {(i.stage, i.name, i.version): i.cls for i in REGISTRY} == before
    for m in [m for m in sys.modules if m.startswith("linemap_kernel_") and m not in modules]:
        del sys.modules[m]


@pytest.fixture(scope="module")
def operator() -> KeyPair:
    return generate_keypair()


@pytest.fixture(scope="module")
def trusted(operator: KeyPair) -> list[Ed25519PublicKey]:
    return [load_public_key(generate_keypair().public_b64), load_public_key(operator.public_b64)]


@pytest.fixture(scope="module")
def scans() -> list[Scan]:
    """Three scans of the default world along a short drive, with odometry."""
    rng = np.random.default_rng(7)
    out = []
    for i in range(3):
        pose = Pose2D(4.5 - 0.1 * i, 2.0, np.pi)
        scan = simulate_scan(default_world(), pose, rng, stamp_s=0.1 * i)
        out.append(Scan(**{**_fields(scan), "odometry": pose}))
    return out


def _fields(scan: Scan) -> dict[str, Any]:
    names = ("stamp_s", "angle_min_rad", "angle_increment_rad", "range_min_m", "range_max_m", "ranges_m")
    return {n: getattr(scan, n) for n in names}


def sign(operator: KeyPair, source: bytes) -> str:
    return sign_digest(load_private_key(operator.private_pem), sha256_hex(source))


# ------------------------------------------------------------------------------------ verify_artifact


def test_signed_artifact_is_accepted_with_the_signing_key_id(
    operator: KeyPair, trusted: list[Ed25519PublicKey]
) -> None:
    got = verify_artifact(GOOD, sha256_hex(GOOD), sign(operator, GOOD), trusted)
    assert got == operator.key_id


def test_sha256_mismatch_is_refused(operator: KeyPair, trusted: list[Ed25519PublicKey]) -> None:
    wrong = sha256_hex(b"something else")
    with pytest.raises(KernelRejected) as exc:
        verify_artifact(GOOD, wrong, sign(operator, GOOD), trusted)
    assert exc.value.reason == f"sha256 mismatch: expected {wrong}, got {sha256_hex(GOOD)}"


def test_tampered_source_is_refused(operator: KeyPair, trusted: list[Ed25519PublicKey]) -> None:
    tampered = GOOD.replace(b"Keeps every", b"Keeps all")
    with pytest.raises(KernelRejected, match="sha256 mismatch"):
        verify_artifact(tampered, sha256_hex(GOOD), sign(operator, GOOD), trusted)


def test_signature_by_an_untrusted_key_is_refused(trusted: list[Ed25519PublicKey]) -> None:
    stranger = generate_keypair()
    with pytest.raises(KernelRejected) as exc:
        verify_artifact(GOOD, sha256_hex(GOOD), sign(stranger, GOOD), trusted)
    assert exc.value.reason.startswith("bad signature: it verifies with none of the trusted keys")


def test_signature_over_another_artifact_is_refused(
    operator: KeyPair, trusted: list[Ed25519PublicKey]
) -> None:
    other = kernel_source(RAISES_BODY)
    with pytest.raises(KernelRejected, match=r"^bad signature"):
        verify_artifact(GOOD, sha256_hex(GOOD), sign(operator, other), trusted)


def test_malformed_signature_is_refused(trusted: list[Ed25519PublicKey]) -> None:
    with pytest.raises(KernelRejected, match=r"^bad signature: signature: not valid base64"):
        verify_artifact(GOOD, sha256_hex(GOOD), "not base64 !!", trusted)


@pytest.mark.parametrize("signature", [None, ""])
def test_unsigned_kernel_is_refused_unless_allowed(
    signature: str | None, trusted: list[Ed25519PublicKey]
) -> None:
    with pytest.raises(KernelRejected) as exc:
        verify_artifact(GOOD, sha256_hex(GOOD), signature, trusted)
    assert exc.value.reason == (
        "unsigned kernel refused; run the agent with --allow-unsigned for development"
    )
    assert verify_artifact(GOOD, sha256_hex(GOOD), signature, trusted, allow_unsigned=True) is None
    assert verify_artifact(GOOD, sha256_hex(GOOD), signature, [], allow_unsigned=True) is None


def test_bad_signature_is_refused_even_when_unsigned_is_allowed(trusted: list[Ed25519PublicKey]) -> None:
    stranger = generate_keypair()
    with pytest.raises(KernelRejected, match=r"^bad signature"):
        verify_artifact(GOOD, sha256_hex(GOOD), sign(stranger, GOOD), trusted, allow_unsigned=True)


def test_no_trusted_keys_is_refused_clearly(operator: KeyPair) -> None:
    with pytest.raises(KernelRejected, match="trusts no signing key"):
        verify_artifact(GOOD, sha256_hex(GOOD), sign(operator, GOOD), [])


def test_rejections_are_agent_errors() -> None:
    exc = KernelRejected("why")
    assert isinstance(exc, AgentError) and isinstance(exc, LinemapError)
    assert exc.reason == str(exc) == "why"


# ---------------------------------------------------------------------------------- load_kernel_class


def test_load_returns_the_class_in_its_own_module() -> None:
    cls = load_kernel_class(GOOD, Stage.NOISE_REMOVAL, "keep-all", "1.0.0")
    assert issubclass(cls, NoiseRemovalKernel) and cls.ident() == "noise-removal/keep-all@1.0.0"
    assert cls.__module__ == module_name("keep-all", "1.0.0") == "linemap_kernel_keep_all_1_0_0"
    assert sys.modules[cls.__module__].__dict__["KeepAll"] is cls
    kernel = cls({"margin_m": 0.5})
    assert kernel.get_params() == {"margin_m": 0.5}
    with pytest.raises(UnknownKernelError):
        REGISTRY.get("noise-removal", "keep-all")  # loading never registers


def test_loading_twice_gives_two_distinct_classes() -> None:
    a = load_kernel_class(GOOD, "noise-removal", "keep-all", "1.0.0")
    b = load_kernel_class(GOOD, "noise-removal", "keep-all", "1.0.0")
    assert a is not b and a.__module__ == b.__module__


def _refusal(
    source: bytes, stage: str = "noise-removal", name: str = "keep-all", version: str = "1.0.0"
) -> str:
    modules = set(sys.modules)
    with pytest.raises(KernelRejected) as exc:
        load_kernel_class(source, stage, name, version)
    assert module_name(name, version) not in sys.modules  # removed on failure
    assert set(sys.modules) - modules == set()
    return exc.value.reason


def test_syntax_error_is_refused_with_its_line() -> None:
    source = GOOD + b"\ndef broken(:\n    pass\n"
    line = source.decode().splitlines().index("def broken(:") + 1
    reason = _refusal(source)
    assert reason.startswith("import failed: SyntaxError: ") and reason.endswith(f"(line {line})")


def test_missing_import_is_refused_with_its_line() -> None:
    reason = _refusal(b"import numpy\nimport no_such_module_here\n")
    assert reason == "import failed: ModuleNotFoundError: No module named 'no_such_module_here' (line 2)"


def test_exception_at_import_is_refused() -> None:
    reason = _refusal(GOOD + b"raise RuntimeError('no robot here')\n")
    assert reason.startswith("import failed: RuntimeError: no robot here (line ")


def test_sys_exit_at_import_is_refused() -> None:
    reason = _refusal(b"import sys\nsys.exit(3)\n")
    assert reason == "import failed: SystemExit: 3 (line 2)"


@pytest.mark.parametrize(
    ("name", "version", "expected"),
    [
        ("keep-some", "1.0.0", "the module defines no kernel noise-removal/keep-some@1.0.0"),
        ("keep-all", "2.0.0", "the module defines no kernel noise-removal/keep-all@2.0.0"),
    ],
)
def test_wrong_name_or_version_is_refused_naming_what_was_found(
    name: str, version: str, expected: str
) -> None:
    reason = _refusal(GOOD, name=name, version=version)
    assert reason == f"{expected}: found noise-removal/keep-all@1.0.0"


def test_wrong_stage_is_refused() -> None:
    reason = _refusal(GOOD, stage="clustering")
    assert (
        reason == "the module defines no kernel clustering/keep-all@1.0.0: found noise-removal/keep-all@1.0.0"
    )


def test_module_without_kernels_is_refused() -> None:
    assert (
        _refusal(b"X = 1\n")
        == "the module defines no kernel noise-removal/keep-all@1.0.0: found no kernel class"
    )


def test_unknown_stage_is_refused() -> None:
    assert _refusal(GOOD, stage="teleport").startswith("unknown stage 'teleport'")


def test_bad_declaration_is_refused() -> None:
    reason = _refusal(kernel_source(version="1.0"), version="1.0")
    assert reason.startswith("invalid kernel declaration: kernel keep-all: version '1.0' is invalid")


def test_self_registering_kernel_is_not_left_registered() -> None:
    source = kernel_source(decorate="@register\n")
    cls = load_kernel_class(source, "noise-removal", "keep-all", "1.0.0")
    assert cls.ident() == "noise-removal/keep-all@1.0.0"
    assert not [i for i in REGISTRY if i.name == "keep-all"]  # undone; the autouse fixture checks all


def test_self_registering_kernel_that_then_fails_is_undone() -> None:
    source = kernel_source(decorate="@register\n", after="\nraise ImportError('late failure')\n")
    assert _refusal(source).startswith("import failed: ImportError: late failure (line ")
    assert not [i for i in REGISTRY if i.name == "keep-all"]


def test_self_registering_under_a_builtin_identity_is_refused() -> None:
    source = kernel_source(name="dbscan", decorate="@register\n")
    reason = _refusal(source, name="dbscan")
    assert reason.startswith(
        "import failed: DuplicateKernelError: kernel noise-removal/dbscan@1.0.0 is already"
    )
    assert REGISTRY.get("noise-removal", "dbscan").__module__ == "shared.kernels.noise.dbscan"


def test_module_tampering_with_the_registry_is_undone() -> None:
    source = (
        GOOD
        + b"\nfrom shared.kernels import REGISTRY\nREGISTRY.unregister('noise-removal', 'dbscan', '1.0.0')\n"
    )
    load_kernel_class(source, "noise-removal", "keep-all", "1.0.0")
    assert REGISTRY.get("noise-removal", "dbscan").__module__ == "shared.kernels.noise.dbscan"


def test_failed_load_restores_a_previous_module_of_the_same_name() -> None:
    first = load_kernel_class(GOOD, "noise-removal", "keep-all", "1.0.0")
    with pytest.raises(KernelRejected, match="import failed: RuntimeError: x"):
        load_kernel_class(b"raise RuntimeError('x')\n", "noise-removal", "keep-all", "1.0.0")
    assert sys.modules[first.__module__].__dict__["KeepAll"] is first


# ---------------------------------------------------------------------------------- check_conformance


def test_conforming_kernel_passes() -> None:
    cls = load_kernel_class(GOOD, "noise-removal", "keep-all", "1.0.0")
    check_conformance(cls)
    check_conformance(cls, {"margin_m": 0.2})


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        (RAISES_BODY, "empty: noise-removal/keep-all@1.0.0: raised ValueError: kaboom"),
        (GARBAGE_BODY, "NoiseResult.keep is bool (3,): expected bool (0,)"),
    ],
)
def test_non_conforming_kernel_is_refused_with_the_problems(body: str, expected: str) -> None:
    cls = load_kernel_class(kernel_source(body), "noise-removal", "keep-all", "1.0.0")
    with pytest.raises(KernelRejected) as exc:
        check_conformance(cls)
    assert exc.value.reason.startswith("conformance failed for noise-removal/keep-all@1.0.0 (")
    assert expected in exc.value.reason


# ---------------------------------------------------------------------------------------------- dry run


def test_stage_inputs_follow_the_default_pipeline(scans: list[Scan]) -> None:
    from shared.pipeline import PipelineConfig

    segmenter = PipelineConfig().segmentation.build(Stage.SEGMENTATION)
    seg = _stage_inputs(Stage.SEGMENTATION, scans)
    assert [args[0] for args, _ in seg] == scans
    noise = _stage_inputs(Stage.NOISE_REMOVAL, scans)
    assert len(noise) == 3 and all(args[0].shape == (n, 2) and n > 100 for args, n in noise)
    for scan, ((points,), _) in zip(scans, noise, strict=True):  # the default pipeline's segmentation
        assert np.array_equal(points, segmenter.apply(scan).points)  # type: ignore[attr-defined]
    clusters = _stage_inputs(Stage.CLUSTERING, scans)
    assert all(n <= noise_n for (_, n), (_, noise_n) in zip(clusters, noise, strict=True))
    lines = _stage_inputs(Stage.STRAIGHT_LINE, scans)
    assert len(lines) == 6  # per scan: (points, groups), then (centroids, centroid groups)
    for (pts, groups), n in (item for item in lines):
        assert pts.shape == (n, 2) and groups.shape == (n,) and n > 0
    hough = REGISTRY.create("straight-line", "hough-cluster")
    cj = REGISTRY.create("straight-line", "centroid-join")
    for (args, n), kernel in zip(lines, [hough, cj] * 3, strict=True):
        result = kernel.apply(*args)  # type: ignore[attr-defined]
        assert isinstance(result, Lines) and result.n_lines > 0
        assert check_result(Stage.STRAIGHT_LINE, result, n) == []
    matching = _stage_inputs(Stage.SCAN_MATCHING, scans)
    assert len(matching) == 2  # consecutive pairs
    (_ref, _cur, initial), _ = matching[0]
    odo0, odo1 = scans[0].odometry, scans[1].odometry
    assert odo0 is not None and odo1 is not None
    assert initial == odo0.between(odo1)
    assert len(_stage_inputs(Stage.SCAN_MATCHING, scans[:1])) == 1
    assert len(_stage_inputs(Stage.NOISE_REMOVAL, [])) == 1  # no scans: a simulated room scan


def _dry(source: bytes, scans: list[Scan], budget_s: float = 20.0, **kw: Any) -> DryRunReport:
    params = kw.pop("params", None)
    name = kw.pop("name", "keep-all")
    return dry_run(source, "noise-removal", name, "1.0.0", params, scans, budget_s, **kw)


def _dry_refusal(source: bytes, scans: list[Scan], budget_s: float = 20.0, **kw: Any) -> str:
    with pytest.raises(KernelRejected) as exc:
        _dry(source, scans, budget_s, **kw)
    assert exc.value.reason.startswith("dry run: ")
    return exc.value.reason


def test_dry_run_of_a_good_kernel_reports_timing(scans: list[Scan]) -> None:
    report = _dry(GOOD, scans, params={"margin_m": 0.1})
    assert report.calls == len(scans)
    assert 0.0 <= report.median_ms <= report.max_ms
    assert report.load_ms >= 0.0 and report.startup_ms > 0.0 and report.total_ms > 0.0


def test_dry_run_refuses_a_kernel_that_raises(scans: list[Scan]) -> None:
    source = kernel_source(RAISES_BODY)
    line = source.decode().splitlines().index('        raise ValueError("kaboom")') + 1
    reason = _dry_refusal(source, scans)
    assert reason == f"dry run: the kernel raised ValueError: kaboom (line {line}) on input 1 of 3"


def test_dry_run_kills_a_kernel_that_hangs(scans: list[Scan]) -> None:
    reason = _dry_refusal(kernel_source(HANGS_BODY), scans, budget_s=0.3)
    assert reason.startswith("dry run: ran longer than its 300 ms budget")


def test_dry_run_refuses_a_kernel_that_allocates_without_bound(scans: list[Scan]) -> None:
    reason = _dry_refusal(kernel_source(HOG_BODY), scans, memory_limit_mb=128)
    assert "out of memory" in reason and "128 MB" in reason


def test_dry_run_refuses_garbage_results(scans: list[Scan]) -> None:
    reason = _dry_refusal(kernel_source(GARBAGE_BODY), scans)
    assert reason.startswith("dry run: result check failed on input 1 of 3: NoiseResult.keep is bool (3,)")


def test_dry_run_refuses_what_load_refuses(scans: list[Scan]) -> None:
    reason = _dry_refusal(GOOD, scans, name="keep-some")
    assert reason == (
        "dry run: the module defines no kernel noise-removal/keep-some@1.0.0:"
        " found noise-removal/keep-all@1.0.0"
    )
    assert _dry_refusal(b"def f(:\n", scans).startswith("dry run: import failed: SyntaxError: ")


def test_dry_run_refuses_bad_parameters(scans: list[Scan]) -> None:
    reason = _dry_refusal(GOOD, scans, params={"margin_m": 5.0})
    assert reason.startswith("dry run: parameters rejected: invalid parameters for kernel 'keep-all'")
