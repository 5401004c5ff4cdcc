"""Weak cuts of a robust fit (rotgraph.estimators.cuts) and their repair in the default solve."""

from dataclasses import replace

import networkx as nx
import numpy as np
import pytest

import rotgraph
from rotgraph import so3
from rotgraph.estimators import adaptive
from rotgraph.evaluate import compare_rotations
from rotgraph.estimators.cuts import bridge_cuts, disjoint_moves, turn_sides
from rotgraph.viewgraph import ViewGraph


def _random_multigraph(seed):
    """A sparse random graph with chains, parallel edges and lone components."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 60))
    m = int(rng.integers(n // 2, 2 * n))
    edges = rng.integers(0, n, (m, 2))
    edges = edges[edges[:, 0] != edges[:, 1]]
    if len(edges) > 3:  # a few parallel copies, some reversed
        dup = edges[rng.choice(len(edges), 3)]
        edges = np.vstack([edges, dup[:2], dup[2:, ::-1]])
    inlier = rng.random(len(edges)) < 0.8
    return n, edges, inlier


@pytest.mark.parametrize("seed", range(40))
def test_bridges_and_components_match_networkx(seed):
    n, edges, inlier = _random_multigraph(seed)
    cuts = bridge_cuts(n, edges, inlier, seed)
    e = edges[inlier]
    g = nx.MultiGraph()
    g.add_nodes_from(range(n))
    g.add_edges_from(map(tuple, e))
    simple = nx.Graph(g)
    want = {frozenset(b) for b in nx.bridges(simple) if g.number_of_edges(*b) == 1}
    got = {frozenset(edges[k]) for k in cuts.bridge[cuts.bridge >= 0]}
    assert got == want
    nodes = np.arange(n)
    for k in np.flatnonzero(cuts.bridge >= 0):  # a bridge's side: one of the two parts it splits its component into
        a, b = edges[cuts.bridge[k]]
        h = simple.copy()
        h.remove_edge(a, b)
        side = set(nodes[cuts.inside(k, nodes)].tolist())
        assert side in (nx.node_connected_component(h, a), nx.node_connected_component(h, b))
    comps = sorted(nx.connected_components(simple), key=len)
    lonely = [set(nodes[cuts.inside(k, nodes)].tolist()) for k in np.flatnonzero(cuts.bridge < 0)]
    assert len(lonely) == len(comps) - 1  # every component but one largest
    assert all(s in comps for s in lonely) and max(map(len, comps)) >= max(map(len, lonely), default=0)


def _two_blocks(seed, wrong_deg=120.0, true_across=3):
    """Two well-connected blocks of cameras joined by ``true_across`` true pairs and one wrong
    pair; the rotations with block B turned so that the wrong pair fits exactly (what a fit that
    kept the wrong pair looks like)."""
    rng = np.random.default_rng(seed)
    nb = 12
    n = 2 * nb
    R = so3.random_rotations(n, rng)
    pairs = [(i, j) for blk in (0, nb) for i in range(blk, blk + nb) for j in range(i + 1, blk + nb) if rng.random() < 0.8 or j == i + 1]
    across = [(int(c // nb), int(nb + c % nb)) for c in rng.choice(nb * nb, true_across + 1, replace=False)]
    edges = np.array(pairs + across)
    rel = R[edges[:, 1]] @ np.transpose(R[edges[:, 0]], (0, 2, 1))
    rel = so3.perturb(rel, np.deg2rad(0.5), rng)
    turn = so3.exp(np.deg2rad(wrong_deg) * np.array([0.0, 0.6, 0.8]))
    i, j = edges[-1]
    rel[-1] = R[j] @ turn @ R[i].T  # the wrong pair: block B seen turned by `turn`
    graph = replace(ViewGraph.from_edges(edges[:, 0], edges[:, 1], rel, node_ids=np.arange(n)), gt_cam_from_world=R)
    assert np.array_equal(graph.edges, edges)
    wrong = R.copy()
    wrong[nb:] = R[nb:] @ turn  # B turned so that the wrong pair fits
    return graph, wrong, nb


@pytest.mark.parametrize("seed", range(6))
def test_turn_sides_restores_truth_and_keeps_the_anchor(seed):
    graph, wrong, nb = _two_blocks(seed)
    q = so3.quaternions_from_matrices(wrong).T.copy()
    inlier = np.ones(graph.n_edges, bool)
    inlier[-4:-1] = False  # the true pairs across called outliers, the wrong one kept
    cuts = bridge_cuts(graph.n_nodes, graph.edges, inlier)
    assert list(cuts.bridge) == [graph.n_edges - 1]
    side = cuts.inside(0, np.arange(graph.n_nodes))
    # the turn that fits the first true pair across; applied with the anchor on either side
    i, j = graph.edges[-4]
    qi, qj = q[:, i], q[:, j]
    e = so3.qmul_rows(so3.qconj_rows(qj[:, None]), so3.qmul_rows(so3.quaternions_from_matrices(graph.cam2_from_cam1[-4:-3]).T, qi[:, None]))[:, 0]
    g = e if side[j] else so3.qconj_rows(e[:, None])[:, 0]
    for anchor in (0, graph.n_nodes - 1):
        fixed = so3.matrices_from_quaternions(turn_sides(q, cuts, [(1.0, 0, g)], anchor).T)
        err = compare_rotations(fixed, graph.gt_cam_from_world)
        assert err.max < 3.0
        assert np.allclose(fixed[anchor], wrong[anchor])


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("wrong_deg", [40.0, 120.0])
def test_default_solve_leaves_the_wrong_basin(seed, wrong_deg, monkeypatch):
    """Started where one wrong pair holds block B turned and two true pairs across agree on
    another turn, the default solve stays there without the cut repair (the fit keeps the one
    edge that fits: 6-7 deg median error at 40 deg, 60 at 120) and finds the truth with it."""
    graph, wrong, nb = _two_blocks(seed, wrong_deg, true_across=2)
    g = replace(graph, initial_cam_from_world=wrong)
    opts = rotgraph.SolveOptions(init="vertices")
    res = rotgraph.average_rotations(g, opts)
    assert res.diagnostics["cut_moves"] == 1
    assert compare_rotations(res.cam_from_world, graph.gt_cam_from_world).median < 1.0
    assert not res.inliers[-1] and res.inliers[-3:-1].all()
    monkeypatch.setattr(adaptive, "CUT_ROUNDS", 0)
    stuck = rotgraph.average_rotations(g, opts)
    assert compare_rotations(stuck.cam_from_world, graph.gt_cam_from_world).median > 5.0


@pytest.mark.parametrize("seed", range(4))
def test_no_consensus_no_move(seed, monkeypatch):
    """One true pair against one wrong one: nothing tells them apart, and the cut is left as it
    is (the same answer as without the repair)."""
    graph, wrong, nb = _two_blocks(seed, 120.0, true_across=1)
    g = replace(graph, initial_cam_from_world=wrong)
    opts = rotgraph.SolveOptions(init="vertices")
    res = rotgraph.average_rotations(g, opts)
    assert "cut_moves" not in res.diagnostics
    monkeypatch.setattr(adaptive, "CUT_ROUNDS", 0)
    assert np.array_equal(rotgraph.average_rotations(g, opts).cam_from_world, res.cam_from_world)


def test_disjoint_moves_keep_the_best_of_nested_sides():
    """A chain 0-1-2-3-4 and a lone pair 5-6: nested subtrees and a component apart."""
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [5, 6], [4, 5]])
    inlier = np.array([True, True, True, True, True, False])
    cuts = bridge_cuts(7, edges, inlier)
    assert len(cuts.lo) == 6  # the four bridges of the chain, the pair's own edge, the pair as a component
    sizes = cuts.hi - cuts.lo
    moves = [(float(10 - s), k, None) for k, s in enumerate(sizes)]  # the smallest sides gain most
    moves.sort(key=lambda m: -m[0])
    kept = disjoint_moves(cuts, moves)
    ranges = sorted((cuts.lo[k], cuts.hi[k]) for _, k, _ in kept)
    assert all(a[1] <= b[0] for a, b in zip(ranges, ranges[1:]))  # no camera turned twice
    assert kept[0] == moves[0] and len(kept) == 2  # the best, and the one side apart from it
