"""Property tests: random mutations of valid input files give a valid result or the clean
InputError (file and, where there is one, line) -- never another exception."""


import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rotgraph import so3
from rotgraph.errors import InputError
from rotgraph.io.rotations import read_absolute_rotations
from rotgraph.pipeline.read import read_view_graph
from rotgraph.io.handeye import read_poses
from rotgraph.io.rotations import read_weighted_quaternions


def _valid_files() -> dict[str, str]:
    R = so3.random_rotations(5, 0)
    q = so3.quaternions_from_matrices(R)
    pairs = [(0, 1), (1, 2), (2, 3), (3, 4), (0, 4), (1, 3)]
    rel = [so3.quaternions_from_matrices(R[j] @ R[i].T) for i, j in pairs]
    fmt = lambda v: " ".join(f"{x:.6f}" for x in v)  # noqa: E731
    xyzw = lambda v: fmt(np.roll(v, -1))  # noqa: E731
    return {
        "edges.txt": "# i j qw qx qy qz w\n" + "".join(f"{i} {j} {fmt(r)} 1\n" for (i, j), r in zip(pairs, rel)),
        "edges.csv": "i,j,qw,qx,qy,qz,weight\n" + "".join(f"{i},{j},{fmt(r).replace(' ', ',')},2\n" for (i, j), r in zip(pairs, rel)),
        "glomap.txt": "".join(f"im{i}.jpg im{j}.jpg {fmt(r)} 0 0 1\n" for (i, j), r in zip(pairs, rel)),
        "graph.g2o": "".join(f"VERTEX_SE3:QUAT {k} 0 0 0 {xyzw(qk * [1, -1, -1, -1])}\n" for k, qk in enumerate(q))
        + "".join(f"EDGE_SE3:QUAT {i} {j} 0 0 0 {xyzw(r * [1, -1, -1, -1])} " + " ".join(["1"] + ["0"] * 20) + "\n" for (i, j), r in zip(pairs, rel)),
        "gt.txt": "".join(f"{k} {fmt(qk)}\n" for k, qk in enumerate(q)),
        "rot.txt": "".join(f"{fmt(qk)} 1.5\n" for qk in q),
        # 1DSfM EGs.txt: i j r11..r33 t1 t2 t3 (R_ij = R_j R_i^T as rotgraph reads it)
        "EGs.txt": "".join(f"{i} {j} " + " ".join(f"{x:.9f}" for x in (R[j] @ R[i].T).ravel()) + " 0 0 1\n" for i, j in pairs),
        # hand-eye poses: 4x4 row-major a line, and 'qw qx qy qz tx ty tz' lines
        "poses44.txt": "".join(" ".join(f"{x:.9f}" for x in np.vstack([np.hstack([Rk, [[1.0], [2.0], [3.0]]]), [[0, 0, 0, 1]]]).ravel()) + "\n" for Rk in R),
        "poses7.txt": "".join(f"{fmt(qk)} 0.1 0.2 0.3\n" for qk in q),
    }


VALID = _valid_files()
READERS = {
    "edges.txt": lambda p: read_view_graph(p),
    "edges.csv": lambda p: read_view_graph(p),
    "glomap.txt": lambda p: read_view_graph(p, "glomap"),
    "graph.g2o": lambda p: read_view_graph(p, "g2o"),
    "gt.txt": lambda p: read_absolute_rotations(p),
    "rot.txt": lambda p: read_weighted_quaternions(p),
    "EGs.txt": lambda p: read_view_graph(p, "1dsfm"),
    "poses44.txt": lambda p: read_poses(p),
    "poses7.txt": lambda p: read_poses(p),
}


def test_the_valid_files_are_valid(tmp_path):
    for name, text in VALID.items():
        p = tmp_path / name
        p.write_text(text)
        READERS[name](p)


def _mutate(text: str, data) -> bytes:
    raw = bytearray(text.encode())
    kind = data.draw(st.sampled_from(["byte", "delete", "insert", "line", "truncate", "token"]))
    if kind == "byte" and raw:
        k = data.draw(st.integers(0, len(raw) - 1))
        raw[k] = data.draw(st.integers(0, 255))
    elif kind == "delete" and raw:
        a = data.draw(st.integers(0, len(raw) - 1))
        del raw[a : a + data.draw(st.integers(1, 20))]
    elif kind == "insert":
        k = data.draw(st.integers(0, len(raw)))
        raw[k:k] = data.draw(st.binary(min_size=1, max_size=12))
    elif kind == "truncate":
        raw = raw[: data.draw(st.integers(0, len(raw)))]
    else:
        lines = text.splitlines(keepends=True)
        k = data.draw(st.integers(0, len(lines) - 1))
        tokens = lines[k].split()
        if kind == "line":
            lines[k] = data.draw(st.sampled_from(["\n", "nan nan\n", lines[k] * 2, "0 0 0 0 0 0 0\n", "\x00\n"]))
        elif tokens:
            t = data.draw(st.integers(0, len(tokens) - 1))
            tokens[t] = data.draw(st.sampled_from(["nan", "inf", "-1", "x", "0", "1e400", "", "99999999999999999999", "é"]))
            lines[k] = " ".join(tokens) + "\n"
        raw = bytearray("".join(lines).encode())
    return bytes(raw)


@pytest.mark.parametrize("name", sorted(VALID))
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_mutations_give_result_or_clean_error(tmp_path, name, data):
    p = tmp_path / name
    p.write_bytes(_mutate(VALID[name], data))
    try:
        READERS[name](p)
    except InputError as exc:
        msg = str(exc)
        assert str(p) in msg and "\n" not in msg.strip()


EXTREMES = ["0", "1e308", "-1.7e308", "1e-320", "5e-324", "1e200", "-1e200", "1e-160", "1e160", "2", "-1"]


@pytest.mark.parametrize("name", sorted(VALID))
def test_extreme_numbers_give_result_or_clean_error_and_no_numpy_warning(tmp_path, name):
    """Numbers near the float limits (overflowing squares, subnormals) in any numeric field:
    a result or the clean InputError, and no numpy RuntimeWarning on the way (it would be
    printed to the user's terminal beside the one-line error)."""
    import random
    import warnings

    rng = random.Random(0)
    src = VALID[name].splitlines(keepends=True)
    sep = "," if name.endswith(".csv") else " "
    p = tmp_path / name
    for _ in range(300):
        lines = list(src)
        k = rng.randrange(len(lines))
        if lines[k].startswith("#"):
            continue
        toks = lines[k].strip().split(sep)
        for _ in range(rng.randint(1, 8)):
            toks[rng.randrange(len(toks))] = rng.choice(EXTREMES)
        lines[k] = sep.join(toks) + "\n"
        p.write_text("".join(lines))
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            try:
                READERS[name](p)
            except InputError as exc:
                assert str(p) in str(exc) and "\n" not in str(exc).strip()
