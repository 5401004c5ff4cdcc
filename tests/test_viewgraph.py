"""The view graph model: construction checks, duplicates, components, networkx interop."""

import networkx as nx
import numpy as np
import pytest

from rotgraph import so3
from rotgraph.errors import InputError
from rotgraph.synth import random_problem
from rotgraph.viewgraph import ViewGraph, cycle_errors


def test_from_edges_string_ids_and_node_order():
    R = so3.random_rotations(3, 0)
    rel = np.stack([R[1] @ R[0].T, R[2] @ R[1].T])
    g = ViewGraph.from_edges(np.array(["b", "c"]), np.array(["c", "a"]), rel)
    assert list(g.node_ids) == ["a", "b", "c"]
    assert g.edges.tolist() == [[1, 2], [2, 0]]
    assert g.n_nodes == 3 and g.n_edges == 2


def test_unknown_id_bad_weight_and_not_a_rotation_are_errors():
    R = np.eye(3)[None]
    with pytest.raises(InputError, match="unknown camera"):
        ViewGraph.from_edges([0], [5], R, node_ids=np.arange(3))
    with pytest.raises(InputError, match="positive"):
        ViewGraph.from_edges([0], [1], R, weights=[-1.0])
    with pytest.raises(InputError, match="not a rotation"):
        ViewGraph.from_edges([0], [1], -R)
    with pytest.raises(InputError, match="self-loop"):
        ViewGraph.from_edges([1], [1], R)


def test_duplicates_error_merge_keep():
    R = so3.random_rotations(2, 1)
    rel = R[1] @ R[0].T
    noisy = so3.perturb(rel, 0.01, 2)
    e_i, e_j = np.array([0, 1, 0]), np.array([1, 0, 1])
    rels = np.stack([rel, noisy.T, rel])  # (1, 0) carries R_10 = R_01^T
    with pytest.raises(InputError, match="duplicate pair"):
        ViewGraph.from_edges(e_i, e_j, rels, source_lines=[1, 2, 3], source_path="f.txt")
    kept = ViewGraph.from_edges(e_i, e_j, rels, duplicates="keep")
    assert kept.n_edges == 3
    merged = ViewGraph.from_edges(e_i, e_j, rels, weights=[1.0, 2.0, 1.0], duplicates="merge")
    assert merged.n_edges == 1 and merged.weights[0] == 4.0
    # The merged rotation is the weighted chordal mean of the three, oriented (0, 1).
    expected = so3.project_to_so3(rel + 2 * noisy + rel)
    assert np.allclose(merged.cam2_from_cam1[0], expected, atol=1e-12)


def test_components_sorted_by_size_and_subgraph():
    a = random_problem(n=20, degree=4, sigma_deg=0, seed=1)
    b = random_problem(n=5, degree=2, sigma_deg=0, seed=2)
    e = np.concatenate([b.edges, a.edges + 5])
    g = ViewGraph.from_edges(e[:, 0], e[:, 1], np.concatenate([b.cam2_from_cam1, a.cam2_from_cam1]), node_ids=np.arange(25))
    labels = g.components()
    assert (labels[5:] == 0).all() and (labels[:5] == 1).all()
    sub, nodes, eidx = g.largest_component()
    assert sub.n_nodes == 20 and np.array_equal(nodes, np.arange(5, 25))
    assert np.array_equal(sub.cam2_from_cam1, g.cam2_from_cam1[eidx])
    s = g.summary()
    assert s["n_components"] == 2 and s["largest_component"] == 20


def test_networkx_round_trip():
    g = random_problem(n=30, degree=6, sigma_deg=1, seed=3)
    G = g.to_networkx()
    assert isinstance(G, nx.Graph) and G.number_of_edges() == g.n_edges
    assert nx.is_connected(G)
    h = ViewGraph.from_networkx(G)
    assert h.n_edges == g.n_edges
    # Same relative rotation for each pair, whatever the orientation networkx reports.
    def pairs(v):
        out = {}
        for (i, j), R in zip(v.edges, v.cam2_from_cam1):
            a, b = v.node_ids[i], v.node_ids[j]
            out[(a, b)] = R
            out[(b, a)] = R.T
        return out

    pg, ph = pairs(g), pairs(h)
    for k, R in pg.items():
        assert np.allclose(ph[k], R, atol=1e-12)


def test_networkx_multigraph_for_parallel_edges():
    R = np.eye(3)[None].repeat(2, 0)
    g = ViewGraph.from_edges([0, 0], [1, 1], R, duplicates="keep")
    assert isinstance(g.to_networkx(), nx.MultiGraph)


def test_cycle_errors_zero_without_noise_and_grow_with_noise():
    clean = random_problem(n=40, degree=10, sigma_deg=0.0, seed=4)
    assert np.degrees(cycle_errors(clean)).max() < 1e-9
    noisy = random_problem(n=40, degree=10, sigma_deg=2.0, seed=4)
    c = np.degrees(cycle_errors(noisy))
    # Three independent 2-degree-per-axis errors: closure angle ~ 2 * sqrt(3) * 1.54 deg median.
    assert 3.0 < np.median(c) < 7.0


def test_components_of_an_empty_graph():
    g = ViewGraph.from_edges([], [], np.zeros((0, 3, 3)), node_ids=np.zeros(0, dtype=np.int64))
    assert g.components().shape == (0,)
    sub, nodes, _ = g.largest_component()
    assert sub.n_nodes == 0 and len(nodes) == 0


def test_small_graph_components_match_csgraph():
    """Graphs of <= 64 nodes take a label-propagation path: same labels as scipy's search."""
    import scipy.sparse as sp
    from scipy.sparse import csgraph

    rng = np.random.default_rng(0)
    for _ in range(300):
        n = int(rng.integers(1, 65))
        e = rng.integers(0, n, (int(rng.integers(0, 2 * n)), 2))
        e = e[e[:, 0] != e[:, 1]]
        g = ViewGraph.from_edges(e[:, 0], e[:, 1], np.broadcast_to(np.eye(3), (len(e), 3, 3)), node_ids=np.arange(n), duplicates="keep")
        nc, lab = csgraph.connected_components(sp.csr_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)), directed=False)
        rank = np.empty(nc, dtype=np.int64)
        rank[np.argsort(-np.bincount(lab, minlength=nc), kind="stable")] = np.arange(nc)
        assert (g.components() == rank[lab]).all()


@pytest.mark.parametrize("ext", ["txt", "npz"])
def test_quaternion_readers_keep_quaternions_until_matrices_are_asked_for(tmp_path, ext):
    """Edge files of quaternions give graphs that hold them (QuaternionRotations): the solver
    takes them as they are, the matrices are made on first access (equal to what the reader
    made before), and from then on the matrices are the graph's rotations."""
    import pickle

    import rotgraph
    from rotgraph.io.writers import write_edges, write_edges_npz
    from rotgraph.pipeline.read import read_view_graph
    from rotgraph.viewgraph import QuaternionRotations

    g = random_problem(n=60, degree=8, sigma_deg=2.0, outliers=0.1, seed=4)
    path = tmp_path / f"edges.{ext}"
    if ext == "npz":
        write_edges_npz(path, g.node_ids[g.edges[:, 0]], g.node_ids[g.edges[:, 1]], g.cam2_from_cam1)
    else:
        write_edges(path, g)
    lazy = read_view_graph(path)
    assert isinstance(lazy.__dict__["_cam2_from_cam1"], QuaternionRotations)
    q = lazy.relative_quaternion_rows()
    assert q.shape == (4, g.n_edges) and (q[0] >= 0).all()
    assert np.abs(np.einsum("ke,ke->e", q, q) - 1).max() < 1e-15
    again = pickle.loads(pickle.dumps(lazy))  # Dask ships graphs: still lazy after the trip
    assert isinstance(again.__dict__["_cam2_from_cam1"], QuaternionRotations)
    r_lazy = rotgraph.average_rotations(lazy)
    assert isinstance(lazy.__dict__["_cam2_from_cam1"], QuaternionRotations)  # the solve made no matrices
    R = lazy.cam2_from_cam1
    assert isinstance(R, np.ndarray) and R.shape == (g.n_edges, 3, 3)
    assert lazy.cam2_from_cam1 is R  # made once, then kept
    np.testing.assert_allclose(R, so3.matrices_from_quaternions(q.T), atol=1e-15, rtol=0)
    np.testing.assert_allclose(R, g.cam2_from_cam1, atol=1e-6)  # the file's digits
    # the same solve from the matrices (quaternions made back from them: equal to rounding)
    np.testing.assert_allclose(rotgraph.average_rotations(lazy).cam_from_world, r_lazy.cam_from_world, atol=1e-12)
    R[0] = R[0].T  # the matrices are now the truth: a change shows in the quaternions
    expect = so3.quaternion_rows_from_matrices(R[:1])[:, 0]
    np.testing.assert_allclose(lazy.relative_quaternion_rows()[:, 0], expect)


def test_largest_component_and_subgraphs_keep_quaternions():
    """largest_component: the graph itself when connected, else the biggest part; the
    subgraph of a graph holding quaternions holds the matching quaternions."""
    from rotgraph.viewgraph import QuaternionRotations

    g = random_problem(n=30, degree=6, sigma_deg=1.0, seed=2)
    sub, nodes, eidx = g.largest_component()
    assert sub is g and np.array_equal(nodes, np.arange(30)) and np.array_equal(eidx, np.arange(g.n_edges))
    lazy = ViewGraph(g.node_ids, g.edges, QuaternionRotations(g.relative_quaternion_rows()), g.weights)
    two = ViewGraph.from_edges(  # a second, smaller component: cameras 100-102
        np.concatenate([g.node_ids[g.edges[:, 0]], [100, 101]]), np.concatenate([g.node_ids[g.edges[:, 1]], [101, 102]]),
        np.concatenate([g.cam2_from_cam1, so3.random_rotations(2, rng=1)]))
    sub, nodes, eidx = two.largest_component()
    assert sub.n_nodes == 30 and np.array_equal(sub.node_ids, g.node_ids) and len(eidx) == g.n_edges
    part, idx = lazy.subgraph(np.arange(10))
    assert isinstance(part.__dict__["_cam2_from_cam1"], QuaternionRotations)
    np.testing.assert_allclose(part.cam2_from_cam1, g.cam2_from_cam1[idx], atol=1e-15)


def _outcome(build):
    try:
        g = build()
    except InputError as exc:
        return str(exc)
    return g


@pytest.mark.parametrize("kind", ["int", "str"])
@pytest.mark.parametrize("case", ["clean", "self-loop", "bad weight", "parallel error", "parallel keep", "parallel merge"])
def test_from_edges_fast_path_is_the_same_graph_and_errors(kind, case):
    """from_edges on codes (positions in node_ids) with checked quaternions, the readers'
    fast path, builds what the id path builds from matrices, and raises the same errors
    (naming the ids, not the codes)."""
    from rotgraph.viewgraph import QuaternionRotations

    g = random_problem(n=12, degree=4, sigma_deg=1.0, seed=3)
    ids = np.arange(100, 112) if kind == "int" else np.array([f"im{k:02d}" for k in range(12)])
    e = g.edges.copy()
    w = np.linspace(1.0, 2.0, len(e))
    rows = g.relative_quaternion_rows().copy()
    duplicates = "error"
    if case == "self-loop":
        e[3, 1] = e[3, 0]
    elif case == "bad weight":
        w[4] = 0.0
    elif case.startswith("parallel"):
        e = np.concatenate([e, e[[2, 5]][:, ::-1]])
        w = np.concatenate([w, [0.5, 3.0]])
        rows = np.concatenate([rows, so3.qconj_rows(rows[:, [2, 5]])], axis=1)
        duplicates = case.split()[1]
    lines = np.arange(len(e)) + 10
    common = dict(duplicates=duplicates, source_lines=lines, source_path="e.txt")
    slow = _outcome(lambda: ViewGraph.from_edges(ids[e[:, 0]], ids[e[:, 1]], so3.matrices_from_quaternion_rows(rows), w,
                                                 **common))
    fast = _outcome(lambda: ViewGraph.from_edges(e[:, 0], e[:, 1], QuaternionRotations(rows.copy()), w, node_ids=ids,
                                                 codes=True, **common))
    if isinstance(slow, str):
        assert fast == slow
        if case == "self-loop":
            assert f"camera {ids[e[3, 0]].item()!r} to itself" in slow  # the id, not its code
        return
    if case in ("clean", "parallel keep"):  # nothing merged: the graph keeps the quaternions it was given
        assert isinstance(fast.__dict__["_cam2_from_cam1"], QuaternionRotations)
        np.testing.assert_array_equal(fast.relative_quaternion_rows(), QuaternionRotations(rows.copy()).rows)
    for a, b in ((slow.node_ids, fast.node_ids), (slow.edges, fast.edges), (slow.weights, fast.weights),
                 (slow.source_lines, fast.source_lines)):
        np.testing.assert_array_equal(a, b)
    assert fast.node_ids.dtype == slow.node_ids.dtype
    np.testing.assert_allclose(fast.cam2_from_cam1, slow.cam2_from_cam1, atol=1e-15, rtol=0)


def test_from_edges_codes_need_their_node_ids():
    R = np.eye(3)[None]
    with pytest.raises(ValueError, match="node_ids"):
        ViewGraph.from_edges([0], [1], R, codes=True)
    with pytest.raises(ValueError, match="positions"):
        ViewGraph.from_edges([0], [2], R, node_ids=np.array([5, 6]), codes=True)
