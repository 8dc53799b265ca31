"""Parsing control messages: the paper's Listing 1, units, case, the extensions, and precise rejections."""

from __future__ import annotations

from pathlib import Path

import pytest

from shared.control import (
    NO_SCAN_MATCHING,
    ControlMessage,
    ControlMessageError,
    KernelOperation,
    KernelSpec,
    OperationKind,
    ScheduleEntry,
    parse_message,
)
from shared.errors import LinemapError
from shared.kernels import Stage
from shared.pipeline import Mode

LISTING1 = Path(__file__).parent / "fixtures" / "listing1.xml"
SHA = "ab" * 32


def wrap(body: str) -> str:
    """A message document around ``body`` (the elements inside ``<message>``); ``body`` starts on line 3."""
    return f'<?xml version="1.0"?>\n<xml><message>\n{body}\n</message></xml>\n'


def reject(doc: str | bytes, *fragments: str) -> ControlMessageError:
    with pytest.raises(ControlMessageError) as info:
        parse_message(doc)
    for fragment in fragments:
        assert fragment in str(info.value), (fragment, str(info.value))
    return info.value


# ------------------------------------------------------------------------------------------- Listing 1


def test_listing1_as_printed() -> None:
    msg = parse_message(LISTING1.read_bytes())
    assert msg == ControlMessage(
        mode=Mode.ONLINE,
        noise_removal=(
            KernelSpec.of("dbscan", {"min_points": 15, "epsilon_m": 0.05}),
            KernelSpec.of("erosion", {"element": "PLUSx4"}),
        ),
        clustering=KernelSpec.of("kmeans", {"n_clusters": 2}),
        straight_line=KernelSpec.of("hough"),
    )
    assert isinstance(msg.noise_removal[0].params_dict()["min_points"], int)  # type: ignore[index]
    assert msg.seq is None and msg.scan_matching is None and msg.operations == ()


def test_listing1_as_str_and_line_numbers_kept() -> None:
    msg = parse_message(LISTING1.read_text(encoding="utf-8"))
    assert msg.line_of("mode") == 4 and msg.line_of("straight-line-method") == 29
    dbscan = msg.noise_removal[0]  # type: ignore[index]
    assert dbscan.line == 8 and dbscan.param_line("min_points") == 9 and dbscan.param_line("epsilon_m") == 12


def test_listing1_bad_value_names_line_and_element() -> None:
    doc = LISTING1.read_text(encoding="utf-8").replace("15", "fifteen")
    err = reject(doc)
    assert str(err) == "line 9 <minpts>: 'fifteen' is not an integer"
    assert isinstance(err, LinemapError) and err.line == 9 and err.element == "<minpts>"


# ------------------------------------------------------------------------------------------------ units


@pytest.mark.parametrize(
    ("epsilon", "metres"),
    [
        ("<epsilon>5</epsilon>", 0.05),
        ('<epsilon unit="cm"> 5 </epsilon>', 0.05),
        ('<epsilon unit="m">0.05</epsilon>', 0.05),
        ('<epsilon unit="mm">50</epsilon>', 0.05),
        ('<epsilon unit="m">2.5e-1</epsilon>', 0.25),
        ('<epsilon unit="mm">\n 7 \n</epsilon>', 0.007),
    ],
)
def test_length_units(epsilon: str, metres: float) -> None:
    msg = parse_message(wrap(f"<noise-removal><dbscan>{epsilon}</dbscan></noise-removal>"))
    assert msg.noise_removal[0].params_dict()["epsilon_m"] == pytest.approx(metres, rel=1e-12)  # type: ignore[index]


def test_generic_params_lengths_by_name_and_lexical_values() -> None:
    msg = parse_message(
        wrap(
            "<noise-removal><erosion><kernel-name>plusx8</kernel-name>"
            '<param name="cell_size_m">3</param><param name="psi"> 1 1 0 </param></erosion>'
            '<dilation><param name="cell_size_m" unit="mm">25</param></dilation></noise-removal>'
            '<clustering><fcm><cluster-no>3</cluster-no><param name="seed">7</param>'
            '<param name="flag">true</param><param name="label">a b</param></fcm></clustering>'
        )
    )
    erosion, dilation = msg.noise_removal  # type: ignore[misc]
    assert erosion.params_dict() == {"element": "plusx8", "cell_size_m": 0.03, "psi": (1, 1, 0)}
    assert dilation.params_dict() == {"cell_size_m": 0.025}
    assert msg.clustering is not None
    assert msg.clustering.params_dict() == {"n_clusters": 3, "seed": 7, "flag": True, "label": "a b"}


def test_heading_flush_angle_units() -> None:
    assert parse_message(wrap("<heading-flush>20</heading-flush>")).heading_flush_deg == 20.0
    rad = parse_message(wrap('<heading-flush unit="rad">0.5</heading-flush>')).heading_flush_deg
    assert rad == pytest.approx(28.64788975654116)


@pytest.mark.parametrize(
    ("body", "fragments"),
    [
        (
            '<noise-removal><dbscan><epsilon unit="km">5</epsilon></dbscan></noise-removal>',
            ["line 3 <epsilon>", "unit 'km' is not a length unit: expected one of m, cm, mm"],
        ),
        ('<noise-removal><dbscan><epsilon unit="M">5</epsilon></dbscan></noise-removal>', ["unit 'M'"]),
        (
            '<noise-removal><dbscan><minpts unit="cm">5</minpts></dbscan></noise-removal>',
            ["<minpts>", "unknown attribute 'unit'"],
        ),
        (
            '<clustering><kmeans><param name="seed" unit="m">5</param></kmeans></clustering>',
            ['<param name="seed">', "unit applies only to lengths"],
        ),
        ('<heading-flush unit="cm">5</heading-flush>', ["<heading-flush>", "not an angle unit"]),
    ],
)
def test_bad_units(body: str, fragments: list[str]) -> None:
    reject(wrap(body), *fragments)


# ------------------------------------------------------------------------------------------ vocabulary


@pytest.mark.parametrize(
    ("text", "kernel"),
    [
        ("Hough", "hough"),
        ("HOUGH", "hough"),
        ("svd", "svd"),
        ("Svd", "svd"),
        ("CentroidJoin", "centroid-join"),
        ("centroidjoin", "centroid-join"),
        ("centroid-join", "centroid-join"),
        ("HoughCluster", "hough-cluster"),
        ("\n  houghcluster\n ", "hough-cluster"),
    ],
)
def test_straight_line_method_any_case(text: str, kernel: str) -> None:
    assert parse_message(wrap(f"<straight-line-method>{text}</straight-line-method>")).straight_line == (
        KernelSpec(kernel)
    )


@pytest.mark.parametrize(
    ("text", "mode"), [("online", Mode.ONLINE), (" OFFLINE ", Mode.OFFLINE), ("Mixed", Mode.MIXED)]
)
def test_mode_any_case(text: str, mode: Mode) -> None:
    assert parse_message(wrap(f"<mode>{text}</mode>")).mode is mode


def test_extensions() -> None:
    msg = parse_message(
        wrap(
            "<seq>42</seq><mode>mixed</mode><n-smax>12</n-smax>"
            "<segmentation><abd-iepf><param name='lambda_deg'>12.5</param></abd-iepf></segmentation>"
            "<noise-removal/>"
            "<straight-line-method>HoughCluster<version>1.0.0</version>"
            '<param name="rho_resolution_m" unit="m">0.05</param></straight-line-method>'
            "<scan-matching> icp-line </scan-matching>"
            '<schedule><stage name="clustering" mode="Offline" n-smax="3"/>'
            '<stage name="noise-removal" mode="online"/></schedule>'
            f'<kernel-install stage="clustering" name="my-kmeans" version="1.2.0" sha256="{SHA.upper()}"/>'
            '<kernel-rollback stage="noise-removal" name="dbscan" version="1.0.0"/>'
        )
    )
    assert msg == ControlMessage(
        seq=42,
        mode=Mode.MIXED,
        n_smax=12,
        segmentation=KernelSpec.of("abd-iepf", {"lambda_deg": 12.5}),
        noise_removal=(),
        straight_line=KernelSpec.of("hough-cluster", {"rho_resolution_m": 0.05}, "1.0.0"),
        scan_matching=KernelSpec("icp-line"),
        schedule=(
            ScheduleEntry(Stage.CLUSTERING, Mode.OFFLINE, 3),
            ScheduleEntry(Stage.NOISE_REMOVAL, Mode.ONLINE, None),
        ),
        operations=(
            KernelOperation(OperationKind.INSTALL, Stage.CLUSTERING, "my-kmeans", "1.2.0", SHA),
            KernelOperation(OperationKind.ROLLBACK, Stage.NOISE_REMOVAL, "dbscan", "1.0.0", None),
        ),
    )


def test_scan_matching_none_and_comments_ignored() -> None:
    msg = parse_message(wrap("<!-- off --><scan-matching>None</scan-matching><?pi x?>"))
    assert msg.scan_matching == NO_SCAN_MATCHING


def test_empty_message_changes_nothing() -> None:
    assert parse_message("<xml><message/></xml>") == ControlMessage()


# ---------------------------------------------------------------------------------------- rejections


@pytest.mark.parametrize(
    ("body", "fragments"),
    [
        ("<minpts>3</minpts>", ["line 3 <minpts>", "unknown element in <message>", "<mode>"]),
        (
            "<noise-removal><dbscn/></noise-removal>",
            ["line 3 <dbscn>", "unknown element in <noise-removal>: expected <dbscan>, <erosion>"],
        ),
        (
            "<noise-removal><dbscan><eps>5</eps></dbscan></noise-removal>",
            ["<eps>", "expected <minpts>, <epsilon>, <param>, <version>"],
        ),
        (
            "<noise-removal><dbscan><minpts>1.5</minpts></dbscan></noise-removal>",
            ["<minpts>: '1.5' is not an integer"],
        ),
        (
            "<noise-removal><dbscan><epsilon>five</epsilon></dbscan></noise-removal>",
            ["<epsilon>: 'five' is not a number"],
        ),
        ("<noise-removal><dbscan><epsilon>nan</epsilon></dbscan></noise-removal>", ["'nan' is not a number"]),
        (
            "<noise-removal><dbscan><epsilon>1e999</epsilon></dbscan></noise-removal>",
            ["expected a finite number"],
        ),
        ("<noise-removal><dbscan><epsilon>1_0</epsilon></dbscan></noise-removal>", ["'1_0' is not a number"]),
        ("<noise-removal><dbscan><epsilon>  </epsilon></dbscan></noise-removal>", ["<epsilon>: is empty"]),
        (
            "<noise-removal><dbscan><minpts>3<b/></minpts></dbscan></noise-removal>",
            ["<b>: unexpected element"],
        ),
        (
            "<noise-removal><dbscan><minpts>3</minpts><minpts>4</minpts></dbscan></noise-removal>",
            ["<minpts>", "'min_points' given twice (first on line 3)"],
        ),
        (
            "<noise-removal><dbscan><minpts>3</minpts>"
            '<param name="min_points">4</param></dbscan></noise-removal>',
            ['<param name="min_points">', "given twice"],
        ),
        ("<noise-removal><dbscan>5</dbscan></noise-removal>", ["<dbscan>: unexpected text '5'"]),
        ("<noise-removal><dbscan x='1'/></noise-removal>", ["<dbscan>: unknown attribute 'x'"]),
        (
            "<clustering><kmeans><cluster-no>two</cluster-no></kmeans></clustering>",
            ["<cluster-no>: 'two' is not an integer"],
        ),
        (
            "<clustering><kmeans/><fcm/></clustering>",
            ["<fcm>", "a second kernel: <clustering> takes exactly one"],
        ),
        ("<clustering/>", ["<clustering>: is empty: expected one of <kmeans>, <fcm>"]),
        ("<clustering><dbscan/></clustering>", ["<dbscan>: unknown element in <clustering>"]),
        (
            "<clustering><fcm><fuzzifier>x</fuzzifier></fcm></clustering>",
            ["<fuzzifier>: 'x' is not a number"],
        ),
        (
            "<straight-line-method>Ransac</straight-line-method>",
            [
                "<straight-line-method>: 'Ransac' is not a known method: "
                "expected Hough, SVD, CentroidJoin or HoughCluster"
            ],
        ),
        ("<straight-line-method>Hough SVD</straight-line-method>", ["'Hough SVD' is not a known method"]),
        ("<straight-line-method/>", ["<straight-line-method>: is empty"]),
        (
            "<straight-line-method>hough<minpts>3</minpts></straight-line-method>",
            ["<minpts>: unknown element"],
        ),
        ("<scan-matching>ndt</scan-matching>", ["<scan-matching>: 'ndt' is not a known method"]),
        ("<scan-matching>none<param name='a'>1</param></scan-matching>", ["takes no parameters"]),
        ("<mode>sometimes</mode>", ["<mode>: 'sometimes' is not a mode: expected online, offline or mixed"]),
        ("<mode>online</mode>\n<mode>offline</mode>", ["line 4 <mode>: given twice (first on line 3)"]),
        ("<seq>-1</seq>", ["<seq>: -1 is negative"]),
        ("<seq>99999999999999999999</seq>", ["<seq>: '99999999999999999999' is out of range"]),
        ("<n-smax>9.5</n-smax>", ["<n-smax>: '9.5' is not an integer"]),
        (
            "<noise-removal><dbscan><version>1.0</version></dbscan></noise-removal>",
            ["<version>", "MAJOR.MINOR.PATCH"],
        ),
        ('<clustering><kmeans><param name="9x">1</param></kmeans></clustering>', ["is not a parameter name"]),
        (
            "<clustering><kmeans><param>1</param></kmeans></clustering>",
            ["<param>: name '' is not a parameter name"],
        ),
        (
            '<schedule><stage name="segmentation" mode="online"/></schedule>',
            ["<stage>: name='segmentation' is not a stage that can be scheduled"],
        ),
        ('<schedule><stage name="clustering" mode="mixed"/></schedule>', ["a stage runs online or offline"]),
        ('<schedule><stage name="clustering"/></schedule>', ["<stage>: needs a mode attribute"]),
        (
            '<schedule><stage name="clustering" mode="online" n-smax="x"/></schedule>',
            ["'x' is not an integer"],
        ),
        (
            '<schedule><stage name="clustering" mode="online"/>'
            '<stage name="clustering" mode="offline"/></schedule>',
            ["stage 'clustering' given twice"],
        ),
        (
            '<kernel-install stage="clustering" name="k" version="1.0.0"/>',
            ["<kernel-install>: needs a sha256"],
        ),
        (
            f'<kernel-update stage="lines" name="k" version="1.0.0" sha256="{SHA}"/>',
            ["stage='lines' is not a stage"],
        ),
        (
            f'<kernel-update stage="clustering" name="K_1" version="1.0.0" sha256="{SHA}"/>',
            ["is not a kernel name"],
        ),
        (
            '<kernel-delete stage="clustering" name="k" version="1.0.0" sha256="xyz"/>',
            ["is not a SHA-256 digest"],
        ),
        (
            '<kernel-delete stage="clustering" name="k" version="v1"/>',
            ["<kernel-delete>", "MAJOR.MINOR.PATCH"],
        ),
        ('<schedule><stage name="clustering" mode="online">x</stage></schedule>', ["holds attributes only"]),
        (
            '<kernel-delete stage="clustering" name="k" version="1.0.0"><x/></kernel-delete>',
            ["<x>: unexpected element inside <kernel-delete>, which holds attributes only"],
        ),
        (
            '<kernel-frobnicate stage="clustering" name="k" version="1.0.0"/>',
            ["<kernel-frobnicate>: unknown element"],
        ),
    ],
)
def test_rejections_name_the_element(body: str, fragments: list[str]) -> None:
    reject(wrap(body), *fragments)


def test_unknown_kernel_names_rejected() -> None:
    reject(wrap("<noise-removal><median/></noise-removal>"), "<median>: unknown element in <noise-removal>")
    reject(
        wrap("<clustering><dbscan-means/></clustering>"), "<dbscan-means>: unknown element in <clustering>"
    )
    reject(
        wrap("<segmentation><split-merge/></segmentation>"),
        "<split-merge>: unknown element in <segmentation>",
    )


def test_wrong_root_and_message_count() -> None:
    reject("<message><mode>online</mode></message>", "line 1 <message>: wrong root element: expected <xml>")
    reject("<xml/>", "<xml>: holds no <message>")
    reject("<xml>\n<message/>\n<message/>\n</xml>", "line 3 <message>: a second <message> (first on line 2)")
    reject("<xml><mode>online</mode></xml>", "<mode>: unknown element in <xml>: expected <message>")
    reject("<xml>hello<message/></xml>", "<xml>: unexpected text 'hello'")
    reject('<xml xmlns="urn:x"><message/></xml>', "wrong root element")


def test_error_pickles() -> None:
    import pickle

    err = ControlMessageError("bad", element="<x>", line=3)
    again = pickle.loads(pickle.dumps(err))
    assert str(again) == "line 3 <x>: bad" and again.line == 3
    assert str(ControlMessageError("bad")) == "control message: bad"
