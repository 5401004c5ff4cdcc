"""Per-edge rotation information matrices in the edge files: read and written.

Convention (rotgraph.viewgraph): R_ij,meas = exp([d]x) R_ij, d ~ N(0, H^-1), d in camera
j's frame, H in radians^-2. The ``rotgraph`` text format carries ``h_xx h_xy h_xz h_yy h_yz
h_zz`` after ``[weight]``, ``csv`` the columns ``info_xx ... info_zz``; g2o's 6x6
information over (x, y, z, qx, qy, qz) becomes the Schur complement of its translation
block, / 4. The g2o test below builds its measurements from g2o's own definition
(EdgeSE3::computeError: error = toVectorMQT(Z^-1 T_i^-1 T_j)), never from rotgraph's reader.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_clean_error, run
from scipy.spatial.transform import Rotation

from rotgraph import so3
from rotgraph.errors import InputError
from rotgraph.io.edges import read_edge_file
from rotgraph.io.formats import detect_format
from rotgraph.io.writers import write_edges
from rotgraph.viewgraph import ViewGraph

UPPER = np.triu_indices(3)
TEXT_COLS = "h_xx h_xy h_xz h_yy h_yz h_zz"
CSV_COLS = "info_xx,info_xy,info_xz,info_yy,info_yz,info_zz"


def random_spd(m: int, rng, scale=1e4) -> np.ndarray:
    """(m, 3, 3) symmetric positive definite, anisotropic, entries of mixed sizes."""
    A = rng.standard_normal((m, 3, 3))
    return scale * (A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(3))


def random_graph(n=12, m=30, seed=0, ids=None) -> ViewGraph:
    rng = np.random.default_rng(seed)
    R = so3.random_rotations(n, rng)
    pairs = set()
    while len(pairs) < m:
        i, j = rng.choice(n, 2, replace=False)
        if (j, i) not in pairs:
            pairs.add((int(i), int(j)))
    i, j = np.array(sorted(pairs)).T
    rel = R[j] @ np.swapaxes(R[i], 1, 2)
    node = np.arange(n) if ids is None else np.asarray(ids)
    return ViewGraph.from_edges(node[i], node[j], rel, rng.uniform(0.5, 3, m), node_ids=node,
                                information=random_spd(m, rng))


def assert_rel_close(a, b, rtol=1e-12):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    np.testing.assert_array_less(np.abs(a - b), rtol * np.maximum(np.abs(b).max(), 1e-300))


def assert_same_edges(g: ViewGraph, h: ViewGraph, rtol=1e-12):
    """Same edges (by external ids, in order), rotations, weights and information."""
    assert list(g.node_ids[g.edges].ravel()) == list(h.node_ids[h.edges].ravel())
    np.testing.assert_allclose(h.cam2_from_cam1, g.cam2_from_cam1, atol=1e-14)
    assert_rel_close(h.weights, g.weights, rtol)
    for a, b in zip(h.information, g.information):
        assert_rel_close(a, b, rtol)


def upper_text(H) -> list[str]:
    return [" ".join(repr(float(x)) for x in h[UPPER]) for h in H]


# ------------------------------------------------------------------ rotgraph text and csv


@pytest.mark.parametrize("ids", [None, [f"cam_{k}.jpg" for k in range(12)]])
def test_text_round_trip(tmp_path, ids):
    g = random_graph(ids=ids)
    p = tmp_path / "edges.txt"
    write_edges(p, g)
    text = p.read_text()
    assert text.startswith(f"# i j qw qx qy qz weight {TEXT_COLS}\n")
    assert {len(line.split()) for line in text.splitlines()[1:]} == {13}
    assert detect_format(p) == "rotgraph"
    h = read_edge_file(p)
    assert_same_edges(g, h)
    # written again: the same information fields, byte for byte
    q = tmp_path / "again.txt"
    write_edges(q, h)
    assert [line.split()[-6:] for line in q.read_text().splitlines()] == [line.split()[-6:] for line in text.splitlines()]


def test_text_without_weight_column(tmp_path):
    """12 fields: i j qw qx qy qz + information; every weight 1."""
    g = random_graph(seed=1)
    q = so3.quaternions_from_matrices(g.cam2_from_cam1)
    ids = g.node_ids[g.edges]
    lines = [f"{a} {b} " + " ".join(repr(float(x)) for x in qk) + " " + u
             for (a, b), qk, u in zip(ids.tolist(), q, upper_text(g.information))]
    p = tmp_path / "e.txt"
    p.write_text("# i j qw qx qy qz " + TEXT_COLS + "\n" + "\n".join(lines) + "\n")
    h = read_edge_file(p)
    assert (h.weights == 1).all()
    for a, b in zip(h.information, g.information):
        assert_rel_close(a, b)


def test_csv_round_trip_any_column_order(tmp_path):
    g = random_graph(seed=2)
    q = so3.quaternions_from_matrices(g.cam2_from_cam1)
    cols = {"i": g.node_ids[g.edges[:, 0]].astype(str), "j": g.node_ids[g.edges[:, 1]].astype(str),
            "note": np.array(["x"] * g.n_edges)}
    cols.update({c: [repr(float(v)) for v in q[:, k]] for k, c in enumerate(("qw", "qx", "qy", "qz"))})
    cols["weight"] = [repr(float(v)) for v in g.weights]
    for name, (r, c) in zip(CSV_COLS.split(","), zip(*UPPER)):
        cols[name] = [repr(float(v)) for v in g.information[:, r, c]]
    order = ["info_zz", "j", "qx", "info_xy", "note", "i", "qw", "info_xx", "qy", "weight", "info_yz", "qz",
             "info_xz", "info_yy"]
    p = tmp_path / "e.csv"
    p.write_text(",".join(order) + "\n" + "".join(",".join(cols[c][k] for c in order) + "\n" for k in range(g.n_edges)))
    assert_same_edges(g, read_edge_file(p))
    # the csv graph written as text reads back the same again
    write_edges(tmp_path / "e.txt", read_edge_file(p))
    assert_same_edges(g, read_edge_file(tmp_path / "e.txt"))


def test_duplicates_merge_carries_information(tmp_path):
    """A reversed parallel edge merges its information as ViewGraph.from_edges does."""
    g = random_graph(seed=3)
    rel = np.concatenate([g.cam2_from_cam1, np.swapaxes(g.cam2_from_cam1[:1], 1, 2)])
    ij = np.concatenate([g.edges, g.edges[:1, ::-1]])
    H = np.concatenate([g.information, g.information[:1] * 2])
    write_edges(tmp_path / "e.txt", ij[:, 0], ij[:, 1], rel, information=H)
    merged = read_edge_file(tmp_path / "e.txt", duplicates="merge")
    expect = ViewGraph.from_edges(ij[:, 0], ij[:, 1], rel, information=H, duplicates="merge")
    assert merged.n_edges == g.n_edges
    for a, b in zip(merged.information, expect.information):
        assert_rel_close(a, b)
    kept = read_edge_file(tmp_path / "e.txt", duplicates="keep")
    assert kept.n_edges == g.n_edges + 1 and kept.information.shape == (g.n_edges + 1, 3, 3)


def test_files_without_information_read_and_write_as_before(tmp_path):
    g = random_graph(seed=4)
    plain = ViewGraph.from_edges(g.node_ids[g.edges[:, 0]], g.node_ids[g.edges[:, 1]], g.cam2_from_cam1, g.weights)
    p = tmp_path / "e.txt"
    write_edges(p, plain)
    text = p.read_text()
    assert text.startswith("# i j qw qx qy qz weight\n")
    assert {len(line.split()) for line in text.splitlines()[1:]} == {7}
    assert read_edge_file(p).information is None
    # 6 and 7 fields still mix
    lines = text.splitlines()
    lines[2] = " ".join(lines[2].split()[:6])
    p.write_text("\n".join(lines) + "\n")
    h = read_edge_file(p)
    assert h.information is None and h.weights[1] == 1
    c = tmp_path / "e.csv"
    c.write_text("i,j,qw,qx,qy,qz,weight\n0,1,1,0,0,0,2\n1,2,1,0,0,0,3\n")
    assert read_edge_file(c).information is None
    gl = tmp_path / "glomap.txt"
    gl.write_text("a.jpg b.jpg 1 0 0 0 0 0 1\n")
    assert read_edge_file(gl, "glomap").information is None


# ------------------------------------------------------------------ g2o


def _quat_matrix(w, v):
    return Rotation.from_quat(np.concatenate([v, w[:, None]], axis=1)).as_matrix()


def _iso(R, t):
    T = np.zeros((len(R), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, t, 1
    return T


def _g2o_from_vector_mqt(xi):
    """g2o's internal::fromVectorMQT: translation xi[:3], rotation of the quaternion
    (sqrt(1 - |v|^2), v) with v = xi[3:] (isometry3d_mappings.cpp)."""
    v = xi[:, 3:]
    w = np.sqrt(1 - (v * v).sum(axis=1))
    return _iso(_quat_matrix(w, v), xi[:, :3])


def _g2o_to_vector_mqt(T):
    """g2o's internal::toVectorMQT: translation and the quaternion's vector part, w >= 0."""
    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()  # x, y, z, w
    q *= np.where(q[:, 3:] < 0, -1, 1)
    return np.concatenate([T[:, :3, 3], q[:, :3]], axis=1)


def _g2o_edge_lines(i, j, Z, info6, rng=None) -> list[str]:
    """EDGE_SE3:QUAT lines as g2o writes them (toVectorQT: x y z qx qy qz qw, then the upper
    triangle of the information, row-major); the quaternion's sign is random when ``rng``."""
    q = Rotation.from_matrix(Z[:, :3, :3]).as_quat()
    if rng is not None:
        q *= rng.choice([-1.0, 1.0], size=(len(q), 1))
    up = " ".join(repr(float(x)) for x in info6[np.triu_indices(6)])
    return [f"EDGE_SE3:QUAT {a} {b} " + " ".join(repr(float(x)) for x in np.concatenate([Z[k, :3, 3], q[k]])) + " " + up
            for k, (a, b) in enumerate(zip(i, j))]


def test_g2o_information_matches_g2o_definition_monte_carlo(tmp_path):
    """Measurements whose g2o error at the true poses is xi ~ N(0, I^-1) (I: a full 6x6
    information with rotation-translation cross terms): rotgraph's d = log(R_ij,meas
    R_ij,true^T) has covariance inv(H), H as rotgraph reads it."""
    rng = np.random.default_rng(20240611)
    N = 20000
    # covariance of g2o's error (x, y, z, qx, qy, qz): anisotropic, strongly correlated
    B = rng.standard_normal((6, 6))
    B[:3] *= 0.05  # translations ~ 5 cm
    B[3:] *= 0.004  # quaternion vector part ~ 0.5-1 degree
    B[3:, :3] += 0.01 * rng.standard_normal((3, 3))  # rotation correlated with translation
    B[5] *= 3  # anisotropic rotation
    Sigma = B @ B.T
    info6 = np.linalg.inv(Sigma)
    info6 = 0.5 * (info6 + info6.T)
    xi = rng.multivariate_normal(np.zeros(6), Sigma, size=N)
    assert np.abs(_g2o_to_vector_mqt(_g2o_from_vector_mqt(xi[:5])) - xi[:5]).max() < 1e-12  # g2o's maps invert

    # true poses world_from_body, one pair (2k, 2k+1) per edge
    Ti = _iso(so3.random_rotations(N, rng), rng.normal(size=(N, 3)))
    Tj = _iso(so3.random_rotations(N, rng), rng.normal(size=(N, 3)))
    rel_true = np.linalg.inv(Ti) @ Tj
    Z = rel_true @ np.linalg.inv(_g2o_from_vector_mqt(xi))
    # g2o's error at the true poses, as EdgeSE3::computeError computes it, is xi
    err = _g2o_to_vector_mqt(np.linalg.inv(Z[:50]) @ np.linalg.inv(Ti[:50]) @ Tj[:50])
    np.testing.assert_allclose(err, xi[:50], atol=1e-9)

    p = tmp_path / "mc.g2o"
    p.write_text("\n".join(_g2o_edge_lines(2 * np.arange(N), 2 * np.arange(N) + 1, Z, info6, rng)) + "\n")
    g = read_edge_file(p, "g2o", duplicates="keep")
    assert g.information is not None and g.n_edges == N
    H = g.information[0]
    np.testing.assert_array_equal(g.information, np.broadcast_to(H, g.information.shape))

    # rotgraph's true edge rotation R_ij = R_j R_i^T with R = Q^T (cam_from_world)
    a, b = g.node_ids[g.edges[:, 0]], g.node_ids[g.edges[:, 1]]
    assert (a == 2 * np.arange(N)).all() and (b == a + 1).all()
    Ri, Rj = np.swapaxes(Ti[:, :3, :3], 1, 2), np.swapaxes(Tj[:, :3, :3], 1, 2)
    d = so3.log(g.cam2_from_cam1 @ np.swapaxes(Rj @ np.swapaxes(Ri, 1, 2), 1, 2))
    C = d.T @ d / N
    cov = np.linalg.inv(H)
    rel_err = np.linalg.norm(C - cov) / np.linalg.norm(cov)
    assert rel_err < 0.05, rel_err  # 0.003 at this seed (0.003-0.013 over 8 seeds)
    # the test has power: the rotation block alone, or no factor 4, or the other frame are far off
    naive = np.linalg.inv(info6[3:, 3:] / 4)
    assert np.linalg.norm(C - naive) / np.linalg.norm(naive) > 0.2
    assert np.linalg.norm(C - cov / 4) / np.linalg.norm(cov) > 0.5
    d_right = np.einsum("eba,eb->ea", Rj @ np.swapaxes(Ri, 1, 2), d)  # R_meas = R_true exp([d']x)
    assert np.linalg.norm(d_right.T @ d_right / N - cov) / np.linalg.norm(cov) > 0.2


def test_g2o_without_cross_terms_is_exactly_the_rotation_block_over_4(tmp_path):
    info = ["100", "0", "0", "0", "0", "0", "100", "0", "0", "0", "0", "4e+06",
            "0", "0", "0", "1e+06", "0.125", "-3.5", "2e+06", "7.25", "6.25"]
    info2 = ["1", "0.5", "0", "0", "0", "0", "2", "0", "0", "0", "0", "3",
             "0", "0", "0", "4000.5", "17", "-12.25", "3999", "3.5", "4001"]
    p = tmp_path / "g.g2o"
    p.write_text(
        "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n"
        f"EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 {' '.join(info)}\n"
        f"EDGE_SE3:QUAT 1 0 -1 0 0 0 0.1 0 0.99498743710662 {' '.join(info2)}\n"
    )
    g = read_edge_file(p, duplicates="keep")
    for k, entries in enumerate((info, info2)):
        full = np.zeros((6, 6))
        full[np.triu_indices(6)] = [float(x) for x in entries]
        full = full + np.triu(full, 1).T
        np.testing.assert_array_equal(g.information[k], full[3:, 3:] / 4)


def test_g2o_conversion_is_the_marginal_information_over_4():
    """S = inv(inv(I)[q, q]) for positive definite I, with and without cross terms, as
    (E, 21) rows or as 21 columns."""
    from rotgraph.io.g2o import rotation_information_from_g2o

    rng = np.random.default_rng(7)
    A = rng.standard_normal((50, 6, 6))
    info = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(6)
    info[25:, :3, 3:] = info[25:, 3:, :3] = 0  # half without cross terms
    r, c = np.triu_indices(6)
    upper = info[:, r, c]
    expect = np.linalg.inv(np.linalg.inv(info)[:, 3:, 3:]) / 4
    for given in (upper, list(upper.T)):
        H = rotation_information_from_g2o(given)
        np.testing.assert_allclose(H, expect, rtol=1e-9, atol=1e-12 * np.abs(expect).max())
        np.testing.assert_array_equal(H[25:], info[25:, 3:, 3:] / 4)


@pytest.mark.parametrize("info", [" ".join(["1"] * 21), " ".join(["1"] + ["0"] * 20)])
def test_g2o_placeholder_information_is_not_used(tmp_path, info):
    """Placeholders (all ones; translation only) give no positive definite H: the file
    reads as before (no information), the first such line recorded in meta."""
    p = tmp_path / "g.g2o"
    p.write_text(f"EDGE_SE3:QUAT 0 1 0 0 0 0 0 0 1 {info}\nEDGE_SE3:QUAT 1 2 0 0 0 0 0 0 1 {info}\n")
    g = read_edge_file(p)
    assert g.information is None
    assert g.meta["g2o_information_not_used"].startswith(f"{p}:1: ")
    r = run("info", p, "--json")
    assert r.exit_code == 0 and r.stderr == ""


DATA = Path(__file__).resolve().parents[2] / "shared" / "datasets"


@pytest.mark.skipif(not (DATA / "parking_garage" / "parking-garage.g2o").exists(), reason="shared datasets absent")
def test_public_pose_graphs():
    path = DATA / "parking_garage" / "parking-garage.g2o"
    g = read_edge_file(path, duplicates="keep")
    assert g.information.shape == (6275, 3, 3)
    # no cross terms in the file: the rotation block / 4, parsed here line by line
    edges = [line.split() for line in path.read_text().splitlines() if line.startswith("EDGE_SE3:QUAT")]
    full = np.zeros((len(edges), 6, 6))
    r, c = np.triu_indices(6)
    full[:, r, c] = [[float(x) for x in e[10:31]] for e in edges]
    assert (full[:, :3, 3:] == 0).all()
    full += np.swapaxes(np.triu(full, 1), 1, 2)
    np.testing.assert_array_equal(g.information, full[:, 3:, 3:] / 4)
    c = read_edge_file(DATA / "cubicle" / "cubicle.g2o", duplicates="keep")
    assert c.information is None and c.meta["g2o_information_not_used"].endswith("not positive definite")


# ------------------------------------------------------------------ malformed inputs, through the CLI

EDGE7 = "0 1 1 0 0 0 1"
EDGE12 = "0 1 1 0 0 0 1 0 0 1 0 1"
EDGE13 = "0 1 1 0 0 0 2 1 0 0 1 0 1"
V = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n"
G2O_INFO = "1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 4 0 0 4 0 4"

BAD = [
    # name, file name, text, line, message
    ("12 then 13 fields", "e.txt", f"# c\n{EDGE12}\n1 2 1 0 0 0 1 0 0 1 0 1\n{EDGE13.replace('0 1 ', '2 3 ', 1)}\n", 4,
     "expected 12 fields (i j qw qx qy qz h_xx"),
    ("13 then 7 fields", "e.txt", f"{EDGE13}\n1 2 1 0 0 0 1\n", 2, "expected 13 fields"),
    ("7 then 13 fields", "e.txt", f"{EDGE7}\n{EDGE13.replace('0 1 ', '1 2 ', 1)}\n", 2,
     "expected 6 or 7 fields (i j qw qx qy qz [weight], or 12 or 13 with h_xx"),
    ("10 fields", "e.txt", "0 1 1 0 0 0 1 0 0 1\n", 1, "expected 6 or 7 fields"),
    ("11 fields", "e.txt", f"{EDGE7}\n1 2 1 0 0 0 1 0 0 1 0\n", 2, "expected 6 or 7 fields"),
    ("not positive definite", "e.txt", f"{EDGE12}\n1 2 1 0 0 0 1 2 0 1 0 1\n", 2, "not positive definite"),
    ("negative diagonal", "e.txt", f"{EDGE13}\n1 2 1 0 0 0 1 -1 0 0 1 0 1\n", 2, "not positive definite"),
    ("not finite", "e.txt", f"{EDGE12}\n1 2 1 0 0 0 1 0 0 inf 0 1\n", 2, "h_yy is not finite"),
    ("not a number", "e.txt", f"{EDGE12}\n1 2 1 0 0 0 1 0 0 1 x 1\n", 2, "h_yz is not a number"),
    ("csv partial columns", "e.csv", "i,j,qw,qx,qy,qz,info_xx,info_yy,info_zz\n0,1,1,0,0,0,1,1,1\n", 1,
     "lacks column(s) info_xy, info_xz, info_yz"),
    ("csv partial columns after comments", "e.csv", "# edges\ni,j,qw,qx,qy,qz,info_xy\n0,1,1,0,0,0,1\n", 2,
     "info_xx, info_xz, info_yy, info_yz, info_zz"),
    ("csv not positive definite", "e.csv", f"i,j,qw,qx,qy,qz,{CSV_COLS}\n0,1,1,0,0,0,1,0,0,1,0,1\n1,2,1,0,0,0,1,0,0,-1,0,1\n",
     3, "not positive definite"),
    ("csv not finite", "e.csv", f"i,j,qw,qx,qy,qz,{CSV_COLS}\n0,1,1,0,0,0,1,0,0,1,0,nan\n", 2, "info_zz is not finite"),
    ("g2o information not finite", "g.g2o", V + "EDGE_SE3:QUAT 0 1 0 0 0 0 0 0 1 " + G2O_INFO.replace("4 0 0 4", "4 0 0 nan") + "\n",
     2, "information(4,4) is not finite"),
    ("g2o information not a number", "g.g2o", V + "EDGE_SE3:QUAT 0 1 0 0 0 0 0 0 1 " + G2O_INFO[:-1] + "x\n",
     2, "information(5,5) is not a number"),
]


@pytest.mark.parametrize("name, fname, text, line, message", BAD, ids=[b[0] for b in BAD])
def test_malformed_information_is_a_clean_error(tmp_path, name, fname, text, line, message):
    p = tmp_path / fname
    p.write_text(text)
    with pytest.raises(InputError) as exc:
        read_edge_file(p)
    assert exc.value.line == line and message in exc.value.message, str(exc.value)
    out = tmp_path / "out.csv"
    r = run("solve", p, "-o", out)
    assert_clean_error(r, p, line)
    assert message in r.stderr and not out.exists()


def test_valid_information_files_solve(tmp_path):
    g = random_graph(seed=5)
    write_edges(tmp_path / "e.txt", g)
    r = run("solve", tmp_path / "e.txt", "-o", tmp_path / "out.csv", "--json")
    assert r.exit_code == 0, r.output
    p = tmp_path / "g.g2o"
    p.write_text(V + "".join(f"EDGE_SE3:QUAT {a} {a + 1} 1 0 0 0 0 0 1 {G2O_INFO}\n" for a in range(4)))
    g = read_edge_file(p)
    np.testing.assert_array_equal(g.information, np.broadcast_to(np.eye(3), (4, 3, 3)))
    r = run("solve", p, "-o", tmp_path / "out2.csv")
    assert r.exit_code == 0, r.output


def test_writer_refuses_bad_information_before_writing(tmp_path):
    g = random_graph(seed=6)
    ids = g.node_ids[g.edges]
    p = tmp_path / "e.txt"
    H = g.information.copy()
    H[3, 0, 1] += 1.0  # not symmetric (the file formats cannot say it: they hold the upper triangle)
    with pytest.raises(ValueError, match="not symmetric"):
        write_edges(p, ids[:, 0], ids[:, 1], g.cam2_from_cam1, information=H)
    H = g.information.copy()
    H[5] *= -1
    with pytest.raises(ValueError, match="not positive definite"):
        write_edges(p, ids[:, 0], ids[:, 1], g.cam2_from_cam1, information=H)
    with pytest.raises(ValueError, match="information"):
        write_edges(p, ids[:, 0], ids[:, 1], g.cam2_from_cam1, information=H[:4])
    assert not p.exists()
