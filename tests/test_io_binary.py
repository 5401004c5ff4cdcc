"""Large edge lists (#19): the streamed pyarrow pass over ``rotgraph`` text reads exactly what
the text parsers read (or gives way to them), and the binary edge format (.npz, Parquet)
round-trips every edge, weight and information matrix."""

from __future__ import annotations

import numpy as np
import pytest

from cli_helpers import run
from rotgraph import so3
from rotgraph.errors import InputError
from rotgraph.io import edges as edges_mod
from rotgraph.io import table_lines, table_stream
from rotgraph.io.edges import read_edge_file
from rotgraph.io.writers import write_edges, write_edges_npz, write_edges_text_blocks
from rotgraph.pipeline.read import read_view_graph
from rotgraph.synth import random_problem


def _same_edges(a, b):
    """The same cameras, edges and relative rotations, bit for bit."""
    np.testing.assert_array_equal(a.node_ids, b.node_ids)
    np.testing.assert_array_equal(a.edges, b.edges)
    np.testing.assert_array_equal(a.cam2_from_cam1, b.cam2_from_cam1)


def _same_graph(a, b):
    _same_edges(a, b)
    np.testing.assert_array_equal(a.weights, b.weights)
    np.testing.assert_array_equal(a.source_lines, b.source_lines)
    assert (a.information is None) == (b.information is None)
    if a.information is not None:
        np.testing.assert_array_equal(a.information, b.information)


def _text_reader(path, duplicates="error", fmt="rotgraph"):
    """The reader without the streamed pass: the text parsers of rotgraph.io.tables."""
    saved = edges_mod._read_rotgraph_fast, edges_mod._read_csv_fast
    edges_mod._read_rotgraph_fast = edges_mod._read_csv_fast = lambda p: None
    try:
        return read_edge_file(path, fmt, duplicates)
    finally:
        edges_mod._read_rotgraph_fast, edges_mod._read_csv_fast = saved


def _outcome(reader, path, duplicates="error"):
    try:
        return reader(path, duplicates)
    except InputError as exc:
        return str(exc)


def _lines(seed=0, n=6):
    g = random_problem(n=n, degree=4, sigma_deg=2.0, outliers=0.0, seed=seed)
    q = so3.quaternions_from_matrices(g.cam2_from_cam1)
    return [f"{i} {j} " + " ".join(repr(x) for x in qk) for (i, j), qk in zip(g.edges.tolist(), q.tolist())]


VARIANTS = {
    "plain": lambda L: "\n".join(L) + "\n",
    "header": lambda L: "# i j qw qx qy qz\n" + "\n".join(L) + "\n",
    "weights": lambda L: "\n".join(f"{x} {k + 1}.5" for k, x in enumerate(L)) + "\n",
    "no final newline": lambda L: "\n".join(L),
    "comments between": lambda L: "\n".join(x if k % 3 else "  # note\n" + x for k, x in enumerate(L)) + "\n",
    "blank lines": lambda L: "\n\n".join(L) + "\n\n",
    "crlf": lambda L: "\r\n".join(L) + "\r\n",
    "crlf blank": lambda L: "\r\n\r\n".join(L) + "\r\n",
    "tabs": lambda L: "\n".join(x.replace(" ", "\t", 1) for x in L) + "\n",
    "double spaces": lambda L: "\n".join(x.replace(" ", "  ", 1) for x in L) + "\n",
    "leading space": lambda L: "\n".join(" " + x for x in L) + "\n",
    "trailing space": lambda L: "\n".join(x + " " for x in L) + "\n",
    "space lines": lambda L: "\n   \n".join(L) + "\n",
    "names": lambda L: "\n".join("c" + x.replace(" ", " c", 1) for x in L) + "\n",
    "names after digits": lambda L: "\n".join(x if k == 0 else "c" + x for k, x in enumerate(L)) + "\n",
    "hash in names": lambda L: "\n".join("a#" + x.replace(" ", " b#", 1) for x in L) + "\n",
    "leading zeros": lambda L: "\n".join("00" + x for x in L) + "\n",
    "negative id": lambda L: "\n".join(("-" + x) if k == 2 else x for k, x in enumerate(L)) + "\n",
    "plus id": lambda L: "\n".join(("+" + x) if k == 2 else x for k, x in enumerate(L)) + "\n",
    "nan": lambda L: "\n".join(x + (" nan" if k == 3 else " 1") for k, x in enumerate(L)) + "\n",
    "inf weight": lambda L: "\n".join(x + (" inf" if k == 3 else " 1") for k, x in enumerate(L)) + "\n",
    "zero weight": lambda L: "\n".join(x + (" 0" if k == 3 else " 1") for k, x in enumerate(L)) + "\n",
    "mixed 6 and 7": lambda L: "\n".join(x + (" 2" if k % 2 else "") for k, x in enumerate(L)) + "\n",
    "bad number": lambda L: "\n".join(x.replace(" ", " 1x", 1) if k == 4 else x for k, x in enumerate(L)) + "\n",
    "huge id": lambda L: "\n".join(("99999999999999999999" + x) if k == 1 else x for k, x in enumerate(L)) + "\n",
    "self loop": lambda L: "\n".join(L + ["3 3 1 0 0 0"]) + "\n",
    "duplicate": lambda L: "\n".join(L + [L[0]]) + "\n",
    "reversed duplicate": lambda L: "\n".join(L + [" ".join([L[0].split()[1], L[0].split()[0]] + L[0].split()[2:])]) + "\n",
    "zero quaternion": lambda L: "\n".join(L + ["0 5 0 0 0 0"]) + "\n",
    "non-unit quaternion": lambda L: "\n".join(L + ["0 5 2 0 0 0"]) + "\n",
    "information": lambda L: "\n".join(x + " 1 2 0 0 5 0 0 7"[:0] + " 1 400 0 0 400 0 400" for x in L) + "\n",
    "bad information": lambda L: "\n".join(x + " 1 -400 0 0 400 0 400" for x in L) + "\n",
    "non-ascii name": lambda L: "\n".join("é" + x.replace(" ", " é", 1) for x in L) + "\n",
    "vertical tab": lambda L: "\n".join(L[:2]) + "\x0b" + "\n".join(L[2:]) + "\n",
    "only comments": lambda L: "# nothing\n#\n",
    "empty": lambda L: "",
}


@pytest.mark.parametrize("block", [None, 40, 97])
@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_streamed_pass_reads_what_the_text_parsers_read(tmp_path, name, block, monkeypatch):
    if block:
        monkeypatch.setattr(table_stream, "STREAM_BLOCK", block)  # many blocks, lines cut anywhere
    p = tmp_path / "edges.txt"
    p.write_bytes(VARIANTS[name](_lines()).encode("utf-8"))
    for duplicates in ("error", "merge"):
        new = _outcome(lambda q, d: read_edge_file(q, "auto", d), p, duplicates)
        old = _outcome(_text_reader, p, duplicates)
        if isinstance(old, str) or isinstance(new, str):
            assert new == old
        else:
            _same_graph(new, old)


def _csv(L, header="i,j,qw,qx,qy,qz", extra=lambda k: ""):
    return header + "\n" + "".join(x.replace(" ", ",") + extra(k) + "\n" for k, x in enumerate(L))


CSV_VARIANTS = {
    "plain": lambda L: _csv(L),
    "weights": lambda L: _csv(L, "i,j,qw,qx,qy,qz,weight", lambda k: f",{k + 1}"),
    "reordered, extra column": lambda L: "note,j,i,qw,qx,qy,qz\n" + "".join(
        f"n{k}," + ",".join([x.split()[1], x.split()[0]] + x.split()[2:]) + "\n" for k, x in enumerate(L)),
    "comment and blank lines first": lambda L: "# made by hand\n\n" + _csv(L),
    "comments between": lambda L: _csv(L).replace("\n", "\n# c\n", 3),
    "information": lambda L: _csv(L, "i,j,qw,qx,qy,qz,info_xx,info_xy,info_xz,info_yy,info_yz,info_zz",
                                  lambda k: ",400,0,0,400,0,400"),
    "partial information": lambda L: _csv(L, "i,j,qw,qx,qy,qz,info_xx", lambda k: ",400"),
    "padded": lambda L: _csv(L).replace(",", ", ", 3),
    "quoted": lambda L: _csv(L).replace("\n0,", '\n"0",'),
    "names": lambda L: "i,j,qw,qx,qy,qz\n" + "".join("a" + x.replace(" ", ",a", 1).replace(" ", ",") + "\n" for x in L),
    "nan": lambda L: _csv(L, "i,j,qw,qx,qy,qz,weight", lambda k: ",nan" if k == 2 else ",1"),
    "empty field": lambda L: _csv(L, "i,j,qw,qx,qy,qz,weight", lambda k: "," if k == 2 else ",1"),
    "short row": lambda L: _csv(L) + "1,2,1,0,0\n",
    "header only": lambda L: "i,j,qw,qx,qy,qz\n",
    "missing column": lambda L: _csv(L, "i,j,qw,qx,qy,qq"),
    "duplicate": lambda L: _csv(L + [L[0]]),
    "crlf": lambda L: _csv(L).replace("\n", "\r\n"),
    "quoted header": lambda L: _csv(L, '"i","j","qw","qx","qy","qz","a,b"', lambda k: ",x"),
}


@pytest.mark.parametrize("block", [None, 50])
@pytest.mark.parametrize("name", sorted(CSV_VARIANTS))
def test_streamed_csv_reads_what_the_text_parsers_read(tmp_path, name, block, monkeypatch):
    if block:
        monkeypatch.setattr(table_stream, "STREAM_BLOCK", block)
    p = tmp_path / "edges.csv"
    p.write_bytes(CSV_VARIANTS[name](_lines()).encode("utf-8"))
    new = _outcome(lambda q, d: read_edge_file(q, "auto", d), p)
    old = _outcome(lambda q, d: _text_reader(q, d, "csv"), p)
    if isinstance(old, str) or isinstance(new, str):
        assert new == old
    else:
        _same_graph(new, old)


def test_streamed_pass_is_taken_on_clean_files(tmp_path):
    g = random_problem(n=300, degree=10, sigma_deg=2.0, outliers=0.1, seed=2)
    p = tmp_path / "e.txt"
    write_edges(p, g)
    assert edges_mod._read_rotgraph_fast(p) is not None
    _same_graph(read_edge_file(p), _text_reader(p))
    p.write_text(p.read_text().replace(" ", "\t"))  # tabs: the text parsers' job
    assert edges_mod._read_rotgraph_fast(p) is None
    for name in ("plain", "weights", "reordered, extra column", "comment and blank lines first", "information", "crlf",
                 "quoted header"):
        c = tmp_path / "e.csv"
        c.write_text(CSV_VARIANTS[name](_lines()), newline="")
        assert edges_mod._read_csv_fast(c) is not None, name


@pytest.mark.parametrize("kwargs", [dict(), dict(uncertainty_spread=2.0), dict(noise_mix=(0.5, 5.0))])
def test_block_writer_reads_back_as_write_edges(tmp_path, kwargs, monkeypatch):
    import rotgraph.io.writers as writers

    monkeypatch.setattr(writers, "EDGE_BLOCK", 37)
    g = random_problem(n=200, degree=8, sigma_deg=2.0, outliers=0.2, seed=3, **kwargs)
    write_edges(tmp_path / "a.txt", g)
    write_edges_text_blocks(tmp_path / "b.txt", g)
    _same_graph(read_edge_file(tmp_path / "a.txt"), read_edge_file(tmp_path / "b.txt"))


@pytest.mark.parametrize("kwargs", [dict(), dict(uncertainty_spread=2.0)])
def test_npz_round_trip(tmp_path, kwargs):
    g = random_problem(n=200, degree=8, sigma_deg=2.0, outliers=0.2, seed=4, **kwargs)
    write_edges(tmp_path / "e.txt", g)
    write_edges_npz(tmp_path / "e.npz", g)
    a, b = read_view_graph(tmp_path / "e.txt"), read_view_graph(tmp_path / "e.npz")
    assert b.format == "rotgraph"
    _same_edges(a, b)
    np.testing.assert_array_equal(a.weights, b.weights)
    if a.information is not None:
        np.testing.assert_array_equal(a.information, b.information)
    # detected by the zip magic too, whatever the extension
    (tmp_path / "e.bin").write_bytes((tmp_path / "e.npz").read_bytes())
    np.testing.assert_array_equal(read_view_graph(tmp_path / "e.bin").edges, b.edges)


def test_npz_and_parquet_with_names_and_without_weights(tmp_path):
    pa = pytest.importorskip("pyarrow")
    import pyarrow.parquet as pq

    R = so3.random_rotations(4, 0)
    pairs = [(0, 1), (1, 2), (2, 3), (3, 0)]
    q = so3.quaternions_from_matrices(np.stack([R[j] @ R[i].T for i, j in pairs]))
    cols = {"i": np.array([f"im{i}" for i, _ in pairs]), "j": np.array([f"im{j}" for _, j in pairs]),
            "qw": q[:, 0], "qx": q[:, 1], "qy": q[:, 2], "qz": q[:, 3]}
    np.savez(tmp_path / "n.npz", **cols)
    pq.write_table(pa.table(cols), tmp_path / "n.parquet")
    text = "".join(f"im{i} im{j} " + " ".join(repr(x) for x in qk) + "\n" for (i, j), qk in zip(pairs, q.tolist()))
    (tmp_path / "n.txt").write_text(text)
    ref = read_view_graph(tmp_path / "n.txt")
    for name in ("n.npz", "n.parquet"):
        g = read_view_graph(tmp_path / name)
        _same_edges(g, ref)
        np.testing.assert_array_equal(g.weights, 1.0)


@pytest.mark.parametrize("seed", range(40))
def test_comment_and_data_line_numbers(seed):
    """The one scan of comment lines and the one count of data lines (behind np.loadtxt's
    pass and the streamed blocks) agree with the line-by-line definitions: a comment line's
    first non-blank character is '#', a blank line is white space only."""
    rng = np.random.default_rng(seed)
    pool = [b"1 2 3", b"4 5 6", b"", b"   ", b"\r", b"# c", b"  # c", b"\t#c#", b"a#b 1", b"x #"]
    first = int(rng.integers(1, 5))
    text = b"\n".join(pool[k] for k in rng.integers(0, len(pool) if seed % 2 else 7, int(rng.integers(0, 30))))
    text += b"\n" if seed % 3 else b""
    split = text.split(b"\n")[: text.count(b"\n") + (1 if text and not text.endswith(b"\n") else 0)]
    comment = [first + k for k, x in enumerate(split) if x.lstrip().startswith(b"#")]
    data = [first + k for k, x in enumerate(split) if x.strip() and not x.lstrip().startswith(b"#")]
    mid_hash = any(b"#" in x and not x.lstrip().startswith(b"#") for x in split)
    if first == 1:
        assert table_lines.comment_line_numbers(text) == (None if mid_hash else comment)
    stripped, removed = table_stream._strip_comments(text, first)
    assert removed == comment
    parts = text.split(b"\n")
    pieces = [x + b"\n" for x in parts[:-1]] + [parts[-1]]  # each line with its break
    assert stripped == b"".join(x for k, x in enumerate(pieces) if first + k not in comment)
    got = table_lines.data_line_numbers(text, comment, len(data), first)
    assert got is not None and got.tolist() == data
    if len(data) + 1 != len(split) - len(comment):  # (that count: rows of every non-comment line)
        assert table_lines.data_line_numbers(text, comment, len(data) + 1, first) is None


@pytest.mark.parametrize("ids", [
    ["7", "012", "3", "40", "5"],  # digits only: integer ids (012 is 12) in text and binary alike
    ["7", "012", "a3", "40", "5"],  # a name among them: every id a string
    ["7", "-12", "3", "-40", "0"],  # a negative number is a name (CLI.md), also as int64 in a binary file
])
def test_text_and_binary_read_the_same_ids_as_the_same_nodes(tmp_path, ids):
    """One edge list as rotgraph text, .npz and Parquet (ids stored as strings) reads to
    equal graphs: ids are resolved by one function (table_columns.resolve_ids), digit-only string
    ids become int64 in every one."""
    integers = all(x.isdigit() for x in ids)
    as_int = all((x[1:] if x.startswith("-") else x).isdigit() for x in ids)  # storable as int64
    R = so3.random_rotations(len(ids), 3)
    pairs = [(0, 1), (1, 2), (2, 3), (3, 4), (4, 0), (0, 2)]
    q = so3.quaternions_from_matrices(np.stack([R[j] @ R[i].T for i, j in pairs]))
    cols = {"i": np.array([ids[i] for i, _ in pairs]), "j": np.array([ids[j] for _, j in pairs]),
            "qw": q[:, 0], "qx": q[:, 1], "qy": q[:, 2], "qz": q[:, 3], "weight": np.arange(1.0, 7.0)}
    text = "".join(f"{ids[i]} {ids[j]} " + " ".join(repr(x) for x in qk) + f" {w!r}\n"
                   for (i, j), qk, w in zip(pairs, q.tolist(), cols["weight"].tolist()))
    (tmp_path / "e.txt").write_text(text)
    np.savez(tmp_path / "e.npz", **cols)
    ref = read_view_graph(tmp_path / "e.txt")
    assert ref.node_ids.dtype.kind == ("i" if integers else "U")
    readers = [read_view_graph, _text_reader]
    names = ["e.txt", "e.npz"]
    if as_int:
        np.savez(tmp_path / "int.npz", **{**cols, "i": cols["i"].astype(np.int64), "j": cols["j"].astype(np.int64)})
        names.append("int.npz")
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq

        pq.write_table(pa.table(cols), tmp_path / "e.parquet")
        names.append("e.parquet")
    except ImportError:
        pass
    for name in names:
        for read in readers[: 2 if name.endswith(".txt") else 1]:
            g = read(tmp_path / name)
            assert g.node_ids.dtype == ref.node_ids.dtype, name
            _same_edges(g, ref)
            np.testing.assert_array_equal(g.weights, ref.weights)


def test_binary_ids_errors_name_the_edge(tmp_path):
    """Empty and too large ids in a binary file: resolve_ids' errors, located by the edge."""
    cols = {"i": np.array(["1", "2", ""]), "j": np.array(["2", "3", "1"]),
            "qw": np.ones(3), "qx": np.zeros(3), "qy": np.zeros(3), "qz": np.zeros(3)}
    np.savez(tmp_path / "e.npz", **cols)
    with pytest.raises(InputError, match=r"e\.npz: edge 2 \(0-based\): empty i"):
        read_view_graph(tmp_path / "e.npz")
    cols["i"] = np.array(["1", "2", "9" * 20])
    np.savez(tmp_path / "e.npz", **cols)
    with pytest.raises(InputError, match=r"edge 2 \(0-based\): i 9+ is too large"):
        read_view_graph(tmp_path / "e.npz")


@pytest.mark.parametrize("change,message", [
    (lambda c: c.pop("qz"), "lacks array(s) qz"),
    (lambda c: c.update(qw=c["qw"][:-1]), "has shape"),
    (lambda c: c.update(qw=np.where(np.arange(len(c["qw"])) == 2, np.nan, c["qw"])), "edge 2 (0-based): quaternion is not finite"),
    (lambda c: c.update(h_xx=np.ones(len(c["i"]))), "not all six"),
    (lambda c: c.update(j=c["i"]), "self-loop"),
    (lambda c: c.update(i=np.zeros(0, np.int64), j=np.zeros(0, np.int64), qw=np.zeros(0), qx=np.zeros(0),
                        qy=np.zeros(0), qz=np.zeros(0), weight=np.zeros(0)), "no edges"),
])
def test_npz_errors_name_the_file_and_edge(tmp_path, change, message):
    g = random_problem(n=20, degree=4, sigma_deg=1.0, outliers=0.0, seed=5)
    write_edges_npz(tmp_path / "e.npz", g)
    with np.load(tmp_path / "e.npz") as z:
        cols = {k: z[k] for k in z.files}
    change(cols)
    np.savez(tmp_path / "e.npz", **cols)
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")) as exc:
        read_view_graph(tmp_path / "e.npz")
    assert "e.npz" in str(exc.value)
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(InputError, match="cannot read the binary edge file"):
        read_view_graph(tmp_path / "bad.npz")


def test_cli_synth_edges_format(tmp_path):
    r = run("synth", "-o", tmp_path, "--n", 60, "--degree", 8, "--seed", 2, "--edges-format", "both")
    assert r.exit_code == 0, r.output
    a, b = read_view_graph(tmp_path / "edges.txt"), read_view_graph(tmp_path / "edges.npz")
    np.testing.assert_array_equal(a.edges, b.edges)
    np.testing.assert_array_equal(a.cam2_from_cam1, b.cam2_from_cam1)
    g = random_problem(n=60, degree=8, sigma_deg=2.0, outliers=0.0, seed=2)
    np.testing.assert_array_equal(b.node_ids[b.edges], g.node_ids[g.edges])
    r = run("synth", "-o", tmp_path / "bin", "--n", 30, "--edges-format", "npz")
    assert r.exit_code == 0 and (tmp_path / "bin" / "edges.npz").exists() and not (tmp_path / "bin" / "edges.txt").exists()
    r = run("solve", tmp_path / "bin" / "edges.npz", "-o", tmp_path / "r.csv")
    assert r.exit_code == 0, r.output
    r = run("eval", tmp_path / "r.csv", tmp_path / "bin" / "gt.txt")
    assert r.exit_code == 0, r.output


def test_writers_with_names(tmp_path):
    g = random_problem(n=30, degree=6, sigma_deg=1.0, outliers=0.0, seed=6)
    names = np.array([f"img_{k:03d}.jpg" for k in range(g.n_nodes)])
    ids_i, ids_j = names[g.edges[:, 0]], names[g.edges[:, 1]]
    write_edges(tmp_path / "a.txt", ids_i, ids_j, g.cam2_from_cam1)
    write_edges_text_blocks(tmp_path / "b.txt", ids_i, ids_j, g.cam2_from_cam1)
    write_edges_npz(tmp_path / "c.npz", ids_i, ids_j, g.cam2_from_cam1)
    a = read_edge_file(tmp_path / "a.txt")
    for other in ("b.txt", "c.npz"):
        _same_edges(a, read_edge_file(tmp_path / other))
    with pytest.raises(ValueError, match="white space"):
        write_edges_text_blocks(tmp_path / "d.txt", np.array(["a b"] * len(ids_j)), ids_j, g.cam2_from_cam1)
    assert not (tmp_path / "d.txt").exists()
