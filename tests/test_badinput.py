"""The bad-input corpus (issue #7): every command that reads files, fed every kind of bad file.

One table, readable as a checklist. Each row names a command line, the input files it gets
(written into ``in/``) and what must happen, per CLI.md:

* ``Err(code, file, line, text)``: exit ``code`` (3 = bad input, 1 = unsolvable, 2 = click's
  usage error), stderr holds exactly one ``rotgraph: error:`` line, and it is the last line
  (any other line is a ``rotgraph: warning:``); for code 3 it starts ``rotgraph: error:
  FILE:LINE: `` (or ``FILE: `` when ``line`` is None: the input has no line to blame) and
  contains ``text``; no ``Traceback`` anywhere. Every output the command was given (``out/out.csv``, ``--edges-out``,
  ``--plot``, the batch folder) exists beforehand with known bytes and is byte-identical (same
  mtime) afterwards, with no temporary file left beside it.
* ``Ok(check)``: the input is valid or documented as tolerated: exit 0 and ``check`` verifies
  the result (e.g. the solved rotations against the ground truth used to write the input).

In both cases every input file keeps its bytes and mtime and no file appears in ``in/``.

The commands run in-process through click's CliRunner (fast); ``test_real_entry_point``
re-runs a few rows through the installed ``rotgraph`` executable to check that the real
stderr is that one line too. The kill tests SIGKILL ``rotgraph solve`` (and ``batch``) at
several moments and check that the output is the old file or a complete new one.

A contract violation found later is added as a row marked xfail(strict=True) with the place of
the fix as its reason; it turns into a failure once fixed, so the mark must then go.
"""

from __future__ import annotations

import csv
import json
import logging
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import scipy.io
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

from rotgraph.cli.main import cli
from cli_helpers import refuses_files

ROOT = Path(__file__).resolve().parents[1]
COLMAP_PROJECT = ROOT / "datasets" / "colmap_synthetic"
_EXE = Path(sys.executable).with_name("rotgraph")  # the entry point installed beside this interpreter
ROTGRAPH_EXE = str(_EXE) if _EXE.exists() else shutil.which("rotgraph") or "rotgraph"

# ============================================================================ valid data
#
# Five cameras with known absolute rotations R_k (cam_from_world) and seven edges, written
# in every format by hand (numpy/scipy, not rotgraph's writers), each in its own convention.

N = 5
PAIRS = [(0, 1), (1, 2), (2, 3), (3, 4), (0, 4), (1, 3), (0, 2)]
R_GT = Rotation.random(N, random_state=7).as_matrix()
D = np.diag([1.0, -1.0, -1.0])


def wxyz(R) -> np.ndarray:
    return np.roll(Rotation.from_matrix(R).as_quat(), 1, axis=-1)


def rel(i, j) -> np.ndarray:
    return R_GT[j] @ R_GT[i].T


def nums(v) -> str:
    return " ".join(repr(float(x)) for x in np.ravel(v))


def edges_txt(pairs=PAIRS, scale=1.0, ids=lambda k: str(k)) -> str:
    return "# i j qw qx qy qz weight\n" + "".join(f"{ids(i)} {ids(j)} {nums(scale * wxyz(rel(i, j)))} 1\n" for i, j in pairs)


def edges_csv() -> str:
    return "i,j,qw,qx,qy,qz,weight\n" + "".join(f"{i},{j},{nums(wxyz(rel(i, j))).replace(' ', ',')},2\n" for i, j in PAIRS)


def glomap_txt() -> str:
    return "".join(f"im{i}.jpg im{j}.jpg {nums(wxyz(rel(i, j)))} 0 0 1\n" for i, j in PAIRS)


def egs_txt() -> str:
    # 1DSfM: EG rotation R = R_i R_j^T in the Bundler frame, i.e. D R_ij^T D.
    return "".join(f"{i} {j} {nums(D @ rel(i, j).T @ D)} 0 0 1\n" for i, j in PAIRS)


def g2o_txt(extra: str = "") -> str:
    # Poses world_from_body Q_k = R_k^T; edge rotation Q_i^T Q_j = R_ij^T; quaternions x y z w.
    xyzw = lambda R: nums(Rotation.from_matrix(R).as_quat())  # noqa: E731
    info = " ".join(["1"] + ["0"] * 20)
    return ("".join(f"VERTEX_SE3:QUAT {k} 0 0 0 {xyzw(R_GT[k].T)}\n" for k in range(N)) + extra
            + "".join(f"EDGE_SE3:QUAT {i} {j} 0 0 0 {xyzw(rel(i, j).T)} {info}\n" for i, j in PAIRS))


def gt_txt(ids=range(N)) -> str:
    return "# id qw qx qy qz\n" + "".join(f"{k} {nums(wxyz(R_GT[k]))}\n" for k in ids)


def estimate_csv(ids=range(N)) -> str:
    return "id,name,qw,qx,qy,qz\n" + "".join(f"{k},{k},{nums(wxyz(R_GT[k])).replace(' ', ',')}\n" for k in ids)


def rotations_txt(scale=1.0) -> str:
    return "# qw qx qy qz weight\n" + "".join(f"{nums(scale * wxyz(R_GT[0] @ Rotation.from_rotvec(v).as_matrix()))} 1\n"
                                              for v in 0.02 * np.eye(3))


# Hand-eye: S = gripper_from_camera; motions L_k (robot) and R_k = S^-1 L_k S (camera).
S_TRUE = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
L_MOT = Rotation.random(6, random_state=3).as_matrix()
R_MOT = S_TRUE.T @ L_MOT @ S_TRUE


def motions_txt(Rs, scale=1.0) -> str:
    return "# qw qx qy qz\n" + "".join(f"{nums(scale * wxyz(R))}\n" for R in Rs)


# absolute poses for --poses: base_from_gripper G_k, cam_from_target C_k = S^-1 G_k^-1 T
G_POSE = Rotation.random(6, random_state=4).as_matrix()
T_TARGET = Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix()
C_POSE = S_TRUE.T @ np.swapaxes(G_POSE, 1, 2) @ T_TARGET


def poses_16(Rs) -> str:
    out = []
    for R in Rs:
        P = np.eye(4)
        P[:3, :3] = R
        out.append(nums(P) + "\n")
    return "".join(out)


def write_mat(**variables) -> Callable[[Path], None]:
    return lambda p: scipy.io.savemat(p, variables)


def good_mat(p: Path) -> None:
    RR = np.stack([rel(i, j) for i, j in PAIRS], axis=2)
    scipy.io.savemat(p, {"RR": RR, "I": np.array(PAIRS).T + 1, "Rgt": np.stack(list(R_GT), axis=2)})


def fake_mat73(p: Path) -> None:
    """A MATLAB v7.3 (HDF5) header: scipy cannot read it."""
    text = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    p.write_bytes(text.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM" + b"\x00" * 512)


# ---------------------------------------------------------------------------- COLMAP


def colmap_copy(p: Path, keep=("database.db", "sparse")) -> None:
    p.mkdir()
    for name in keep:
        src = COLMAP_PROJECT / name
        (shutil.copytree if src.is_dir() else shutil.copyfile)(src, p / name)


def colmap_model_only(p: Path) -> None:
    colmap_copy(p, keep=("sparse",))


def colmap_empty_db(p: Path) -> None:
    p.mkdir()
    (p / "database.db").write_bytes(b"")


def colmap_garbage_db(p: Path) -> None:
    p.mkdir()
    (p / "database.db").write_bytes(bytes(range(256)) * 16)


def colmap_truncated_db(p: Path) -> None:
    p.mkdir()
    data = (COLMAP_PROJECT / "database.db").read_bytes()
    (p / "database.db").write_bytes(data[: len(data) // 3])


def colmap_header_only_db(p: Path) -> None:
    p.mkdir()
    (p / "database.db").write_bytes(b"SQLite format 3\x00" + bytes(84))


def colmap_foreign_sqlite(p: Path) -> None:
    p.mkdir()
    con = sqlite3.connect(p / "database.db")
    con.execute("CREATE TABLE notes (x TEXT)")
    con.commit()
    con.close()


def colmap_db_is_a_folder(p: Path) -> None:
    p.mkdir()
    (p / "database.db").mkdir()


def colmap_no_usable_pair(p: Path) -> None:
    """Every verified pair marked WATERMARK: nothing survives the configuration filter."""
    import pycolmap

    colmap_copy(p, keep=("database.db",))
    db = pycolmap.Database.open(str(p / "database.db"))
    try:
        pair_ids, geoms = db.read_two_view_geometries()
        for pid, g in zip(pair_ids, geoms):
            g.config = pycolmap.TwoViewGeometryConfiguration.WATERMARK
            db.update_two_view_geometry(*pycolmap.pair_id_to_image_pair(pid), g)
    finally:
        db.close()


def edge_columns(pairs=PAIRS, **changes) -> dict:
    """The columns of a Parquet edge file (i j qw qx qy qz weight) of ``pairs``; ``changes``
    replace columns (None removes one)."""
    q = np.array([wxyz(rel(i, j)) for i, j in pairs]).reshape(-1, 4)
    cols = {"i": np.array([i for i, _ in pairs], dtype=np.int64), "j": np.array([j for _, j in pairs], dtype=np.int64),
            **{c: q[:, k].copy() for k, c in enumerate(("qw", "qx", "qy", "qz"))}, "weight": np.ones(len(pairs))}
    cols.update(changes)
    return {c: a for c, a in cols.items() if a is not None}


def parquet_parts(**parts) -> Callable[[Path], None]:
    """A folder of Parquet parts, as Dask, Spark or Arrow write one: ``parts`` relative path
    (``/`` for sub-folders) -> columns (written by pyarrow) or bytes (written as they are)."""
    def make(p: Path) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        p.mkdir()
        for name, content in parts.items():
            f = p / name
            f.parent.mkdir(parents=True, exist_ok=True)
            if isinstance(content, bytes):
                f.write_bytes(content)
            else:
                pq.write_table(pa.table(content), f)
    return make


def folder_with(**files) -> Callable[[Path], None]:
    def make(p: Path) -> None:
        p.mkdir()
        for name, content in files.items():
            (p / name).write_bytes(content.encode() if isinstance(content, str) else content)
    return make


# ============================================================================ checks of valid results


def read_solution(path: Path) -> dict:
    """The ``solve`` CSV as {id: R}, checking its layout on the way."""
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    assert rows[0][:6] == ["id", "name", "qw", "qx", "qy", "qz"], rows[0]
    out = {}
    for r in rows[1:]:
        assert len(r) == len(rows[0]), r
        q = np.array([float(x) for x in r[2:6]])
        assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-9, r
        out[r[0]] = Rotation.from_quat(np.roll(q, -1)).as_matrix()
    return out


def gauge_error_deg(sol: dict, gt: dict) -> float:
    """Max error after the best common gauge (the rotations R_gt_k^T R_k must agree)."""
    keys = sorted(set(sol) & set(gt))
    W = [gt[k].T @ sol[k] for k in keys]
    return max(np.degrees(Rotation.from_matrix(W[0].T @ w).magnitude()) for w in W)


GT_BY_ID = {str(k): R_GT[k] for k in range(N)}


def solved_like_gt(ids=lambda k: str(k), n=N, tol=1e-6):
    def check(ctx) -> None:
        sol = read_solution(ctx.out / "out.csv")
        gt = {ids(k): R_GT[k] for k in range(N)}
        assert len(sol) == n and set(sol) <= set(gt), sorted(sol)
        assert gauge_error_deg(sol, gt) < tol
    return check


def info_json(**expected):
    def check(ctx) -> None:
        s = json.loads(ctx.result.stdout)
        for k, v in expected.items():
            assert s[k] == v, (k, s[k], v)
    return check


def eval_json(n_evaluated, max_deg=1e-6):
    def check(ctx) -> None:
        s = json.loads(ctx.result.stdout)
        assert s["n_evaluated"] == n_evaluated and s["max"] < max_deg, s
    return check


def mean_is(R, tol=1e-9):
    def check(ctx) -> None:
        q = np.array([float(x) for x in ctx.result.stdout.split()[:4]])
        assert q[0] >= 0 and np.abs(q - wxyz(R)).max() < tol, (q, wxyz(R))
    return check


def handeye_is(S, tol_deg=1e-6):
    def check(ctx) -> None:
        out = json.loads(ctx.result.stdout)
        q = np.array(out["quaternion"])
        err = np.degrees((Rotation.from_quat(np.roll(q, -1)).inv() * Rotation.from_matrix(S)).magnitude())
        assert err < tol_deg, (q, wxyz(S))
    return check


def warned(text: str, then: Callable | None = None):
    """Exit 0 with a warning containing ``text`` (logged, or printed as 'rotgraph: warning:')."""
    def check(ctx) -> None:
        logged = [r.getMessage() for r in ctx.records if r.levelno >= logging.WARNING]
        printed = [s for s in ctx.result.stderr.splitlines() if s.startswith("rotgraph: warning:")]
        assert any(text in m for m in logged + printed), (logged, printed)
        if then is not None:
            then(ctx)
    return check


def batch_manifest(statuses, errors=()):
    def check(ctx) -> None:
        manifest = json.loads((ctx.out / "batch" / "manifest.json").read_text())
        assert [e["status"] for e in manifest] == statuses, manifest
        for e, text in zip(manifest, errors):
            assert text in (e["error"] or ""), e
    return check


# ============================================================================ the corpus


@dataclass
class Err:
    code: int | tuple = 3  # several: any of them (2 is click's usage error, with its own format)
    file: str | None = None  # the file the message must name, relative to in/ or "{o}/..." (None: the input)
    line: int | None = None  # the line it must name (None: no line)
    text: str = ""


@dataclass
class Ok:
    check: Callable | None = None
    code: int = 0


@dataclass
class Case:
    id: str
    argv: list  # "{in}" is the input below; "{i}" the in/ folder, "{o}" the out/ folder
    input: str  # file or folder name in in/ that "{in}" stands for
    files: dict  # name in in/ -> str, bytes or a callable writing the path
    expect: Err | Ok
    marks: tuple = ()


# the commands, with every output they can write given as existing files (checked untouched on error)
SOLVE = ["solve", "{in}", "-o", "{o}/out.csv", "--edges-out", "{o}/edges.csv"]
INFO = ["info", "{in}", "--json"]
INFO_PLOT = ["info", "{in}", "--plot", "{o}/plot.png"]
EVAL_EST = ["eval", "{in}", "{i}/gt.txt", "--plot", "{o}/plot.png"]  # the estimate is bad
EVAL_GT = ["eval", "{i}/est.csv", "{in}", "--plot", "{o}/plot.png"]  # the ground truth is bad
MEAN = ["mean", "{in}"]
HANDEYE_A = ["handeye", "{in}", "{i}/B.txt", "--json"]
HANDEYE_B = ["handeye", "{i}/A.txt", "{in}", "--json"]
POSES_A = ["handeye", "{in}", "{i}/B.txt", "--poses", "--json"]
BATCH = ["batch", "@{in}", "--out-dir", "{o}/batch", "-q"]

EDGE = "0 1 1 0 0 0\n"
UTF16 = "0 1 1 0 0 0\n1 2 1 0 0 0\n".encode("utf-16")  # with a BOM, as Windows tools write it
UTF16_NOBOM = "0 1 1 0 0 0\n".encode("utf-16-le")
GARBAGE = bytes(range(256)) * 8
LATIN1 = "0 1 1 0 0 0\ncaf\xe9 2 1 0 0 0\n".encode("latin-1")
G2O_INFO = " ".join(["1"] + ["0"] * 20)
I64 = 2**63 - 1


def edge_line(i, j, q="1 0 0 0"):
    return f"{i} {j} {q}\n"


CASES: list[Case] = []


def case(id, argv, input, files, expect, marks=()):
    CASES.append(Case(id, argv, input, files, expect, marks))


# ---------------------------------------------------------------- solve, rotgraph text format
T = "e.txt"
case("solve/txt valid", SOLVE, T, {T: edges_txt()}, Ok(solved_like_gt()))
case("solve/txt empty file", SOLVE, T, {T: b""}, Err(text="no edges"))
case("solve/txt header only", SOLVE, T, {T: "# i j qw qx qy qz weight\n"}, Err(text="no edges"))
case("solve/txt blank lines only", SOLVE, T, {T: "\n\n   \n"}, Err(text="no edges"))
case("solve/txt truncated line", SOLVE, T, {T: edges_txt() + "1 2 1 0"}, Err(line=9, text="expected 6 or 7 fields"))
case("solve/txt truncated number", SOLVE, T, {T: EDGE + "1 2 1 0 0 1e"}, Err(line=2, text="qz is not a number: '1e'"))
case("solve/txt non-numeric", SOLVE, T, {T: EDGE + "1 2 1 0 zero 0\n"}, Err(line=2, text="qy is not a number"))
case("solve/txt too many fields", SOLVE, T, {T: EDGE + "1 2 1 0 0 0 1 9\n"}, Err(line=2, text="expected 6 or 7 fields"))
case("solve/txt nan", SOLVE, T, {T: EDGE + "1 2 nan 0 0 0\n"}, Err(line=2, text="not finite"))
case("solve/txt inf", SOLVE, T, {T: EDGE + "1 2 1 0 0 -inf\n"}, Err(line=2, text="not finite"))
case("solve/txt overflow 1e400", SOLVE, T, {T: EDGE + "1 2 1e400 0 0 0\n"}, Err(line=2, text="not finite"))
case("solve/txt nan weight", SOLVE, T, {T: EDGE + "1 2 1 0 0 0 nan\n"}, Err(line=2, text="not finite"))
case("solve/txt zero weight", SOLVE, T, {T: EDGE + "1 2 1 0 0 0 0\n"}, Err(line=2, text="weight"))
case("solve/txt negative weight", SOLVE, T, {T: EDGE + "1 2 1 0 0 0 -1\n"}, Err(line=2, text="weight"))
case("solve/txt zero quaternion", SOLVE, T, {T: EDGE + "1 2 0 0 0 0\n"}, Err(line=2, text="zero quaternion"))
case("solve/txt non-unit quaternions are normalised, with a warning", SOLVE, T, {T: edges_txt(scale=3.0)},
     Ok(warned("not unit length", solved_like_gt())))
case("solve/txt duplicate pair", SOLVE, T, {T: EDGE + "1 2 1 0 0 0\n1 0 1 0 0 0\n"}, Err(line=3, text="duplicate pair"))
case("solve/txt duplicate pair, --duplicates merge", SOLVE + ["--duplicates", "merge"], T,
     {T: edges_txt(PAIRS + [(1, 0)])}, Ok(solved_like_gt()))
case("solve/txt self-loop", SOLVE, T, {T: EDGE + "2 2 1 0 0 0\n"}, Err(line=2, text="self-loop"))
case("solve/txt binary garbage", SOLVE, T, {T: GARBAGE}, Err(line=1, text="binary"))
case("solve/txt NUL later in the file", SOLVE, T, {T: EDGE + EDGE + "\x00\n"}, Err(line=3, text="binary"))
case("solve/txt latin-1", SOLVE, T, {T: LATIN1}, Err(line=2, text="UTF-8"))
case("solve/txt UTF-16 with BOM", SOLVE, T, {T: UTF16}, Err(line=1, text="UTF-16"))
case("solve/txt UTF-16 without BOM", SOLVE, T, {T: UTF16_NOBOM}, Err(line=1, text="UTF-16"))
case("solve/txt UTF-8 BOM is fine", SOLVE, T, {T: b"\xef\xbb\xbf" + edges_txt().encode()}, Ok(solved_like_gt()))
case("solve/txt CRLF line ends are fine", SOLVE, T, {T: edges_txt().replace("\n", "\r\n").encode()}, Ok(solved_like_gt()))
case("solve/txt missing file", SOLVE, "nope.txt", {}, Err(text="no such file"))
case("solve/txt missing file, --format rotgraph", SOLVE + ["--format", "rotgraph"], "nope.txt", {}, Err(text="no such file"))
case("solve/a folder with no input", SOLVE, "dir", {"dir": folder_with(**{"notes.md": "hello\n"})}, Err(text="folder holds no input"))
case("solve/a folder, --format rotgraph", SOLVE + ["--format", "rotgraph"], "dir", {"dir": folder_with()}, Err(text="folder"))
case("solve/id 2**63-1 is the largest integer id", SOLVE, T, {T: edges_txt(ids=lambda k: str(I64 - k))},
     Ok(solved_like_gt(ids=lambda k: str(I64 - k))))
case("solve/id 2**63 is too large", SOLVE, T, {T: edge_line(2**63, 1) + EDGE}, Err(line=1, text="too large"))
case("solve/id 10**30 is too large", SOLVE, T, {T: EDGE + edge_line(1, 10**30)}, Err(line=2, text="too large"))
case("solve/negative ids are names", SOLVE, T, {T: edges_txt(ids=lambda k: str(-k - 1))},
     Ok(solved_like_gt(ids=lambda k: str(-k - 1))))
case("solve/every edge rejected by the robust loss", SOLVE + ["--method", "irls", "--loss", "truncated_l2", "--loss-scale-deg", "1e-9", "--no-rescale"],
     T, {T: "".join(edge_line(i, j, nums(wxyz(Rotation.random(random_state=10 * i + j).as_matrix())))
                    for i, j in [(0, 1), (1, 2), (0, 2), (2, 3), (3, 0), (1, 3)])},
     Err(code=1, text="every edge"))



def _every_written_camera_has_an_inlier_edge(ctx) -> None:
    solved = set(read_solution(ctx.out / "out.csv"))
    with open(ctx.out / "edges.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    kept = {r[k] for r in rows if r["inlier"] == "1" for k in ("i", "j")}
    assert solved <= kept, f"cameras written although every edge of theirs is rejected: {sorted(solved - kept)}"


def _camera_6_contradicted() -> str:
    """K6 (consistent) plus camera 6 with two edges 120 degrees apart: the L2 average puts
    camera 6 in between, ~50 degrees from both, so both of its edges are outliers."""
    R6 = Rotation.random(random_state=99).as_matrix()
    off = Rotation.from_rotvec([0, 0, np.radians(120)]).as_matrix()
    return (edges_txt([(i, j) for i in range(N) for j in range(i + 1, N)])
            + edge_line(0, 9, nums(wxyz(R6 @ R_GT[0].T))) + edge_line(1, 9, nums(wxyz(off @ R6 @ R_GT[1].T))))


# robust, but L2-like at this scale (l2 itself rejects nothing: #16)
case("solve/a camera whose every edge is rejected is left out (CLI.md)",
     SOLVE + ["--method", "irls", "--loss-scale-deg", "100", "--no-rescale"], T, {T: _camera_6_contradicted()},
     Ok(_every_written_camera_has_an_inlier_edge))

# outputs that cannot be written, or would overwrite an input: fail before touching anything
# a folder is a COLMAP model output (#18): only for COLMAP project inputs
case("solve/-o names a folder", ["solve", "{in}", "-o", "{o}"], T, {T: edges_txt()}, Err(code=3, file="{o}", text="needs a COLMAP project input"))
case("solve/-o in a missing folder", ["solve", "{in}", "-o", "{o}/missing/out.csv"], T, {T: edges_txt()},
     Err(file="{o}/missing", text="output folder does not exist"))
case("solve/--edges-out in a missing folder leaves -o untouched", SOLVE[:-1] + ["{o}/missing/edges.csv"], T, {T: edges_txt()},
     Err(file="{o}/missing", text="output folder does not exist"))
case("solve/-o is the input", ["solve", "{in}", "-o", "{in}"], T, {T: edges_txt()}, Err(code=3, text="would overwrite the input"))
case("solve/--edges-out is -o", ["solve", "{in}", "-o", "{o}/out.csv", "--edges-out", "{o}/out.csv"], T, {T: edges_txt()},
     Err(file="{o}/out.csv", text="named twice as an output"))


# a folder that refuses new files (even for root): exit 3 'cannot write here', before the input is read (#15)
SYS = (pytest.mark.skipif(not os.path.isdir("/sys") or not refuses_files("/sys"), reason="/sys accepts files here"),)
PROC = (pytest.mark.skipif(not os.path.isdir("/proc") or not refuses_files("/proc"), reason="/proc accepts files here"),)
case("solve/-o in /sys: refused before the (bad) input is read", ["solve", "{in}", "-o", "/sys/rotgraph-out.csv", "--edges-out", "{o}/edges.csv"],
     T, {T: GARBAGE}, Err(file="/sys/rotgraph-out.csv", text="cannot write here: permission denied"), SYS)
case("solve/--edges-out in /proc", SOLVE[:-1] + ["/proc/rotgraph-edges.csv"], T, {T: edges_txt()},
     Err(file="/proc/rotgraph-edges.csv", text="cannot write here"), PROC)
case("info/--plot in /sys", ["info", "{in}", "--plot", "/sys/rotgraph-plot.png"], T, {T: edges_txt()},
     Err(file="/sys/rotgraph-plot.png", text="cannot write here"), SYS)
case("batch/--out-dir in /sys", ["batch", "{in}", "--out-dir", "/sys/rotgraph-batch", "-q"], T, {T: edges_txt()},
     Err(file="/sys/rotgraph-batch", text="cannot write here"), SYS)

# ---------------------------------------------------------------- solve, csv
C = "e.csv"
case("solve/csv valid", SOLVE, C, {C: edges_csv()}, Ok(solved_like_gt()))
case("solve/csv empty file", SOLVE, C, {C: b""}, Err(text="empty file"))
case("solve/csv header only", SOLVE, C, {C: "i,j,qw,qx,qy,qz,weight\n"}, Err(line=1, text="no edges"))
case("solve/csv missing column", SOLVE, C, {C: "i,j,qw,qx,qy\n0,1,1,0,0\n"}, Err(line=1, text="lacks column(s) qz"))
case("solve/csv column twice", SOLVE, C, {C: "i,j,qw,qx,qy,qz,qz\n0,1,1,0,0,0,0\n"}, Err(line=1, text="twice"))
case("solve/csv truncated row", SOLVE, C, {C: edges_csv() + "1,2,1,0"}, Err(line=9, text="expected 7 fields"))
case("solve/csv non-numeric", SOLVE, C, {C: "i,j,qw,qx,qy,qz\n0,1,1,0,0,0\n1,2,1,0,,0\n"}, Err(line=3, text="qy is not a number"))
case("solve/csv nan", SOLVE, C, {C: "i,j,qw,qx,qy,qz\n0,1,1,0,0,0\n1,2,NaN,0,0,0\n"}, Err(line=3, text="not finite"))
case("solve/csv self-loop", SOLVE, C, {C: "i,j,qw,qx,qy,qz\n0,1,1,0,0,0\n1,1,1,0,0,0\n"}, Err(line=3, text="self-loop"))
case("solve/csv duplicate pair", SOLVE, C, {C: "i,j,qw,qx,qy,qz\n0,1,1,0,0,0\n1,0,1,0,0,0\n"}, Err(line=3, text="duplicate pair"))
case("solve/csv UTF-16", SOLVE, C, {C: "i,j,qw,qx,qy,qz\n0,1,1,0,0,0\n".encode("utf-16")}, Err(line=1, text="UTF-16"))
case("solve/csv latin-1", SOLVE, C, {C: "i,j,qw,qx,qy,qz\nb\xe9,1,1,0,0,0\n".encode("latin-1")}, Err(line=2, text="UTF-8"))
case("solve/csv unbalanced quote", SOLVE, C, {C: 'i,j,qw,qx,qy,qz\n0,1,1,0,0,0\n"1,2,1,0,0,0\n'}, Err(line=3, text="expected 6 fields"))
case("solve/csv huge id", SOLVE, C, {C: f"i,j,qw,qx,qy,qz\n0,{2**64},1,0,0,0\n"}, Err(line=2, text="too large"))

# ---------------------------------------------------------------- solve, glomap
G = "pairs.txt"
GL = ["--format", "glomap"]
case("solve/glomap valid (auto-detected)", SOLVE, G, {G: glomap_txt()}, Ok(solved_like_gt(ids=lambda k: f"im{k}.jpg")))
case("solve/glomap empty", SOLVE + GL, G, {G: b""}, Err(text="no edges"))
case("solve/glomap truncated line", SOLVE + GL, G, {G: glomap_txt() + "im1.jpg im2.jpg 1 0 0 0 0 0"}, Err(line=8, text="expected 9 fields"))
case("solve/glomap non-numeric", SOLVE + GL, G, {G: "a b 1 0 0 0 0 0 0\nb c 1 0 O 0 0 0 0\n"}, Err(line=2, text="not a number"))
case("solve/glomap nan", SOLVE + GL, G, {G: "a b 1 0 0 0 0 0 0\nb c nan 0 0 0 0 0 0\n"}, Err(line=2, text="not finite"))
case("solve/glomap zero quaternion", SOLVE + GL, G, {G: "a b 1 0 0 0 0 0 0\nb c 0 0 0 0 0 0 0\n"}, Err(line=2, text="zero quaternion"))
case("solve/glomap self-loop", SOLVE + GL, G, {G: "a b 1 0 0 0 0 0 0\nb b 1 0 0 0 0 0 0\n"}, Err(line=2, text="self-loop"))
case("solve/glomap duplicate pair", SOLVE + GL, G, {G: "a b 1 0 0 0 0 0 0\nb a 1 0 0 0 0 0 0\n"}, Err(line=2, text="duplicate"))

# ---------------------------------------------------------------- solve, 1DSfM
E = "EGs.txt"
case("solve/1dsfm valid EGs.txt", SOLVE, E, {E: egs_txt()}, Ok(solved_like_gt()))
case("solve/1dsfm valid scene folder", SOLVE, "scene", {"scene": folder_with(**{"EGs.txt": egs_txt()})}, Ok(solved_like_gt()))
case("solve/1dsfm empty EGs.txt", SOLVE, E, {E: b""}, Err(text="no edges"))
case("solve/1dsfm scene folder with empty EGs.txt", SOLVE, "scene", {"scene": folder_with(**{"EGs.txt": ""})},
     Err(file="scene/EGs.txt", text="no edges"))
case("solve/1dsfm truncated line", SOLVE, E, {E: egs_txt() + "0 3 1 0 0 0 1 0"}, Err(line=8, text="expected 14 fields"))
case("solve/1dsfm not a rotation", SOLVE, E, {E: "0 1 1 0 0 0 1 0 0 0 2 0 0 0\n"}, Err(line=1, text="not a rotation"))
case("solve/1dsfm negative id", SOLVE, E, {E: egs_txt() + "-1 2 1 0 0 0 1 0 0 0 1 0 0 0\n"}, Err(line=8, text="non-negative integer"))
case("solve/1dsfm id 2**63", SOLVE, E, {E: egs_txt() + f"{2**63} 2 1 0 0 0 1 0 0 0 1 0 0 0\n"}, Err(line=8, text="too large"))
case("solve/1dsfm id beyond list.txt", SOLVE, "scene",
     {"scene": folder_with(**{"EGs.txt": egs_txt(), "list.txt": "a.jpg\nb.jpg\n"})},
     Err(file="scene/EGs.txt", line=2, text="has no line in"))
case("solve/1dsfm truncated gt_bundle.out", SOLVE, "scene",
     {"scene": folder_with(**{"EGs.txt": egs_txt(), "gt_bundle.out": "# Bundle file v0.3\n5 0\n500 0 0\n1 0 0\n"})},
     Err(file="scene/gt_bundle.out", line=4, text="truncated"))
case("solve/1dsfm binary gt_bundle.out", SOLVE, "scene",
     {"scene": folder_with(**{"EGs.txt": egs_txt(), "gt_bundle.out": GARBAGE})},
     Err(file="scene/gt_bundle.out", line=1, text="binary"))

# ---------------------------------------------------------------- solve, a folder of Parquet parts (#32)
DS = "ds"
BOOKKEEPING = {"_SUCCESS": b"", "_metadata": GARBAGE, "_common_metadata": GARBAGE, ".part.0.parquet.crc": GARBAGE}
PARTS4 = {"x=0/part.0.parquet": edge_columns(PAIRS[:2]), "x=0/part.1.parquet": edge_columns([]),
          "x=1/part.2.parquet": edge_columns(PAIRS[2:5]), "part.10.parquet": edge_columns(PAIRS[5:]), **BOOKKEEPING}
P1 = "ds/part.1.parquet"


def two_parts(**changes) -> dict:
    """A dataset of two parts whose second (``part.1.parquet``, edges 3 to 6) has ``changes``."""
    return {DS: parquet_parts(**{"part.0.parquet": edge_columns(PAIRS[:3]), "part.1.parquet": edge_columns(PAIRS[3:], **changes)})}


case("solve/parquet parts valid (hive-style, an empty part, bookkeeping files)", SOLVE, DS, {DS: parquet_parts(**PARTS4)},
     Ok(solved_like_gt()))
case("solve/parquet parts, bookkeeping files only", SOLVE, DS, {DS: folder_with(**BOOKKEEPING)}, Err(text="folder holds no input"))
case("solve/parquet parts, every part empty", SOLVE, DS,
     {DS: parquet_parts(**{"part.0.parquet": edge_columns([]), "part.1.parquet": edge_columns([])})}, Err(text="no edges"))
case("solve/parquet part without a column the first has", SOLVE, DS, two_parts(weight=None), Err(file=P1, text="no weight"))
case("solve/parquet part with a column the first lacks", SOLVE, DS,
     two_parts(**{c: np.ones(4) for c in ("h_xx", "h_xy", "h_xz", "h_yy", "h_yz", "h_zz")}), Err(file=P1, text="also h_xx"))
case("solve/parquet part without qz", SOLVE, DS, two_parts(qz=None), Err(file=P1, text="lacks array(s) qz"))
case("solve/parquet part with text quaternions", SOLVE, DS, two_parts(qw=np.array(["1"] * 4)), Err(file=P1, text="expected numbers"))
case("solve/parquet part zero quaternion", SOLVE, DS, two_parts(qw=np.array([1.0, 0, 1, 1]), qx=np.zeros(4), qy=np.zeros(4), qz=np.zeros(4)),
     Err(file=P1, text="edge 1 (0-based): zero quaternion"))
case("solve/parquet part self-loop", SOLVE, DS, two_parts(j=np.array([4, 0, 3, 2])), Err(file=P1, line=2, text="self-loop"))
case("solve/parquet parts duplicate pair across parts", SOLVE, DS, two_parts(i=np.array([1, 0, 1, 0]), j=np.array([0, 4, 3, 2])),
     Err(file=P1, line=1, text="duplicate pair"))
case("solve/parquet part negative weight", SOLVE, DS, two_parts(weight=np.array([1.0, 1, 1, -1])),
     Err(file=P1, line=4, text="weight"))
case("solve/parquet part that is not Parquet", SOLVE, DS,
     {DS: parquet_parts(**{"part.0.parquet": edge_columns(), "part.1.parquet": GARBAGE})}, Err(file=P1, text="cannot read"))
case("solve/parquet parts and a file of another kind", SOLVE, DS,
     {DS: parquet_parts(**{"part.0.parquet": edge_columns(), "notes.txt": b"hello\n"})}, Err(file="ds/notes.txt", text="cannot read"))
case("solve/-o inside the input parquet parts", ["solve", "{in}", "-o", "{in}/out.csv"], DS, {DS: parquet_parts(**PARTS4)},
     Err(file="ds/out.csv", text="input Parquet dataset"))
case("solve/--edges-out inside the input parquet parts", SOLVE[:-1] + ["{in}/x=1/edges.csv"], DS, {DS: parquet_parts(**PARTS4)},
     Err(file="ds/x=1/edges.csv", text="input Parquet dataset"))
case("info/parquet parts", INFO, DS, {DS: parquet_parts(**PARTS4)}, Ok(info_json(n_cameras=N, n_edges=len(PAIRS))))
case("certify/parquet parts", ["certify", "{i}/gt.txt", "{in}", "--json"], DS, {DS: parquet_parts(**PARTS4), "gt.txt": gt_txt()},
     Ok(info_json(certified=True)))
case("certify/parquet part zero quaternion", ["certify", "{i}/gt.txt", "{in}", "--json"], DS,
     {**two_parts(qw=np.array([1.0, 0, 1, 1]), qx=np.zeros(4), qy=np.zeros(4), qz=np.zeros(4)), "gt.txt": gt_txt()}, Err(file=P1, text="zero quaternion"))
case("batch/parquet parts are one problem", ["batch", "{in}", "--out-dir", "{o}/batch", "-q"], DS, {DS: parquet_parts(**PARTS4)},
     Ok(batch_manifest(["ok"])))
case("batch/--out-dir inside the input parquet parts", ["batch", "{in}", "--out-dir", "{in}/out", "-q"], DS, {DS: parquet_parts(**PARTS4)},
     Err(file="ds/out", text="input Parquet dataset"))
case("batch/--out-dir is the input parquet parts", ["batch", "{in}", "--out-dir", "{in}", "-q"], DS, {DS: parquet_parts(**PARTS4)},
     Err(file="ds", text="input Parquet dataset"))

# ---------------------------------------------------------------- solve, .mat
M = "x.mat"
case("solve/mat valid", SOLVE, M, {M: good_mat}, Ok(solved_like_gt()))
case("solve/mat empty file", SOLVE, M, {M: b""}, Err(text="MATLAB"))
case("solve/mat garbage", SOLVE, M, {M: GARBAGE}, Err(text="MATLAB"))
case("solve/mat text file named .mat", SOLVE, M, {M: edges_txt()}, Err(text="MATLAB"))
case("solve/mat v7.3 (HDF5)", SOLVE, M, {M: fake_mat73}, Err(text="v7.3"))
case("solve/mat wrong variables", SOLVE, M, {M: write_mat(A=np.eye(3), B=np.ones((2, 1)))}, Err(text="'RR' missing"))
case("solve/mat I missing", SOLVE, M, {M: write_mat(RR=np.eye(3)[:, :, None])}, Err(text="'I' missing"))
case("solve/mat RR not numeric", SOLVE, M, {M: write_mat(RR="hello", I=np.array([[1], [2]]))}, Err(text="'RR'"))
case("solve/mat RR wrong shape", SOLVE, M, {M: write_mat(RR=np.ones((4, 4, 2)), I=np.array([[1, 2], [2, 3]]))}, Err(text="3x3xK"))
case("solve/mat I wrong shape", SOLVE, M, {M: write_mat(RR=np.stack([np.eye(3)] * 2, 2), I=np.ones((3, 3)))}, Err(text="'I'"))
case("solve/mat I and RR disagree", SOLVE, M, {M: write_mat(RR=np.stack([np.eye(3)] * 2, 2), I=np.array([[1], [2]]))}, Err(text="'I' has 1 edges but 'RR' has 2"))
case("solve/mat 0-based I", SOLVE, M, {M: write_mat(RR=np.eye(3)[:, :, None], I=np.array([[0], [1]]))}, Err(text="1-based"))
case("solve/mat non-integer I", SOLVE, M, {M: write_mat(RR=np.eye(3)[:, :, None], I=np.array([[1.5], [2]]))}, Err(text="integer"))
case("solve/mat nan in RR", SOLVE, M, {M: write_mat(RR=np.full((3, 3, 1), np.nan), I=np.array([[1], [2]]))}, Err(text="not finite"))
case("solve/mat RR not a rotation", SOLVE, M, {M: write_mat(RR=2 * np.eye(3)[:, :, None], I=np.array([[1], [2]]))}, Err(text="not a rotation"))
case("solve/mat empty RR", SOLVE, M, {M: write_mat(RR=np.zeros((3, 3, 0)), I=np.zeros((2, 0)))}, Err(text="no edges"))
case("solve/mat self-loop", SOLVE, M, {M: write_mat(RR=np.stack([np.eye(3)] * 2, 2), I=np.array([[1, 2], [2, 2]]))}, Err(text="I(:,2) = (2, 2): self-loop"))
case("solve/mat duplicate pair", SOLVE, M, {M: write_mat(RR=np.stack([np.eye(3)] * 2, 2), I=np.array([[1, 2], [2, 1]]))}, Err(text="duplicate"))
case("solve/mat huge index is a sparse id", SOLVE, M, {M: write_mat(RR=np.eye(3)[:, :, None], I=np.array([[1], [2**62]], dtype=np.int64))},
     Ok(lambda ctx: read_solution(ctx.out / "out.csv").keys() == {"0", str(2**62 - 1)}))
case("solve/mat index beyond int64", SOLVE, M, {M: write_mat(RR=np.eye(3)[:, :, None], I=np.array([[1.0], [1e30]]))}, Err(text="too large"))
case("solve/mat uint64 index beyond int64", SOLVE, M, {M: write_mat(RR=np.eye(3)[:, :, None], I=np.array([[1], [2**64 - 1]], dtype=np.uint64))},
     Err(text="too large"))

# ---------------------------------------------------------------- solve, g2o
P = "graph.g2o"
case("solve/g2o valid", SOLVE, P, {P: g2o_txt()}, Ok(solved_like_gt()))
case("solve/g2o skipped tags warn", SOLVE, P, {P: g2o_txt("FIX 0\n")}, Ok(warned("skipped", solved_like_gt())))
case("solve/g2o empty", SOLVE, P, {P: b""}, Err(text="no edges"))
case("solve/g2o vertices only", SOLVE, P, {P: g2o_txt().split("EDGE")[0]}, Err(text="no edges"))
case("solve/g2o unknown tag", SOLVE, P, {P: g2o_txt("EDGE_SE3:EULER 0 1 0 0 0 0 0 0\n")}, Err(line=6, text="unknown g2o tag"))
case("solve/g2o lower-case tag", SOLVE, P, {P: g2o_txt("edge_se3:quat 0 1 0 0 0 0 0 0 1 " + G2O_INFO + "\n")}, Err(line=6, text="unknown g2o tag"))
case("solve/g2o 2D graph", SOLVE, P, {P: "VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"}, Err(line=1, text="2D"))
case("solve/g2o truncated edge", SOLVE, P, {P: g2o_txt() + "EDGE_SE3:QUAT 0 3 0 0 0 0 0"}, Err(line=13, text="expected 31 fields"))
case("solve/g2o non-numeric", SOLVE, P, {P: g2o_txt() + "EDGE_SE3:QUAT 0 3 0 0 0 0 0 x 1 " + G2O_INFO + "\n"}, Err(line=13, text="not a number"))
case("solve/g2o nan quaternion", SOLVE, P, {P: g2o_txt() + "EDGE_SE3:QUAT 0 3 0 0 0 0 0 nan 1 " + G2O_INFO + "\n"}, Err(line=13, text="not finite"))
case("solve/g2o zero quaternion", SOLVE, P, {P: g2o_txt() + "EDGE_SE3:QUAT 0 3 0 0 0 0 0 0 0 " + G2O_INFO + "\n"}, Err(line=13, text="zero quaternion"))
case("solve/g2o self-loop", SOLVE, P, {P: g2o_txt() + "EDGE_SE3:QUAT 3 3 0 0 0 0 0 0 1 " + G2O_INFO + "\n"}, Err(line=13, text="self-loop"))
# g2o keeps parallel edges by default (pose graphs have them, #15): the error is asked for
case("solve/g2o duplicate pair", SOLVE + ["--duplicates", "error"], P, {P: g2o_txt() + "EDGE_SE3:QUAT 1 0 0 0 0 0 0 0 1 " + G2O_INFO + "\n"},
     Err(line=13, text="duplicate"))
case("solve/g2o duplicate vertex", SOLVE, P, {P: g2o_txt("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n")}, Err(line=6, text="defined twice"))
case("solve/g2o id 2**64", SOLVE, P, {P: g2o_txt() + f"EDGE_SE3:QUAT 0 {2**64} 0 0 0 0 0 0 1 " + G2O_INFO + "\n"}, Err(line=13, text="64-bit"))
case("solve/g2o binary", SOLVE, P, {P: GARBAGE}, Err(line=1, text="binary"))
case("solve/g2o only skipped tags (0 edges after skipping)", SOLVE, P, {P: "FIX 0\nVERTEX_XYZ 1 0 0 0\n"}, Err(text="no edges"))
case("solve/g2o a warning, then an error", SOLVE, P,
     {P: g2o_txt("FIX 0\n") + "EDGE_SE3:QUAT 0 3 0 0 0 0 0 0 0 " + G2O_INFO + "\n"}, Err(line=14, text="zero quaternion"))
case("solve/g2o edge to an unknown vertex warns", SOLVE, P, {P: g2o_txt() + "EDGE_SE3:QUAT 4 9 0 0 0 0 0 0 1 " + G2O_INFO + "\n"},
     Ok(warned("without a VERTEX_SE3:QUAT line")))

# ---------------------------------------------------------------- solve, COLMAP
def solved_colmap(ctx) -> None:
    sol = read_solution(ctx.out / "out.csv")
    assert set(sol) == {str(k) for k in range(1, 15)}, sorted(sol)  # the 14 images of the bundled project


case("solve/colmap valid project", SOLVE + ["--quiet"], "proj", {"proj": colmap_copy}, Ok(solved_colmap))
case("solve/colmap model folder without a database", SOLVE + ["--quiet"], "proj", {"proj": colmap_model_only}, Ok(solved_colmap))
case("solve/colmap empty database.db", SOLVE, "proj", {"proj": colmap_empty_db}, Err(file="proj/database.db", text="empty"))
case("solve/colmap empty database.db given directly", SOLVE, "proj/database.db", {"proj": colmap_empty_db}, Err(text="empty"))
case("solve/colmap garbage database.db", SOLVE, "proj", {"proj": colmap_garbage_db}, Err(file="proj/database.db", text="SQLite"))
case("solve/colmap truncated database.db", SOLVE, "proj", {"proj": colmap_truncated_db}, Err(file="proj/database.db", text="corrupt or unreadable"))
case("solve/colmap SQLite header only", SOLVE, "proj", {"proj": colmap_header_only_db}, Err(file="proj/database.db", text="corrupt or unreadable"))
case("solve/colmap SQLite without COLMAP tables", SOLVE, "proj", {"proj": colmap_foreign_sqlite}, Err(file="proj/database.db", text="no images"))
case("solve/colmap database.db is a folder", SOLVE, "proj", {"proj": colmap_db_is_a_folder}, Err(text="folder"))
case("solve/colmap no usable pair (0 edges after filtering)", SOLVE, "proj", {"proj": colmap_no_usable_pair},
     Err(file="proj/database.db", text="no usable image pair"))
case("solve/colmap --format colmap on a text file", SOLVE + ["--format", "colmap"], T, {T: edges_txt()}, Err(text="not an SQLite file"))

# ---------------------------------------------------------------- info
case("info/valid", INFO, T, {T: edges_txt()}, Ok(info_json(n_cameras=N, n_edges=len(PAIRS), n_components=1)))
case("info/empty", INFO_PLOT, T, {T: b""}, Err(text="no edges"))
case("info/binary", INFO_PLOT, T, {T: GARBAGE}, Err(line=1, text="binary"))
case("info/UTF-16", INFO_PLOT, T, {T: UTF16}, Err(line=1, text="UTF-16"))
case("info/missing", INFO_PLOT, "nope.txt", {}, Err(text="no such file"))
case("info/folder with no input", INFO_PLOT, "dir", {"dir": folder_with()}, Err(text="folder holds no input"))
case("info/truncated csv", INFO_PLOT, C, {C: edges_csv()[:-20]}, Err(line=8, text="expected 7 fields"))
case("info/mat wrong variables", INFO_PLOT, M, {M: write_mat(A=np.eye(3))}, Err(text="'RR' missing"))
case("info/g2o unknown tag", INFO_PLOT, P, {P: "VERTEX_SE3:EULER 0 0 0 0 0 0 0\n"}, Err(line=1, text="unknown g2o tag"))
case("info/corrupt colmap database", INFO_PLOT, "proj", {"proj": colmap_garbage_db}, Err(file="proj/database.db", text="SQLite"))
case("info/duplicate pair", INFO_PLOT, T, {T: EDGE + "1 0 1 0 0 0\n"}, Err(line=2, text="duplicate"))
case("info/huge id", INFO_PLOT, T, {T: EDGE + edge_line(1, 2**64)}, Err(line=2, text="too large"))

# ---------------------------------------------------------------- eval: a bad estimate (GT good), a bad ground truth (estimate good)
GTF = {"gt.txt": gt_txt()}
ESF = {"est.csv": estimate_csv()}
S_ = "est.csv"
case("eval/valid", ["eval", "{in}", "{i}/gt.txt", "--json"], S_, {S_: estimate_csv(), **GTF}, Ok(eval_json(N)))
case("eval/estimate empty", EVAL_EST, S_, {S_: b"", **GTF}, Err(text="empty"))
case("eval/estimate header only", EVAL_EST, S_, {S_: "id,name,qw,qx,qy,qz\n", **GTF}, Err(line=1, text="no rotations"))
case("eval/estimate truncated row", EVAL_EST, S_, {S_: estimate_csv()[:-30], **GTF}, Err(line=6, text="expected 6 fields"))
case("eval/estimate non-numeric", EVAL_EST, S_, {S_: "id,name,qw,qx,qy,qz\n0,a,1,0,zero,0\n", **GTF}, Err(line=2, text="not a number"))
case("eval/estimate nan", EVAL_EST, S_, {S_: "id,name,qw,qx,qy,qz\n0,a,nan,0,0,0\n", **GTF}, Err(line=2, text="not finite"))
case("eval/estimate zero quaternion", EVAL_EST, S_, {S_: "id,name,qw,qx,qy,qz\n0,a,0,0,0,0\n", **GTF}, Err(line=2, text="zero quaternion"))
case("eval/estimate duplicate id", EVAL_EST, S_, {S_: estimate_csv() + "0,0,1,0,0,0\n", **GTF}, Err(line=7, text="appears twice"))
case("eval/estimate binary", EVAL_EST, S_, {S_: GARBAGE, **GTF}, Err(line=1, text="binary"))
case("eval/estimate UTF-16", EVAL_EST, S_, {S_: estimate_csv().encode("utf-16"), **GTF}, Err(line=1, text="UTF-16"))
case("eval/estimate missing", EVAL_EST, "nope.csv", GTF, Err(text="no such file"))
case("eval/estimate is a folder", EVAL_EST, "dir", {"dir": folder_with(), **GTF}, Err(text="folder"))
case("eval/estimate id 2**63", EVAL_EST, S_, {S_: estimate_csv() + f"{2**63},x,1,0,0,0\n", **GTF}, Err(line=7, text="too large"))
case("eval/estimate without id or name", EVAL_EST, S_, {S_: "qw,qx,qy,qz\n1,0,0,0\n", **GTF}, Err(line=1, text="'id' or a 'name'"))
case("eval/non-unit quaternions are normalised, with a warning", ["eval", "{in}", "{i}/gt.txt", "--json"], S_,
     {S_: "id,name,qw,qx,qy,qz\n" + "".join(f"{k},{k},{nums(2 * wxyz(R_GT[k])).replace(' ', ',')}\n" for k in range(N)), **GTF},
     Ok(warned("not unit length", eval_json(N))))
G_ = "gt.txt"
case("eval/GT with unknown ids: the common cameras are evaluated", ["eval", "{i}/est.csv", "{in}", "--json"], G_,
     {G_: gt_txt() + "99 1 0 0 0\n", **ESF}, Ok(eval_json(N)))
case("eval/GT covering part of the estimate", ["eval", "{i}/est.csv", "{in}", "--json"], G_, {G_: gt_txt(ids=[0, 2, 4]), **ESF}, Ok(eval_json(3)))
case("eval/GT only unknown ids", EVAL_GT, G_, {G_: "# id qw qx qy qz\n7 1 0 0 0\n8 1 0 0 0\n", **ESF}, Err(text="no camera of the estimate"))
case("eval/GT empty", EVAL_GT, G_, {G_: b"", **ESF}, Err(text="no rotations"))
case("eval/GT header only", EVAL_GT, G_, {G_: "# id qw qx qy qz\n", **ESF}, Err(text="no rotations"))
case("eval/GT truncated line", EVAL_GT, G_, {G_: gt_txt() + "5 1 0", **ESF}, Err(line=7, text="expected 5 fields"))
case("eval/GT inconsistent layout", EVAL_GT, G_, {G_: gt_txt() + "5 five 1 0 0 0\n", **ESF}, Err(line=7, text="expected 5 fields"))
case("eval/GT non-numeric", EVAL_GT, G_, {G_: gt_txt() + "5 1 0 0 O\n", **ESF}, Err(line=7, text="not a number"))
case("eval/GT inf", EVAL_GT, G_, {G_: gt_txt() + "5 1 0 0 inf\n", **ESF}, Err(line=7, text="not finite"))
case("eval/GT duplicate id", EVAL_GT, G_, {G_: gt_txt() + "3 1 0 0 0\n", **ESF}, Err(line=7, text="appears twice"))
case("eval/GT latin-1", EVAL_GT, G_, {G_: gt_txt().encode() + "caf\xe9 1 0 0 0\n".encode("latin-1"), **ESF}, Err(line=7, text="UTF-8"))
case("eval/GT missing", EVAL_GT, "nope.txt", ESF, Err(text="no such file"))
case("eval/GT binary", EVAL_GT, G_, {G_: GARBAGE, **ESF}, Err(line=1, text="binary"))
case("eval/GT huge id", EVAL_GT, G_, {G_: gt_txt() + f"{10**30} 1 0 0 0\n", **ESF}, Err(line=7, text="too large"))
case("eval/GT .mat without Rgt", EVAL_GT, "x.mat", {"x.mat": write_mat(RR=np.eye(3)[:, :, None], I=np.array([[1], [2]])), **ESF},
     Err(text="no absolute rotations"))
case("eval/GT .mat with wrong variables", EVAL_GT, "x.mat", {"x.mat": write_mat(A=np.eye(3)), **ESF}, Err(text="'RR' missing"))
case("eval/GT corrupt Bundler file", EVAL_GT, "gt_bundle.out", {"gt_bundle.out": "# Bundle file v0.3\n2 0\n1 0 0\n", **ESF}, Err(line=3, text="truncated"))
def colmap_truncated_model(p: Path) -> None:
    colmap_copy(p, keep=("sparse",))
    images = p / "sparse" / "0" / "images.bin"
    images.write_bytes(images.read_bytes()[:1000])


case("eval/GT corrupt COLMAP model", EVAL_GT, "proj/sparse/0", {"proj": colmap_truncated_model, **ESF}, Err(text="sparse model"))
case("eval/GT colmap folder without a model", EVAL_GT, "proj", {"proj": colmap_empty_db, **ESF}, Err(text="no COLMAP sparse model"))

# ---------------------------------------------------------------- mean
R_ = "rot.txt"
case("mean/valid", MEAN, R_, {R_: rotations_txt()}, Ok())
case("mean/one rotation", MEAN, R_, {R_: f"{nums(wxyz(R_GT[1]))}\n"}, Ok(mean_is(R_GT[1])))
case("mean/non-unit quaternions are normalised, with a warning", MEAN, R_,
     {R_: f"{nums(5 * wxyz(R_GT[1]))}\n{nums(-0.5 * wxyz(R_GT[1]))}\n"}, Ok(warned("not unit length", mean_is(R_GT[1]))))
case("mean/empty", MEAN, R_, {R_: b""}, Err(line=1, text="empty"))
case("mean/comments only", MEAN, R_, {R_: "# qw qx qy qz\n"}, Err(line=1, text="empty"))
case("mean/truncated line", MEAN, R_, {R_: "1 0 0 0\n1 0"}, Err(line=2, text="expected 4 or 5 fields"))
case("mean/non-numeric", MEAN, R_, {R_: "1 0 0 0\n1 0 O 0\n"}, Err(line=2, text="not a number"))
case("mean/nan", MEAN, R_, {R_: "1 0 0 0\nnan 0 0 0\n"}, Err(line=2, text="not finite"))
case("mean/inf weight", MEAN, R_, {R_: "1 0 0 0 1\n1 0 0 0 inf\n"}, Err(line=2, text="not finite"))
case("mean/zero quaternion", MEAN, R_, {R_: "1 0 0 0\n0 0 0 0\n"}, Err(line=2, text="zero quaternion"))
case("mean/negative weight", MEAN, R_, {R_: "1 0 0 0 1\n1 0 0 0 -1\n"}, Err(line=2, text="negative weight"))
case("mean/all weights zero", MEAN, R_, {R_: "1 0 0 0 0\n1 0 0 0 0\n"}, Err(line=1, text="weights are zero"))
case("mean/binary", MEAN, R_, {R_: GARBAGE}, Err(line=1, text="binary"))
case("mean/latin-1", MEAN, R_, {R_: "1 0 0 0\n# caf\xe9\n".encode("latin-1")}, Err(line=2, text="UTF-8"))
case("mean/UTF-16", MEAN, R_, {R_: "1 0 0 0\n".encode("utf-16")}, Err(line=1, text="UTF-16"))
case("mean/missing", MEAN, "nope.txt", {}, Err(text="no such file"))
case("mean/a folder", MEAN, "dir", {"dir": folder_with()}, Err(text="folder"))
case("mean/csv header only", MEAN, "r.csv", {"r.csv": "qw,qx,qy,qz\n"}, Err(line=1, text="no rotations"))
case("mean/csv missing column", MEAN, "r.csv", {"r.csv": "qw,qx,qy\n1,0,0\n"}, Err(line=1, text="lacks column(s) qz"))
case("mean/csv truncated row", MEAN, "r.csv", {"r.csv": "qw,qx,qy,qz\n1,0,0,0\n1,0"}, Err(line=3, text="expected 4 fields"))

# ---------------------------------------------------------------- handeye (motions; --poses)
A_, B_ = "A.txt", "B.txt"
MA, MB = motions_txt(L_MOT), motions_txt(R_MOT)
case("handeye/valid", HANDEYE_A, A_, {A_: MA, B_: MB}, Ok(handeye_is(S_TRUE)))
case("handeye/non-unit quaternions are normalised, with a warning", HANDEYE_A, A_,
     {A_: motions_txt(L_MOT, 2.0), B_: motions_txt(R_MOT, 0.5)}, Ok(warned("not unit length", handeye_is(S_TRUE))))
case("handeye/A empty", HANDEYE_A, A_, {A_: b"", B_: MB}, Err(line=1, text="empty"))
case("handeye/B empty", HANDEYE_B, B_, {A_: MA, B_: b""}, Err(line=1, text="empty"))
case("handeye/A shorter than B", HANDEYE_A, A_, {A_: motions_txt(L_MOT[:5]), B_: MB}, Err(line=7, text="5 rotations in this file but 6"))
case("handeye/B shorter than A", HANDEYE_B, B_, {A_: MA, B_: motions_txt(R_MOT[:4])}, Err(line=6, text="4 rotations in this file but 6"))
case("handeye/A truncated line", HANDEYE_A, A_, {A_: MA + "1 0", B_: MB}, Err(line=8, text="expected 4 or 5 fields"))
case("handeye/B nan", HANDEYE_B, B_, {A_: MA, B_: motions_txt(R_MOT[:2]) + "nan 0 0 1\n" + motions_txt(R_MOT[3:])[14:]},
     Err(line=4, text="not finite"))
case("handeye/A zero quaternion", HANDEYE_A, A_, {A_: "0 0 0 0\n" + MA, B_: "1 0 0 0\n" + MB}, Err(line=1, text="zero quaternion"))
case("handeye/A binary", HANDEYE_A, A_, {A_: GARBAGE, B_: MB}, Err(line=1, text="binary"))
case("handeye/B UTF-16", HANDEYE_B, B_, {A_: MA, B_: MB.encode("utf-16")}, Err(line=1, text="UTF-16"))
case("handeye/B missing", HANDEYE_B, "nope.txt", {A_: MA}, Err(text="no such file"))
case("handeye/A a folder", HANDEYE_A, "dir", {"dir": folder_with(), B_: MB}, Err(text="folder"))
case("handeye/all weights zero", HANDEYE_A, A_, {A_: "".join(line + " 0\n" for line in MA.splitlines()[1:]), B_: MB},
     Err(line=1, text="weights are zero"))
P16A, P16B = poses_16(G_POSE), poses_16(C_POSE)
case("handeye --poses/valid", POSES_A, A_, {A_: P16A, B_: P16B}, Ok(handeye_is(S_TRUE)))
case("handeye --poses/'qw qx qy qz tx ty tz', non-unit: normalised, with a warning", POSES_A, A_,
     {A_: "".join(f"{nums(3 * wxyz(R))} 0 0 0\n" for R in G_POSE), B_: "".join(f"{nums(wxyz(R))} 0 0 0\n" for R in C_POSE)},
     Ok(warned("not unit length", handeye_is(S_TRUE))))
case("handeye --poses/last row not 0 0 0 1", POSES_A, A_, {A_: P16A.replace(" 0.0 0.0 0.0 1.0\n", " 0.0 0.0 1.0 1.0\n", 1), B_: P16B},
     Err(line=1, text="0 0 0 1"))
case("handeye --poses/reflection", POSES_A, A_, {A_: P16A + poses_16([-np.eye(3)]), B_: P16B + poses_16([np.eye(3)])},
     Err(line=7, text="reflection"))
case("handeye --poses/not orthonormal", POSES_A, A_, {A_: P16A + poses_16([1.1 * np.eye(3)]), B_: P16B + poses_16([np.eye(3)])},
     Err(line=7, text="not orthonormal"))
case("handeye --poses/mixed layouts", POSES_A, A_, {A_: P16A + "1 0 0 0 0 0 0\n", B_: P16B}, Err(line=7, text="like the first pose line"))
case("handeye --poses/unknown layout", POSES_A, A_, {A_: "1 0 0 0 0\n", B_: P16B}, Err(line=1, text="expected a pose"))
case("handeye --poses/nan", POSES_A, A_, {A_: P16A.replace("1.0", "nan", 1), B_: P16B}, Err(line=1, text="not finite"))
case("handeye --poses/latin-1", POSES_A, A_, {A_: P16A.encode() + "# \xe9\n".encode("latin-1"), B_: P16B}, Err(line=7, text="UTF-8"))

# ---------------------------------------------------------------- batch: its @LIST file (no Dask cluster is started)
L_ = "list.txt"
case("batch/list file missing", BATCH, "nope.txt", {}, Err(text="no such file"))
case("batch/list file binary", BATCH, L_, {L_: GARBAGE}, Err(line=1, text="binary"))
case("batch/list file UTF-16", BATCH, L_, {L_: "e.txt\n".encode("utf-16")}, Err(line=1, text="UTF-16"))
case("batch/list file latin-1", BATCH, L_, {L_: "e.txt\ncaf\xe9.txt\n".encode("latin-1")}, Err(line=2, text="UTF-8"))
case("batch/list file is a folder", BATCH, "dir", {"dir": folder_with()}, Err(text="folder"))
case("batch/list file empty", BATCH, L_, {L_: b""}, Err(text="no input"))
case("batch/list file with comments only", BATCH, L_, {L_: "# nothing yet\n"}, Err(text="no input"))
case("batch/list naming missing files: failed in the manifest, exit 1", BATCH, L_, {L_: "a.txt\nb.txt\n"},
     Ok(batch_manifest(["failed", "failed"], ["no such file", "no such file"]), code=1))


# ============================================================================ running a case


OLD = {"out.csv": b"id,name,qw,qx,qy,qz\nold,old,1.0,0.0,0.0,0.0\n", "edges.csv": b"i,j,residual_deg,inlier\nold,old,0.0,1\n",
       # earlier outputs of rotgraph (as io.outputs.is_rotgraph_output knows them: a file of the user's is test_overwrite's)
       "plot.png": b"\x89PNG old plot, tEXtSoftware\x00rotgraph", "batch/manifest.json": b'[\n  {\n    "input": "old"\n  }\n]\n',
       "batch/e.csv": b"id,name,qw,qx,qy,qz\n"}


def snapshot(folder: Path) -> dict:
    """Every file and folder under ``folder``: bytes and mtime (so new and removed files show
    too, even a temporary file created and deleted again: its folder's mtime changes)."""
    out = {}
    for p in [folder, *sorted(folder.rglob("*"))]:
        st = p.lstat()
        out[str(p.relative_to(folder))] = (p.read_bytes() if p.is_file() else "dir", st.st_mtime_ns)
    return out


def make_inputs(indir: Path, files: dict) -> None:
    indir.mkdir()
    for name, content in files.items():
        p = indir / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if callable(content):
            content(p)
        elif isinstance(content, bytes):
            p.write_bytes(content)
        else:
            p.write_bytes(content.encode("utf-8"))
    past = time.time() - 1000  # so that a rewrite would show in the mtime even on coarse clocks
    for p in [indir, *indir.rglob("*")]:
        os.utime(p, (past, past))


def make_outputs(outdir: Path) -> None:
    for name, content in OLD.items():
        p = outdir / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(content)
    past = time.time() - 1000
    for p in [outdir, *outdir.rglob("*")]:
        os.utime(p, (past, past))


@dataclass
class Ctx:
    result: object
    out: Path
    records: list = field(default_factory=list)


@dataclass
class Run:
    exit_code: int
    stdout: str
    stderr: str
    output: str = ""


def check_error_output(r: Run, expect: Err, named: Path) -> None:
    assert "Traceback" not in r.output + r.stderr, r.output
    if r.exit_code == 2:  # click's usage error: 'Usage: ...', then 'Error: ...'
        assert "Error: " in r.stderr and expect.text in r.stderr, r.stderr
        return
    lines = r.stderr.splitlines()
    errors = [s for s in lines if s.startswith("rotgraph: error:")]
    assert len(errors) == 1, r.stderr
    assert lines[-1] == errors[0], r.stderr
    assert all(s.startswith("rotgraph: warning:") for s in lines[:-1]), r.stderr
    msg = errors[0]
    if r.exit_code == 3:
        where = f"rotgraph: error: {named}:" + (f"{expect.line}: " if expect.line is not None else " ")
        assert msg.startswith(where), f"expected {where!r}..., got {msg!r}"
    assert expect.text in msg, msg


def run_case(c: Case, tmp_path: Path, invoke, records=()) -> Run:
    """Write the inputs and old outputs, run ``invoke(argv) -> Run``, check what CLI.md says."""
    indir, outdir = tmp_path / "in", tmp_path / "out"
    make_inputs(indir, c.files)
    make_outputs(outdir)
    argv = [a.format(**{"in": indir / c.input, "i": indir, "o": outdir}) for a in c.argv]
    before_in, before_out = snapshot(indir), snapshot(outdir)
    r = invoke(argv)
    print(r.stderr)  # shown by pytest -rA: the corpus' messages, for review
    assert snapshot(indir) == before_in, "an input was modified, or a file appeared beside it"
    after_out = snapshot(outdir)
    leftovers = [k for k in after_out if k.endswith(".tmp")]
    assert not leftovers, leftovers
    if isinstance(c.expect, Err):
        codes = c.expect.code if isinstance(c.expect.code, tuple) else (c.expect.code,)
        assert r.exit_code in codes, (r.exit_code, r.output)
        named = Path(c.expect.file.format(o=outdir)) if c.expect.file and "{" in c.expect.file else indir / (c.expect.file or c.input)
        check_error_output(r, c.expect, named)
        assert after_out == before_out, "an output was touched"
    else:
        assert r.exit_code == c.expect.code, r.output
        assert "Traceback" not in r.output + r.stderr
        if c.expect.check is not None:
            c.expect.check(Ctx(r, outdir, list(records)))
    return r


@pytest.mark.parametrize("c", [pytest.param(c, id=c.id, marks=c.marks) for c in CASES])
def test_bad_input(c: Case, tmp_path, caplog):
    def invoke(argv) -> Run:
        with caplog.at_level(logging.WARNING):
            r = CliRunner().invoke(cli, argv)
        assert r.exception is None or isinstance(r.exception, SystemExit), (
            f"{type(r.exception).__name__}: {r.exception}\n" + "".join(traceback.format_exception(*r.exc_info)))
        return Run(r.exit_code, r.stdout, r.stderr, r.output)

    run_case(c, tmp_path, invoke, caplog.records)


# Rows re-run through the installed executable: the real stderr is that one error line, after
# the warnings, if any (the g2o row logs one for its skipped FIX line, then fails).
ENTRY_POINT_ROWS = {  # id -> number of stderr lines
    "solve/txt binary garbage": 1,
    "solve/txt UTF-16 with BOM": 1,
    "solve/g2o a warning, then an error": 2,
    "solve/colmap garbage database.db": 1,
    "solve/every edge rejected by the robust loss": 1,
    "eval/GT only unknown ids": 1,
    "mean/zero quaternion": 1,
    "handeye/A shorter than B": 1,
    "batch/list file missing": 1,
}


@pytest.mark.parametrize("c", [pytest.param(c, id=c.id) for c in CASES if c.id in ENTRY_POINT_ROWS])
def test_real_entry_point(c: Case, tmp_path):
    def invoke(argv) -> Run:
        p = subprocess.run([ROTGRAPH_EXE, *map(str, argv)], capture_output=True, text=True, timeout=120)
        return Run(p.returncode, p.stdout, p.stderr, p.stdout + p.stderr)

    r = run_case(c, tmp_path, invoke)
    assert len(r.stderr.splitlines()) == ENTRY_POINT_ROWS[c.id], r.stderr


# ============================================================================ SIGKILL at any moment

BIG_N = 6000  # ~2.5 s for 'rotgraph solve' on one core (read ~0.5 s, solve ~1.5 s, write)


@pytest.fixture(scope="module")
def big_problem(tmp_path_factory) -> tuple[Path, int]:
    from rotgraph.io.writers import write_edges
    from rotgraph.synth import random_problem

    folder = tmp_path_factory.mktemp("big")
    g = random_problem(n=BIG_N, degree=30, sigma_deg=2.0, outliers=0.1, graph="er", seed=5)
    write_edges(folder / "edges.txt", g)
    return folder / "edges.txt", g.n_edges


def _tmp_files(folder: Path) -> list[str]:
    return [e.name for e in os.scandir(folder) if e.name.endswith(".tmp")]


def _kill_group(p: subprocess.Popen) -> None:
    """SIGKILL the process group started for ``p`` (the command and any workers it spawned)."""
    try:
        os.killpg(p.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    p.wait(timeout=30)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 20:  # orphaned workers die with the group; wait until they are gone
        try:
            os.killpg(p.pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.05)
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except ProcessLookupError:
            return


def _old_or_complete(path: Path, old: bytes, n_rows: int, header: str) -> str:
    """'old' or 'new'; anything else (a partial or corrupt file) fails."""
    data = path.read_bytes()
    if data == old:
        return "old"
    text = data.decode("utf-8")
    assert text.endswith("\n"), f"{path} ends mid-line"
    lines = text.splitlines()
    assert lines[0].startswith(header) and len(lines) == n_rows + 1, (path, lines[0], len(lines))
    return "new"


@pytest.mark.parametrize("moment", ["0.05 s", "0.5 s", "1.5 s", "when .out.csv.*.tmp appears", "when .edges.csv.*.tmp appears",
                                    "after exit"])
def test_solve_killed_at_any_moment_leaves_old_or_complete_output(big_problem, tmp_path, moment):
    edges, n_edges = big_problem
    out, eout = tmp_path / "out.csv", tmp_path / "edges.csv"
    old, eold = b"id,name,qw,qx,qy,qz\nold,old,1.0,0.0,0.0,0.0\n", b"i,j,residual_deg,inlier\n"
    out.write_bytes(old)
    eout.write_bytes(eold)
    before = (edges.stat().st_mtime_ns, edges.stat().st_size)
    p = subprocess.Popen([ROTGRAPH_EXE, "solve", str(edges), "-o", str(out), "--edges-out", str(eout), "-q"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    caught = None
    try:
        if moment == "after exit":
            assert p.wait(timeout=120) == 0, p.stderr.read()
        elif moment.endswith(" s"):
            time.sleep(float(moment.split()[0]))
        else:
            t0 = time.monotonic()
            prefix = moment.split()[1].split("*")[0]
            while p.poll() is None and time.monotonic() - t0 < 120:
                caught = [n for n in _tmp_files(tmp_path) if n.startswith(prefix)]
                if caught:
                    break
    finally:
        _kill_group(p)
    states = (_old_or_complete(out, old, BIG_N, "id,name,qw,qx,qy,qz"),
              _old_or_complete(eout, eold, n_edges, "i,j,residual_deg,inlier"))
    if states[0] == "new":
        sol = read_solution(out)
        assert len(sol) == BIG_N
    if moment == "after exit":
        assert states == ("new", "new") and not _tmp_files(tmp_path)
    if moment == "0.05 s":
        assert states == ("old", "old")
    # A kill between the creation and the rename of a temporary file may leave it behind
    # (atomic_write: documented); it is hidden ('.out.csv.*.tmp'), never the target.
    assert all(name.startswith((".out.csv.", ".edges.csv.")) for name in _tmp_files(tmp_path))
    assert (edges.stat().st_mtime_ns, edges.stat().st_size) == before
    print(moment, states, "caught", caught)


@pytest.mark.slow
def test_batch_killed_mid_run_leaves_old_or_complete_outputs(tmp_path):
    """SIGKILL ``rotgraph batch`` (and its Dask workers) once the first result is being
    written: every ``<stem>.csv`` and ``manifest.json`` is the old file or a complete new one."""
    pytest.importorskip("distributed")
    from rotgraph.io.writers import write_edges
    from rotgraph.synth import random_problem

    inputs = []
    for k in range(3):
        g = random_problem(n=2000, degree=20, sigma_deg=2.0, outliers=0.1, graph="er", seed=10 + k)
        write_edges(tmp_path / f"p{k}.txt", g)
        inputs.append(tmp_path / f"p{k}.txt")
    out = tmp_path / "results"
    out.mkdir()
    old = b"id,name,qw,qx,qy,qz\nold,old,1.0,0.0,0.0,0.0\n"
    old_manifest = b'[\n  {\n    "input": "old"\n  }\n]\n'
    for k in range(3):
        (out / f"p{k}.csv").write_bytes(old)
    (out / "manifest.json").write_bytes(old_manifest)
    p = subprocess.Popen([ROTGRAPH_EXE, "batch", *map(str, inputs), "--out-dir", str(out), "--workers", "1", "-q"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        t0 = time.monotonic()
        while p.poll() is None and time.monotonic() - t0 < 120:
            if any(n.startswith(".p") for n in _tmp_files(out)) or any((out / f"p{k}.csv").read_bytes() != old for k in range(3)):
                break
    finally:
        _kill_group(p)
    print([_old_or_complete(out / f"p{k}.csv", old, 2000, "id,name,qw,qx,qy,qz") for k in range(3)], _tmp_files(out))
    for k in range(3):
        _old_or_complete(out / f"p{k}.csv", old, 2000, "id,name,qw,qx,qy,qz")
    data = (out / "manifest.json").read_bytes()
    if data != old_manifest:
        manifest = json.loads(data)
        assert len(manifest) == 3 and all(e["status"] in ("ok", "pending", "failed") for e in manifest)
    assert all(n.startswith(".") for n in _tmp_files(out))
