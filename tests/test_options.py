"""One API shape (issue #30): every estimator takes an options object and keyword overrides of
its fields, as ``average_rotations(graph, options, **overrides)`` does (one mechanism:
:func:`rotgraph.options.resolve_options`): ``mean`` with :class:`MeanOptions`,
``solve_handeye`` with :class:`HandEyeOptions`, ``certify`` with :class:`CertifyOptions`,
``refine_chordal`` with :class:`RefineOptions`, ``random_problem`` with :class:`ProblemOptions`;
an earlier version's positional arguments through :func:`rotgraph.options.legacy_positional`."""

import dataclasses

import numpy as np
import pytest

import rotgraph
from rotgraph import so3
from rotgraph.errors import OptionError, UnknownOptionError
from rotgraph.options import resolve_options

from rotgraph.synth import RigProblemOptions, random_rig_problem  # noqa: E402

OPTION_CLASSES = [rotgraph.SolveOptions, rotgraph.MeanOptions, rotgraph.HandEyeOptions, rotgraph.CertifyOptions,
                  rotgraph.RefineOptions, rotgraph.ProblemOptions, RigProblemOptions]

BAD_VALUES = [
    (rotgraph.MeanOptions, "metric", "euclidean"),
    (rotgraph.MeanOptions, "norm", "linf"),
    (rotgraph.MeanOptions, "loss", "nope"),
    (rotgraph.MeanOptions, "scale_deg", 0.0),
    (rotgraph.MeanOptions, "scale_deg", float("nan")),
    (rotgraph.MeanOptions, "max_iterations", -1),
    (rotgraph.MeanOptions, "step_tol_rad", -1e-9),
    (rotgraph.HandEyeOptions, "method", "tsai"),
    (rotgraph.HandEyeOptions, "loss", "nope"),
    (rotgraph.HandEyeOptions, "scale_deg", -1.0),
    (rotgraph.HandEyeOptions, "threshold_deg", 0.0),
    (rotgraph.HandEyeOptions, "max_hypotheses", 0),
    (rotgraph.HandEyeOptions, "max_iterations", -1),
    (rotgraph.HandEyeOptions, "step_tol_rad", -1.0),
    (rotgraph.CertifyOptions, "method", "arpack"),
    (rotgraph.CertifyOptions, "tol", -1e-4),
    (rotgraph.CertifyOptions, "stationarity_tol", -1.0),
    (rotgraph.CertifyOptions, "gap_tol", float("nan")),
    (rotgraph.CertifyOptions, "max_iterations", -5),
    (rotgraph.RefineOptions, "method", "lbfgs"),
    (rotgraph.RefineOptions, "max_iterations", -1),
    (rotgraph.RefineOptions, "stationarity_tol", float("nan")),
    (rotgraph.ProblemOptions, "graph", "grid"),
    (rotgraph.ProblemOptions, "outlier_model", "nope"),
    (rotgraph.ProblemOptions, "sigma_deg", -1.0),
    (rotgraph.ProblemOptions, "noise_mix", "half"),
    (rotgraph.ProblemOptions, "uncertainty_spread", 0.5),
    (RigProblemOptions, "known", "some"),
]


@pytest.mark.parametrize("cls,field,value", BAD_VALUES, ids=[f"{c.__name__}.{f}={v}" for c, f, v in BAD_VALUES])
def test_a_bad_value_is_an_option_error_naming_the_field(cls, field, value):
    with pytest.raises(OptionError, match=field) as info:
        cls(**{field: value}).validated()
    assert "\n" not in str(info.value)
    assert isinstance(info.value, ValueError)  # users' ``except ValueError`` keeps working


@pytest.mark.parametrize("cls", OPTION_CLASSES, ids=lambda c: c.__name__)
def test_options_are_frozen_documented_and_their_defaults_valid(cls):
    opts = cls()
    assert opts.validated() is opts
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(opts, dataclasses.fields(cls)[0].name, None)
    for f in dataclasses.fields(cls):  # every field in the Parameters section
        assert f"\n    {f.name} : " in cls.__doc__, f"{cls.__name__}.{f.name} is not documented"


def test_resolve_options():
    opts = rotgraph.MeanOptions(norm="l1")
    assert resolve_options(rotgraph.MeanOptions, None, {}) == rotgraph.MeanOptions()
    assert resolve_options(rotgraph.MeanOptions, opts, {}) is opts
    assert resolve_options(rotgraph.MeanOptions, opts, {"metric": "chordal"}) == rotgraph.MeanOptions("chordal", "l1")
    with pytest.raises(UnknownOptionError, match="'tol'.*step_tol_rad"):
        resolve_options(rotgraph.MeanOptions, opts, {"tol": 1e-6})
    with pytest.raises(OptionError, match="MeanOptions"):
        resolve_options(rotgraph.MeanOptions, rotgraph.HandEyeOptions(), {})
    with pytest.raises(OptionError, match="norm"):
        resolve_options(rotgraph.MeanOptions, opts, {"norm": "l3"})


@pytest.fixture(scope="module")
def rotations():
    R = so3.perturb(np.repeat(so3.random_rotations(1, rng=1), 120, 0), 0.1, rng=2)
    R[:20] = so3.random_rotations(20, rng=3)
    return R


def _same_mean(a, b):
    return (np.array_equal(a.quaternion, b.quaternion) and a.cost == b.cost and a.iterations == b.iterations
            and a.scale == b.scale)


@pytest.mark.parametrize("fields", [
    dict(), dict(metric="chordal", norm="l1"), dict(metric="quaternion", norm="l2"),
    dict(norm="robust", loss="huber", scale_deg=3.0, max_iterations=30, step_tol_rad=1e-8),
])
def test_mean_options_object_and_keywords_give_identical_results(rotations, fields):
    w = np.linspace(0.5, 2.0, len(rotations))
    by_keyword = rotgraph.mean(rotations, weights=w, **fields)
    by_object = rotgraph.mean(rotations, rotgraph.MeanOptions(**fields), weights=w)
    assert _same_mean(by_keyword, by_object)
    base = {k: v for k, v in fields.items() if k != "metric"}
    overridden = rotgraph.mean(rotations, rotgraph.MeanOptions(metric="quaternion", **base), weights=w,
                               metric=fields.get("metric", "geodesic"))
    assert _same_mean(by_keyword, overridden)


def test_mean_positional_form_of_earlier_versions_warns_and_agrees(rotations):
    w = np.linspace(0.5, 2.0, len(rotations))
    with pytest.warns(DeprecationWarning, match="MeanOptions"):
        old = rotgraph.mean(rotations, "chordal", "l1", w)
    assert _same_mean(old, rotgraph.mean(rotations, metric="chordal", norm="l1", weights=w))
    with pytest.raises(TypeError, match="norm"), pytest.warns(DeprecationWarning):
        rotgraph.mean(rotations, "chordal", "l1", norm="l2")
    with pytest.raises(TypeError):
        rotgraph.mean(rotations, rotgraph.MeanOptions(), "l1")


@pytest.mark.parametrize("call", [
    lambda R: rotgraph.mean(R, tol=1e-6),
    lambda R: rotgraph.solve_handeye(R, R, tolerance=1e-6),
    lambda R: rotgraph.certify(R, np.array([[0, 1]]), R[:1], eigen_tol=1e-6),
    lambda R: rotgraph.average_rotations(rotgraph.random_problem(n=8, degree=3, seed=0), nope=1),
], ids=["mean", "solve_handeye", "certify", "average_rotations"])
def test_an_unknown_keyword_raises(rotations, call):
    with pytest.raises(TypeError):  # as Python's own unexpected keyword argument
        call(rotations[:4])


def test_an_unknown_keyword_is_an_unknown_option_error(rotations):
    for call in (lambda: rotgraph.mean(rotations, tol=1e-6), lambda: rotgraph.solve_handeye(rotations, rotations, tol=1),
                 lambda: rotgraph.certify(rotations[:2], np.array([[0, 1]]), rotations[:1], bogus=1)):
        with pytest.raises(UnknownOptionError) as info:
            call()
        assert isinstance(info.value, OptionError) and isinstance(info.value, TypeError)


@pytest.fixture(scope="module")
def motions():
    S = so3.random_rotations(rng=1)
    L = so3.random_rotations(24, rng=2)
    C = so3.perturb(S.T @ L @ S, 0.01, rng=5)
    C[:3] = so3.random_rotations(3, rng=6)
    return L, C


@pytest.mark.parametrize("fields", [
    dict(), dict(method="l1", threshold_deg=5.0), dict(method="quaternion"),
    dict(loss="cauchy", scale_deg=2.0, seed=3, max_hypotheses=40, max_iterations=25, step_tol_rad=1e-8),
])
def test_handeye_options_object_and_keywords_give_identical_results(motions, fields):
    L, C = motions
    w = np.linspace(1.0, 2.0, len(L))
    a = rotgraph.solve_handeye(L, C, weights=w, **fields)
    b = rotgraph.solve_handeye(L, C, rotgraph.HandEyeOptions(**fields), weights=w)
    c = rotgraph.solve_handeye(L, C, rotgraph.HandEyeOptions(method="procrustes"), weights=w,
                               **{"method": "robust", **fields})
    for other in (b, c):
        assert np.array_equal(a.quaternion, other.quaternion) and np.array_equal(a.residuals_deg, other.residuals_deg)
        assert np.array_equal(a.inliers, other.inliers) and a.cost == other.cost and a.iterations == other.iterations


@pytest.mark.parametrize("fields", [dict(), dict(method="lobpcg", seed=2, tol=1e-6, gap_tol=0.1, max_iterations=50)])
def test_certify_options_object_and_keywords_give_identical_results(fields):
    g = rotgraph.random_problem(n=30, degree=5, seed=0)
    res = rotgraph.average_rotations(g, method="l2")
    args = (res.cam_from_world, g.edges, g.cam2_from_cam1, g.weights)
    a = rotgraph.certify(*args, inliers=res.inliers, **fields)
    b = rotgraph.certify(*args, rotgraph.CertifyOptions(**fields), inliers=res.inliers)
    c = rotgraph.certify(*args, rotgraph.CertifyOptions(method="dense", tol=0.5), inliers=res.inliers,
                         **{"method": "auto", "tol": None, **fields})
    for other in (b, c):
        da, do = a.to_dict(), other.to_dict()
        da.pop("seconds"), do.pop("seconds")
        assert da == do


@pytest.mark.parametrize("fields", [dict(), dict(method="irls", max_iterations=7, stationarity_tol=1e-6)])
def test_refine_chordal_options_object_and_keywords_give_identical_results(fields):
    g = rotgraph.random_problem(n=30, degree=5, sigma_deg=5.0, seed=0)
    R0 = rotgraph.average_rotations(g, method="l2").cam_from_world
    args = (R0, g.edges, g.cam2_from_cam1, g.weights)
    a = rotgraph.refine_chordal(*args, **fields)
    b = rotgraph.refine_chordal(*args, rotgraph.RefineOptions(**fields))
    c = rotgraph.refine_chordal(*args, rotgraph.RefineOptions(method="irls", max_iterations=1),
                                **{"method": "trust-region", "max_iterations": 200, **fields})
    for other in (b, c):
        assert np.array_equal(a[0], other[0], equal_nan=True) and a[1:] == other[1:]
    with pytest.raises(UnknownOptionError):
        rotgraph.refine_chordal(*args, tol=1e-6)


def _same_graph(a, b):
    return (np.array_equal(a.edges, b.edges) and np.array_equal(a.cam2_from_cam1, b.cam2_from_cam1)
            and np.array_equal(a.gt_cam_from_world, b.gt_cam_from_world)
            and np.array_equal(a.meta["outlier"], b.meta["outlier"])
            and (a.information is None) == (b.information is None)
            and (a.information is None or np.array_equal(a.information, b.information)))


@pytest.mark.parametrize("fields", [dict(n=40, degree=6, seed=3),
                                    dict(n=50, degree=5, sigma_deg=1.0, outliers=0.2, graph="traj", seed=1),
                                    dict(n=30, outlier_model="flip", outliers=0.3, noise_mix="0.2:8", seed=2),
                                    dict(n=30, degree=6, uncertainty_spread=3.0, seed=4)])
def test_random_problem_options_object_and_keywords_give_identical_results(fields):
    a = rotgraph.random_problem(**fields)
    b = rotgraph.random_problem(rotgraph.ProblemOptions(**fields))
    c = rotgraph.random_problem(rotgraph.ProblemOptions(n=7, graph="posegraph"), **{"n": 100, "graph": "er", **fields})
    assert _same_graph(a, b) and _same_graph(a, c)


def test_random_problem_positional_form_of_earlier_versions_warns_and_agrees():
    with pytest.warns(DeprecationWarning, match="ProblemOptions"):
        old = rotgraph.random_problem(40, 6, 1.0, 0.1, "traj", 5)
    assert _same_graph(old, rotgraph.random_problem(n=40, degree=6, sigma_deg=1.0, outliers=0.1, graph="traj", seed=5))
    with pytest.warns(DeprecationWarning):
        assert _same_graph(rotgraph.random_problem(40, 6, seed=5), rotgraph.random_problem(n=40, degree=6, seed=5))
    with pytest.raises(TypeError, match="degree"), pytest.warns(DeprecationWarning):
        rotgraph.random_problem(40, 6, degree=5)
    with pytest.raises(TypeError, match="positional"):
        rotgraph.random_problem(40, 6, 1.0, 0.1, "traj", 5, "extra")
    with pytest.raises(TypeError):
        rotgraph.random_problem(rotgraph.ProblemOptions(), 6)
    with pytest.raises(UnknownOptionError):
        rotgraph.random_problem(n=10, cameras=10)


def test_random_rig_problem_options_and_its_positional_form_of_earlier_versions():
    fields = dict(n_frames=8, sensors=3, rigs=2, degree=5, sigma_deg=1.0, outliers=0.1, known="half", seed=4)
    a = random_rig_problem(**fields)
    b = random_rig_problem(RigProblemOptions(**fields))
    with pytest.warns(DeprecationWarning, match="RigProblemOptions"):
        c = random_rig_problem(8, 3, 2, 5, 1.0, 0.1, known="half", seed=4)
    for other in (b, c):
        assert _same_graph(a, other) and np.array_equal(a.rigs.sensor_ids, other.rigs.sensor_ids)
        assert np.array_equal(a.rigs.cam_from_rig, other.rigs.cam_from_rig, equal_nan=True)
    with pytest.raises(TypeError, match="sensors"), pytest.warns(DeprecationWarning):
        random_rig_problem(8, 3, sensors=2)
    with pytest.raises(UnknownOptionError):
        random_rig_problem(frames=8)
