"""Synthetic problems with known ground truth: view graphs (:func:`random_problem`,
:func:`random_rig_problem`) and COLMAP projects (:func:`synthesize_colmap_project`, for tests
and benchmarks; made in :mod:`rotgraph.synth_colmap`, re-exported here).

View graphs (``graph=``):

* ``er``: uniformly random rotations, an Erdős–Rényi-like graph (a random spanning tree
  plus uniform random pairs): SfM view graphs.
* ``traj``: cameras along a smooth path, edges to the next few cameras plus random loop
  closures (10 % of the edges).
* ``posegraph``: a SLAM pose graph: a robot driving several laps of a loop (yaw along the
  path, small pitch/roll wobble), odometry edges ``(i, i+1)`` (plus ``(i, i+2)`` from an
  average degree of 5 up) and loop closures between poses of different laps that are
  less than 2 m apart; the average degree is ``degree`` (3–6 is SLAM-like).

Noise is Gaussian in the tangent space, on the right: ``R_ij = R_j R_i^T exp([e]x)``,
``e ~ N(0, sigma^2 I_3)`` per edge (isotropic, so ``exp([e]x) R_j R_i^T`` has the same
law). The median angle of such a perturbation is about 1.54 ``sigma``.

Outliers (``outlier_model=``):

* ``uniform``: a fraction ``outliers`` of the edges is replaced by Haar-random rotations
  (``posegraph``: exactly ``round(outliers * E)`` edges, all on loop closures: odometry is
  kept; at most every loop closure);
* ``flip``: a consistent wrong hypothesis, as a symmetric scene or doppelganger gives: a
  group of ``round(flip_group * n)`` cameras, each seen turned 180° about the world
  y axis (``R_c F``, ``F = exp(pi [e_y]x)``) on a fraction ``outliers`` of the edges
  that touch the group: such an edge measures ``R_j F R_i^T exp([e]x)`` (the same whichever
  end is turned, as ``F = F^T``): exactly 180° off the truth without noise.

``graph.meta["outlier"]`` flags the wrong edges, ``meta["edge_sigma_deg"]`` the noise level
of every edge (``noise_mix=(f, s)``: a random fraction ``f`` of the edges gets ``s`` degrees
instead of ``sigma_deg``: mixed edge quality, no weights given), and for the pose graphs
``meta["loop_closure"]`` the loop-closure edges; ``meta["flipped_cameras"]`` lists the
group of the ``flip`` model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import so3
from .choices import GRAPHS, OUTLIER_MODELS
from .errors import OptionError
from .options import Options, legacy_positional, resolve_options
from .synth_colmap import synthesize_colmap_project
from .viewgraph import ViewGraph

__all__ = ["random_problem", "ProblemOptions", "random_rig_problem", "RigProblemOptions", "synthesize_colmap_project",
           "GRAPHS", "OUTLIER_MODELS", "FLIP_AXIS"]

#: The world axis about which the ``flip`` outlier model turns a camera (180 degrees).
FLIP_AXIS = np.array([0.0, 1.0, 0.0])
#: Pose graphs: loop closures join poses less than this far apart (metres; 0.3 m steps).
LOOP_CLOSURE_RADIUS = 2.0
#: Edges per block where random_problem computes rotations (bounds its temporaries).
_BLOCK = 1 << 18


def _er_pairs(n: int, n_edges: int, rng) -> np.ndarray:
    """A random spanning tree (connectivity guaranteed) plus uniform random extra pairs.

    O(E) memory and O(E log E) time, no Python loop over edges: the pairs drawn so far are
    one sorted array of keys ``min * n + max`` (membership by binary search), distinct
    candidates by sorting (numpy 2.3+'s hash-based np.unique is ~10x slower). The draws
    and the pairs are those of the earlier set-based version (same seed, same graph)."""
    from .io.table_columns import unique

    perm = rng.permutation(n)
    # Random recursive tree: node perm[k] attaches to a random earlier node.
    parents = perm[(rng.random(n - 1) * np.arange(1, n)).astype(np.int64)]
    pairs = np.stack([parents, perm[1:]], axis=1)
    keys = unique(np.minimum(pairs[:, 0], pairs[:, 1]) * n + np.maximum(pairs[:, 0], pairs[:, 1]))
    target = min(n_edges, n * (n - 1) // 2)
    extra = []
    while len(keys) < target:
        m = int((target - len(keys)) * 1.3) + 16
        a = rng.integers(0, n, m)
        b = rng.integers(0, n, m)
        ok = a != b
        k = unique(np.minimum(a[ok], b[ok]) * n + np.maximum(a[ok], b[ok]))
        del a, b, ok
        pos = np.minimum(np.searchsorted(keys, k), len(keys) - 1)
        k = k[keys[pos] != k]
        k = rng.permutation(k)[: target - len(keys)]
        keys = np.concatenate([keys, k])
        keys.sort()
        extra.append(k)
    del keys
    if extra:
        k = np.concatenate(extra)
        pairs = np.concatenate([pairs, np.stack([k // n, k % n], axis=1)])
    flip = rng.random(len(pairs)) < 0.5  # both edge directions occur
    pairs[flip] = pairs[flip][:, ::-1]
    return pairs


def _trajectory(n: int, degree: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """Cameras on a smooth path (yaw sweep with wobble), edges to the next k cameras plus
    random loop closures (10 % of the edges)."""
    t = np.linspace(0, 4 * np.pi, n)
    v = np.stack([0.1 * np.sin(3 * t), t, 0.1 * np.cos(2 * t)], axis=1) + 0.02 * rng.standard_normal((n, 3))
    R = so3.exp(v)
    k = max(1, int(round(0.45 * degree)))
    ii = np.concatenate([np.arange(n - d) for d in range(1, k + 1)])
    jj = np.concatenate([np.arange(d, n) for d in range(1, k + 1)])
    n_loop = max(0, int(0.1 * len(ii)))
    a = rng.integers(0, n, 3 * n_loop + 8)
    b = rng.integers(0, n, 3 * n_loop + 8)
    ok = np.abs(a - b) > k
    pairs = np.concatenate([np.stack([ii, jj], 1), np.stack([a[ok], b[ok]], 1)[:n_loop]])
    lo, hi = np.minimum(pairs[:, 0], pairs[:, 1]), np.maximum(pairs[:, 0], pairs[:, 1])
    _, first = np.unique(lo * n + hi, return_index=True)
    return R, pairs[np.sort(first)]


def _pose_graph(n: int, degree: float, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A SLAM pose graph: rotations (n, 3, 3) cam_from_world (= body_from_world), edges
    (E, 2) and the loop-closure mask (E,).

    The robot drives ``laps`` laps (one per ~150 poses, at least 2) of a circle of 10 m
    radius whose centre and radius wobble from lap to lap (up to ~0.7 m), climbing 0.3 m a lap;
    heading along the path with a smooth yaw wobble (~6 deg) and pitch/roll wobble
    (~3 deg). Odometry: ``(i, i + d)`` for ``d = 1 .. k``, ``k = max(1, (degree - 1) // 2)``;
    loop closures: ``round(n * degree / 2) - (odometry edges)`` pairs (at least none) drawn
    uniformly from the pairs less than :data:`LOOP_CLOSURE_RADIUS` apart and more than
    ``2 k + 2`` poses apart in time.
    """
    from scipy.spatial import cKDTree

    laps = max(2, int(round(n / 150)))
    t = np.linspace(0.0, 2 * np.pi * laps, n, endpoint=False)
    lap_phase = rng.uniform(0, 2 * np.pi, 3)
    radius = 10.0 + 0.4 * np.sin(t / laps * 1.5 + lap_phase[0])
    centre = 0.4 * np.stack([np.sin(t / laps + lap_phase[1]), np.cos(t / laps + lap_phase[2])], axis=1)
    pos = np.stack([centre[:, 0] + radius * np.cos(t), centre[:, 1] + radius * np.sin(t), 0.3 * t / (2 * np.pi)], axis=1)
    ph = rng.uniform(0, 2 * np.pi, 3)
    yaw = t + np.pi / 2 + 0.1 * np.sin(7.3 * t + ph[0]) + 0.01 * rng.standard_normal(n)
    pitch = 0.05 * np.sin(3.1 * t + ph[1]) + 0.005 * rng.standard_normal(n)
    roll = 0.05 * np.sin(5.3 * t + ph[2]) + 0.005 * rng.standard_normal(n)
    z = np.zeros(n)
    world_from_body = (so3.exp(np.stack([z, z, yaw], 1)) @ so3.exp(np.stack([z, pitch, z], 1))
                       @ so3.exp(np.stack([roll, z, z], 1)))
    R = np.ascontiguousarray(np.swapaxes(world_from_body, 1, 2))
    k = max(1, int((degree - 1) // 2))
    ii = np.concatenate([np.arange(n - d) for d in range(1, min(k, n - 1) + 1)])
    jj = np.concatenate([np.arange(d, n) for d in range(1, min(k, n - 1) + 1)])
    n_loop = max(0, int(round(n * degree / 2)) - len(ii))
    loops = np.zeros((0, 2), dtype=np.int64)
    if n_loop:
        cand = cKDTree(pos).query_pairs(LOOP_CLOSURE_RADIUS, output_type="ndarray")
        cand = cand[np.abs(cand[:, 0] - cand[:, 1]) > 2 * k + 2]
        cand = cand[np.lexsort((cand[:, 1], cand[:, 0]))]  # query_pairs' order is not specified
        loops = cand[rng.permutation(len(cand))[:n_loop]]
        swap = rng.random(len(loops)) < 0.5  # a loop closure may be found from either end
        loops[swap] = loops[swap][:, ::-1]
    pairs = np.concatenate([np.stack([ii, jj], 1), loops]).astype(np.int64)
    is_loop = np.zeros(len(pairs), dtype=bool)
    is_loop[len(ii):] = True
    return R, pairs, is_loop


def _parse_noise_mix(noise_mix) -> tuple[float, float] | None:
    if noise_mix is None:
        return None
    if isinstance(noise_mix, str):
        try:
            f, s = (float(x) for x in noise_mix.split(":"))
        except ValueError:
            raise OptionError(f"noise_mix must be 'FRACTION:SIGMA_DEG', e.g. '0.5:5', got {noise_mix!r}") from None
    else:
        f, s = (float(x) for x in noise_mix)
    if not (0.0 <= f <= 1.0) or not s >= 0.0:
        raise OptionError(f"noise_mix: the fraction must be in [0, 1] and the sigma >= 0, got {f}, {s}")
    return f, s


def _check_problem_options(n: int, sigma_deg: float, outliers: float, graph: str, outlier_model: str,
                           flip_group: float, noise_mix, uncertainty_spread) -> None:
    """:func:`random_problem`'s options (OptionError)."""
    if graph not in GRAPHS:
        raise OptionError(f"graph must be one of {GRAPHS}")
    if outlier_model not in OUTLIER_MODELS:
        raise OptionError(f"outlier_model must be one of {OUTLIER_MODELS}")
    if n < 2:
        raise OptionError("need at least 2 cameras")
    if not 0.0 <= outliers <= 1.0 or not 0.0 <= flip_group <= 1.0:
        raise OptionError("outliers and flip_group must be fractions in [0, 1]")
    if not sigma_deg >= 0.0:
        raise OptionError("sigma_deg must be >= 0")
    if uncertainty_spread is not None and not (uncertainty_spread >= 1.0 and sigma_deg > 0 and noise_mix is None):
        raise OptionError("uncertainty_spread must be >= 1, with sigma_deg > 0 and no noise_mix")


def _cameras_and_pairs(graph: str, n: int, degree: float, rng: np.random.Generator):
    """``(R, pairs, is_loop)``: the true rotations, the edges and (pose graphs) which edges are
    loop closures (None otherwise): :func:`random_problem`'s first draws."""
    is_loop = None
    if graph == "er":
        R = so3.random_rotations(n, rng)
        pairs = _er_pairs(n, int(round(n * degree / 2)), rng)
    elif graph == "traj":
        R, pairs = _trajectory(n, degree, rng)
    else:
        R, pairs, is_loop = _pose_graph(n, degree, rng)
    return R, pairs, is_loop


def _draw_outliers(outlier_model: str, outliers: float, flip_group: float, is_loop, n: int, i: np.ndarray, j: np.ndarray,
                   rng: np.random.Generator):
    """``(is_out, wrong, flipped_cameras)``: the outlier edges, the random rotations that
    replace them (``uniform``; None for ``flip``) and the flipped group (``flip``; else
    empty)."""
    m = len(i)
    flipped_cameras = np.zeros(0, dtype=np.int64)
    wrong = None
    if outlier_model == "uniform":
        if is_loop is None:
            is_out = rng.random(m) < outliers
        else:
            loop_idx = np.flatnonzero(is_loop)
            k = min(int(round(outliers * m)), len(loop_idx))
            is_out = np.zeros(m, dtype=bool)
            is_out[rng.choice(loop_idx, k, replace=False)] = True
        wrong = so3.random_rotations(int(is_out.sum()), rng)
    else:
        flipped_cameras = np.sort(rng.choice(n, int(round(flip_group * n)), replace=False))
        in_group = np.zeros(n, dtype=bool)
        in_group[flipped_cameras] = True
        is_out = (in_group[i] | in_group[j]) & (rng.random(m) < outliers)
    return is_out, wrong, flipped_cameras


def _relative_rotations(R: np.ndarray, i: np.ndarray, j: np.ndarray, flipped, z, sig: np.ndarray) -> np.ndarray:
    """``R_j R_i^T`` of each edge (``flipped`` edges, when given: ``R_j F R_i^T``), times the
    isotropic noise ``exp(sig z)`` when ``z`` is given (sig in degrees)."""
    # In blocks of edges: O(E) memory without (E, 3, 3) temporaries, each edge computed as
    # before (same bits).
    m = len(i)
    rel = np.empty((m, 3, 3))
    F = so3.exp(np.pi * FLIP_AXIS)
    flip_any = flipped is not None and flipped.any()
    for s in range(0, m, _BLOCK):
        b = slice(s, s + _BLOCK)
        r = R[j[b]] @ np.swapaxes(R[i[b]], 1, 2)
        if flip_any:
            o = flipped[b]
            if o.any():
                r[o] = R[j[b][o]] @ F @ np.swapaxes(R[i[b][o]], 1, 2)
        if z is not None:
            r = r @ so3.exp(np.deg2rad(sig[b])[:, None] * z[b])
        rel[b] = r
    return rel


def _anisotropic_noise(rel: np.ndarray, sigma_deg: float, uncertainty_spread: float, rng: np.random.Generator):
    """``(rel with the noise, information)`` of ``uncertainty_spread`` (its draws after all
    others: the same seed gives the same graph and outliers)."""
    m = len(rel)
    axes = so3.random_rotations(m, rng)
    std = np.deg2rad(sigma_deg) * np.exp(rng.uniform(-1.0, 1.0, (m, 3)) * np.log(uncertainty_spread))
    d = np.einsum("eab,eb->ea", axes, std * rng.standard_normal((m, 3)))
    rel = so3.exp(d) @ rel
    information = axes @ (std[:, :, None] ** -2 * np.swapaxes(axes, 1, 2))
    return rel, information


@dataclass(frozen=True)
class ProblemOptions(Options):
    """The problem :func:`random_problem` draws (see the module docstring); frozen,
    :meth:`~rotgraph.options.Options.validated` by :func:`random_problem`, which also takes
    each field as a keyword.

    Parameters
    ----------
    n : int, default 100
        Number of cameras (>= 2).
    degree : float, default 10.0
        Average number of edges per camera.
    sigma_deg : float, default 2.0
        Per-axis standard deviation of the edge noise in degrees (>= 0).
    outliers : float, default 0.0
        Fraction of outlier edges, in [0, 1].
    graph : {"er", "traj", "posegraph"}, default "er"
        The kind of graph (:data:`~rotgraph.choices.GRAPHS`).
    seed : int or None, default 0
        Random seed.
    outlier_model : {"uniform", "flip"}, default "uniform"
        How outlier edges are made (:data:`~rotgraph.choices.OUTLIER_MODELS`).
    flip_group : float, default 0.2
        Fraction of cameras in the flipped group of ``outlier_model="flip"``, in [0, 1].
    noise_mix : (float, float) or str, optional
        ``(f, s)`` or ``"f:s"``: a fraction ``f`` of the edges has noise ``s`` degrees.
    uncertainty_spread : float, optional
        ``K >= 1``: anisotropic per-edge noise and its information matrices (needs
        ``sigma_deg > 0`` and no ``noise_mix``).
    """

    n: int = 100
    degree: float = 10.0
    sigma_deg: float = 2.0
    outliers: float = 0.0
    graph: str = "er"
    seed: int | None = 0
    outlier_model: str = "uniform"
    flip_group: float = 0.2
    noise_mix: tuple | str | None = None  # (fraction, sigma_deg) or "fraction:sigma_deg"
    uncertainty_spread: float | None = None

    def check(self) -> None:
        """An unknown graph or outlier model, fewer than 2 cameras, a fraction outside [0, 1],
        a negative sigma, a bad ``noise_mix`` or ``uncertainty_spread``:
        :class:`~rotgraph.errors.OptionError`."""
        _check_problem_options(self.n, self.sigma_deg, self.outliers, self.graph, self.outlier_model, self.flip_group,
                               self.noise_mix, self.uncertainty_spread)
        _parse_noise_mix(self.noise_mix)


def _options_of_call(cls, options, legacy: tuple, overrides: dict, form: str):
    """The validated ``cls`` options of a call of :func:`random_problem` or
    :func:`random_rig_problem` (``resolve_options``); a number in place of ``options`` is the
    positional form of earlier versions, ``form`` (``"name(arg, ...)"``), taken with a
    ``DeprecationWarning`` (:func:`rotgraph.options.legacy_positional`)."""
    function, names = form.partition("(")[0], tuple(a.strip() for a in form.partition("(")[2].rstrip(")").split(","))
    if isinstance(options, (int, float, np.number)):
        legacy_positional(form, (options, *legacy), names, overrides,
                          f"give them by keyword ({names[0]}=, {names[1]}=, ...) or a {cls.__name__}", stacklevel=4)
        options = None
    elif legacy:
        raise TypeError(f"{function}() takes 1 positional argument but {1 + len(legacy)} were given")
    return resolve_options(cls, options, overrides)


def random_problem(options: ProblemOptions | None = None, *legacy, **overrides) -> ViewGraph:
    """A random view graph with ground truth (``graph.gt_cam_from_world``).

    ``n`` cameras with uniformly random rotations (``er``), along a trajectory (``traj``)
    or a SLAM robot's poses (``posegraph``), about ``n * degree / 2`` edges, each
    ``R_ij = R_j R_i^T exp(e)`` with isotropic noise ``e ~ N(0, sigma^2 I)`` (sigma in
    degrees; ``noise_mix=(f, s)`` or ``"f:s"``: a random fraction ``f`` of the edges has
    ``s`` degrees instead). Outliers: ``outlier_model="uniform"``, a fraction ``outliers``
    of the edges replaced by uniformly random rotations (pose graphs: on loop closures
    only); ``"flip"``, a group of ``flip_group * n`` cameras seen turned 180° about the
    world y axis on a fraction ``outliers`` of their edges (a consistent wrong
    hypothesis). ``uncertainty_spread=K`` (>= 1): every edge gets its own anisotropic
    noise instead, standard deviations ``sigma * exp(u)`` along three random axes with
    ``u ~ U(-ln K, ln K)`` each, drawn as ``R_ij = exp(d) R_j R_i^T``, ``d ~ N(0, C_ij)``,
    and the graph carries the true information matrices ``C_ij^-1``
    (:attr:`~rotgraph.viewgraph.ViewGraph.information`; outlier edges keep the
    information their noise would have had). ``graph.meta["outlier"]`` flags the wrong edges; see the module
    docstring for the other ``meta`` entries. Deterministic for a given ``seed``; the
    ``er`` and ``traj`` graphs of the defaults are those of earlier versions.

    ``options`` (or keyword overrides of its fields, as
    ``average_rotations(graph, options, **overrides)`` takes them) say which problem:
    :class:`ProblemOptions`. The positional form of earlier versions,
    ``random_problem(n, degree, sigma_deg, outliers, graph, seed)``, still works and warns
    (``DeprecationWarning``).

    Parameters
    ----------
    options : ProblemOptions, optional
        The problem; default ``ProblemOptions()``.
    **overrides
        Fields of :class:`ProblemOptions` that replace those of ``options`` (``n=``,
        ``degree=``, ``sigma_deg=``, ``outliers=``, ``graph=``, ``seed=``,
        ``outlier_model=``, ``flip_group=``, ``noise_mix=``, ``uncertainty_spread=``).

    Returns
    -------
    ViewGraph
        ``n`` cameras; ``cam2_from_cam1`` (E, 3, 3) float64 holds ``R_ij = R_j R_i^T`` for
        edge ``(i, j)``; ``gt_cam_from_world`` (n, 3, 3) the true absolute rotations
        (world-to-camera); ``meta["outlier"]`` (E,) bool the wrong edges.

    Raises
    ------
    OptionError
        A bad option value (also a ``ValueError``), or an unknown keyword
        (:class:`~rotgraph.errors.UnknownOptionError`, also a ``TypeError``).

    Examples
    --------
    >>> import rotgraph
    >>> g = rotgraph.random_problem(n=30, degree=6, outliers=0.1, seed=1)
    >>> same = rotgraph.random_problem(rotgraph.ProblemOptions(n=30, degree=6, outliers=0.1, seed=1))
    >>> bool((g.cam2_from_cam1 == same.cam2_from_cam1).all())
    True
    """
    o = _options_of_call(ProblemOptions, options, legacy, overrides,
                         "random_problem(n, degree, sigma_deg, outliers, graph, seed)")
    n, degree, sigma_deg, outliers, graph, seed = o.n, o.degree, o.sigma_deg, o.outliers, o.graph, o.seed
    outlier_model, flip_group, noise_mix, uncertainty_spread = o.outlier_model, o.flip_group, o.noise_mix, o.uncertainty_spread
    mix = _parse_noise_mix(noise_mix)
    rng = np.random.default_rng(seed)
    R, pairs, is_loop = _cameras_and_pairs(graph, n, degree, rng)
    i, j = pairs[:, 0], pairs[:, 1]
    m = len(pairs)
    # The draws come in the order of earlier versions (noise, outliers, outlier rotations),
    # then the new ones: the same seed gives the same er / traj problems as before.
    noisy = sigma_deg > 0 or (mix is not None and mix[1] > 0)
    z = rng.standard_normal((m, 3)) if noisy else None
    is_out, wrong, flipped_cameras = _draw_outliers(outlier_model, outliers, flip_group, is_loop, n, i, j, rng)
    sig = np.full(m, float(sigma_deg))
    if mix is not None:
        sig[rng.permutation(m)[: int(round(mix[0] * m))]] = mix[1]
    rel = _relative_rotations(R, i, j, is_out if outlier_model == "flip" else None,
                              z if noisy and uncertainty_spread is None else None, sig)
    del z
    information = None
    if uncertainty_spread is not None:
        rel, information = _anisotropic_noise(rel, sigma_deg, uncertainty_spread, rng)
    if outlier_model == "uniform":
        rel[is_out] = wrong
    g = ViewGraph.from_edges(i, j, rel, node_ids=np.arange(n), information=information)
    g.gt_cam_from_world = R
    g.meta.update(outlier=is_out, sigma_deg=sigma_deg, outliers=outliers, graph=graph, seed=seed,
                  outlier_model=outlier_model, edge_sigma_deg=sig)
    if mix is not None:
        g.meta["noise_mix"] = mix
    if uncertainty_spread is not None:
        g.meta["uncertainty_spread"] = float(uncertainty_spread)
    if is_loop is not None:
        g.meta["loop_closure"] = is_loop
    if outlier_model == "flip":
        g.meta.update(flipped_cameras=flipped_cameras, flip_group=flip_group)
    return g


@dataclass(frozen=True)
class RigProblemOptions(Options):
    """The problem :func:`random_rig_problem` draws; frozen,
    :meth:`~rotgraph.options.Options.validated` by :func:`random_rig_problem`, which also
    takes each field as a keyword.

    Parameters
    ----------
    n_frames : int, default 20
        Frames (captures) of each rig (>= 2).
    sensors : int, default 3
        Sensors of each rig (>= 1); sensor 0 the reference.
    rigs : int, default 1
        Number of rigs (>= 1).
    degree : float, default 10.0
        Average number of random image pairs per image.
    sigma_deg : float, default 1.0
        Per-axis standard deviation of the edge noise in degrees.
    outliers : float, default 0.0
        Fraction of the edges replaced by uniformly random rotations.
    within_frame : float, default 1.0
        Probability that a pair of images of one frame is an edge.
    known : {"none", "all", "half"}, default "none"
        Which ``cam_from_rig`` the graph gives: references only, all, every other
        non-reference sensor.
    missing : float, default 0.0
        Fraction of the non-reference images dropped (a sensor that failed).
    seed : int or None, default 0
        Random seed.
    """

    n_frames: int = 20
    sensors: int = 3
    rigs: int = 1
    degree: float = 10.0
    sigma_deg: float = 1.0
    outliers: float = 0.0
    within_frame: float = 1.0
    known: str = "none"
    missing: float = 0.0
    seed: int | None = 0

    def check(self) -> None:
        """An unknown ``known``, fewer than 1 sensor or rig or 2 frames:
        :class:`~rotgraph.errors.OptionError`."""
        if self.known not in ("all", "none", "half"):
            raise OptionError("known must be all, none or half")
        if self.sensors < 1 or self.rigs < 1 or self.n_frames < 2:
            raise OptionError("need at least 1 sensor, 1 rig and 2 frames")


def random_rig_problem(options: RigProblemOptions | None = None, *legacy, **overrides) -> ViewGraph:
    """A random multi-camera rig problem with ground truth (issue #17).

    ``rigs`` rigs, each of ``sensors`` sensors (sensor 0 the reference, ``cam_from_rig``
    the identity; the others Haar-random) and ``n_frames`` frames (Haar-random
    ``rig_from_world``); image ``cam_from_world = cam_from_rig @ rig_from_world``; a
    fraction ``missing`` of the non-reference images dropped (a sensor that failed). Edges:
    about ``n_images * degree / 2`` random image pairs, plus each pair of images within a
    frame with probability ``within_frame``; noise and uniform outliers as
    :func:`random_problem`. ``known``: which ``cam_from_rig`` the graph gives (``all``,
    ``none`` (references only: the identity) or ``half`` (every other non-reference
    sensor)). Sensor ids are ``rig * sensors + k``, frame ids ``rig * n_frames + f``.
    ``graph.rigs`` holds them; ``graph.meta["gt_cam_from_rig"]`` (rigs * sensors, 3, 3) the
    true extrinsics, ``meta["outlier"]`` the wrong edges.

    ``options`` (or keyword overrides of its fields) say which problem:
    :class:`RigProblemOptions`; the positional form of earlier versions,
    ``random_rig_problem(n_frames, sensors, rigs, degree, sigma_deg, outliers)``, still works
    and warns (``DeprecationWarning``).

    Parameters
    ----------
    options : RigProblemOptions, optional
        The problem; default ``RigProblemOptions()``.
    **overrides
        Fields of :class:`RigProblemOptions` that replace those of ``options``.

    Returns
    -------
    ViewGraph
        The images' graph with ``rigs`` (:class:`~rotgraph.viewgraph.Rigs`) and
        ``gt_cam_from_world``.

    Raises
    ------
    OptionError
        A bad option value, or an unknown keyword (:class:`~rotgraph.errors.UnknownOptionError`).
    """
    from .viewgraph import Rigs

    o = _options_of_call(RigProblemOptions, options, legacy, overrides,
                         "random_rig_problem(n_frames, sensors, rigs, degree, sigma_deg, outliers)")
    n_frames, sensors, rigs, degree, sigma_deg, outliers = o.n_frames, o.sensors, o.rigs, o.degree, o.sigma_deg, o.outliers
    within_frame, known, missing, seed = o.within_frame, o.known, o.missing, o.seed
    rng = np.random.default_rng(seed)
    K = rigs * sensors
    S = so3.random_rotations(K, rng)
    S[::sensors] = np.eye(3)
    F = so3.random_rotations(rigs * n_frames, rng)
    rig = np.repeat(np.arange(rigs), n_frames * sensors)
    frame = np.repeat(np.arange(rigs * n_frames), sensors)
    sensor = rig * sensors + np.tile(np.arange(sensors), rigs * n_frames)
    keep = (sensor % sensors == 0) | (rng.random(len(sensor)) >= missing)
    frame, sensor = frame[keep], sensor[keep]
    n = len(frame)
    R = S[sensor] @ F[frame]
    pairs = _er_pairs(n, int(round(n * degree / 2)), rng)
    a, b = np.triu_indices(n, 1)
    same = frame[a] == frame[b]
    extra = np.stack([a[same], b[same]], axis=1)[rng.random(int(same.sum())) < within_frame]
    pairs = np.unique(np.sort(np.concatenate([pairs, extra]), axis=1), axis=0)
    i, j = pairs[:, 0], pairs[:, 1]
    m = len(pairs)
    rel = R[j] @ np.swapaxes(R[i], 1, 2)
    if sigma_deg > 0:
        rel = rel @ so3.exp(np.deg2rad(sigma_deg) * rng.standard_normal((m, 3)))
    is_out = rng.random(m) < outliers
    rel[is_out] = so3.random_rotations(int(is_out.sum()), rng)
    given = S[sensor].copy()
    k_in_rig = sensor % sensors
    unknown = k_in_rig > 0 if known == "none" else (k_in_rig % 2 == 1) if known == "half" else np.zeros(n, bool)
    given[unknown] = np.nan
    g = ViewGraph.from_edges(i, j, rel, node_ids=np.arange(n))
    g.gt_cam_from_world = R
    g.rigs = Rigs(frame, given, sensor, k_in_rig == 0)
    g.meta.update(outlier=is_out, sigma_deg=sigma_deg, outliers=outliers, gt_cam_from_rig=S, seed=seed,
                  graph="rig", known=known)
    return g
