"""Compressed inputs (gzip, bzip2, xz; rotgraph.io.compressed): read as the text they hold,
told by their magic bytes, detected through the compression, with clean errors; and the
read progress of large files."""

from __future__ import annotations

import bz2
import gzip
import lzma
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from scipy.spatial.transform import Rotation

from cli_helpers import assert_clean_error, run
from rotgraph.errors import InputError
from rotgraph.io import compressed, table_stream, tables
from rotgraph.io.compressed import compression_of, reading_progress, uncompressed_name
from rotgraph.io.formats import detect_format, detect_rotation_format
from rotgraph.io.rotations import read_absolute_rotations
from rotgraph.io.writers import write_absolute_rotations_text, write_edges, write_edges_npz
from rotgraph.pipeline.read import read_view_graph

COMPRESS = {"gz": gzip.compress, "bz2": bz2.compress, "xz": lzma.compress}


def problem(n=15, m=40, seed=0):
    rng = np.random.default_rng(seed)
    R = Rotation.random(n, random_state=seed).as_matrix()
    pairs = set()
    while len(pairs) < m:
        a, b = (int(x) for x in rng.choice(n, 2, replace=False))
        if (b, a) not in pairs:
            pairs.add((a, b))
    ij = np.array(sorted(pairs))
    i, j = ij[:, 0], ij[:, 1]
    return R, i, j, R[j] @ np.swapaxes(R[i], 1, 2), rng.uniform(1, 10, m)


def squeeze(path: Path, kind: str, name: str | None = None) -> Path:
    """A compressed copy of ``path`` (named ``name``, else ``path.kind``)."""
    out = path.parent / (name or f"{path.name}.{kind}")
    out.write_bytes(COMPRESS[kind](path.read_bytes()))
    return out


def same_graph(a, b):
    assert a.format == b.format
    assert np.array_equal(a.node_ids, b.node_ids) and np.array_equal(a.edges, b.edges)
    assert np.array_equal(a.cam2_from_cam1, b.cam2_from_cam1) and np.array_equal(a.weights, b.weights)
    assert np.array_equal(a.source_lines, b.source_lines)


@pytest.fixture
def edges(tmp_path):
    R, i, j, Rij, w = problem()
    p = tmp_path / "edges.txt"
    write_edges(p, i, j, Rij, w)
    return p


def test_magic_bytes_and_names():
    assert compression_of(gzip.compress(b"x")) == "gzip"
    assert compression_of(bz2.compress(b"x")) == "bzip2" and compression_of(bz2.compress(b"")) == "bzip2"
    assert compression_of(lzma.compress(b"x")) == "xz"
    assert compression_of(b"BZh9 is a name\n") is None and compression_of(b"0 1 1 0 0 0\n") is None
    assert uncompressed_name("a/edges.txt.gz") == "edges.txt" and uncompressed_name("x.CSV.XZ") == "x.CSV"
    assert uncompressed_name("g.g2o.bz2") == "g.g2o" and uncompressed_name("plain.txt") == "plain.txt"


@pytest.mark.parametrize("kind", ["gz", "bz2", "xz"])
def test_each_compression_reads_as_the_text(edges, kind):
    z = squeeze(edges, kind)
    assert detect_format(z) == "rotgraph"
    same_graph(read_view_graph(z), read_view_graph(edges))


@pytest.mark.parametrize("kind", ["gz", "bz2", "xz"])
def test_told_by_magic_not_by_name(edges, kind, tmp_path):
    hidden = squeeze(edges, kind, name=f"edges_{kind}.txt")  # compressed, named as plain text
    same_graph(read_view_graph(hidden), read_view_graph(edges))
    plain = tmp_path / f"plain.txt.{kind}"  # plain text, named as compressed
    plain.write_bytes(edges.read_bytes())
    same_graph(read_view_graph(plain), read_view_graph(edges))


def test_solve_output_identical(edges, tmp_path):
    ref = tmp_path / "ref.csv"
    assert run("solve", edges, "-o", ref, "-q").exit_code == 0
    for kind in COMPRESS:
        out = tmp_path / f"out_{kind}.csv"
        r = run("solve", squeeze(edges, kind), "-o", out, "-q")
        assert r.exit_code == 0, r.output
        assert out.read_bytes() == ref.read_bytes()


# --------------------------------------------------------------- detection through compression


def test_detection_of_every_text_format_through_compression(tmp_path):
    R, i, j, Rij, w = problem()
    q = Rotation.from_matrix(Rij).as_quat()[:, [3, 0, 1, 2]]
    i, j, w = i.tolist(), j.tolist(), w.tolist()

    def f(xs, sep=" "):
        return sep.join(repr(float(x)) for x in xs)

    info = "1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1"  # g2o's 6x6 information, upper triangle
    files = {
        "e.csv": "i,j,qw,qx,qy,qz,weight\n" + "".join(f"{a},{b},{f(qq, ',')},{ww!r}\n" for a, b, qq, ww in zip(i, j, q, w)),
        "table": "i,j,qw,qx,qy,qz\n" + "".join(f"{a},{b},{f(qq, ',')}\n" for a, b, qq in zip(i, j, q)),
        "rel.txt": "".join(f"im{a}.jpg im{b}.jpg {f(qq)} 0 0 1\n" for a, b, qq in zip(i, j, q)),
        "EGs.txt": "".join(f"{a} {b} {f(Rij[k].T.ravel())} 0 0 1\n" for k, (a, b) in enumerate(zip(i, j))),
        "g.g2o": "".join(f"EDGE_SE3:QUAT {a} {b} 0 0 0 {f(qq[[1, 2, 3, 0]])} {info}\n" for a, b, qq in zip(i, j, q)),
    }
    expect = {"e.csv": "csv", "table": "csv", "rel.txt": "glomap", "EGs.txt": "1dsfm", "g.g2o": "g2o"}
    for name, text in files.items():
        plain = tmp_path / name
        plain.write_text(text)
        assert detect_format(plain) == expect[name], name
        for kind in COMPRESS:
            z = squeeze(plain, kind)
            assert detect_format(z) == expect[name], z
            same_graph(read_view_graph(z, duplicates=None), read_view_graph(plain, duplicates=None))
    # by the name inside: an edge file named .g2o whose first line says nothing, .csv likewise
    g2o_named = tmp_path / "odd.g2o"
    g2o_named.write_text("# a pose graph\n" + files["g.g2o"])
    assert detect_format(squeeze(g2o_named, "gz")) == "g2o"


def test_binary_and_mat_inputs_compressed(tmp_path):
    R, i, j, Rij, w = problem()
    npz = tmp_path / "e.npz"
    write_edges_npz(npz, i, j, Rij, w)
    z = squeeze(npz, "gz")
    assert detect_format(z) == "rotgraph"
    same_graph(read_view_graph(z), read_view_graph(npz))
    mat = tmp_path / "m.mat"
    RR = np.moveaxis(Rij, 0, -1)  # Chatterjee-Govindu: RR(:,:,k) = R_j R_i^T, I 1-based
    scipy.io.savemat(mat, {"RR": RR, "I": np.stack([i + 1, j + 1]).astype(float), "Rgt": np.moveaxis(R, 0, -1)})
    zm = squeeze(mat, "xz")
    assert detect_format(zm) == "mat"
    a, b = read_view_graph(zm), read_view_graph(mat)
    assert np.array_equal(a.cam2_from_cam1, b.cam2_from_cam1) and np.array_equal(a.gt_cam_from_world, b.gt_cam_from_world)


def test_rotation_files_compressed(tmp_path, edges):
    R, *_ = problem()
    gt = tmp_path / "gt.txt"
    write_absolute_rotations_text(gt, np.arange(len(R)), R)
    z = squeeze(gt, "bz2")
    assert detect_rotation_format(z) == "text"
    a, b = read_absolute_rotations(z), read_absolute_rotations(gt)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[2], b[2])
    est = tmp_path / "est.csv"
    assert run("solve", edges, "-o", est, "-q").exit_code == 0
    r = run("eval", squeeze(est, "gz"), z, "--json")
    assert r.exit_code == 0, r.output


# --------------------------------------------------------------- errors


def test_truncated_gz_is_a_clean_error_naming_the_file(edges, tmp_path):
    data = gzip.compress(edges.read_bytes())
    bad = tmp_path / "cut.txt.gz"
    bad.write_bytes(data[: len(data) // 2])
    r = run("solve", bad, "-o", tmp_path / "o.csv")
    assert_clean_error(r, bad)
    assert "corrupt or truncated gzip" in r.stderr
    assert not (tmp_path / "o.csv").exists()
    with pytest.raises(InputError, match="corrupt or truncated gzip"):
        read_view_graph(bad)


@pytest.mark.parametrize("kind", ["bz2", "xz"])
def test_corrupt_bz2_xz_are_clean_errors(edges, tmp_path, kind):
    data = bytearray(COMPRESS[kind](edges.read_bytes()))
    data[len(data) // 2] ^= 0xFF  # one bad byte inside the stream
    bad = tmp_path / f"bad.txt.{kind}"
    bad.write_bytes(bytes(data))
    r = run("info", bad)
    assert_clean_error(r, bad)
    with pytest.raises(InputError) as exc:
        read_view_graph(bad)
    assert exc.value.path == str(bad)


@pytest.mark.parametrize("kind", ["gz", "xz"])
def test_bad_line_inside_compressed_names_the_line(edges, tmp_path, kind):
    lines = edges.read_text().splitlines()
    lines[4] = "3 7 1 0 nan 0"
    broken = tmp_path / "broken.txt"
    broken.write_text("\n".join(lines) + "\n")
    z = squeeze(broken, kind)
    r = run("solve", z, "-o", tmp_path / "o.csv")
    assert_clean_error(r, z, line=5)
    assert "not finite" in r.stderr


def test_bad_csv_row_inside_compressed_names_the_line(tmp_path):
    p = tmp_path / "e.csv"
    p.write_text("i,j,qw,qx,qy,qz\n0,1,1,0,0,0\n1,2,1,0,0,0\n2,3,1,zero,0,0\n")
    z = squeeze(p, "gz")
    with pytest.raises(InputError) as exc:
        read_view_graph(z)
    assert exc.value.path == str(z) and exc.value.line == 4


# --------------------------------------------------------------- large files: streamed, with progress


def test_large_compressed_file_streams_through_pyarrow(edges, monkeypatch):
    z = squeeze(edges, "gz")
    kinds, names = ("id", "id") + ("f",) * 5, ("i", "j", "qw", "qx", "qy", "qz", "weight")
    plain = tables.read_table_file(edges, kinds=kinds, names=names)
    small = tables.read_table_file(z, kinds=kinds, names=names, block=97)  # many blocks, each cut at a line end
    assert plain is not None and small is not None
    assert np.array_equal(plain.lines, small.lines)
    for a, b in zip(plain.cols, small.cols):
        assert np.array_equal(a, b)
    seen = []
    monkeypatch.setattr(table_stream, "_stream_table", lambda *a, **k: seen.append(1))  # the reader asks the streamer first
    tables.read_table_file(z, kinds=kinds, names=names)
    assert seen


def test_truncated_large_file_in_the_stream_is_a_clean_error(edges, tmp_path):
    data = gzip.compress(edges.read_bytes())
    bad = tmp_path / "cut.txt.gz"
    bad.write_bytes(data[: len(data) - 20])  # the head decompresses; the end does not
    with pytest.raises(InputError, match="corrupt or truncated gzip") as exc:
        tables.read_table_file(bad, kinds=("id", "id") + ("f",) * 5, names=tuple("abcdefg"), block=64)
    assert exc.value.path == str(bad)


@pytest.mark.parametrize("kind", [None, "gz", "xz"])
def test_read_progress_in_bytes(edges, monkeypatch, kind):
    monkeypatch.setattr(compressed, "PROGRESS_MIN_BYTES", 100)
    monkeypatch.setattr(compressed, "PROGRESS_MIN_COMPRESSED_BYTES", 100)
    monkeypatch.setattr(table_stream, "STREAM_BLOCK", 512)
    p = edges if kind is None else squeeze(edges, kind)
    size = p.stat().st_size
    seen = []
    g = read_view_graph(p, progress=lambda stage, done, total: seen.append((stage, done, total)))
    assert g.n_edges == 40
    assert seen and {s for s, _, _ in seen} == {"read"} and {t for _, _, t in seen} == {size}
    done = [d for _, d, _ in seen]
    assert done[0] == 0 and done[-1] == size and done == sorted(done)
    seen.clear()
    with reading_progress(lambda *a: seen.append(a)):  # the text path (read_text) reports too
        from rotgraph.io.text import read_text

        assert read_text(p) == edges.read_text()
    assert seen[-1] == ("read", size, size)


def test_no_progress_without_callback_or_for_small_files(edges):
    seen = []
    read_view_graph(squeeze(edges, "gz"), progress=lambda *a: seen.append(a))  # far below the thresholds
    assert seen == []


# --------------------------------------------------------------- batch finds compressed edge files


def test_batch_folder_takes_compressed_edge_files(edges, tmp_path):
    from rotgraph.pipeline.inputs import expand_inputs, output_names

    folder = tmp_path / "scenes"
    folder.mkdir()
    squeeze(edges, "gz", name="scenes/a.txt.gz")
    squeeze(edges, "xz", name="scenes/b.csv.xz")
    (folder / "notes.json.gz").write_bytes(gzip.compress(b"{}"))
    (folder / "archive.gz").write_bytes(gzip.compress(b"whatever"))
    problems = expand_inputs([str(folder)], tmp_path / "out")
    found = sorted(Path(p.path).name for p in problems if p.error is None)
    assert found == ["a.txt.gz", "b.csv.xz"]
    assert sorted(output_names([p for p in problems if p.error is None])) == ["a.csv", "b.csv"]


@pytest.mark.parametrize("tail", [b"\0" * 64, b"garbage"])
def test_fast_and_standard_decoders_agree(edges, tmp_path, tail):
    """pyarrow's codec (the streamed path) and the standard library (read_text) give the same
    data or the same error, e.g. for zeros after a gzip stream (which gzip accepts)."""
    from rotgraph.io.compressed import open_input

    z = tmp_path / "padded.txt.gz"
    z.write_bytes(gzip.compress(edges.read_bytes()) + tail)
    got = []
    for fast in (False, True):
        try:
            with open_input(z, fast=fast) as fh:
                got.append(b"".join(iter(lambda: fh.read(100), b"")))
        except InputError as exc:
            got.append(exc.message)
    assert got[0] == got[1]
    if tail.strip(b"\0"):
        with pytest.raises(InputError, match="corrupt or truncated gzip"):
            read_view_graph(z)
    else:
        same_graph(read_view_graph(z), read_view_graph(edges))


def test_solve_read_bar_in_bytes_on_a_terminal(edges, monkeypatch, tmp_path):
    """rotgraph solve's progress (cli.progress.Progress) draws the read stage in bytes, one
    bar per file read; with stderr not a terminal it is given no callback at all."""
    import io

    from rotgraph.cli.progress import Progress
    from rotgraph.pipeline.solve import solve_file

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    monkeypatch.setattr(compressed, "PROGRESS_MIN_COMPRESSED_BYTES", 100)
    monkeypatch.setattr(table_stream, "STREAM_BLOCK", 256)
    term = Terminal()
    monkeypatch.setattr("sys.stderr", term)
    progress = Progress(quiet=False, mininterval=0.0)
    z = squeeze(edges, "xz")
    solve_file(str(z), str(tmp_path / "o.csv"), callback=progress, read_progress=progress.count)
    progress.close()
    text = term.getvalue()
    assert "  read: 100%" in text and "B/s" in text, text
    progress = Progress(quiet=False)
    progress.count("read", 0, 5000)
    first = progress.bar
    progress.count("read", 0, 7000)  # another file: another bar
    assert progress.bar is not first and progress.bar.unit == "B"
    progress.close()
