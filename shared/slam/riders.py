"""Riders: keyframes taken out of the pose graph's solver and carried rigidly by another node at their place.

A robot that patrols a building for days adds a keyframe every half metre; places
(:mod:`shared.slam.places`) already keep one keyframe scan per place, but every keyframe stayed a node of
the graph with its edges, so the solver, each update's bookkeeping and each rebuild from scratch grew with
the distance driven. The reduced pose graph (Johannsson et al., ICRA 2013) keeps the nodes bounded by the
places instead. Here a retired keyframe **rides** on the held keyframe at its place (the first there,
25 cm and 20 degrees at most away): at the solver's next rebuild from scratch its pose becomes the
anchor's pose composed with a fixed offset (the two poses' relative estimate then), and every edge that
touched it is carried onto the anchor:

- **carried** (:func:`carry`): an edge ``i -> j`` with measurement ``z`` becomes ``a_i -> a_j`` with
  ``O_i z O_j^-1`` (``O`` the rider's offset in its anchor's frame; identity for a node in the solver), its
  information taken through the first-order map of that composition, ``L' = A^-T L A^-1`` with
  ``A = [[R(O_i), R(O_i) R(z) J v], [0, 0, 1]]``, ``v`` the translation of ``O_j^-1``, ``J`` the 90 degree
  rotation (exact to first order: the rider moves with its anchor, as it now does). The offset is the two
  nodes' relative estimate when the rider leaves the solver, so only a keyframe that a loop edge joins
  directly to its anchor rides (the offset then rests on a measurement of it): a closure the search
  found, or the tie the mapper measures when a keyframe retires without one (its scan matched onto the
  anchor's: :meth:`shared.slam.mapper.GraphMapper._tie`); one whose tie failed stays in the solver.
  Adding the offset's doubt (that closure's covariance) to the carried edges was tried: on the
  corridor-doors world it lost 16 points of completeness (the mechanism not found), so the offsets are
  taken as exact;
- an edge whose two ends ride on the same anchor says nothing any more and is **dropped**; so is a carried
  loop-closure edge that the robust kernel has outvoted (its residual beyond ``robust_sigmas``: the graph
  already decided it was false);
- carried edges that now join the same two nodes (and are of one kind: loop closure or chain) are
  **fused** (:func:`fuse`) by covariance intersection (Julier and Uhlmann 1997): ``L = w L_1 + (1 - w)
  L_2`` with ``w`` maximising ``det L``. Laps of the same corridor carried onto the same places are not
  independent witnesses (their offsets come from one estimate), and covariance intersection is consistent
  whatever their correlation, where adding informations would make the graph ever more certain of a place
  the longer the robot drives there. An edge between two nodes in the solver is never fused with a
  carried one: it measures the newer chain, independently of the old laps, and covariance intersection
  would take from it what it knows whenever the carried edge is weak in some direction; the two stay side
  by side, one factor each.

So the nodes in the solver grow with the places and with the few retired keyframes whose tie failed, not
with every keyframe. What a rider loses is its own freedom: the chain of a later lap no longer bends on
its own, only with the places it rides on, which is what retiring it already said (the place's first
keyframe is the reference every visit is matched against).

Pure: arrays in, arrays out. Edge rows are :mod:`shared.slam.graph`'s: ``i, j, x, y, theta``, the kind
(bits :data:`LOOP`, :data:`CARRIED`) and the information's nine entries (row-major) over the
measurement's coordinates in the frame of ``i``.
"""

from __future__ import annotations

import math

import numpy as np

from shared.types import FloatArray, IntArray

__all__ = [
    "CARRIED",
    "EDGE_WIDTH",
    "LOOP",
    "RIDE_WIDTH",
    "carry",
    "compose_many",
    "fuse",
    "inverse_edge",
    "inverse_jacobian",
    "reduce_edges",
    "remainder_tau",
    "residual_sigmas",
    "take_riders",
]

#: columns of an edge row
EDGE_WIDTH = 15
#: bits of an edge row's sixth column: a loop closure (robust in the solver), carried from a rider
LOOP, CARRIED = 1, 2

_J = np.array([[0.0, -1.0], [1.0, 0.0]])


def _rot(theta: float) -> FloatArray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def _wrap(theta: float) -> float:
    return math.remainder(theta, math.tau)


def _compose(a: FloatArray, b: FloatArray) -> FloatArray:
    """Pose ``a @ b`` of two ``(3,)`` rows (x, y, theta)."""
    xy = a[:2] + _rot(float(a[2])) @ b[:2]
    return np.array([xy[0], xy[1], _wrap(float(a[2] + b[2]))])


def compose_many(a: FloatArray, b: FloatArray) -> FloatArray:
    """Poses ``a @ b_k`` of one ``(3,)`` row and rows ``b`` ``(K, 3)``, as :func:`_compose` gives each one
    (the headings by the same IEEE remainder): a node's riders handed on in one pass. O(K) numpy."""
    c, s = math.cos(float(a[2])), math.sin(float(a[2]))
    out = np.empty_like(b, dtype=np.float64)
    out[:, 0] = a[0] + (c * b[:, 0] + -s * b[:, 1])
    out[:, 1] = a[1] + (s * b[:, 0] + c * b[:, 1])
    theta = a[2] + b[:, 2]
    remainder_tau(theta)
    out[:, 2] = theta
    return out


def remainder_tau(theta: FloatArray) -> None:
    """``theta`` replaced in place by its IEEE remainder by 2 pi (``math.remainder``, bit for bit: -pi and
    pi stay). Within (-2 pi, 2 pi) that is one exact subtraction or addition of 2 pi (Sterbenz's lemma);
    values farther out take the per-value path. O(n)."""
    size = np.abs(theta)
    outside = size > math.pi
    if not outside.any():
        return
    near = outside & (size < math.tau)
    down, up = near & (theta > 0), near & (theta < 0)  # both before either moves a value
    theta[down] -= math.tau
    theta[up] += math.tau
    for k in np.flatnonzero(outside & ~near).tolist():
        theta[k] = _wrap(float(theta[k]))


def _inverse(a: FloatArray) -> FloatArray:
    xy = -(_rot(-float(a[2])) @ a[:2])
    return np.array([xy[0], xy[1], _wrap(-float(a[2]))])


def inverse_jacobian(a: FloatArray) -> FloatArray:
    """``d(a^-1) / da`` of a pose row ``a`` ``(3,)`` over additive coordinates (x, y, theta):
    ``[[-R(-a), R(-a) J a_t], [0, 0, -1]]`` (a covariance of ``a^-1`` is ``D S D^T``). O(1)."""
    r = _rot(-float(a[2]))
    out = np.zeros((3, 3))
    out[:2, :2] = -r
    out[:2, 2] = r @ _J @ a[:2]
    out[2, 2] = -1.0
    return out


def _through(information: FloatArray, jac: FloatArray) -> FloatArray:
    """Information over ``y = f(x)`` from that over ``x``, with ``jac = dy/dx`` (invertible):
    ``jac^-T L jac^-1``, made symmetric."""
    inv = np.linalg.inv(jac)
    out: FloatArray = inv.T @ information @ inv
    return 0.5 * (out + out.T)


def carry(
    row: FloatArray, offset_i: FloatArray, offset_j: FloatArray, anchor_i: int, anchor_j: int
) -> FloatArray:
    """Edge ``row`` (``i -> j``) carried onto the anchors: ``anchor_i -> anchor_j`` with measurement
    ``offset_i @ z @ offset_j^-1`` and its information through that map (module docstring), marked
    :data:`CARRIED`. Offsets are ``(3,)`` rows (x, y, theta) of the rider in its anchor's frame (zeros for
    a node in the solver). O(1)."""
    z = row[2:5]
    v = _inverse(offset_j)
    out = row.copy()
    out[0], out[1] = float(anchor_i), float(anchor_j)
    out[2:5] = _compose(_compose(offset_i, z), v)
    out[5] = float(int(row[5]) | CARRIED)
    r_i = _rot(float(offset_i[2]))
    jac = np.eye(3)
    jac[:2, :2] = r_i
    jac[:2, 2] = r_i @ _rot(float(z[2])) @ _J @ v[:2]
    out[6:] = _through(row[6:].reshape(3, 3), jac).ravel()
    return out


def inverse_edge(row: FloatArray) -> FloatArray:
    """Edge ``row`` (``i -> j``) as ``j -> i``: the inverse measurement ``(-R(-theta) t, -theta)`` and its
    information through the inversion's first-order map
    ``B = [[-R(-theta), R(-theta) J t], [0, 0, -1]]``. O(1)."""
    z = row[2:5]
    out = row.copy()
    out[0], out[1] = row[1], row[0]
    out[2:5] = _inverse(z)
    out[6:] = _through(row[6:].reshape(3, 3), inverse_jacobian(z)).ravel()
    return out


def fuse(a: FloatArray, b: FloatArray) -> FloatArray:
    """Two edges between the same nodes (same direction) as one, by covariance intersection: information
    ``w L_a + (1 - w) L_b`` with ``w`` in [0, 1] maximising its determinant (a cubic in ``w``, maximised
    in closed form), measurement the information-weighted mean of the two (headings
    unwrapped to ``a``'s). A loop edge if either is. O(1)."""
    la, lb = a[6:].reshape(3, 3), b[6:].reshape(3, 3)
    za, zb = a[2:5].copy(), b[2:5].copy()
    zb[2] = za[2] + _wrap(float(zb[2] - za[2]))

    # det(w L_a + (1 - w) L_b) is a cubic in w: through its values at four points, then its largest
    # value on [0, 1] at an end or where its derivative vanishes
    ws = np.array([0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0])
    cubic = np.polyfit(ws, [np.linalg.det(w * la + (1.0 - w) * lb) for w in ws.tolist()], 3)
    roots = np.roots(np.polyder(cubic))
    inside = [float(r.real) for r in roots if abs(r.imag) < 1e-12 and 0.0 < r.real < 1.0]
    w = max([0.0, 1.0, *inside], key=lambda x: float(np.polyval(cubic, x)))
    info = w * la + (1.0 - w) * lb
    mean = np.linalg.solve(info, w * la @ za + (1.0 - w) * lb @ zb)
    out = a.copy()
    out[2:5] = [mean[0], mean[1], _wrap(float(mean[2]))]
    out[5] = float(max(a[5], b[5]))
    out[6:] = (0.5 * (info + info.T)).ravel()
    return out


def residual_sigmas(row: FloatArray, estimate: FloatArray) -> float:
    """How far the estimate ``(N, 3)`` is from edge ``row``'s measurement, in the edge's standard
    deviations (Mahalanobis distance over the coordinates in the frame of ``i``). O(1)."""
    i, j = int(row[0]), int(row[1])
    predicted = _compose(_inverse(estimate[i]), estimate[j])
    d = predicted - row[2:5]
    d[2] = _wrap(float(d[2]))
    return float(math.sqrt(max(float(d @ row[6:].reshape(3, 3) @ d), 0.0)))


def reduce_edges(
    rows: FloatArray, anchor: IntArray, offset: FloatArray, estimate: FloatArray, robust_sigmas: float
) -> FloatArray:
    """The edges ``rows`` ``(E, EDGE_WIDTH)`` of a graph whose node ``n`` rides on ``anchor[n]`` at
    ``offset[n]`` (``anchor[n] == n`` and a zero offset for a node in the solver), under the estimate
    ``(N, 3)`` (riders included): carried onto the anchors, those joining a node to itself dropped, carried
    loop edges the robust kernel outvoted (beyond ``robust_sigmas``) dropped, parallel ones fused; in the
    order of each pair's first edge (module docstring). O(E)."""
    groups: dict[tuple[int, int, int], FloatArray] = {}
    for row in rows:
        i, j = int(row[0]), int(row[1])
        ai, aj = int(anchor[i]), int(anchor[j])
        if ai == aj:
            continue
        moved = ai != i or aj != j
        out = carry(row, offset[i], offset[j], ai, aj) if moved else row.copy()
        if out[0] > out[1]:
            out = inverse_edge(out)
        loop = bool(int(out[5]) & LOOP)
        if moved and loop and residual_sigmas(out, estimate) > robust_sigmas:
            continue
        # a carried edge fuses with carried ones only: the newer chain's own edges stay as measured
        key = (int(out[0]), int(out[1]), int(out[5]))
        held = groups.get(key)
        if held is None:
            groups[key] = out
            continue
        if loop and (
            residual_sigmas(out, estimate) > robust_sigmas or residual_sigmas(held, estimate) > robust_sigmas
        ):
            # an outvoted closure fused with a sound one would drag it: keep the one the estimate agrees with
            if residual_sigmas(out, estimate) < residual_sigmas(held, estimate):
                groups[key] = out
            continue
        groups[key] = fuse(held, out)
    if not groups:
        return np.zeros((0, EDGE_WIDTH))
    return np.vstack(list(groups.values()))


#: a row of the rider table: the node it rides on (-1: in the solver) and its offset there (x, y, theta)
RIDE_WIDTH = 4


def _ties(edges: FloatArray, estimate: FloatArray, robust_sigmas: float) -> dict[int, list[FloatArray]]:
    """Per node, the loop edges joining it directly to another that the estimate agrees with (within
    ``robust_sigmas``), in order. O(E)."""
    ties: dict[int, list[FloatArray]] = {}
    for row in edges:
        if not int(row[5]) & LOOP or residual_sigmas(row, estimate) > robust_sigmas:
            continue
        ties.setdefault(int(row[0]), []).append(row)
        ties.setdefault(int(row[1]), []).append(row)
    return ties


def _tie(ties: dict[int, list[FloatArray]], index: int, to: tuple[int, ...]) -> FloatArray | None:
    """The most informative loop edge joining node ``index`` directly to a node of ``to`` (the first of
    them that has one); None when none does."""
    rows = ties.get(index, [])
    for node in to:
        joined = [r for r in rows if node in (int(r[0]), int(r[1]))]
        if joined:
            return max(joined, key=lambda r: float(np.linalg.det(r[6:].reshape(3, 3))))
    return None


def take_riders(
    rides: FloatArray,
    queued: list[tuple[int, int]],
    estimate: FloatArray,
    edges: FloatArray,
    robust_sigmas: float,
) -> tuple[FloatArray, FloatArray]:
    """The rider table ``rides`` ``(N, RIDE_WIDTH)`` and the edges ``(E, EDGE_WIDTH)`` after the ``queued``
    ``(node, anchor)`` pairs leave the solver (module docstring): each node that a loop closure joins
    directly to the anchor asked for (or to the node that one rides on) rides there at their relative
    estimate; one already riding, or without such a closure that the estimate agrees with, stays as it is
    (a closure to some other node, metres away, was tried: on a corridor of repeating doors it glued old
    laps where they were not). Riders of a node that leaves are handed on. Then the edges are carried and
    fused (:func:`reduce_edges`). O(E + queued x N)."""
    rides = rides.copy()
    ties = _ties(edges, estimate, robust_sigmas)
    for index, wanted in queued:
        if rides[index, 0] >= 0:
            continue
        tie = _tie(ties, index, (wanted, int(rides[wanted, 0])) if rides[wanted, 0] >= 0 else (wanted,))
        if tie is None:
            continue  # no closure ties it to its place directly: it stays in the solver
        other = int(tie[1]) if int(tie[0]) == index else int(tie[0])
        offset = _compose(_inverse(estimate[other]), estimate[index])
        anchor = other
        if rides[other, 0] >= 0:  # tied to the node its anchor rides on
            anchor = int(rides[other, 0])
            offset = _compose(rides[other, 1:4], offset)
        if anchor == index:
            continue
        rides[index] = [anchor, *offset.tolist()]
        handed = np.flatnonzero(rides[:, 0] == index)  # its riders handed on, in one pass
        if len(handed):
            rides[handed, 1:4] = compose_many(offset, rides[handed, 1:4])
            rides[handed, 0] = anchor
    riding = rides[:, 0] >= 0
    anchor_of = np.where(riding, rides[:, 0], np.arange(len(rides))).astype(np.intp)
    offsets = np.where(riding[:, None], rides[:, 1:4], 0.0)
    return rides, reduce_edges(edges, anchor_of, offsets, estimate, robust_sigmas)
