"""One API shape (issue #30 item 6): every public function and class of ``rotgraph.__all__``
has a NumPy-style docstring, and a bad option value is an :class:`~rotgraph.errors.OptionError`
(a :class:`~rotgraph.errors.RotgraphError` and still a ``ValueError``), never a plain
``ValueError``."""

import inspect
import re

import numpy as np
import pytest

import rotgraph
from rotgraph.errors import OptionError, RotgraphError


def _public_objects():
    out = []
    for name in rotgraph.__all__:
        obj = getattr(rotgraph, name)
        if not inspect.ismodule(obj):  # rotgraph.so3 and rotgraph.losses are modules
            assert inspect.isclass(obj) or callable(obj), name
            out.append((name, obj))
    return out


def _sections(doc: str) -> set[str]:
    """The NumPy-style section titles of ``doc``: a line followed by a line of dashes."""
    lines = inspect.cleandoc(doc).splitlines()
    return {lines[k].strip() for k in range(len(lines) - 1)
            if lines[k].strip() and re.fullmatch(r"-{3,}", lines[k + 1].strip())}


def test_every_public_name_imports():
    for name in rotgraph.__all__:
        assert getattr(rotgraph, name) is not None, name
    assert "OptionError" in rotgraph.__all__ and rotgraph.OptionError is OptionError


@pytest.mark.parametrize("name,obj", _public_objects(), ids=[n for n, _ in _public_objects()])
def test_public_docstring_has_numpy_sections(name, obj):
    doc = obj.__doc__
    assert doc and doc.strip(), f"{name} has no docstring"
    sections = _sections(doc)
    if inspect.isclass(obj):
        assert sections & {"Parameters", "Attributes"}, f"{name}: no Parameters or Attributes section"
    else:
        assert "Parameters" in sections, f"{name}: no Parameters section"
        assert "Returns" in sections, f"{name}: no Returns section"


def test_option_error_is_a_rotgraph_error_and_a_value_error():
    assert issubclass(OptionError, RotgraphError)
    assert issubclass(OptionError, ValueError)


@pytest.mark.parametrize("field,value", [
    ("method", "nope"), ("init", "nope"), ("linear_solver", "nope"), ("rig_extrinsics", "nope"),
    ("nodewise_norm", "l3"), ("loss", "nope"), ("loss_scale_deg", 0.0), ("outlier_threshold_deg", -1.0),
    ("step_tol_deg", -1.0), ("stage_tol_deg", -1.0),
])
def test_bad_solve_options_raise_option_error(field, value):
    with pytest.raises(OptionError):
        rotgraph.SolveOptions(**{field: value}).validated()
    with pytest.raises(ValueError):  # users' ``except ValueError`` keeps working
        rotgraph.SolveOptions(**{field: value}).validated()


def test_good_solve_options_validate_to_themselves():
    opts = rotgraph.SolveOptions()
    assert opts.validated() is opts


def test_bad_option_values_of_the_entry_points_raise_option_error(tmp_path):
    graph = rotgraph.random_problem(n=10, degree=4, seed=0)
    R = rotgraph.so3.random_rotations(5, rng=0)
    cases = [
        lambda: rotgraph.average_rotations(graph, method="nope"),
        lambda: rotgraph.average_rotations(graph, loss_scale_deg=-1.0),
        lambda: rotgraph.default_options("rotgraph", method="nope"),
        lambda: rotgraph.mean(R, metric="nope"),
        lambda: rotgraph.mean(R, norm="nope"),
        lambda: rotgraph.mean(R, norm="robust", loss="nope"),
        lambda: rotgraph.mean(R, norm="robust", scale_deg=-1.0),
        lambda: rotgraph.solve_handeye(R, R, method="nope"),
        lambda: rotgraph.solve_handeye(R, R, threshold_deg=0.0),
        lambda: rotgraph.motions_from_poses(R, R, pairs="nope"),
        lambda: rotgraph.certify(graph.gt_cam_from_world, graph.edges, graph.cam2_from_cam1, method="nope"),
        lambda: rotgraph.certify(graph.gt_cam_from_world, graph.edges, graph.cam2_from_cam1, tol=-1.0),
        lambda: rotgraph.refine_chordal(graph.gt_cam_from_world, graph.edges, graph.cam2_from_cam1, method="nope"),
        lambda: rotgraph.random_problem(n=1),
        lambda: rotgraph.random_problem(graph="nope"),
        lambda: rotgraph.random_problem(sigma_deg=-1.0),
        lambda: rotgraph.random_problem(noise_mix="nope"),
        lambda: rotgraph.read_view_graph(tmp_path / "edges.txt", fmt="nope"),
        lambda: rotgraph.read_view_graph(tmp_path / "edges.txt", duplicates="nope"),
        lambda: rotgraph.read_absolute_rotations(tmp_path / "gt.txt", fmt="nope"),
        lambda: rotgraph.ViewGraph.from_edges([0], [1], np.eye(3)[None], duplicates="nope"),
        lambda: rotgraph.losses.check_loss("nope"),
    ]
    for call in cases:
        with pytest.raises(OptionError):
            call()
