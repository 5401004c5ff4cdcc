"""Stage 1 of the distributed solve part by part (rotgraph.pipeline.partition, #32): the
parts' degrees and spanning forests merged pairwise give the whole graph's components and
degrees exactly (against scipy and networkx on random multigraphs with several components,
duplicate edges and self-loops); where the partitioner's sample is the whole component the
cut is the one of the whole graph in one process; a larger graph's sample is its share a part,
deterministic, of the component's edges. (The distributed solve's answer with this plan:
tests/test_distributed.py.)"""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components

from rotgraph.pipeline import blocks
from rotgraph.pipeline import partition as pt


def multigraph(rng, sizes, degree: float, loops: int = 3, dups: int = 5):
    """Random edges (2, E) on components of the given sizes (each a random tree plus random
    edges inside it: connected), with some duplicate edges and self-loops, shuffled; and the
    camera count. Camera codes are interleaved across components."""
    n = sum(sizes)
    perm = rng.permutation(n)
    edges, start = [], 0
    for s in sizes:
        cams = perm[start:start + s]
        start += s
        if s > 1:
            edges.append(np.stack([cams[1:], cams[rng.integers(0, np.arange(1, s))]]))  # a random tree
            k = int(degree * s / 2)
            edges.append(np.stack([cams[rng.integers(0, s, k)], cams[rng.integers(0, s, k)]]))
    e = np.concatenate(edges, axis=1)
    e = e[:, e[0] != e[1]]
    e = np.concatenate([e, e[:, rng.integers(0, e.shape[1], dups)], np.tile(rng.integers(0, n, loops), (2, 1))], axis=1)
    return e[:, rng.permutation(e.shape[1])].astype(np.int32), n


def parts_of(e, k: int, rng):
    cuts = np.sort(rng.integers(0, e.shape[1], k - 1))
    return np.split(e, cuts, axis=1)


@pytest.mark.parametrize("seed", range(4))
def test_components_and_degrees_equal_the_whole_graphs(seed):
    rng = np.random.default_rng(seed)
    e, n = multigraph(rng, [300, 120, 120, 7, 1 + seed, 2], degree=6.0)
    parts = parts_of(e, 2 + seed, rng)
    ids = np.arange(n)
    root = pt.pairwise(pt.merge, [pt.summarise(p, ids) for p in parts])
    assert root["forest"].shape[1] <= n - 1
    base = pt.component(root)
    # networkx on the whole multigraph (self-loops left out, as the solve does)
    G = nx.MultiGraph()
    G.add_nodes_from(range(n))
    G.add_edges_from(e[:, e[0] != e[1]].T.tolist())
    comps = sorted(nx.connected_components(G), key=len, reverse=True)
    assert base["n_components"] == len(comps)
    assert set(np.flatnonzero(base["keep"])) == comps[0]
    deg = np.array([G.degree(v) for v in range(n)], dtype=float)
    assert np.array_equal(root["degree"], deg)
    assert np.array_equal(base["degree"], np.where(base["keep"], deg, 0.0))
    assert base["n_edges"] == G.subgraph(comps[0]).number_of_edges()
    assert base["n_input_edges"] == e.shape[1]
    assert base["degree"][base["anchor"]] == deg[list(comps[0])].max()
    # the merged forest spans each component with one edge fewer than its cameras
    f = root["forest"]
    k, labels = connected_components(pt._adjacency(n, f[0], f[1]), directed=False)
    assert k == len(comps) and f.shape[1] == n - len(comps)
    assert all(len(set(labels[list(c)])) == 1 for c in comps)


@pytest.mark.parametrize("graph", ["er", "traj"])
def test_cut_equals_the_whole_graphs_where_the_sample_is_the_whole_component(graph):
    """Degree <= PARTITION_DEGREE: every part gives all its component edges, and the plan is
    the one of the whole graph in one process: the same cut as the partitioner on the whole
    component's adjacency, the block-pair counts of every edge, the anchor of highest degree."""
    from rotgraph.synth import random_problem

    g = random_problem(n=400, degree=12, sigma_deg=1.0, outliers=0.0, graph=graph, seed=3)
    e = g.edges.T.astype(np.int32)
    extra = np.array([[400, 401], [401, 402], [403, 403]]).T.astype(np.int32)  # a 3-camera component, a loop
    ids = np.arange(404)
    rng = np.random.default_rng(1)
    plan = blocks.partition(ids, 4, *parts_of(np.concatenate([e, extra], axis=1)[:, rng.permutation(e.shape[1] + 3)], 5, rng))
    labels, name = pt._split(pt._adjacency(400, e[0], e[1]), 4)
    assert plan["partitioner"] == name and np.array_equal(plan["block"][:400], labels)
    assert (plan["block"][400:] == -1).all() and plan["n_components"] == 3
    bi, bj = labels[e[0]], labels[e[1]]
    counts = np.zeros((4, 4), np.int64)
    np.add.at(counts, (np.minimum(bi, bj), np.maximum(bi, bj)), 1)
    assert np.array_equal(plan["counts"], counts)
    assert plan["cut_edges"] == int((bi != bj).sum()) and plan["n_edges"] == e.shape[1]
    assert plan["n_input_edges"] == e.shape[1] + 3
    deg = np.bincount(e.ravel(), minlength=404)
    assert plan["anchor"] == int(np.argmax(deg)) and np.array_equal(plan["degree"], np.where(ids < 400, deg, 0))


def test_a_denser_graphs_sample_is_each_parts_share():
    """Above PARTITION_DEGREE / 2 edges a camera the parts give about that many edges in all,
    each in proportion to its component edges, all in the component, the same every run."""
    rng = np.random.default_rng(7)
    e, n = multigraph(rng, [500, 40], degree=80.0)
    parts = parts_of(e, 6, rng)
    ids = np.arange(n)
    base = pt.component(pt.pairwise(pt.merge, [pt.summarise(p, ids) for p in parts]))
    got = [pt.sample(p, k, base) for k, p in enumerate(parts)]
    target = pt.PARTITION_DEGREE * 500 // 2
    assert abs(sum(s.shape[1] for s in got) - target) <= len(parts)
    for p, s in zip(parts, got):
        inside = base["keep"][p[0]] & (p[0] != p[1])
        assert abs(s.shape[1] - target * inside.sum() / base["n_edges"]) <= 0.5
        assert base["keep"][s].all() and (s[0] != s[1]).all()
        pairs = set(map(tuple, p[:, inside].T.tolist()))
        assert set(map(tuple, s.T.tolist())) <= pairs
    again = [pt.sample(p, k, base) for k, p in enumerate(parts)]
    assert all(np.array_equal(a, b) for a, b in zip(got, again))
    plan = blocks.partition(ids, 3, *parts)
    assert set(plan["block"][base["keep"]]) == {0, 1, 2} and (plan["block"][~base["keep"]] == -1).all()
    assert plan["counts"][np.triu_indices(3)].sum() == base["n_edges"]
