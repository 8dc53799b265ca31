"""The kernel registry and the parameter contract, on a throwaway registry (not the global one)."""

from __future__ import annotations

import json

import pytest
from numpy.typing import ArrayLike

from shared.errors import DuplicateKernelError, KernelParameterError, LinemapError, UnknownKernelError
from shared.kernels import REGISTRY, ClusteringKernel, Clusters, KernelParams, KernelRegistry, Stage, param


class ToyParams(KernelParams):
    n_clusters: int = param(2, description="clusters", ge=1, le=10)
    radius_m: float = param(0.5, description="radius", unit="m", gt=0.0)


class Toy(ClusteringKernel[ToyParams]):
    """A toy kernel."""

    name = "toy"
    version = "1.2.0"
    Params = ToyParams

    def apply(self, points: ArrayLike) -> Clusters:
        raise NotImplementedError


def make_registry() -> KernelRegistry:
    reg = KernelRegistry()
    reg.register(Toy)
    return reg


def test_lookup_by_stage_and_name() -> None:
    reg = make_registry()
    assert reg.get("clustering", "toy") is Toy
    assert reg.get(Stage.CLUSTERING, "toy", "1.2.0") is Toy
    kernel = reg.create("clustering", "toy", {"n_clusters": 3})
    assert kernel.params.n_clusters == 3


def test_unknown_names_are_clear() -> None:
    reg = make_registry()
    with pytest.raises(UnknownKernelError, match="known kernels are toy"):
        reg.get("clustering", "nope")
    with pytest.raises(UnknownKernelError, match=r"unknown stage 'bogus'"):
        reg.get("bogus", "toy")
    with pytest.raises(UnknownKernelError, match=r"registered versions are 1\.2\.0"):
        reg.get("clustering", "toy", "9.9.9")


def test_duplicates_refused_and_versions_coexist() -> None:
    reg = make_registry()
    with pytest.raises(DuplicateKernelError, match=r"clustering/toy@1\.2\.0"):
        reg.register(Toy)

    class Toy2(Toy):
        version = "1.10.0"

    reg.register(Toy2)
    assert reg.get("clustering", "toy") is Toy2, "the highest version wins (1.10 > 1.2)"
    reg.unregister("clustering", "toy", "1.10.0")
    assert reg.get("clustering", "toy") is Toy


def test_bad_declarations_refused() -> None:
    class BadName(Toy):
        name = "Bad Name"

    class BadVersion(Toy):
        name = "ok-name"
        version = "v1"

    reg = KernelRegistry()
    with pytest.raises(LinemapError, match=r"lower-case"):
        reg.register(BadName)
    with pytest.raises(LinemapError, match=r"MAJOR\.MINOR\.PATCH"):
        reg.register(BadVersion)


def test_catalogue_is_json_with_units() -> None:
    desc = make_registry().describe()
    text = json.dumps(desc)
    assert '"unit": "m"' in text
    assert desc[0]["summary"] == "A toy kernel."


def test_parameter_errors_name_parameter_value_and_range() -> None:
    with pytest.raises(KernelParameterError) as exc:
        Toy(n_clusters=0, radius_m=-1.0)
    msg = str(exc.value)
    assert "toy.n_clusters: 0" in msg and "allowed range 1 <= n_clusters <= 10" in msg
    assert "toy.radius_m: -1.0" in msg and "allowed range radius_m > 0.0 m" in msg
    assert {name for name, _ in exc.value.problems} == {"n_clusters", "radius_m"}


def test_params_accept_model_mapping_and_overrides() -> None:
    a = Toy(ToyParams(n_clusters=4))
    b = Toy({"n_clusters": 4})
    c = Toy(n_clusters=4)
    assert a == b == c and hash(a) == hash(c)
    assert a.with_params(radius_m=1.0).params.radius_m == 1.0
    assert a.params.radius_m == 0.5, "with_params returns a new kernel"
    assert "Toy(n_clusters=4" in repr(a)


def test_global_registry_lists_builtins_in_stage_order() -> None:
    stages = [info.stage for info in REGISTRY.list()]
    order = list(Stage)
    assert stages == sorted(stages, key=order.index)
