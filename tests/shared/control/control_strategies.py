"""Hypothesis strategies for control messages (any the builder can write, any kernel name) and pipeline
configurations."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from hypothesis import strategies as st

from shared.control import (
    NO_SCAN_MATCHING,
    ControlMessage,
    KernelOperation,
    KernelSpec,
    OperationKind,
    ParamValue,
    ScheduleEntry,
)
from shared.control.vocabulary import (
    CLUSTERING_KERNELS,
    LOOP_CLOSURE,
    MAX_INT,
    NOISE_KERNELS,
    SCAN_MATCHERS,
    SEGMENTATION_KERNELS,
    STRAIGHT_LINE_SPELLING,
    KernelElement,
    Kind,
    format_value,
)
from shared.kernels import Stage
from shared.pipeline import KernelChoice, Mode, PipelineConfig, StageSchedule
from shared.pipeline.config import SCHEDULED

__all__ = ["configs", "messages"]

ints = st.integers(-MAX_INT, MAX_INT)
floats = st.floats(allow_nan=False, allow_infinity=False)
words = st.text(st.characters(categories=("L", "N")) | st.just(" "), min_size=1, max_size=12).filter(
    lambda s: s == s.strip()
)


def _writable(value: ParamValue) -> bool:
    try:
        format_value(value)
    except ValueError:
        return False
    return True


generic_values: st.SearchStrategy[ParamValue] = st.one_of(
    ints,
    floats,
    st.booleans(),
    st.tuples(ints, ints),
    st.lists(st.integers(-5, 5), min_size=2, max_size=4).map(tuple),
    words.filter(_writable),
)
versions = st.none() | st.tuples(*[st.integers(0, 99)] * 3).map(lambda v: ".".join(map(str, v)))


@st.composite
def kernel_specs(draw: st.DrawFn, entry: KernelElement) -> KernelSpec:
    """A spec of ``entry`` with some named and some generic parameters."""
    params: dict[str, ParamValue] = {}
    for named in entry.named:
        if draw(st.booleans()):
            strategy: st.SearchStrategy[Any] = {
                Kind.INT: ints,
                Kind.FLOAT: floats,
                Kind.LENGTH: floats,
                Kind.TEXT: words,
                Kind.BOOL: st.booleans(),
            }[named.kind]
            params[named.param] = draw(strategy)
    taken = {p.param for p in entry.named}
    names = st.from_regex(r"[a-z_][a-z0-9_]{0,10}", fullmatch=True).filter(lambda n: n not in taken)
    for name in draw(st.lists(names, max_size=3, unique=True)):
        params[name] = draw(floats) if name.endswith("_m") else draw(generic_values)
    return KernelSpec.of(entry.name, params, draw(versions))


kernel_names = st.from_regex(r"[a-z][a-z0-9]{0,6}(-[a-z0-9]{1,4}){0,2}", fullmatch=True)


def _from_table(table: dict[str, KernelElement]) -> st.SearchStrategy[KernelSpec]:
    """A kernel of the paper's vocabulary, or any other name (written as ``<kernel name="..">``)."""
    other = kernel_names.filter(lambda n: n not in table).map(KernelElement)
    return (st.sampled_from(list(table.values())) | other).flatmap(kernel_specs)


schedule_entries = st.lists(st.sampled_from(SCHEDULED), unique=True, max_size=3).flatmap(
    lambda stages: st.tuples(
        *[
            st.builds(
                ScheduleEntry,
                st.just(s),
                st.sampled_from([Mode.ONLINE, Mode.OFFLINE]),
                st.none() | ints,
            )
            for s in stages
        ]
    )
)
operations = st.builds(
    KernelOperation,
    st.sampled_from(OperationKind),
    st.sampled_from(Stage),
    kernel_names,
    versions.filter(lambda v: v is not None),
    st.from_regex(r"[0-9a-f]{64}", fullmatch=True),
)


@st.composite
def messages(draw: st.DrawFn) -> ControlMessage:
    """Any message the builder can write (values outside the kernels' ranges included)."""
    ops = draw(st.lists(operations, max_size=3))
    return ControlMessage(
        seq=draw(st.none() | st.integers(0, MAX_INT)),
        mode=draw(st.none() | st.sampled_from(Mode)),
        n_smax=draw(st.none() | ints),
        heading_flush_deg=draw(st.none() | floats),
        segmentation=draw(st.none() | _from_table(SEGMENTATION_KERNELS)),
        noise_removal=draw(st.none() | st.lists(_from_table(NOISE_KERNELS), max_size=3).map(tuple)),
        clustering=draw(st.none() | _from_table(CLUSTERING_KERNELS)),
        straight_line=draw(
            st.none() | _from_table({k: KernelElement(k) for k in STRAIGHT_LINE_SPELLING})
        ),
        scan_matching=draw(
            st.none()
            | st.just(NO_SCAN_MATCHING)
            | _from_table({k: KernelElement(k) for k in SCAN_MATCHERS})
        ),
        schedule=draw(st.none() | schedule_entries),
        loop_closure=draw(st.none() | kernel_specs(LOOP_CLOSURE).map(lambda s: replace(s, version=None))),
        operations=tuple(op for op in ops),
    )


# ------------------------------------------------------------------------- valid pipeline configurations

_versions = st.none() | st.just("1.0.0")
_elements = st.sampled_from(["DENSEx3", "PLUSx4", "PLUSx8", "STARx8"])


def _choice(name: str, **params: st.SearchStrategy[Any]) -> st.SearchStrategy[KernelChoice]:
    """A choice of kernel ``name`` with a random subset of ``params``."""
    keys = sorted(params)
    return st.builds(
        lambda chosen, version, values: KernelChoice(
            name=name,
            version=version,
            params={k: v for k, v in zip(keys, values, strict=True) if k in chosen},
        ),
        st.sets(st.sampled_from(keys)) if keys else st.just(set()),
        _versions,
        st.tuples(*[params[k] for k in keys]),
    )


def _morph(name: str) -> st.SearchStrategy[KernelChoice]:
    return _choice(
        name,
        element=_elements,
        cell_size_m=st.floats(0.001, 1.0),
        psi=st.tuples(*[st.integers(0, 5)] * 3),
    )


noise_choices = st.one_of(
    _choice("dbscan", epsilon_m=st.floats(0.0001, 10.0), min_points=st.integers(1, 1000)),
    _morph("erosion"),
    _morph("dilation"),
    _morph("opening"),
)
clustering_choices = st.one_of(
    _choice(
        "kmeans", n_clusters=st.integers(1, 1000), seed=st.integers(0, 2**31), tolerance_m=st.floats(0, 1)
    ),
    _choice(
        "fcm",
        n_clusters=st.integers(1, 1000),
        fuzzifier=st.floats(1.001, 10.0),
        tolerance=st.floats(1e-9, 0.999),
        max_iterations=st.integers(1, 10000),
    ),
)
line_choices = st.one_of(
    _choice("hough", theta_resolution_deg=st.floats(0.05, 10.0), min_points=st.integers(2, 100)),
    _choice("svd", min_points=st.integers(2, 100)),
    _choice("centroid-join", max_gap_m=st.floats(0.01, 1000.0)),
    _choice("hough-cluster", delta=st.integers(0, 2), rho_resolution_m=st.floats(0.001, 1.0)),
)
matcher_choices = st.none() | _choice("icp", max_iterations=st.integers(1, 1000)) | _choice("icp-line")
segmentation_choices = _choice("abd-iepf", lambda_deg=st.floats(1.0, 80.0), min_points=st.integers(1, 100))
schedules = st.dictionaries(
    st.sampled_from(SCHEDULED),
    st.builds(
        StageSchedule, mode=st.sampled_from([Mode.ONLINE, Mode.OFFLINE]), n_smax=st.integers(1, 10_000)
    ),
)


loop_closures = st.fixed_dictionaries(
    {},
    optional={
        "enabled": st.booleans(),
        "search_radius_m": st.floats(0.0, 100.0),
        "min_inlier_share": st.floats(0.0, 1.0),
        "window_m": st.floats(0.0, 10.0),
        "window_rad": st.floats(0.0, 3.14),
        "max_candidates": st.integers(1, 50),
        "final_batch": st.booleans(),
    },
)


@st.composite
def configs(draw: st.DrawFn) -> PipelineConfig:
    """A valid pipeline configuration whose every kernel is in the control vocabulary."""
    return PipelineConfig(
        mode=draw(st.sampled_from(Mode)),
        n_smax=draw(st.integers(1, 10_000)),
        heading_flush_deg=draw(st.floats(0.001, 360.0)),
        segmentation=draw(segmentation_choices),
        noise_removal=tuple(draw(st.lists(noise_choices, max_size=3))),
        clustering=draw(clustering_choices),
        straight_line=draw(line_choices),
        scan_matching=draw(matcher_choices),
        schedule=draw(schedules),
        loop_closure=draw(st.none() | loop_closures),
    )
