"""Edge tables of another layout (``--columns``, ``read_view_graph(columns=)``), and the
``-o`` extension rule (an unknown extension is a usage error, exit 2)."""

from __future__ import annotations

import gzip
import json
import os

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cli_helpers import assert_clean_error, run
from rotgraph.errors import InputError, OptionError
from rotgraph.io.edges import parse_columns
from rotgraph.pipeline.read import read_view_graph
from rotgraph.pipeline.solve import output_format_of


def rows(n=12, m=30, seed=3):
    """``(i, j, q (w, x, y, z), weight)`` of m random edges (lists of floats)."""
    rng = np.random.default_rng(seed)
    pairs = set()
    while len(pairs) < m:
        a, b = (int(x) for x in rng.choice(n, 2, replace=False))
        if (b, a) not in pairs:
            pairs.add((a, b))
    q = Rotation.random(m, random_state=seed).as_quat()[:, [3, 0, 1, 2]]
    w = rng.integers(20, 900, m).astype(float)
    return [(a, b, qq.tolist(), ww) for (a, b), qq, ww in zip(sorted(pairs), q, w.tolist())]


def fields(qq):
    return " ".join(repr(x) for x in qq)


@pytest.fixture
def files(tmp_path):
    """The same edges as a 7-column rotgraph file, an 8-column export (GLOMAP/COLMAP-like
    ``relative_rotations.txt``: inliers, then a configuration word) and CSVs of other layouts."""
    e = rows()
    out = {}
    out["seven"] = tmp_path / "edges.txt"
    out["seven"].write_text("".join(f"{a} {b} {fields(q)} {w!r}\n" for a, b, q, w in e))
    out["eight"] = tmp_path / "relative_rotations.txt"
    out["eight"].write_text("# image_id1 image_id2 qw qx qy qz num_inliers config\n"
                            + "".join(f"{a} {b} {fields(q)} {int(w)} CALIBRATED\n" for a, b, q, w in e))
    out["header"] = tmp_path / "with_header.txt"  # a first line of names, no '#'
    out["header"].write_text("IMAGE_ID1 IMAGE_ID2 QW QX QY QZ NUM_INLIERS CONFIG\n"
                             + "".join(f"{a} {b} {fields(q)} {int(w)} CALIBRATED\n" for a, b, q, w in e))
    out["csv"] = tmp_path / "pairs.csv"  # other names, other order
    out["csv"].write_text("config,image1,image2,w,x,y,z,inliers\n"
                          + "".join(f"OK,{a},{b},{fields(q).replace(' ', ',')},{int(w)}\n" for a, b, q, w in e))
    out["headerless"] = tmp_path / "pairs_noheader.csv"
    out["headerless"].write_text("".join(f"OK,{a},{b},{fields(q).replace(' ', ',')},{int(w)}\n" for a, b, q, w in e))
    return out


def same(a, b):
    assert np.array_equal(a.node_ids, b.node_ids) and np.array_equal(a.edges, b.edges)
    assert np.array_equal(a.cam2_from_cam1, b.cam2_from_cam1) and np.array_equal(a.weights, b.weights)


def test_parse_columns():
    assert parse_columns("i,j,qw,qx,qy,qz,weight,-") == ("i", "j", "qw", "qx", "qy", "qz", "weight", "-")
    assert parse_columns(" I, J ,QW,qx,qy,qz,tx,ty,tz") == ("i", "j", "qw", "qx", "qy", "qz", "tx", "ty", "tz")
    assert parse_columns(["i", "j", "qw", "qx", "qy", "qz"] + [f"info_{s}" for s in ("xx", "xy", "xz", "yy", "yz", "zz")])[-1] == "h_zz"
    for bad, msg in [("i,j,qw,qx,qy", "no qz"), ("i,j,qw,qx,qy,qz,w", "unknown column name 'w'"),
                     ("i,i,j,qw,qx,qy,qz", "named twice"), ("i,j,qw,qx,qy,qz,h_xx", "all six or none"),
                     ("i,j,qw,qx,qy,qz,,", "unknown column name ''")]:
        with pytest.raises(OptionError, match=msg):
            parse_columns(bad)


def test_eight_columns_read_as_the_seven_column_file(files):
    ref = read_view_graph(files["seven"])
    spec = "i,j,qw,qx,qy,qz,weight,-"
    for key in ("eight", "header"):
        g = read_view_graph(files[key], columns=spec)
        assert g.format == "rotgraph"
        same(g, ref)
    csv_spec = "-,i,j,qw,qx,qy,qz,weight"
    for key in ("csv", "headerless"):
        g = read_view_graph(files[key], columns=csv_spec)
        assert g.format == "csv"
        same(g, ref)
    six = read_view_graph(files["eight"], columns="i,j,qw,qx,qy,qz,-,-")  # without the weights: all 1
    assert np.array_equal(six.weights, np.ones(six.n_edges)) and np.array_equal(six.cam2_from_cam1, ref.cam2_from_cam1)


def test_columns_on_the_streamed_and_compressed_paths(files, tmp_path, monkeypatch):
    from rotgraph.io import edges

    ref = read_view_graph(files["seven"])
    z = tmp_path / "relative_rotations.txt.gz"
    z.write_bytes(gzip.compress(files["eight"].read_bytes()))
    same(read_view_graph(z, columns="i,j,qw,qx,qy,qz,weight,-"), ref)
    calls = []
    monkeypatch.setattr(edges, "read_table_file", lambda *a, **k: calls.append(1))  # the text parsers alone
    same(read_view_graph(files["eight"], columns="i,j,qw,qx,qy,qz,weight,-"), ref)
    same(read_view_graph(files["header"], columns="i,j,qw,qx,qy,qz,weight,-"), ref)
    same(read_view_graph(files["csv"], columns="-,i,j,qw,qx,qy,qz,weight"), ref)
    assert len(calls) == 3  # each read asked the (patched) streamed pass first


def test_information_columns_by_name(tmp_path):
    H = "2 0.1 0 3 0 4"
    p = tmp_path / "e.txt"
    p.write_text("0 1 1 0 0 0 9 9 9 " + H + "\n1 2 1 0 0 0 9 9 9 " + H + "\n")
    g = read_view_graph(p, columns="i,j,qw,qx,qy,qz,tx,ty,tz,h_xx,h_xy,h_xz,h_yy,h_yz,h_zz")
    assert g.information is not None and np.allclose(g.information[0], [[2, 0.1, 0], [0.1, 3, 0], [0, 0, 4]])


def test_wrong_field_count_errors_with_columns(files, tmp_path):
    p = tmp_path / "e.txt"
    p.write_text("0 1 1 0 0 0 5 x\n1 2 1 0 0 0 5\n")
    with pytest.raises(InputError) as exc:
        read_view_graph(p, columns="i,j,qw,qx,qy,qz,weight,-")
    assert exc.value.line == 2 and "expected 8 fields" in exc.value.message and "--columns" in exc.value.message
    bad = tmp_path / "bad.txt"
    bad.write_text("0 1 1 0 0 0 5 x\n1 2 1 zero 0 0 5 x\n")
    with pytest.raises(InputError) as exc:
        read_view_graph(bad, columns="i,j,qw,qx,qy,qz,weight,-")
    assert exc.value.line == 2 and "qx is not a number" in exc.value.message


def test_without_columns_the_message_names_the_layout_and_columns(files, tmp_path):
    r = run("solve", files["eight"], "-o", tmp_path / "o.csv")
    assert_clean_error(r, files["eight"], line=2)
    assert "i j qw qx qy qz [weight]" in r.stderr and "--columns i,j,qw,qx,qy,qz,-,-" in r.stderr
    r = run("info", files["headerless"])
    assert_clean_error(r, files["headerless"], line=1)
    assert "--columns" in r.stderr
    # a truncated line in the middle of a good file: no advice about columns
    cut = tmp_path / "cut.txt"
    cut.write_text(files["seven"].read_text() + "1 2 1 0\n")
    r = run("solve", cut, "-o", tmp_path / "o.csv")
    assert_clean_error(r, cut, line=31)
    assert "--columns" not in r.stderr


def test_cli_columns_solve_info_certify(files, tmp_path):
    ref = tmp_path / "ref.csv"
    assert run("solve", files["seven"], "-o", ref, "-q", "--use-weights").exit_code == 0
    out = tmp_path / "out.csv"
    r = run("solve", files["eight"], "-o", out, "-q", "--use-weights", "--columns", "i,j,qw,qx,qy,qz,weight,-")
    assert r.exit_code == 0, r.output
    assert out.read_bytes() == ref.read_bytes()
    r = run("info", files["csv"], "--columns", "-,i,j,qw,qx,qy,qz,weight", "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)["n_edges"] == 30
    r = run("solve", files["eight"], "-o", tmp_path / "c.csv", "-q", "--columns", "i,j,qw,qx,qy,qz,weight,-",
            "--edges-out", tmp_path / "e.csv", "--certify")
    assert r.exit_code in (0, 1), r.output
    r = run("certify", tmp_path / "c.csv", files["eight"], "--inliers", tmp_path / "e.csv", "--columns",
            "i,j,qw,qx,qy,qz,weight,-", "--json")
    assert r.exit_code in (0, 1) and "certified" in json.loads(r.stdout), r.output


def test_cli_columns_usage_errors(files, tmp_path):
    r = run("solve", files["eight"], "-o", tmp_path / "o.csv", "--columns", "i,j,qw,qx,qy")
    assert r.exit_code == 2 and "--columns" in r.stderr and "qz" in r.stderr
    g2o = tmp_path / "g.g2o"
    g2o.write_text("EDGE_SE3:QUAT 0 1 0 0 0 0 0 0 1 " + " ".join(["1"] * 21) + "\n")
    r = run("solve", g2o, "-o", tmp_path / "o.csv", "--columns", "i,j,qw,qx,qy,qz")
    assert r.exit_code == 2 and "g2o" in r.stderr, r.output
    r = run("solve", files["eight"], "-o", tmp_path / "o.csv", "--format", "glomap", "--columns", "i,j,qw,qx,qy,qz,-,-")
    assert r.exit_code == 2, r.output
    assert not (tmp_path / "o.csv").exists()


def test_batch_passes_columns_to_each_solve(files, tmp_path):
    """The batch task (pipeline.batch.solve_task, called here without Dask) reads with the columns."""
    from rotgraph.pipeline.batch import solve_task

    out = tmp_path / "o.csv"
    job = {"input": str(files["eight"]), "path": str(files["eight"]), "output": str(out), "output_path": str(out),
           "options": None, "overrides": {}, "method": "adaptive", "fmt": "auto", "duplicates": None, "gt": None,
           "eval": False, "columns": parse_columns("i,j,qw,qx,qy,qz,weight,-")}
    entry = solve_task(job)
    assert entry["status"] == "ok", entry
    assert entry["n_edges"] == 30
    job["columns"] = None
    assert solve_task(job)["status"] == "failed"


# --------------------------------------------------------------- -o: an unknown extension is a usage error


def test_output_format_of_extensions(tmp_path):
    assert output_format_of("r.csv") == "csv" and output_format_of("r.JSON") == "json" and output_format_of("r.txt") == "text"
    assert output_format_of("rotations") == "csv" and output_format_of("-") == "csv" and output_format_of("/dev/null") == "csv"
    assert output_format_of("out.d/rotations") == "csv" and output_format_of("model/") == "colmap"
    assert output_format_of("x.xyz", "json") == "json"  # named explicitly: wins
    with pytest.raises(OptionError, match="unknown output extension '.xyz'"):
        output_format_of("x.xyz")
    fifo = tmp_path / "pipe.xyz"
    os.mkfifo(fifo)
    assert output_format_of(fifo) == "csv"  # an existing FIFO is written through, whatever its name


def test_unknown_output_extension_exit_2_listing_formats(tmp_path):
    edges = tmp_path / "e.txt"
    edges.write_text("0 1 1 0 0 0\n1 2 1 0 0 0\n0 2 1 0 0 0\n")
    out = tmp_path / "x.xyz"
    r = run("solve", edges, "-o", out)
    assert r.exit_code == 2, r.output
    for known in (".csv", ".json", ".txt", "--output-format"):
        assert known in r.stderr
    assert not out.exists() and "Traceback" not in r.output
    r = run("solve", edges, "-o", out, "--output-format", "csv", "-q")
    assert r.exit_code == 0 and out.read_text().startswith("id,name,qw")
