"""The chain covariance from prefix sums (shared.slam.chainsum) against the reference sum over the chain
(shared.slam.closure.chain_covariance), on random chains extended in random pieces."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.slam.chainsum import ChainSums, between
from shared.slam.closure import chain_covariance
from shared.types import Pose2D


def _chain(seed: int, n: int, far_m: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    poses = np.cumsum(rng.normal(0.0, 0.5, (n, 3)), axis=0)
    poses[:, :2] += far_m  # far from the origin: the sums' cancellation must stay within rounding
    a = rng.normal(0.0, 0.02, (n - 1, 3, 3))
    covs = np.einsum("mij,mkj->mik", a, a) + 1e-6 * np.eye(3)
    return poses, covs.reshape(-1, 9)


@given(
    st.integers(0, 2**32 - 1),
    st.integers(2, 80),
    st.sampled_from([0.0, 150.0, -2000.0]),
    st.lists(st.integers(1, 30), min_size=1, max_size=6),
    st.data(),
)
@settings(max_examples=150, deadline=None)
def test_prefix_sums_give_the_reference_chain(seed, n, far_m, pieces, data) -> None:  # type: ignore[no-untyped-def]
    poses, covs = _chain(seed, n, far_m)
    sums, have = ChainSums(), 1
    for piece in pieces:  # the chain grows as keyframes come; queries in between
        have = min(n, have + piece)
        c = data.draw(st.integers(0, have - 1))
        k = data.draw(st.integers(c, have - 1))
        got = sums.covariance(poses[:have], covs[: have - 1], c, k)
        ref = chain_covariance([Pose2D(*p) for p in poses[c : k + 1]], covs[c:k].reshape(-1, 3, 3))
        scale = max(1.0, float(np.abs(ref).max()))
        assert np.allclose(got, ref, rtol=1e-9, atol=1e-12 * scale * (1.0 + far_m**2)), (c, k)
        assert np.allclose(got, got.T)


def test_a_chain_of_one_keyframe_is_certain() -> None:
    poses, _ = _chain(0, 3, 0.0)
    assert not between(np.zeros((3, 13)), poses, 2, 2).any()


def test_a_day_of_keyframes_grows_in_pieces_and_answers_the_first_lap() -> None:
    """70,000 keyframes (a day at one every half metre): the chain back to the first keyframes is the
    reference's, from sums kept as they came."""
    poses, covs = _chain(7, 70_000, 40.0)
    sums = ChainSums()
    for end in (10, 1_000, 50_000, 70_000):
        sums.covariance(poses[:end], covs[: end - 1], 0, end - 1)
    got = sums.covariance(poses, covs, 3, 69_999)
    ref = chain_covariance([Pose2D(*p) for p in poses[3:70_000]], covs[3:69_999].reshape(-1, 3, 3))
    assert np.allclose(got, ref, rtol=1e-7, atol=1e-9 * float(np.abs(ref).max()))
