"""Weak cuts of a robust fit and their repair by consensus (issue #29).

A robust fit keeps the edges it calls inliers. Where those edges hold a part ``S`` of the
cameras to the rest by a single edge (a *bridge* of the inlier graph) or by none (``S`` a
component of its own), the relative rotation of ``S`` and the rest is set by that one edge,
right or wrong, or by nothing: a spanning tree through a wrong pair, an L1 answer that fits
one gross error exactly, leave ``S`` turned as a block. Each of the other edges across the
cut (called outliers by the fit) says how ``S`` should be turned to fit it; when several of
them agree, that consensus predicts the cut better than the one edge, and the fit's own noise
model says by how much. (Measured on bench_family's dev half: a community of 28 of 45 cameras
held by one wrong edge where two true pairs agreed: 24 deg median error; a sparse lattice
turned in pieces: 77 deg.)

:func:`bridge_cuts` finds the cuts (all at once, vectorised: a spanning forest, its
pre-order, each subtree's range by a sparse table of depths, each tree edge's crossing
edges told apart by XOR-ed random labels); :func:`cut_moves` scores every cut's candidate
turns (one per crossing edge, each the turn that fits that edge) under the fit's noise model
and returns each cut's best; :func:`disjoint_moves` keeps those that turn different cameras,
:func:`turn_sides` applies them. The adaptive method
(:mod:`.adaptive`) makes the move, solves again and keeps the answer only when the model's
cost of all the edges fell.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import depth_first_order

from .. import so3_rows
from .leverage import standardised
from .noise_model import NoiseModel
from .residuals import EdgeSystem, error_quaternions

#: Work bound of the cut scoring: cuts times edges called outliers (each pair one comparison
#: of their pre-order ranges). Above it the cuts with the fewest cameras on their smaller side
#: are scored first, up to the bound (the blocks a wrong edge turns are small ones hanging off
#: a large, well-connected rest).
CUT_WORK_MAX = 20_000_000
#: Crossing edges scored at most per cut (the candidate turns times the edges they are
#: scored on: a square): beyond it the cut is held by consensus enough to be left alone.
MAX_CROSSING = 64


@dataclass
class Cuts:
    """The weak cuts of an inlier graph on ``n`` cameras: for cut ``k``, the cameras of pre-order
    position ``lo[k] <= tin < hi[k]`` are its side ``S``; ``bridge[k]`` is the one inlier edge
    across it (its index among all edges) or -1 (``S`` a component of the inlier graph)."""

    tin: np.ndarray  # (n,) each camera's pre-order position
    lo: np.ndarray
    hi: np.ndarray
    bridge: np.ndarray

    def inside(self, k: int, nodes: np.ndarray) -> np.ndarray:
        return (self.tin[nodes] >= self.lo[k]) & (self.tin[nodes] < self.hi[k])


def bridge_cuts(n: int, edges: np.ndarray, inlier: np.ndarray, seed: int = 0) -> Cuts:
    """The bridges of the graph of the ``inlier`` edges and its components but the largest,
    as :class:`Cuts`. A spanning forest (depth-first, from a virtual root joined to every
    camera); a tree edge ``(parent x, x)`` is a bridge when no other inlier edge
    has exactly one end in the subtree of ``x``: each inlier edge gets a random 64-bit label,
    each camera the XOR of its edges' labels, and the XOR over a subtree (a range of the
    pre-order) is the tree edge's own label only then (a false match has probability 2^-64)."""
    idx = np.flatnonzero(inlier)
    e = edges[idx]
    # the virtual root n joined to every camera: the depth-first search enters each component by
    # its first camera and finishes it before it takes the next such edge (the others, unlabelled,
    # are never tree edges into a component and never counted)
    rows = np.concatenate([e[:, 0], np.full(n, n)])
    cols = np.concatenate([e[:, 1], np.arange(n)])
    order, pred = depth_first_order(coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n + 1, n + 1)).tocsr(), n,
                                    directed=False, return_predecessors=True)
    order = order[1:]  # the cameras in pre-order (the virtual root first, dropped)
    parent = pred[:n]  # every camera's: the virtual root reaches them all
    tin = np.empty(n, dtype=np.int64)
    tin[order] = np.arange(n)
    depth = _depths(parent, n)
    hi = _subtree_ends(depth[order], tin, depth)
    labels = np.random.default_rng([seed, 29, 7]).integers(0, np.iinfo(np.int64).max, len(e), dtype=np.int64)
    val = np.zeros(n, dtype=np.int64)
    np.bitwise_xor.at(val, e[:, 0], labels)
    np.bitwise_xor.at(val, e[:, 1], labels)
    prefix = np.concatenate([[0], np.bitwise_xor.accumulate(val[order])])
    crossing = prefix[hi] ^ prefix[tin]  # XOR of the labels of the inlier edges leaving each subtree
    # each camera's tree edge among the inlier edges, and how many edges join it to its parent
    # (parallel ones: no bridge)
    down = parent[e[:, 1]] == e[:, 0]  # edge u -> v with u the parent of v
    up = parent[e[:, 0]] == e[:, 1]
    tree = np.full(n, -1)
    tree[e[down, 1]] = np.flatnonzero(down)
    tree[e[up, 0]] = np.flatnonzero(up)
    many = np.bincount(np.concatenate([e[down, 1], e[up, 0]]), minlength=n)
    child = np.flatnonzero((parent != n) & (many == 1))
    is_bridge = crossing[child] == labels[tree[child]]
    bridges = child[is_bridge]
    # components but one largest: cuts with no inlier edge across
    roots = np.flatnonzero(parent == n)
    lonely = np.delete(roots, np.argmax(hi[roots] - tin[roots]))
    x = np.concatenate([bridges, lonely])
    return Cuts(tin, tin[x], hi[x], np.concatenate([idx[tree[bridges]], np.full(len(lonely), -1)]))


def _depths(parent: np.ndarray, root: int) -> np.ndarray:
    """Each node's depth in the tree of ``parent`` (every node's, the virtual root ``root``
    its own ancestor: depth 0), by pointer jumping (log2 n passes)."""
    up = np.append(parent, root)  # the root's own entry
    depth = (up != np.arange(len(up))).astype(np.int64)
    while True:
        nxt = up[up]
        if np.array_equal(nxt, up):
            break
        depth = depth + depth[up] * (up != root)
        up = nxt
    return depth[:-1]


def _subtree_ends(d_pre: np.ndarray, tin: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Each node's subtree end in the pre-order (exclusive): the first later position of a
    depth not above its own, by a sparse table of range minima of the depths ``d_pre`` (in
    pre-order) and a binary search of every node at once."""
    m = len(d_pre)
    table = [d_pre]
    while (2 << (len(table) - 1)) <= m:
        h = 1 << (len(table) - 1)
        table.append(np.minimum(table[-1][:-h], table[-1][h:]))
    end = tin + 1
    for k in range(len(table) - 1, -1, -1):
        step = 1 << k
        ok = end + step <= m
        at = np.where(ok, end, 0)
        ok &= table[k][np.minimum(at, len(table[k]) - 1)] > depth
        end = np.where(ok, end + step, end)
    return end


def cut_moves(cuts: Cuts, q: np.ndarray, edges: np.ndarray, qrel: np.ndarray, inlier: np.ndarray, system: EdgeSystem,
              lev: np.ndarray, w: np.ndarray, model: NoiseModel) -> list:
    """Each cut's turn of its side that lowers the noise model's cost
    (:meth:`NoiseModel.vector_cost`) of the edges across it the most, when one does:
    ``[(gain, cut, quaternion)]``, the largest gain first. Each crossing edge proposes the
    turn that fits it exactly; every proposal is scored on all the crossing edges (their
    residual sizes from a stacked :class:`EdgeSystem`: the information matrices as the solve
    weighs them)."""
    out = np.flatnonzero(~inlier)
    if not len(cuts.lo) or not len(out):
        return []
    n = q.shape[1]
    k_order = np.argsort(np.minimum(cuts.hi - cuts.lo, n - (cuts.hi - cuts.lo)), kind="stable")
    k_order = k_order[: max(1, CUT_WORK_MAX // len(out))]
    ti, tj = cuts.tin[edges[out, 0]], cuts.tin[edges[out, 1]]
    info = system.scaled_information()
    found = []
    for k in k_order:
        lo, hi = cuts.lo[k], cuts.hi[k]
        cross = out[((ti >= lo) & (ti < hi)) != ((tj >= lo) & (tj < hi))]
        if cuts.bridge[k] >= 0:
            cross = np.append(cross, cuts.bridge[k])
        if not len(cross) or len(cross) > MAX_CROSSING:
            continue
        move = _score_turns(cross, cuts.inside(k, edges[cross, 1]), q, edges, qrel, info, lev, w, model)
        if move is not None:
            found.append((move[0], int(k), move[1]))
    return sorted(found, key=lambda m: -m[0])


def disjoint_moves(cuts: Cuts, moves: list) -> list:
    """Of ``moves`` (:func:`cut_moves`, best first), each that turns no camera an earlier kept
    one turns (sides are pre-order ranges: nested or apart)."""
    kept = []
    for m in moves:
        lo, hi = cuts.lo[m[1]], cuts.hi[m[1]]
        if all(hi <= cuts.lo[k[1]] or cuts.hi[k[1]] <= lo for k in kept):
            kept.append(m)
    return kept


def _score_turns(cross, head_in, q, edges, qrel, info, lev, w, model):
    """``(gain, turn)`` of the best proposal for one cut (None when none beats no turn):
    proposal ``a`` turns the side by the error of crossing edge ``a`` (its conjugate when the
    edge leaves the side), scored on the ``c`` crossing edges as ``c x c`` stacked edges."""
    c = len(cross)
    i, j = edges[cross, 0], edges[cross, 1]
    err = error_quaternions(q[:, i], q[:, j], qrel[:, cross])
    turns = np.where(head_in[None, :], err, so3_rows.qconj_rows(err))
    turns = np.concatenate([np.array([[1.0], [0.0], [0.0], [0.0]]), turns], axis=1)  # proposal 0: no turn
    k = turns.shape[1]
    # proposal a, edge b: nodes 2b (tail) and 2b+1 (head) of copy a; the side's end turned
    qi = np.repeat(q[:, i][:, None, :], k, axis=1)
    qj = np.repeat(q[:, j][:, None, :], k, axis=1)
    tt = np.repeat(turns[:, :, None], c, axis=2)
    qj = np.where(head_in[None, None, :], so3_rows.qmul_rows(qj.reshape(4, -1), tt.reshape(4, -1)).reshape(4, k, c), qj)
    qi = np.where(head_in[None, None, :], qi, so3_rows.qmul_rows(qi.reshape(4, -1), tt.reshape(4, -1)).reshape(4, k, c))
    nodes = np.stack([qi, qj], axis=-1).reshape(4, -1)  # (4, k * c * 2)
    pairs = np.arange(k * c * 2).reshape(-1, 2)
    stacked = EdgeSystem(k * c * 2, pairs, np.tile(qrel[:, cross], (1, k)), 0,
                         information=None if info is None else np.tile(info[cross], (k, 1, 1)))
    t = standardised(stacked.angles(nodes), np.tile(lev[cross], k)).reshape(k, c)
    cost = model.vector_cost_terms(t.ravel()).reshape(k, c) @ w[cross]
    agree = (model.weights(t.ravel())[1] >= 0.5).reshape(k, c).sum(axis=1)
    # a move must make more of the crossing edges inliers than now, and at least two (a consensus:
    # one edge can always be fitted, which says nothing), and cost less
    none = cost[0]
    cost = np.where(agree > max(int(agree[0]), 1), cost, np.inf)
    a = int(np.argmin(cost))
    if not none - cost[a] > 0:
        return None
    return float(none - cost[a]), turns[:, a]


def turn_sides(q: np.ndarray, cuts: Cuts, moves: list, anchor: int) -> np.ndarray:
    """``q`` with each move's side turned by its quaternion ``g`` (``R_x -> R_x G``: a change of
    the side's world frame), then every camera by the one turn that puts the anchor back (a
    change of gauge: no residual changes)."""
    out = q.copy()
    every = np.arange(q.shape[1])
    for _, k, g in moves:
        side = cuts.inside(k, every)
        out[:, side] = so3_rows.qmul_rows(out[:, side], np.repeat(g[:, None], int(side.sum()), axis=1))
    back = so3_rows.qmul_rows(so3_rows.qconj_rows(out[:, anchor:anchor + 1]), q[:, anchor:anchor + 1])
    return so3_rows.qmul_rows(out, np.repeat(back, q.shape[1], axis=1))
