"""File readers and writers of view graphs and absolute rotations (rotgraph.io, through rotgraph.read_view_graph).

Convention tests build random absolute rotations R_i (cam_from_world), write R_ij = R_j R_i^T
in each format's *own* convention (written out here by hand with numpy/scipy, not with
rotgraph's writers) and check that the reader returns R_j R_i^T. Real-data tests use the
shared benchmark sets (shared/datasets, see its README) and are skipped when absent.
"""

from __future__ import annotations

import logging
import os
import stat
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from scipy.spatial.transform import Rotation

from rotgraph import so3
from rotgraph.errors import InputError
from rotgraph.io import tables
from rotgraph.io.formats import detect_format
from rotgraph.io.rotations import read_absolute_rotations
from rotgraph.io.writers import write_absolute_rotations_text, write_edges, write_edges_csv, write_rotations
from rotgraph.pipeline.read import read_view_graph

DATA = Path(__file__).resolve().parents[2] / "shared" / "datasets"
D = np.diag([1.0, -1.0, -1.0])


def need(rel: str) -> Path:
    p = DATA / rel
    if not p.exists():
        pytest.skip(f"shared data set not available: {p}")
    return p


def T(R):
    return np.swapaxes(R, -1, -2)


def random_problem(rng, n=12, m=30):
    """Random R_i (n, 3, 3) and m distinct undirected pairs (i, j), i != j, random direction."""
    R = Rotation.random(n, random_state=rng).as_matrix()
    pairs = set()
    while len(pairs) < m:
        i, j = rng.choice(n, 2, replace=False)
        if (j, i) not in pairs:
            pairs.add((int(i), int(j)))
    ij = np.array(sorted(pairs))
    return R, ij[:, 0], ij[:, 1]


def wxyz(R):
    """scipy (x, y, z, w) -> (w, x, y, z), independent of rotgraph.so3."""
    q = Rotation.from_matrix(R).as_quat()
    return np.roll(q, 1, axis=-1)


def max_err(A, B) -> float:
    return float(np.abs(np.asarray(A) - np.asarray(B)).max())


def edges_by_pair(graph):
    """{(id_i, id_j): R_ij} of a graph, for order-independent comparisons."""
    ids = graph.node_ids.tolist()
    return {(ids[a], ids[b]): graph.cam2_from_cam1[k] for k, (a, b) in enumerate(graph.edges.tolist())}


def check_relative(graph, R, i, j, id_of=lambda k: k, tol=1e-12):
    got = edges_by_pair(graph)
    assert len(got) == len(i)
    for a, b in zip(i.tolist(), j.tolist()):
        assert max_err(got[(id_of(a), id_of(b))], R[b] @ R[a].T) < tol


def fmt_floats(values) -> str:
    return " ".join(repr(float(v)) for v in values)


# =========================================================================== round trips


def test_rotgraph_text_round_trip_int_ids_and_weights(tmp_path, rng):
    R, i, j = random_problem(rng)
    w = rng.uniform(0.5, 50, len(i))
    p = tmp_path / "edges.txt"
    write_edges(p, i, j, R[j] @ T(R[i]), w)
    assert p.read_text().splitlines()[0] == "# i j qw qx qy qz weight"
    g = read_view_graph(p)
    assert g.format == "rotgraph" and g.node_ids.dtype == np.int64
    check_relative(g, R, i, j)
    assert np.array_equal(g.weights, w)  # repr floats: exact
    assert np.array_equal(g.node_ids[g.edges], np.stack([i, j], 1))
    assert np.array_equal(g.source_lines, np.arange(2, len(i) + 2))


def test_rotgraph_text_convention_hand_written(tmp_path, rng):
    """Independent of rotgraph's writer (and of rotgraph.so3): quaternions from scipy."""
    R, i, j = random_problem(rng)
    q = wxyz(R[j] @ T(R[i]))
    q[::2] *= -1  # q and -q are the same rotation
    p = tmp_path / "hand.txt"
    p.write_text("".join(f"{a} {b} {fmt_floats(qq)}\n" for a, b, qq in zip(i, j, q)))
    check_relative(read_view_graph(p), R, i, j)


def test_rotgraph_text_round_trip_names_and_graph_object(tmp_path, rng):
    R, i, j = random_problem(rng)
    names = np.array([f"IMG_{k:03d}.jpg" for k in range(len(R))])
    p = tmp_path / "edges.txt"
    write_edges(p, names[i], names[j], R[j] @ T(R[i]))
    g = read_view_graph(p)
    assert g.node_ids.dtype.kind == "U"
    check_relative(g, R, i, j, id_of=lambda k: str(names[k]))
    assert np.all(g.weights == 1.0)
    p2 = tmp_path / "again.txt"
    write_edges(p2, g)  # a ViewGraph writes itself
    g2 = read_view_graph(p2)
    assert np.array_equal(g2.node_ids, g.node_ids)
    assert max_err(g2.cam2_from_cam1, g.cam2_from_cam1) < 1e-15


def test_csv_round_trip_any_column_order_and_extra_columns(tmp_path, rng):
    R, i, j = random_problem(rng)
    q = wxyz(R[j] @ T(R[i])).tolist()
    w = rng.uniform(1, 9, len(i))
    wl = w.tolist()
    rows = ["# a comment line", "note,weight,qz,qy,qx,qw,j,i"]
    rows += [f"x{k}, {wl[k]!r},{q[k][3]!r},{q[k][2]!r},{q[k][1]!r},{q[k][0]!r},{j[k]},{i[k]}" for k in range(len(i))]
    p = tmp_path / "edges.csv"
    p.write_text("\n".join(rows) + "\n")
    g = read_view_graph(p)
    assert g.format == "csv"
    check_relative(g, R, i, j)
    assert np.array_equal(np.sort(g.weights), np.sort(w))
    assert g.source_lines.min() == 3


def test_mixed_weight_columns_and_int_vs_name_ids(tmp_path):
    p = tmp_path / "mixed.txt"
    p.write_text("0 1 1 0 0 0\n1 2 1 0 0 0 5\n\n# c\n2 0 1 0 0 0 2.5\n")
    g = read_view_graph(p)
    assert g.node_ids.tolist() == [0, 1, 2] and g.weights.tolist() == [1.0, 5.0, 2.5]
    assert g.source_lines.tolist() == [1, 2, 5]
    p.write_text("0 1 1 0 0 0\n1 b 1 0 0 0\n")  # one name makes every id a string
    g = read_view_graph(p)
    assert g.node_ids.tolist() == ["0", "1", "b"]
    p.write_text("-1 1 1 0 0 0\n")  # not a non-negative integer: a name
    assert read_view_graph(p).node_ids.tolist() == ["-1", "1"]


def test_huge_integer_ids(tmp_path):
    p = tmp_path / "huge.txt"
    p.write_text(f"{10**18} 3 1 0 0 0\n")
    g = read_view_graph(p)
    assert g.node_ids.tolist() == [3, 10**18] and g.node_ids.dtype == np.int64
    p.write_text(f"{10**20} 3 1 0 0 0\n")
    with pytest.raises(InputError, match="too large") as exc:
        read_view_graph(p)
    assert f"{p}:1:" in str(exc.value)


def test_glomap_parsing(tmp_path, rng):
    R, i, j = random_problem(rng)
    names = np.array([f"cam{k}/img {k}.png".replace(" ", "_") for k in range(len(R))])
    q = wxyz(R[j] @ T(R[i]))
    t = rng.standard_normal((len(i), 3))
    # GLOMAP's WriteRelPose: single spaces and a trailing space
    lines = [f"{names[a]} {names[b]} {fmt_floats(q[k])} {fmt_floats(t[k])} " for k, (a, b) in enumerate(zip(i, j))]
    p = tmp_path / "relpose.txt"
    p.write_text("\n".join(lines) + "\n")
    assert detect_format(p) == "glomap"
    g = read_view_graph(p)
    assert g.format == "glomap"
    check_relative(g, R, i, j, id_of=lambda k: str(names[k]))
    assert np.array_equal(g.names, g.node_ids)
    # numeric-looking image names stay names in this format
    p.write_text("1 2 1 0 0 0 0 0 0\n")
    g = read_view_graph(p, fmt="glomap")
    assert g.node_ids.tolist() == ["1", "2"]


def test_duplicates_policies_on_text(tmp_path):
    p = tmp_path / "dup.txt"
    q = wxyz(Rotation.from_rotvec([0, 0, 0.1]).as_matrix())
    p.write_text(f"0 1 {fmt_floats(q)} 2\n1 2 1 0 0 0\n1 0 {fmt_floats(q * [1, -1, -1, -1])} 3\n")
    with pytest.raises(InputError, match="duplicate pair") as exc:
        read_view_graph(p)
    assert f"{p}:3:" in str(exc.value)
    assert read_view_graph(p, duplicates="keep").n_edges == 3
    g = read_view_graph(p, duplicates="merge")
    assert g.n_edges == 2 and sorted(g.weights.tolist()) == [1.0, 5.0]


def test_non_unit_quaternions_are_normalised_with_one_warning(tmp_path, caplog):
    p = tmp_path / "scaled.txt"
    p.write_text("0 1 2 0 0 0\n1 2 0 0 0 3\n2 3 1 0 0 0\n3 4 1.0000001 0 0 0\n")
    with caplog.at_level(logging.WARNING, logger="rotgraph"):
        g = read_view_graph(p)
    msgs = [r.getMessage() for r in caplog.records if "unit length" in r.getMessage()]
    assert len(msgs) == 1 and "2 of 4" in msgs[0]
    assert max_err(g.cam2_from_cam1[0], np.eye(3)) < 1e-15
    assert max_err(g.cam2_from_cam1[1], Rotation.from_rotvec([0, 0, np.pi]).as_matrix()) < 1e-15


# =========================================================================== writers


def test_write_rotations_round_trip(tmp_path, rng):
    R = Rotation.random(7, random_state=rng).as_matrix()
    ids = np.array([3, 5, 8, 13, 21, 34, 55])
    extra = {"degree": np.arange(7), "err_deg": rng.random(7), "inlier": np.arange(7) % 2 == 0}
    p = tmp_path / "out.csv"
    write_rotations(p, ids, None, R, extra_columns=extra)
    lines = p.read_text().splitlines()
    assert lines[0] == "id,name,qw,qx,qy,qz,degree,err_deg,inlier"
    first = lines[1].split(",")
    assert first[0] == first[1] == "3" and first[8] == "1"
    q_file = np.array([[float(x) for x in ln.split(",")[2:6]] for ln in lines[1:]])
    assert (q_file[:, 0] >= 0).all()
    assert np.array_equal(q_file, so3.quaternions_from_matrices(R))  # full precision
    assert np.array_equal(np.array([float(ln.split(",")[7]) for ln in lines[1:]]), extra["err_deg"])
    got_ids, got_names, got_R = read_absolute_rotations(p)
    assert got_ids.tolist() == ids.tolist() and got_names.tolist() == [str(x) for x in ids]
    assert max_err(got_R, R) < 1e-15


def test_write_rotations_quotes_awkward_names(tmp_path, rng):
    R = Rotation.random(3, random_state=rng).as_matrix()
    names = np.array(["a,b.jpg", 'say "hi".jpg', "#hash.jpg"])
    p = tmp_path / "out.csv"
    write_rotations(p, np.array([0, 1, 2]), names, R)
    ids, got_names, got_R = read_absolute_rotations(p)
    assert got_names.tolist() == names.tolist() and ids.tolist() == [0, 1, 2]
    assert max_err(got_R, R) < 1e-15


def test_write_edges_csv(tmp_path):
    p = tmp_path / "edges_out.csv"
    write_edges_csv(p, np.array([0, 1]), np.array([1, 2]), np.array([0.25, 12.5]), np.array([True, False]))
    assert p.read_text() == "i,j,residual_deg,inlier\n0,1,0.25,1\n1,2,12.5,0\n"


def test_write_absolute_rotations_text_round_trip(tmp_path, rng):
    R = Rotation.random(5, random_state=rng).as_matrix()
    p = tmp_path / "gt.txt"
    write_absolute_rotations_text(p, np.arange(5), R)
    ids, names, got = read_absolute_rotations(p)
    assert ids.tolist() == list(range(5)) and names is None
    assert max_err(got, R) < 1e-15


def test_writers_reject_ids_that_do_not_survive_a_text_file(tmp_path):
    I = np.eye(3)[None].repeat(1, 0)
    for bad in ("a b", "#x", ""):
        with pytest.raises(ValueError):
            write_edges(tmp_path / "e.txt", np.array([bad]), np.array(["c"]), I)
    assert not (tmp_path / "e.txt").exists()


def test_outputs_get_normal_permissions(tmp_path):
    # atomic_write's mkstemp creates 0600 files; outputs must look like open(path, "w") ones
    p = tmp_path / "gt.txt"
    write_absolute_rotations_text(p, np.arange(1), np.eye(3)[None])
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~umask


# =========================================================================== conventions (synthetic)


def test_g2o_convention(tmp_path, rng):
    R, i, j = random_problem(rng)
    Q = T(R)  # world_from_body
    info = " ".join(["1"] * 21)
    lines = ["# a comment", "PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1", "FIX 0"]
    for k in range(len(R)):
        q = Rotation.from_matrix(Q[k]).as_quat()  # (x, y, z, w), as g2o writes
        lines.append(f"VERTEX_SE3:QUAT {k} {fmt_floats(rng.standard_normal(3))} {fmt_floats(q)}")
    for a, b in zip(i, j):
        q = Rotation.from_matrix(Q[a].T @ Q[b]).as_quat()  # the edge T_a^-1 T_b
        lines.append(f"EDGE_SE3:QUAT {a} {b} {fmt_floats(rng.standard_normal(3))} {fmt_floats(q)} {info}")
    p = tmp_path / "graph.g2o"
    p.write_text("\n".join(lines) + "\n")
    g = read_view_graph(p)
    assert g.format == "g2o" and g.gt_cam_from_world is None  # vertices: an initial guess, never ground truth
    check_relative(g, R, i, j)
    assert max_err(g.initial_cam_from_world, R) < 1e-12
    assert np.array_equal(g.source_lines, np.arange(len(R) + 4, len(R) + 4 + len(i)))
    # the same content without the .g2o extension is found by its tags
    q = tmp_path / "graph.txt"
    q.write_text(p.read_text())
    assert detect_format(q) == "g2o"


def write_1dsfm_scene(folder: Path, R, i, j, unregistered=()):
    """A 1DSfM scene in its own conventions: Bundler frame, EG R = R_i R_j^T."""
    folder.mkdir()
    Rb = D @ R  # Bundler world -> camera (camera looks down -z, y up)
    with open(folder / "EGs.txt", "w") as fh:
        for a, b in zip(i, j):
            fh.write(f"{a} {b} {fmt_floats((Rb[a] @ Rb[b].T).ravel())} 0.1 0.2 0.3\n")
    (folder / "list.txt").write_text("".join(f"images/img{k}.jpg 0 1000\n" for k in range(len(R))))
    with open(folder / "gt_bundle.out", "w") as fh:
        fh.write(f"# Bundle file v0.3\n{len(R)} 0\n")
        for k in range(len(R)):
            rows = np.zeros((3, 3)) if k in unregistered else Rb[k]
            fh.write("1000 0 0\n" + "".join(fmt_floats(r) + "\n" for r in rows) + "0 0 0\n")
    (folder / "cc.txt").write_text("".join(f"{k}\n" for k in range(len(R))))


def test_1dsfm_convention(tmp_path, rng):
    R, i, j = random_problem(rng)
    scene = tmp_path / "scene"
    write_1dsfm_scene(scene, R, i, j, unregistered=(2,))
    for path in (scene, scene / "EGs.txt"):
        assert detect_format(path) == "1dsfm"
        g = read_view_graph(path)
        check_relative(g, R, i, j)
        assert g.names.tolist() == [f"images/img{k}.jpg" for k in g.node_ids.tolist()]
        gt = g.gt_cam_from_world
        has = np.isfinite(gt).all(axis=(1, 2))
        assert g.node_ids[~has].tolist() == ([2] if 2 in g.node_ids else [])
        assert max_err(gt[has], R[g.node_ids[has]]) < 1e-12
    ids, names, got = read_absolute_rotations(scene / "gt_bundle.out")
    assert 2 not in ids.tolist() and max_err(got, R[ids]) < 1e-12


@pytest.mark.parametrize("layout", ["matlab_uint8", "rows_int32", "float_stacked"])
def test_mat_convention(tmp_path, rng, layout):
    R, i, j = random_problem(rng, n=10, m=25)
    RR = R[j] @ T(R[i])  # Chatterjee-Govindu: RR(:,:,k) = Rgt_j Rgt_i^T for I(:,k) = (i, j)
    Rgt = R.copy()
    Rgt[4] = 0  # no ground truth for camera 4
    I = np.stack([i, j]) + 1
    if layout == "matlab_uint8":
        data = {"RR": np.moveaxis(RR, 0, 2), "I": I.astype(np.uint8), "Rgt": np.moveaxis(Rgt, 0, 2)}
    elif layout == "rows_int32":
        data = {"RR": np.moveaxis(RR, 0, 2), "I": I.T.astype(np.int32), "Rgt": np.moveaxis(Rgt, 0, 2)}
    else:
        data = {"RR": RR, "I": I.astype(np.float64), "Rgt": Rgt}
    p = tmp_path / "scene.mat"
    scipy.io.savemat(p, data)
    g = read_view_graph(p)
    assert g.format == "mat" and g.node_ids.tolist() == list(range(10))
    check_relative(g, R, i, j)
    has = np.isfinite(g.gt_cam_from_world).all(axis=(1, 2))
    assert np.flatnonzero(~has).tolist() == [4]
    assert max_err(g.gt_cam_from_world[has], R[has]) < 1e-12


def test_mat_ids_cover_rgt_cameras_without_edges(tmp_path, rng):
    R = Rotation.random(6, random_state=rng).as_matrix()
    data = {"RR": np.moveaxis((R[1] @ R[0].T)[None], 0, 2), "I": np.array([[1], [2]], np.uint8), "Rgt": np.moveaxis(R, 0, 2)}
    p = tmp_path / "one.mat"
    scipy.io.savemat(p, data)
    g = read_view_graph(p)
    assert g.n_nodes == 6 and g.n_edges == 1
    ids, _, got = read_absolute_rotations(p)
    assert ids.tolist() == list(range(6)) and max_err(got, R) < 1e-12


def test_clean_numeric_files_take_the_fast_path(tmp_path, rng, monkeypatch):
    """The line-by-line parsers run only to locate errors (speed on 10^6-line files)."""
    def boom(*a, **k):
        raise AssertionError("slow path used")

    monkeypatch.setattr(tables, "_slow_table", boom)  # every text reader's (g2o's too) line-by-line parser
    R, i, j = random_problem(rng, n=40, m=300)
    write_edges(tmp_path / "a.txt", i, j, R[j] @ T(R[i]), np.arange(1, 301))
    names = np.array([f"n{k}" for k in range(40)])
    write_edges(tmp_path / "b.txt", names[i], names[j], R[j] @ T(R[i]))
    for f in ("a.txt", "b.txt"):
        check_relative(read_view_graph(tmp_path / f), R, i, j, id_of=(lambda k: k) if f == "a.txt" else (lambda k: str(names[k])))
    write_1dsfm_scene(tmp_path / "s", R, i, j)
    check_relative(read_view_graph(tmp_path / "s"), R, i, j)
    test_g2o_convention(tmp_path, rng)


# =========================================================================== real data


def test_ellis_island_mat():
    g = read_view_graph(need("ellis_island/Ellis.mat"))
    assert (g.n_nodes, g.n_edges) == (247, 20297)
    gt = g.gt_cam_from_world
    has = np.isfinite(gt).all(axis=(1, 2))
    assert has.sum() == 227
    both = has[g.edges[:, 0]] & has[g.edges[:, 1]]
    Ri, Rj = gt[g.edges[both, 0]], gt[g.edges[both, 1]]
    err = np.degrees(so3.angle_between(g.cam2_from_cam1[both], Rj @ T(Ri)))
    assert both.sum() == 20010
    assert abs(np.median(err) - 2.894) < 0.01
    # the other reading is far worse: the direction is not a coin flip
    assert np.median(np.degrees(so3.angle_between(g.cam2_from_cam1[both], Ri @ T(Rj)))) > 30
    ids, names, R = read_absolute_rotations(DATA / "ellis_island/Ellis.mat")
    assert len(ids) == 227 and names is None and np.isfinite(R).all()


def test_madrid_metropolis_1dsfm():
    folder = need("madrid_metropolis")
    g = read_view_graph(folder)
    assert (g.n_nodes, g.n_edges) == (394, 23784)
    assert g.node_ids.min() == 0 and g.node_ids.max() == 1339
    cc = np.loadtxt(folder / "cc.txt", dtype=np.int64)
    assert np.array_equal(np.sort(cc), g.node_ids)
    assert g.names[0].startswith("images/") and g.names[0].endswith(".jpg")
    assert g.gt_cam_from_world is None  # no gt_bundle.out in the shared copy
    with pytest.raises(InputError, match="no absolute rotations"):
        read_absolute_rotations(folder)


def test_parking_garage_g2o():
    g = read_view_graph(need("parking_garage/parking-garage.g2o"))
    assert (g.n_nodes, g.n_edges) == (1661, 6275)
    assert g.gt_cam_from_world is None
    gt = g.initial_cam_from_world  # vertex initial guesses (odometry, not ground truth)
    a, b = g.node_ids[g.edges[:, 0]], g.node_ids[g.edges[:, 1]]
    odo = b == a + 1
    assert odo.sum() == 1660
    Ri, Rj = gt[g.edges[odo, 0]], gt[g.edges[odo, 1]]
    err = np.degrees(so3.angle_between(g.cam2_from_cam1[odo], Rj @ T(Ri)))
    # The vertices are the odometry composed: agreement up to the file's 6-digit rounding
    # (max 1.7e-4 degrees; 1e-6 degrees is below what the file's precision can give).
    assert err.max() < 1e-3
    transposed = np.degrees(so3.angle_between(T(g.cam2_from_cam1[odo]), Rj @ T(Ri)))
    assert np.median(transposed) > 1.0


def test_cubicle_parallel_edges():
    path = need("cubicle/cubicle.g2o")
    assert read_view_graph(path, duplicates="keep").n_edges == 16869
    merged = read_view_graph(path, duplicates="merge")
    assert merged.n_edges == 12486 and merged.n_nodes == 5750
    with pytest.raises(InputError, match="duplicate pair") as exc:
        read_view_graph(path)
    assert str(path) in str(exc.value) and exc.value.line is not None


def test_lund_door_reference_rotations():
    txt = need("lund_door/gt_rotations.txt")
    ids_t, names_t, R_t = read_absolute_rotations(txt)
    ids_c, names_c, R_c = read_absolute_rotations(DATA / "lund_door/gt_rotations.csv")
    assert len(R_t) == len(R_c) == 12
    assert ids_t.tolist() == list(range(1, 13))
    assert names_t.tolist() == names_c.tolist() == ids_c.tolist() == [f"DSC_{k:04d}.JPG" for k in range(1, 13)]
    assert np.array_equal(R_t, R_c)


# =========================================================================== bad input

MAT_WRONG = "mat-wrong-variables"
EDGE = "0 1 1 0 0 0\n"
G2O_V = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n"
G2O_E = "EDGE_SE3:QUAT 0 1 0 0 0 0 0 0 1 " + " ".join(["1"] * 21) + "\n"

# name, file name, content (bytes or str), fmt, expected line (None: no line), message part
BAD = [
    ("empty", "e.txt", b"", "auto", None, "no edges"),
    ("comments only", "e.txt", "# nothing\n\n", "auto", None, "no edges"),
    ("csv header only", "e.csv", "i,j,qw,qx,qy,qz\n", "auto", 1, "no edges"),
    ("csv without header", "e.csv", "0,1,1,0,0,0\n", "auto", 1, "header lacks"),
    ("csv short row", "e.csv", "i,j,qw,qx,qy,qz\n0,1,1,0,0,0\n1,2,1,0,0\n", "auto", 3, "expected 6 fields"),
    ("truncated line", "e.txt", EDGE + "1 2 1 0\n", "auto", 2, "expected 6 or 7 fields"),
    ("non-numeric", "e.txt", EDGE + "1 2 1 0 x 0\n", "auto", 2, "qy is not a number"),
    ("nan", "e.txt", EDGE + "1 2 1 0 nan 0\n", "auto", 2, "not finite"),
    ("inf", "e.txt", EDGE + "1 2 1 0 0 inf\n", "auto", 2, "not finite"),
    ("zero quaternion", "e.txt", EDGE + "1 2 0 0 0 0\n", "auto", 2, "zero quaternion"),
    ("duplicate pair", "e.txt", EDGE + "1 2 1 0 0 0\n1 0 1 0 0 0\n", "auto", 3, "duplicate pair"),
    ("self-loop", "e.txt", EDGE + "2 2 1 0 0 0\n", "auto", 2, "self-loop"),
    ("negative weight", "e.txt", EDGE + "1 2 1 0 0 0 -3\n", "auto", 2, "weight"),
    ("trailing comment", "e.txt", "0 1 1 0 0 0 # no\n", "auto", 1, "expected 6 or 7 fields"),
    ("binary garbage", "e.txt", bytes(range(256)) * 8, "auto", 1, "binary"),
    ("latin-1", "e.txt", "0 1 1 0 0 0\ncaf\xe9 2 1 0 0 0\n".encode("latin-1"), "auto", 2, "UTF-8"),
    ("missing file", "nope.txt", None, "auto", None, "no such file"),
    ("missing file, explicit format", "nope.txt", None, "rotgraph", None, "no such file"),
    ("mat garbage", "x.mat", b"this is not a MATLAB file at all", "auto", None, "MATLAB"),
    ("mat wrong variables", "x.mat", MAT_WRONG, "auto", None, "'RR' missing"),
    ("g2o unknown tag", "g.g2o", G2O_V + "EDGE_SE3:EULER 0 1 0 0 0 0 0 0\n", "auto", 3, "unknown g2o tag"),
    ("g2o EDGE_SE2", "g.g2o", "VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", "auto", 1, "2D pose graphs"),
    ("g2o short edge", "g.g2o", G2O_V + "EDGE_SE3:QUAT 0 1 0 0 0 0 0 0 1\n", "auto", 3, "expected 31 fields"),
    ("g2o bad quaternion", "g.g2o", G2O_V + G2O_E.replace(" 0 0 0 1 1", " 0 0 x 1 1", 1), "auto", 3, "qz is not a number"),
    ("g2o vertices only", "g.g2o", G2O_V, "auto", None, "no edges"),
    ("g2o duplicate vertex", "g.g2o", G2O_V + G2O_V + G2O_E, "auto", 3, "defined twice"),
    ("huge id", "e.txt", f"{10**20} 1 1 0 0 0\n", "auto", 1, "too large"),
    ("1dsfm not a rotation", "EGs.txt", "0 1 1 0 0 0 1 0 0 0 2 0 0 0\n", "auto", 1, "not a rotation"),
    ("glomap short", "r.txt", "a b 1 0 0 0 0 0 0\nb c 1 0 0 0 0 0\n", "glomap", 2, "expected 9 fields"),
]


@pytest.mark.parametrize("case", BAD, ids=[c[0] for c in BAD])
def test_bad_input_raises_input_error_with_file_and_line(tmp_path, case):
    _, name, content, fmt, line, message = case
    p = tmp_path / name
    if content == MAT_WRONG:
        scipy.io.savemat(p, {"A": np.eye(3), "I": np.ones((2, 1))})
    elif isinstance(content, bytes):
        p.write_bytes(content)
    elif content is not None:
        p.write_text(content)
    with pytest.raises(InputError) as exc:
        read_view_graph(p, fmt=fmt)
    text = str(exc.value)
    assert str(p) in text
    assert message in text
    if line is None:
        assert exc.value.line is None
    else:
        assert f"{p}:{line}:" in text


def test_mat_bad_indices(tmp_path):
    p = tmp_path / "x.mat"
    scipy.io.savemat(p, {"RR": np.eye(3)[:, :, None], "I": np.array([[0], [1]], np.uint8)})
    with pytest.raises(InputError, match="1-based") as exc:
        read_view_graph(p)
    assert str(p) in str(exc.value)


def test_colmap_projects_are_detected_and_a_corrupt_database_is_a_clean_error(tmp_path):
    (tmp_path / "proj").mkdir()
    (tmp_path / "proj" / "database.db").write_bytes(b"SQLite format 3\x00" + bytes(100))
    for p in (tmp_path / "proj", tmp_path / "proj" / "database.db"):
        assert detect_format(p) == "colmap"
        with pytest.raises(InputError, match="corrupt or unreadable"):
            read_view_graph(p)
    with pytest.raises(InputError, match="no input"):
        read_view_graph(tmp_path)


@pytest.mark.parametrize(
    "name, content, expected",
    [
        ("a.txt", "# c\n0 1 1 0 0 0\n", "rotgraph"),
        ("a.txt", "0,1,1,0,0,0\n", "csv"),
        ("a.csv", "i j\n", "csv"),
        ("a.txt", "x.jpg y.jpg 1 0 0 0 1 2 3\n", "glomap"),
        ("a.txt", "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n", "g2o"),
        ("a.txt", "0 1 1 0 0 0 1 0 0 0 1 0 0 0\n", "1dsfm"),
        ("EGs.txt", "", "1dsfm"),
        ("a.mat", "", "mat"),
        ("a.db", "", "colmap"),
        # the binary encoding of the rotgraph format, by extension or magic (whatever the bytes look like)
        ("a.npz", "x,y\n", "rotgraph"),
        ("a.parquet", "x.jpg y.jpg 1 0 0 0 1 2 3\n", "rotgraph"),
        ("a.pq", "", "rotgraph"),
        ("a.bin", "PK\x03\x04,1 0 0 0\n", "rotgraph"),
        ("a.txt", "PAR1 x.jpg 1 0 0 0 1 2 3\n", "rotgraph"),
    ],
)
def test_detect_format(tmp_path, name, content, expected):
    p = tmp_path / name
    p.write_text(content)
    assert detect_format(p) == expected


def test_absolute_rotations_bad_input(tmp_path):
    p = tmp_path / "gt.txt"
    p.write_text("1 1 0 0 0\n2 1 0 0 0\n1 1 0 0 0\n")
    with pytest.raises(InputError, match="appears twice") as exc:
        read_absolute_rotations(p)
    assert f"{p}:3:" in str(exc.value)
    p.write_text("1 a 1 0 0 0 9\n")
    with pytest.raises(InputError, match="expected 5 fields") as exc:
        read_absolute_rotations(p)
    assert f"{p}:1:" in str(exc.value)
    q = tmp_path / "gt.csv"
    q.write_text("qw,qx,qy,qz\n1,0,0,0\n")
    with pytest.raises(InputError, match="'id' or a 'name'"):
        read_absolute_rotations(q)
