"""A folder of Parquet parts as an edge input (#32): Dask's ``part.0.parquet ...``, Spark's and
Arrow's (hive-style ``key=value/`` sub-folders, ``_metadata``, ``_SUCCESS``, ``.crc``) read
as the one Parquet file they were cut from: the same cameras, edges (in the natural order of
the parts' names), rotations, weights, information and ids, and the same solution. The bad
cases (errors naming the part) are rows of tests/test_badinput.py."""

from __future__ import annotations

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
import pyarrow.parquet as pq  # noqa: E402

from cli_helpers import run  # noqa: E402
from rotgraph.errors import InputError  # noqa: E402
from rotgraph.io.formats import PARQUET_PARTS, binary_edge_format, detect_format  # noqa: E402
from rotgraph.io.parts import parquet_parts  # noqa: E402
from rotgraph.io.writers import write_edges_npz  # noqa: E402
from rotgraph.pipeline.inputs import expand_inputs  # noqa: E402
from rotgraph.pipeline.read import read_view_graph  # noqa: E402
from rotgraph.synth import random_problem  # noqa: E402

#: Part names in their natural order (part.2 before part.10: not the order of the strings).
FLAT = ["part.0.parquet", "part.2.parquet", "part.10.parquet", "part.11.parquet"]
HIVE = ["x=1/part-0.parquet", "x=1/part-1.parquet", "x=2/part-0.parquet", "x=10/part-0.parquet"]
BOOKKEEPING = ["_SUCCESS", "_metadata", "_common_metadata", ".part.0.parquet.crc", "x=1/.part-0.parquet.crc",
               "_temporary/0/part.0.parquet", ".hidden/part.0.parquet", "sub/part.0.parquet"]


def _columns(tmp_path, strings: bool) -> dict:
    """The binary edge columns of a synthetic problem with weights and information."""
    g = random_problem(n=60, degree=8, sigma_deg=2.0, outliers=0.1, seed=3, uncertainty_spread=3.0)
    g.weights = np.random.default_rng(1).uniform(0.5, 2.0, g.n_edges)
    write_edges_npz(tmp_path / "e.npz", g)
    with np.load(tmp_path / "e.npz") as z:
        cols = {c: z[c] for c in z.files}
    if strings:
        cols["i"], cols["j"] = (np.array([f"im{k}.jpg" for k in cols[c]]) for c in ("i", "j"))
    assert "h_xx" in cols and "weight" in cols
    return cols


def _write_parts(folder, cols: dict, names: list, empty: int | None = None) -> None:
    """``cols`` cut into ``names`` in order (the part ``empty`` with no rows), plus the
    bookkeeping files a writer leaves, which are no parts."""
    m = len(cols["i"])
    cuts = np.linspace(0, m, len(names) - (empty is not None) + 1).astype(int).tolist()
    if empty is not None:
        cuts.insert(empty, cuts[empty])
    for name, a, b in zip(names, cuts[:-1], cuts[1:]):
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.table({c: v[a:b] for c, v in cols.items()}), folder / name)
    for name in BOOKKEEPING:
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(b"not a part")


@pytest.mark.parametrize("strings", [False, True], ids=["integer ids", "string ids"])
@pytest.mark.parametrize("names,empty", [(["part.0.parquet"], None), (FLAT, None), (HIVE, 1)],
                         ids=["1 part", "4 parts", "4 hive parts, one empty"])
def test_parts_read_as_the_single_file(tmp_path, names, empty, strings):
    cols = _columns(tmp_path, strings)
    pq.write_table(pa.table(cols), tmp_path / "e.parquet")
    _write_parts(tmp_path / "ds", cols, names, empty)
    ref, g = read_view_graph(tmp_path / "e.parquet"), read_view_graph(tmp_path / "ds")
    assert g.format == ref.format == "rotgraph"
    assert g.node_ids.dtype == ref.node_ids.dtype
    np.testing.assert_array_equal(g.node_ids, ref.node_ids)
    np.testing.assert_array_equal(g.edges, ref.edges)
    np.testing.assert_array_equal(g.cam2_from_cam1, ref.cam2_from_cam1)
    np.testing.assert_array_equal(g.weights, ref.weights)
    np.testing.assert_array_equal(g.information, ref.information)
    np.testing.assert_array_equal(g.source_lines, ref.source_lines)


def test_solve_on_the_parts_is_solve_on_the_single_file(tmp_path):
    cols = _columns(tmp_path, strings=False)
    pq.write_table(pa.table(cols), tmp_path / "e.parquet")
    _write_parts(tmp_path / "ds", cols, HIVE, empty=1)
    for name in ("e.parquet", "ds"):
        r = run("solve", tmp_path / name, "-o", tmp_path / f"{name}.csv", "--edges-out", tmp_path / f"{name}-edges.csv", "-q")
        assert r.exit_code == 0, r.output
    assert (tmp_path / "ds.csv").read_bytes() == (tmp_path / "e.parquet.csv").read_bytes()
    assert (tmp_path / "ds-edges.csv").read_bytes() == (tmp_path / "e.parquet-edges.csv").read_bytes()


def test_the_parts_and_their_order(tmp_path):
    _write_parts(tmp_path, {"i": np.arange(8), "j": np.arange(1, 9)}, HIVE + ["y=0/z=3/part.9.pq", "y=0/z=3/000000_0"])
    assert [p.relative_to(tmp_path).as_posix() for p in parquet_parts(tmp_path)] == \
        ["x=1/part-0.parquet", "x=1/part-1.parquet", "x=2/part-0.parquet", "x=10/part-0.parquet",
         "y=0/z=3/000000_0", "y=0/z=3/part.9.pq"]
    assert binary_edge_format(tmp_path) == PARQUET_PARTS and detect_format(tmp_path) == "rotgraph"
    assert parquet_parts(tmp_path / "x=1/part-0.parquet") == [] and parquet_parts(tmp_path / "missing") == []


def test_folders_that_are_not_parquet_parts_keep_their_meaning(tmp_path):
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "edges.txt").write_text("0 1 1 0 0 0\n")
    (tmp_path / "other" / "_part.parquet").write_bytes(b"")  # _-prefixed: no part
    assert parquet_parts(tmp_path / "other") == [] and binary_edge_format(tmp_path / "other") is None
    with pytest.raises(InputError, match="folder holds no input"):
        detect_format(tmp_path / "other")
    scene = tmp_path / "scene"  # a 1DSfM scene with a Parquet file in it is a 1DSfM scene
    scene.mkdir()
    (scene / "EGs.txt").write_text("0 1 1 0 0 0 1 0 0 0 1 0 0 0\n")
    pq.write_table(pa.table({"i": [0]}), scene / "extra.parquet")
    assert detect_format(scene) == "1dsfm" and binary_edge_format(scene) is None


def test_integer_and_string_parts_read_as_text_ids(tmp_path):
    """Parts storing ids as integers and as strings: all read as strings are (digits -> int64)."""
    cols = _columns(tmp_path, strings=False)
    pq.write_table(pa.table(cols), tmp_path / "e.parquet")
    m = len(cols["i"]) // 2
    (tmp_path / "ds").mkdir()
    pq.write_table(pa.table({c: v[:m] for c, v in cols.items()}), tmp_path / "ds" / "part.0.parquet")
    pq.write_table(pa.table({c: (v[m:].astype(str) if c in ("i", "j") else v[m:]) for c, v in cols.items()}),
                   tmp_path / "ds" / "part.1.parquet")
    ref, g = read_view_graph(tmp_path / "e.parquet"), read_view_graph(tmp_path / "ds")
    assert g.node_ids.dtype.kind == "i"
    np.testing.assert_array_equal(g.node_ids, ref.node_ids)
    np.testing.assert_array_equal(g.edges, ref.edges)


def test_a_batch_takes_a_folder_of_parts_as_one_problem(tmp_path):
    cols = _columns(tmp_path, strings=False)
    _write_parts(tmp_path / "data" / "big", cols, FLAT)
    (tmp_path / "data" / "small.txt").write_text("0 1 1 0 0 0\n1 2 1 0 0 0\n")
    problems = expand_inputs([tmp_path / "data"])
    assert sorted(p.path.name for p in problems) == ["big", "small.txt"]
    assert [p.path.name for p in expand_inputs([tmp_path / "data" / "big"])] == ["big"]
