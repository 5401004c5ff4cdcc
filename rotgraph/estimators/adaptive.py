"""The adaptive default of multiple rotation averaging: weights from the data's own noise.

Instead of a loss and a scale fixed in advance, the noise of the edges is estimated from
the problem (:mod:`.noise_model`) and the rotations are its maximum-likelihood estimate:

1. **Start**: the maximum spanning tree and the linear chordal relaxation; the one whose
   median edge residual is smaller (a tree poisoned by outliers loses to the relaxation;
   on clean or tree-like data both are good).
2. **L1** (L1RA, a few iterations): into the basin of the inliers.
3. **Gaussian noise + uniform outliers**, re-fitted by EM at every iteration, each edge
   weighted by its posterior inlier probability: on data with Gaussian noise this is the
   L2 solution of the inlier edges (the oracle's), outliers excluded softly.
4. **Heavier tails, mixed edge quality or no outliers**, told by the penalised likelihood
   of the residuals of 3: a multivariate t (real two-view geometries) or two Gaussian
   scales (edges of two qualities) plus outliers, or a Gaussian without outliers (clean
   data: the plain L2 answer), whichever fits better; nothing when 3's model fits best.

Each model gives every edge its expected inverse variance times its inlier probability as
IRLS weight; the final model's posterior says which edges are outliers (probability of
being an inlier below 1/2) and gives the threshold angle reported.
"""

from __future__ import annotations

import logging

import numpy as np

from .irls import solve_irls, solve_weighted
from .linear import chordal_start
from .noise_model import NoiseModel, fit_gaussian, fit_t, residual_dofs, standardised, subset

__all__ = ["solve_adaptive"]

logger = logging.getLogger(__name__)

#: A t with this many degrees of freedom or more is a Gaussian (no second stage): only tails
#: of infinite variance (nu <= 2) are worth giving up the L2 answer for. Measured: 16 let a
#: nu = 8 fit take the clean garage pose graph (residual sum 1.44x the L2 optimum); 8 let
#: nu = 4 take it with its g2o information (whitened sum 2.5x); lund_door (real photos, ground
#: truth) fits nu = 4 too, and is more accurate with two Gaussian scales instead (0.516 deg
#: against 0.523); Ellis Island (nu = 0.5), Madrid and cubicle (nu = 1) keep the t.
GAUSSIAN_NU = 4.0
#: Fewer degrees of freedom in the residuals than this (``E - n + 1`` cycles, weighted by
#: leverage: :func:`~.noise_model.residual_dofs`) and no edge is told an outlier: the L2
#: answer. A lone cycle has one: its L1 answer puts the whole cycle error on one edge, which
#: any outlier model then flags. 10 cycles: what two to three model parameters need.
MIN_DOFS = 10.0
#: Step tolerance (rad) of the L1 means that restart cameras left without an inlier edge.
RESEED_TOL = 1e-6
#: Two Gaussian scales are two edge qualities when this far apart, each holding this much.
SCALE_RATIO, MIN_COMPONENT = 2.0, 0.05
#: Relative residual of the conjugate-gradient Laplacian solve of the L1 stage's first step
#: from a spanning tree (the other solves keep :data:`~.laplacian.RTOL`, 1e-4). It is the
#: worst conditioned solve of all (the tree's edges fit exactly: L1 weights at their cap
#: beside the others'), and an inexact first step of a start is corrected by the next ones.
#: From the chordal start (clean data) it is not, and the inexact step cost one more L1
#: iteration (r2x500 known: 2 -> 3): that start keeps RTOL.
#: Measured on rig frame graphs of 500 frames with 10 % wrong pairs: 113-141 CG products at
#: 1e-4, 51-70 at 1e-2, final rotations equal to 5 digits. The whole L1 stage at 1e-2 saved
#: more (bench_scale 20k-100k cameras: 6-16 %) but changed which 1-4 cameras of 2000 end
#: near 180 deg on structured outliers (flip class: mean error +0.8 to +3.9 %, 3 seeds);
#: the first step alone leaves those classes as they were (median equal, mean within 1 %).
L1_FIRST_RTOL = 1e-2


def solve_adaptive(q_tree, n, edges, qrel, w, anchor, system, lap, lev, opts, callback=None, mark=None, w_linear=None,
                   full=True):
    """Run the adaptive pipeline (module docstring) from the spanning-tree rotations
    ``q_tree`` (4, n); ``lev`` (E,) is each edge's leverage (:func:`~.noise_model.leverage`),
    by which the residuals are standardised. Returns ``(q, iterations, converged, model, info)``: the final
    :class:`~.noise_model.NoiseModel` (of leverage-standardised residuals) and a dict of what
    was chosen and why (start, medians, models, likelihoods), for reports; ``info["flags"]``,
    when present, is the model that tells outliers (for a heavy-tailed final model).
    ``w_linear``: the weights of the chordal start (default ``w``; with information
    matrices, ``w`` times each edge's isotropic precision). Residual sizes are
    ``system.angles`` throughout (Mahalanobis norms with information matrices).
    ``full=False``: stages 1-3 only (the Gaussian + outliers model, no search for heavier
    tails, edge qualities or clean data): a start for a caller that refines further (the
    rig solve's round 0)."""
    mark = mark or (lambda *a: None)
    tol = np.deg2rad(opts.step_tol_deg)
    stage_tol = max(np.deg2rad(opts.stage_tol_deg), tol)
    info: dict = {}
    # 1. the start
    q = q_tree
    if opts.init == "auto" and len(edges) > n - 1:
        q_chordal = chordal_start(n, edges, qrel, w if w_linear is None else w_linear, anchor, opts.linear_solver, opts.seed)
        med = {name: float(np.degrees(np.median(system.angles(cand)))) for name, cand in (("mst", q_tree), ("chordal", q_chordal))}
        info["start_median_residual_deg"] = med
        if med["chordal"] < med["mst"]:
            q = q_chordal
        info["start"] = min(med, key=med.get)
        mark("start_" + info["start"], 1, True)
    iterations = 0
    # 2. L1 (its first step from a spanning tree at a looser CG tolerance: L1_FIRST_RTOL)
    from_tree = (opts.init == "auto" and info.get("start", "mst") == "mst") or opts.init == "mst"
    q, it, conv = solve_irls(q, edges, qrel, w, anchor, "l1", 1.0, min(opts.l1_iterations, 1), stage_tol, laplacian=lap,
                             system=system, callback=callback, stage="l1", rtol=L1_FIRST_RTOL if from_tree else None)
    if not conv and opts.l1_iterations > 1:
        q, more, conv = solve_irls(q, edges, qrel, w, anchor, "l1", 1.0, opts.l1_iterations - 1, stage_tol, laplacian=lap,
                                   system=system, callback=callback, stage="l1", first_iteration=2)
        it += more
    iterations += it
    mark("l1", it, conv)
    fit_seed = opts.seed
    dofs = residual_dofs(lev)  # each residual's weight in the fits: a bridge's zero residual tells nothing
    if dofs.sum() < MIN_DOFS:
        # Too few cycles to tell an outlier from noise (one cycle's error can be put on any of its edges): the
        # L2 answer, every edge an inlier.
        plain = lambda theta: w  # noqa: E731 - constant weights: the L2 cost
        q, it, conv = solve_weighted(q, system, lap, plain, opts.max_iterations, tol, callback, "l2")
        mark("l2", it, conv)
        t = standardised(system.angles(q), lev)
        info.update(model="gauss0", residual_dofs=float(dofs.sum()))
        return q, iterations + it, conv, _pure_gaussian(t, np.maximum(dofs, 1e-12)), info

    # 3. Gaussian + uniform outliers, re-fitted at every iteration (warm-started EM)
    state = {"model": None}

    def gaussian_weights(theta):
        t = standardised(theta, lev)
        state["model"] = fit_gaussian(t, 1, start=state["model"], iterations=8 if state["model"] else 50, seed=fit_seed,
                                      weights=dofs)
        return w * state["model"].weights(t)[0]

    q, it, conv = solve_weighted(q, system, lap, gaussian_weights, opts.max_iterations, tol, callback, "gaussian")
    iterations += it
    mark("gaussian", it, conv)
    # Cameras left with no inlier edge may be stuck where the start put them (a spanning tree
    # through consistent wrong pairs; the L1 stage stops on the median step): move each to
    # the L1 mean of its neighbours' predictions and go on.
    theta = system.angles(q)
    inlier = state["model"].weights(standardised(theta, lev))[1] >= 0.5
    q_new, moved = _reseed_orphans(q, n, edges, qrel, inlier, anchor)
    if moved:
        info["reseeded_cameras"] = moved
        q, it, conv = solve_weighted(q_new, system, lap, gaussian_weights, opts.max_iterations, tol, callback, "gaussian",
                                     first_iteration=iterations + 1)
        iterations += it
        mark("gaussian_reseeded", it, conv)
        theta = system.angles(q)
    model: NoiseModel = state["model"]
    info["gaussian"] = model.describe()
    if not full:
        info["model"] = "gauss"
        return q, iterations, conv, model, info

    # 4. heavier tails or two qualities?
    t, om = subset(standardised(theta, lev), fit_seed, dofs)
    model = fit_gaussian(t, 1, start=model, seed=fit_seed, weights=om)
    heavy = fit_t(t, seed=fit_seed, enough_nu=GAUSSIAN_NU, weights=om)  # a t of nu >= GAUSSIAN_NU is not a candidate
    ll = {"gauss": model.log_likelihood(t, om), "t": heavy.log_likelihood(t, om)}
    info["log_likelihood"] = ll
    candidates = {"gauss": model}
    if heavy.nu < GAUSSIAN_NU:
        candidates["t"] = heavy
    # With information matrices the edges' qualities are given: the model fits their common
    # scale (plus outliers and tails), not qualities of its own (measured: the parking
    # garage's g2o information with gauss2 allowed: whitened residual sum 2.2x the L2
    # optimum). So two scales are only fitted without (the fit is the costliest of stage 4:
    # 50 EM iterations on data of one scale, where it does not converge).
    if system.information is None:
        two = fit_gaussian(t, 2, seed=fit_seed, weights=om)
        ll["gauss2"] = two.log_likelihood(t, om)
        if max(two.sigma) / min(two.sigma) > SCALE_RATIO and min(two.inlier_fraction) > MIN_COMPONENT:
            candidates["gauss2"] = two
    # BIC-like penalty: one parameter more than the single Gaussian each
    penalty = 0.5 * np.log(max(float(om.sum()), 2.0))  # the residuals' degrees of freedom, not their count
    best = max(candidates, key=lambda k: ll[k] - (penalty if k != "gauss" else 0.0))
    if best == "gauss":
        q, it, best, model = _clean_or_not(q, system, lap, w, lev, dofs, model, penalty, opts, tol, callback, info)
        iterations += it
        if best == "gauss0":
            mark("l2", it, True)
    info["model"] = best
    if best not in ("gauss", "gauss0"):
        if best == "t":
            fixed = heavy

            def stage_weights(theta):
                return w * fixed.weights(standardised(theta, lev))[0]
        else:
            state["model"] = two

            def stage_weights(theta):
                tt = standardised(theta, lev)
                state["model"] = fit_gaussian(tt, 2, start=state["model"], iterations=8, seed=fit_seed, weights=dofs)
                return w * state["model"].weights(tt)[0]

        q, it, conv = solve_weighted(q, system, lap, stage_weights, opts.max_iterations, tol, callback, best)
        iterations += it
        mark(best, it, conv)
        model = heavy if best == "t" else state["model"]
    if best == "t":
        # A heavy tail explains every residual: which edges are outliers (not explained by
        # Gaussian noise) is told by the Gaussian + uniform model of the final residuals.
        t = standardised(system.angles(q), lev)
        t, om = subset(t, fit_seed, dofs)
        info["flags"] = fit_gaussian(t, 1, seed=fit_seed, weights=om)
    logger.info("adaptive: start %s, noise model %s (%s)", info.get("start", "mst"), best,
                ", ".join(f"{k} {v}" for k, v in model.describe().items()))
    return q, iterations, conv, model, info


def _clean_or_not(q, system, lap, w, lev, dofs, model, penalty, opts, tol, callback, info):
    """Are there outliers at all, or is the data clean (Gaussian noise only)?

    The Gaussian + uniform fit always finds a few "outliers" in the tail of clean data, and
    the robust weights then make their residuals larger still. So the question is asked at
    the L2 answer: one Gauss-Newton step of plain (information-weighted) L2 from ``q``, then
    the penalised likelihood of its residuals with and without the outlier component. Clean
    (the outlier fraction does not pay for its parameter): the L2 stage is run to the end,
    every edge an inlier (model "gauss0"). Else ``q`` is kept. Returns ``(q, iterations,
    "gauss" or "gauss0", model)``."""
    plain = lambda theta: w  # noqa: E731 - constant weights: the L2 cost
    q1, it1, conv = solve_weighted(q, system, lap, plain, 1, 0.0, None, "l2-test")
    t1, om = subset(standardised(system.angles(q1), lev), opts.seed, dofs)
    pure = _pure_gaussian(t1, om)
    # EM from the robust stage's model, and from the residuals' own median: the L2 step can move the residuals far
    # from that model (consistent wrong pairs pull the plain L2 answer), where the warm start alone ended in a fit
    # below the pure Gaussian (a negative "gain": doppelganger projects called clean, 7 deg median error)
    fits = [fit_gaussian(t1, 1, start=model, seed=opts.seed, weights=om), fit_gaussian(t1, 1, seed=opts.seed, weights=om)]
    mixed = max(fits, key=lambda m: m.log_likelihood(t1, om))
    gain = mixed.log_likelihood(t1, om) - pure.log_likelihood(t1, om)
    info["outlier_test"] = {"log_likelihood_gain": float(gain), "penalty": float(penalty)}
    if gain > penalty:
        return q, 0, "gauss", model
    q, it, conv = solve_weighted(q1, system, lap, plain, opts.max_iterations, tol, callback, "l2", first_iteration=2)
    t = subset(standardised(system.angles(q), lev), opts.seed)
    return q, it + it1, "gauss0", _pure_gaussian(t, om)


def _pure_gaussian(t, om) -> NoiseModel:
    """The Gaussian (no outliers) of residual angles ``t`` counted ``om`` times each."""
    return NoiseModel("gauss", (max(float(np.sqrt((t * t) @ om / (3.0 * max(float(om.sum()), 1e-300)))), 1e-12),), (1.0,), 0.0)


def _reseed_orphans(q, n, edges, qrel, inlier, anchor):
    """``(q, k)``: the rotations with each camera that has edges but no inlier among them
    (but the anchor) set to the geodesic L1 mean of its neighbours' predictions
    ``R_ij R_i`` (all such cameras at once: :func:`~.single_iterative.geodesic_l1_means`);
    ``k`` how many were moved by more than a tenth of a degree."""
    has_edge = np.bincount(edges.ravel(), minlength=n) > 0
    has_inlier = np.bincount(edges[inlier].ravel(), minlength=n) > 0
    orphans = np.flatnonzero(has_edge & ~has_inlier & (np.arange(n) != anchor))
    if not len(orphans):
        return q, 0
    from .. import so3
    from .single_iterative import geodesic_l1_means

    # every edge seen from both ends: (camera, neighbour, rotation neighbour -> camera)
    cam = np.concatenate([edges[:, 1], edges[:, 0]])
    nbr = np.concatenate([edges[:, 0], edges[:, 1]])
    rot = np.concatenate([qrel, so3.qconj_rows(qrel)], axis=1)
    pick = np.flatnonzero(np.isin(cam, orphans))
    pick = pick[np.argsort(cam[pick], kind="stable")]
    pred = so3.qmul_rows(rot[:, pick], q[:, nbr[pick]])
    starts = np.searchsorted(cam[pick], np.r_[orphans, n])
    # a restart for IRLS, not a result: 1e-6 rad is plenty (measured against one
    # single.mean per camera, 450 cameras re-seeded on 30 graphs of 20 % outliers: the same
    # rotation for 440, for the rest a cost within 4e-6 rad of it or lower, 5 of them in
    # another local minimum of the L1 cost)
    means = geodesic_l1_means(pred, starts, tol=RESEED_TOL)
    moved = int((np.abs((means * q[:, orphans]).sum(axis=0)) < np.cos(np.deg2rad(0.05))).sum())  # half-angle cosine: 0.1 deg
    q = q.copy()
    q[:, orphans] = means
    return q, moved
