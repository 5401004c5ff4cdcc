"""The adaptive default of multiple rotation averaging: weights from the data's own noise.

Instead of a loss and a scale fixed in advance, the noise of the edges is estimated from
the problem (:mod:`.noise_model`) and the rotations are its maximum-likelihood estimate:

1. **Starts**: the maximum spanning tree and the linear chordal relaxation.
2. **L1** (L1RA, a few iterations): into the basin of the inliers.
3. **Gaussian noise + uniform outliers**, re-fitted by EM at every iteration, each edge
   weighted by its posterior inlier probability: on data with Gaussian noise this is the
   L2 solution of the inlier edges (the oracle's), outliers excluded softly. Its inlier
   scale is graduated (stage ``"graduated"``): from the spread of all residuals down to the
   fitted scale by :data:`ANNEAL_FACTOR` an iteration.
   Stages 2-3 run from both starts and the answer of lower L1 cost over *every* edge is
   kept (``diagnostics["start"]``, ``["robust_cost_deg"]``): a spanning tree through
   consistent wrong edges, or a relaxation pulled by them, leaves many edges far off and
   loses. (A start's median residual cannot judge: a tree fits its own edges exactly, over
   half the edges of a sparse graph.) A tree already :data:`START_COST_RATIO` times costlier
   than the relaxation is not run.
4. **Heavier tails, mixed edge quality or no outliers**: a multivariate t of any degrees of
   freedom (real two-view geometries: 0.5-1; Laplace-like or mixed noise: 4-16; with
   information matrices only below :data:`HEAVY_TAIL_NU`) or two Gaussian scales (edges of
   two qualities; not with information matrices) plus outliers, chosen against 3's model by how
   well each predicts held-out residuals (cross-validation over the edges); or, when 3's
   model wins, a Gaussian without outliers (clean data: the plain L2 answer) when the
   outlier fraction does not pay for its parameter at the L2 answer.

Each model gives every edge its expected inverse variance times its inlier probability as
IRLS weight; the final model's posterior says which edges are outliers (probability of
being an inlier below 1/2) and gives the threshold angle reported (for a t of fewer than
:data:`HEAVY_TAIL_NU` degrees of freedom, a t of that many + uniform refitted to its residuals).
"""

from __future__ import annotations

import logging

import numpy as np

from .irls import solve_irls, solve_weighted
from .laplacian import make_laplacian
from .cuts import bridge_cuts, cut_moves, disjoint_moves, turn_sides
from .leverage import fitted_residual_dofs, residual_dofs, standardised
from .linear import chordal_start
from .noise_model import NoiseModel, choose_held_out, cross_validated_log_likelihood, fit_gaussian, fit_t, subset

__all__ = ["solve_adaptive", "choose_model", "HEAVY_TAIL_NU"]

logger = logging.getLogger(__name__)

#: Below this many degrees of freedom a t's tail swallows gross errors (Ellis Island, 12 % of
#: its edges > 30 deg off: a t of nu = 0.5 with its own uniform component flags none of
#: them): which edges are outliers is then told by a t of this many dof + uniform refitted to
#: the final residuals. From it up the t's own uniform component tells them.
#: (Until 2026-12 a t of nu >= 4 was not a candidate at all, chosen on garage, lund_door and
#: the classes; the family's dev half, where Laplace, t and mixed-scale noise are common:
#: 63 -> 81 of 100 draws within 1.02x of the best peer with every nu a candidate.)
HEAVY_TAIL_NU = 4.0
#: Folds of the cross-validation that chooses the noise model of stage 4 (issue #29 item 2;
#: on the family's dev half it chose t where the BIC-like penalty had chosen a Gaussian on
#: 18 of 100 draws: 82 -> 83 within 1.02x of the best peer, 5 -> 4 above 1.15x).
MODEL_FOLDS = 5
#: Fewer degrees of freedom in the residuals than this (``E - n + 1`` cycles, weighted by
#: leverage: :func:`~.leverage.residual_dofs`) and no edge is told an outlier: the L2
#: answer. A lone cycle has one: its L1 answer puts the whole cycle error on one edge, which
#: any outlier model then flags. 10 cycles: what two to three model parameters need.
MIN_DOFS = 10.0
#: An edge with fewer degrees of freedom than this in the robust fit (a bridge of it, leverage
#: ~1) is counted in ``diagnostics["residual_dofs"]["edges_without"]``: its residual tells
#: nothing of its noise, so it neither shapes the noise model nor gets flagged.
NO_DOFS = 0.05
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
#: Graduated non-convexity of the Gaussian + outliers stage (Yang et al., "Graduated
#: non-convexity for robust spatial perception", RA-L 2020): its inlier scale starts at the
#: residuals' own spread after the L1 stage (every edge an inlier: near the convex L2 cost)
#: and narrows by this factor an iteration until it reaches the fitted scale. Jumping to the
#: fitted scale at once locked sparse graphs with many gross errors into the L1 answer's
#: basin. Measured on 113 sparse draws (degree < 6, >= 10 % outliers) of bench_family's
#: dev side (even seeds 1000-2998): median error / inlier-L2 oracle 1.47 -> 1.21, draws above
#: 3x the oracle 28 -> 19, 39 draws better by more than 1.2x, 8 worse. Factors 0.5-0.8 are
#: within noise of each other (0.7: 1.19, 15 above 3x; pairwise 10 better, 6 worse than 0.5);
#: 0.5 takes the fewest iterations (10^6 edges with 10 % outliers: 5 graduated + 1 Gaussian
#: where the Gaussian stage alone took 3; 0.7: 9 + 1). A start at 2-16x the fitted scale, or
#: at a fixed 5 deg, did worse than the residuals' spread.
ANNEAL_FACTOR = 0.5
#: The spanning-tree start is carried through the L1 and Gaussian stages beside the chordal
#: relaxation unless its L1 cost is this many times the relaxation's. bench_family dev half,
#: 80 draws with both starts: every ratio from 1.25 to 3 gave the same answers as running
#: both always (5 draws had a tree less than 1.25x as costly as the relaxation, 54 one of
#: 1.25-3x: those ended in one basin from both); at 2 the tree is run on 22 of the 80, at 3
#: on 59. On large graphs with outliers the tree start is 3-5x costlier and never run.
START_COST_RATIO = 2.0
#: Rounds of the repair of weak cuts at most (:func:`_repair_cuts`).
CUT_ROUNDS = 8


def solve_adaptive(q_tree, n, edges, qrel, w, anchor, system, lap, lev, opts, callback=None, mark=None, w_linear=None,
                   full=True, cap_rough=True):
    """Run the adaptive pipeline (module docstring) from the spanning-tree rotations
    ``q_tree`` (4, n); ``lev`` (E,) is each edge's leverage (:func:`~.leverage.leverage`),
    by which the residuals are standardised. Returns ``(q, iterations, converged, model, info)``: the final
    :class:`~.noise_model.NoiseModel` (of leverage-standardised residuals) and a dict of what
    was chosen and why (starts and their L1 costs, models, likelihoods), for reports; ``info["flags"]``,
    when present, is the model that tells outliers (for a heavy-tailed final model).
    ``w_linear``: the weights of the chordal start (default ``w``; with information
    matrices, ``w`` times each edge's isotropic precision). Residual sizes are
    ``system.angles`` throughout (Mahalanobis norms with information matrices).
    ``full=False``: stages 1-3 only (the Gaussian + outliers model, no search for heavier
    tails, edge qualities or clean data): a start for a caller that refines further (the
    rig solve's round 0). ``cap_rough=False``: the rough stages weigh the information uncapped
    (:func:`_rough_stages`; the solve again after the tests of the weights and information)."""
    mark = mark or (lambda *a, **k: None)
    tol = np.deg2rad(opts.step_tol_deg)
    stage_tol = max(np.deg2rad(opts.stage_tol_deg), tol)
    info: dict = {}
    starts = _starts(q_tree, n, edges, qrel, w if w_linear is None else w_linear, anchor, opts, mark)
    dofs = residual_dofs(lev)  # each residual's weight in the fits: a bridge's zero residual tells nothing
    if dofs.sum() < MIN_DOFS:
        # Too few cycles to tell an outlier from noise (one cycle's error can be put on any of its edges): the
        # L2 answer, every edge an inlier.
        plain = lambda theta: w  # noqa: E731 - constant weights: the L2 cost
        q, it, conv = solve_weighted(starts.get("chordal", q_tree), system, lap, plain, opts.max_iterations, tol, callback, "l2")
        mark("l2", it, conv)
        t = standardised(system.angles(q), lev)
        info.update(model="gauss0", residual_dofs=float(dofs.sum()))
        return q, it, conv, _pure_gaussian(t, np.maximum(dofs, 1e-12)), info
    rough = _rough_stages(n, edges, anchor, system, lap, opts, cap_rough)
    q, iterations, conv, state = _best_start(starts, n, edges, qrel, w, anchor, system, lap, lev, dofs, opts, tol, stage_tol,
                                             callback, mark, info, rough)
    q, it, state = _repair_cuts(q, state, n, edges, qrel, w, anchor, system, lap, lev, dofs, opts, tol, callback, mark, info)
    iterations += it
    model: NoiseModel = state["model"]
    info["gaussian"] = model.describe()
    if not full:
        info["model"] = "gauss"
        return q, iterations, conv, model, info
    # 4. heavier tails or two qualities, chosen out of sample; or no outliers at all
    # Each residual counts the smaller of its degrees of freedom in the graph and in the robust fit: an inlier
    # edge whose cycles all run through edges the fit let go is a bridge of the fit, its residual ~0 whatever
    # its noise (sparse graphs with many gross errors: a t or a second Gaussian 6e-5 deg wide, an unbounded
    # likelihood, then chosen on most draws); an outlier keeps its share in the graph (so that the outlier
    # fraction stays a share of edges).
    fit_dofs = fitted_residual_dofs(n, edges, model.weights(standardised(system.angles(q), lev))[0]
                                    * (w if w_linear is None else w_linear))
    info["residual_dofs"] = {"graph": round(float(dofs.sum()), 3)}
    dofs = np.minimum(dofs, fit_dofs)
    info["residual_dofs"].update(fit=round(float(dofs.sum()), 3), edges_without=int(np.count_nonzero(dofs < NO_DOFS)))
    t, om = subset(standardised(system.angles(q), lev), opts.seed, dofs)
    best, model, heavy, two = choose_model(t, om, model, system.information is not None, opts.seed, info)
    if best == "gauss":
        # the clean-data test's penalty (an outlier fraction of 0 is the boundary of its model: a held-out score
        # cannot tell it from a small one; BIC-like, the residuals' degrees of freedom, not their count)
        penalty = 0.5 * np.log(max(float(om.sum()), 2.0))
        q, it, best, model = _clean_or_not(q, system, lap, w, lev, dofs, model, penalty, opts, tol, callback, info)
        iterations += it
        if best == "gauss0":
            mark("l2", it, True)
    info["model"] = best
    if best not in ("gauss", "gauss0"):
        q, it, conv, model = _final_stage(best, heavy, two, q, system, lap, w, lev, dofs, opts, tol, callback)
        iterations += it
        mark(best, it, conv)
    if best == "t" and heavy.nu < HEAVY_TAIL_NU:
        # A tail this heavy explains gross errors too: which edges are outliers is told by a t of
        # HEAVY_TAIL_NU dof + uniform refitted to the final residuals: the heaviest tail still
        # called noise (a Gaussian + uniform refit had flagged the tail itself: cubicle 2,133 of
        # 16,869 edges where 0.1 % of its triangles close above 10 deg; now 75. Ellis Island:
        # 5,881 -> 3,627 flagged, 98.2 % of its 2,467 edges > 30 deg off the truth among them,
        # 94 % of the flagged > 5 deg off).
        t, om = subset(standardised(system.angles(q), lev), opts.seed, dofs)
        info["flags"] = fit_t(t, seed=opts.seed, weights=om, nus=(HEAVY_TAIL_NU,))
    logger.info("adaptive: start %s, noise model %s (%s)", info.get("start", "mst"), best,
                ", ".join(f"{k} {v}" for k, v in model.describe().items()))
    return q, iterations, conv, model, info


def _starts(q_tree, n, edges, qrel, w_linear, anchor, opts, mark) -> dict:
    """Stage 1: the given start (the maximum spanning tree with init "auto") and, with init
    "auto", the chordal relaxation (weights ``w_linear``), by name."""
    starts = {"mst" if opts.init == "auto" else opts.init: q_tree}
    if opts.init == "auto" and len(edges) > n - 1:
        starts["chordal"] = chordal_start(n, edges, qrel, w_linear, anchor, opts.linear_solver, opts.seed)
        mark("start_chordal", 1, True)
    return starts


def _best_start(starts, n, edges, qrel, w, anchor, system, lap, lev, dofs, opts, tol, stage_tol, callback, mark, info,
                rough=None):
    """Stages 2-3 (:func:`_robust_stages`) from each start, the answer of lowest L1 cost over
    every edge kept (a spanning tree far costlier than the relaxation from the outset is not
    run: :data:`START_COST_RATIO`). Returns ``(q, iterations, converged, state)``; the starts'
    costs and the choice go into ``info``."""
    cost = {k: _l1_cost(w, system, v) for k, v in starts.items()}
    if len(starts) > 1:
        info["start_cost_deg"] = cost
        if cost["mst"] >= START_COST_RATIO * cost["chordal"]:
            del starts["mst"]
    runs = {name: _robust_stages(q0, name == "mst", n, edges, qrel, w, anchor, system, lap, lev, dofs, opts, tol, stage_tol,
                                 callback, lambda s, it, c, name=name: mark(s, it, c, start=name), rough)
            for name, q0 in starts.items()}
    cost = {name: _l1_cost(w, system, r[0]) for name, r in runs.items()}
    info["start"] = min(cost, key=cost.get)
    if len(runs) > 1:
        info["robust_cost_deg"] = cost
    q, iterations, conv, state, more = runs[info["start"]]
    iterations += sum(r[1] for name, r in runs.items() if name != info["start"])  # work done, kept or not
    info.update(more)
    return q, iterations, conv, state


def _repair_cuts(q, state, n, edges, qrel, w, anchor, system, lap, lev, dofs, opts, tol, callback, mark, info):
    """Weak cuts of stage 3's answer repaired (:mod:`.cuts`): where the inlier edges hold a
    part of the cameras to the rest by one edge or none, and the edges across that the fit
    calls outliers agree on another turn of the part that its noise model likes better, the
    part is turned so and stage 3 run again from there; the answer is kept only when that
    model's cost of all the edges (:meth:`~.noise_model.NoiseModel.vector_cost`) fell, and
    the search goes on from it, at most :data:`CUT_ROUNDS` times. Each round turns every cut
    it can at once (the best of nested ones), and only the best one when that did not lower
    the cost. Returns ``(q, iterations,
    state)``; ``info["cut_moves"]`` counts the moves kept."""
    model = state["model"]
    t = standardised(system.angles(q), lev)
    cost = model.vector_cost(t, w)
    moves, iterations = 0, 0
    for _ in range(CUT_ROUNDS):
        inlier = model.weights(t)[1] >= 0.5
        cuts = bridge_cuts(n, edges, inlier, opts.seed)
        found = cut_moves(cuts, q, edges, qrel, inlier, system, lev, w, model)
        if not found:
            break
        batch = disjoint_moves(cuts, found)
        for chosen in ([batch, found[:1]] if len(batch) > 1 else [batch]):  # every cut apart at once, else the best
            trial = {"model": model}
            q_new, it, _ = _gaussian_stage(turn_sides(q, cuts, chosen, anchor), n, edges, qrel, anchor, system, lap, lev,
                                           _gaussian_weights(trial, w, lev, dofs, opts.seed), trial, opts, tol, callback,
                                           lambda *a, **k: None, {})
            iterations += it
            t_new = standardised(system.angles(q_new), lev)
            new_cost = model.vector_cost(t_new, w)
            if new_cost < cost:
                q, t, cost, state, moves = q_new, t_new, new_cost, trial, moves + len(chosen)
                break
        else:  # nothing kept
            break
    if iterations:
        info["cut_moves"] = moves
        mark("cut_repair", iterations, True)
    return q, iterations, state


def _rough_stages(n, edges, anchor, system, lap, opts, cap=True):
    """``(system, laplacian)`` of the L1 and graduated stages with information matrices: each
    edge's isotropic part (trace / 3), no larger than the median edge's
    (:meth:`~.residuals.EdgeSystem.isotropic`), and the scalar Laplacian; None without.
    Those stages find the basin and the inliers; the Gaussian stage that follows weighs the
    full information (3x3 blocks, exact), and a wrong edge of high information is by then
    far off in its Mahalanobis norm. Until 2026-12 the isotropic part was not capped: wrong
    edges of high information then set the basin (random_problem(150, 4, 1 deg, 20 %
    outliers, spread 3) with the outliers' information x25, seeds 0-11: 6 of 12 above
    80 deg; capped: 0.99-1.49 deg, as the solve without information). Without any
    information in these stages the structured draws did as well but the uniform-outlier
    ones with valid information lost (bench_family's dev side, 120 draws with information:
    mean log error / oracle 0.128 -> 0.114 without, 0.065 capped; benchmarks/README.md).
    ``cap=False`` for the solve again from the first answer with the information the tests of
    the weights and information found (the basin is found; capped there, clean draws with
    informative weights were pulled from the L2 answer: dev 186 0.75 -> 1.27x the best peer,
    15 clean edges flagged). A block solve costs 4-5x a scalar one (its fill, matrix products and Gauss-Newton
    blocks): at 20k cameras / 10^6 edges the information-weighted solve took 2.5x the scalar
    one with every stage on blocks."""
    if system.information is None:
        return None
    return system.isotropic(cap), make_laplacian(n, edges, anchor, opts.linear_solver, like=lap)


def choose_model(t, om, model, with_information: bool, seed, info):
    """Stage 4's choice among the Gaussian + outliers (refitted to the residuals ``t``, counted
    ``om`` times), a t and two Gaussian scales, by cross-validation. Returns ``(best, the
    Gaussian, the t, the two scales or None)``; likelihoods go into ``info``."""
    model = fit_gaussian(t, 1, start=model, seed=seed, weights=om)
    heavy = fit_t(t, seed=seed, weights=om)
    ll = {"gauss": model.log_likelihood(t, om), "t": heavy.log_likelihood(t, om)}
    info["log_likelihood"] = ll
    candidates, two = {"gauss": model}, None
    # With information matrices the edges' qualities are given: the model fits their common
    # scale (plus outliers and tails), not qualities of its own (measured: the parking
    # garage's g2o information with gauss2 allowed: whitened residual sum 2.2x the L2
    # optimum). So two scales are only fitted without (the fit is the costliest of stage 4:
    # 50 EM iterations on data of one scale, where it does not converge), and a t of
    # HEAVY_TAIL_NU degrees of freedom or more (a continuous mixture of Gaussian scales: edge
    # qualities again) neither: synthetic pose graphs with their true anisotropic information
    # (bench_classes' slam-aniso, 6 seeds) took a t of 16 dof, 0.98-1.11x the L2 answer's error
    # with up to 8 clean edges flagged (the leverage standardises the isotropic part only).
    if not with_information or heavy.nu < HEAVY_TAIL_NU:
        candidates["t"] = heavy
    if not with_information:
        two = fit_gaussian(t, 2, seed=seed, weights=om)
        ll["gauss2"] = two.log_likelihood(t, om)
        if max(two.sigma) / min(two.sigma) > SCALE_RATIO and min(two.inlier_fraction) > MIN_COMPONENT:
            candidates["gauss2"] = two
    # Chosen by how well each predicts held-out residuals (MODEL_FOLDS-fold cross-validation over the edges, each
    # model refitted on the other folds), not by an in-sample likelihood a model of more parameters always wins
    fitters = {"gauss": lambda tt, ww: fit_gaussian(tt, 1, start=model, seed=seed, weights=ww),
               "t": lambda tt, ww: fit_t(tt, seed=seed, weights=ww, nus=(heavy.nu,)),  # its nu as fitted on all
               "gauss2": lambda tt, ww: fit_gaussian(tt, 2, seed=seed, weights=ww)}
    # (a model that does not even fit better in-sample is not a contender: no folds for it)
    contenders = [k for k in candidates if k == "gauss" or ll[k] > ll["gauss"]]
    best = "gauss"
    if len(contenders) > 1:
        held = cross_validated_log_likelihood(t, om, {k: fitters[k] for k in contenders}, MODEL_FOLDS, seed)
        best, info["held_out_log_likelihood"] = choose_held_out(held)  # more parameters must beat chance
    return best, model, heavy, two


def _final_stage(best, heavy, two, q, system, lap, w, lev, dofs, opts, tol, callback):
    """The maximum-likelihood rotations of stage 4's model ``best`` ("t": the fixed ``heavy``,
    each step kept only if it lowers its negative log-likelihood of the residual vectors;
    "gauss2": the two scales ``two`` re-fitted at every iteration). Returns ``(q, iterations,
    converged, model)``."""
    state = {"model": two}
    if best == "t":
        def stage_weights(theta):
            return w * heavy.weights(standardised(theta, lev))[0]
    else:
        def stage_weights(theta):
            tt = standardised(theta, lev)
            state["model"] = fit_gaussian(tt, 2, start=state["model"], iterations=8, seed=opts.seed, weights=dofs)
            return w * state["model"].weights(tt)[0]

    # a fixed t: its negative log-likelihood (of the residual vectors) is the cost every step must not raise
    cost = (lambda theta: heavy.vector_cost(standardised(theta, lev), dofs * w)) if best == "t" else None
    q, it, conv = solve_weighted(q, system, lap, stage_weights, opts.max_iterations, tol, callback, best, cost=cost)
    return q, it, conv, (heavy if best == "t" else state["model"])


def _l1_cost(w, system, q) -> float:
    """The weighted mean residual size (deg) of rotations ``q``: the L1 stage's cost."""
    return float(np.degrees(w @ system.angles(q) / w.sum()))


def _robust_stages(q, from_tree, n, edges, qrel, w, anchor, system, lap, lev, dofs, opts, tol, stage_tol, callback, mark,
                   rough=None):
    """Stages 2 (L1) and 3 (Gaussian + uniform outliers, re-fitted at every iteration;
    cameras left without an inlier edge re-seeded) from the start ``q``.
    Returns ``(q, iterations, converged, state, info)``, ``state["model"]`` the fitted
    Gaussian + outliers model. ``rough``: ``(system, laplacian)`` of the L1 and graduated
    stages when they differ from the final one's (information matrices: their isotropic
    parts, capped, :meth:`~.residuals.EdgeSystem.isotropic`)."""
    info: dict = {}
    final_system, final_lap = system, lap
    system, lap = rough or (system, lap)
    state = {"model": None}
    # L1, its first step from a spanning tree at a looser CG tolerance: L1_FIRST_RTOL
    q, iterations, conv = solve_irls(q, edges, qrel, w, anchor, "l1", 1.0, min(opts.l1_iterations, 1), stage_tol, laplacian=lap,
                                     system=system, callback=callback, stage="l1", rtol=L1_FIRST_RTOL if from_tree else None)
    if not conv and opts.l1_iterations > 1:
        q, more, conv = solve_irls(q, edges, qrel, w, anchor, "l1", 1.0, opts.l1_iterations - 1, stage_tol, laplacian=lap,
                                   system=system, callback=callback, stage="l1", first_iteration=2)
        iterations += more
    mark("l1", iterations, conv)
    gaussian_weights = _gaussian_weights(state, w, lev, dofs, opts.seed)
    # Graduated non-convexity: the first iterations weight the edges as a Gaussian whose scale starts at the
    # residuals' own spread (every edge an inlier) and narrows by ANNEAL_FACTOR an iteration down to the fitted one
    t = standardised(system.angles(q), lev)
    state["floor"] = float(np.sqrt((t * t) @ dofs / (3.0 * max(float(dofs.sum()), 1e-300))))
    it = 0
    while it < opts.max_iterations:
        q, one, conv = solve_weighted(q, system, lap, gaussian_weights, 1, 0.0, callback, "graduated", first_iteration=it + 1)
        it += one
        if state["floor"] <= state["model"].sigma[0]:
            break
        state["floor"] *= ANNEAL_FACTOR
    iterations += it
    mark("graduated", it, True)
    state["floor"] = 0.0
    if system is not final_system:  # the rough view's stages are over: its kept sizes are not needed
        system.forget()
    q, it, conv = _gaussian_stage(q, n, edges, qrel, anchor, final_system, final_lap, lev, gaussian_weights, state, opts,
                                  tol, callback, mark, info, iterations)
    return q, iterations + it, conv, state, info


def _gaussian_weights(state, w, lev, dofs, seed):
    """The IRLS weights of the Gaussian + uniform outliers model, re-fitted (into
    ``state["model"]``) to the residuals at every call; its inlier scale no narrower than
    ``state["floor"]`` when set (the graduated stage)."""

    def gaussian_weights(theta):
        t = standardised(theta, lev)
        state["model"] = fit_gaussian(t, 1, start=state["model"], iterations=8 if state["model"] else 50, seed=seed,
                                      weights=dofs)
        model = state["model"]
        if state.get("floor", 0.0) > model.sigma[0]:  # graduated: the inlier scale no narrower than the floor
            model = NoiseModel("gauss", (state["floor"],), (1.0 - model.outlier_fraction,), model.outlier_fraction)
        return w * model.weights(t)[0]

    return gaussian_weights


def _gaussian_stage(q, n, edges, qrel, anchor, system, lap, lev, gaussian_weights, state, opts, tol, callback, mark, info,
                    done=0):
    """Stage 3's fixed point from ``q`` (``gaussian_weights``: :func:`_gaussian_weights`), then
    again after cameras with no inlier edge are re-seeded. Returns ``(q, iterations, converged)``;
    ``done``: the iterations before it (the re-seeded run's numbering)."""
    q, iterations, conv = solve_weighted(q, system, lap, gaussian_weights, opts.max_iterations, tol, callback, "gaussian")
    mark("gaussian", iterations, conv)
    # Cameras left with no inlier edge may be stuck where the start put them (a spanning tree
    # through consistent wrong pairs; the L1 stage stops on the median step): move each to
    # the L1 mean of its neighbours' predictions and go on.
    theta = system.angles(q)
    inlier = state["model"].weights(standardised(theta, lev))[1] >= 0.5
    q_new, moved = _reseed_orphans(q, n, edges, qrel, inlier, anchor)
    if moved:
        info["reseeded_cameras"] = moved
        q, it, conv = solve_weighted(q_new, system, lap, gaussian_weights, opts.max_iterations, tol, callback, "gaussian",
                                     first_iteration=done + iterations + 1)
        iterations += it
        mark("gaussian_reseeded", it, conv)
    return q, iterations, conv


def _clean_or_not(q, system, lap, w, lev, dofs, model, penalty, opts, tol, callback, info):
    """Are there outliers at all, or is the data clean (Gaussian noise only)?

    The Gaussian + uniform fit always finds a few "outliers" in the tail of clean data, and
    the robust weights then make their residuals larger still. So the question is asked at
    the L2 answer: one Gauss-Newton step of plain (information-weighted) L2 from ``q``, then
    the penalised likelihood of its residuals with and without the outlier component. Clean
    (the outlier fraction does not pay for its parameter): the L2 stage is run to the end,
    and the two hypotheses are compared once more, each at its own answer (the plain
    Gaussian at the L2 answer, the Gaussian + outliers at ``q``); clean again: every edge an
    inlier (model "gauss0"). Else ``q`` is kept. Returns ``(q, iterations, "gauss" or
    "gauss0", model)``. (With information matrices the test's step is on the 3x3 blocks:
    on their isotropic parts, 8 of 50 clean family draws with information were told to
    have outliers.)"""
    plain = lambda theta: w  # noqa: E731 - constant weights: the L2 cost
    q1, it1, conv = solve_weighted(q, system, lap, plain, 1, 0.0, None, "l2-test")
    t1, om = subset(standardised(system.angles(q1), lev), opts.seed, dofs)
    pure = _pure_gaussian(t1, om)
    gain = _with_outliers(t1, om, model, opts.seed).log_likelihood(t1, om) - pure.log_likelihood(t1, om)
    info["outlier_test"] = {"log_likelihood_gain": float(gain), "penalty": float(penalty)}
    if gain > penalty:
        return q, 0, "gauss", model
    q2, it, conv = solve_weighted(q1, system, lap, plain, opts.max_iterations, tol, callback, "l2", first_iteration=2)
    # ... and each hypothesis at its own maximum: the plain Gaussian at the L2 answer against the Gaussian + outliers
    # at the robust one. On a sparse graph the L2 step spreads gross errors over whole cycles, where one step's
    # residuals no longer show them; clean data never gain here (the L2 answer is the Gaussian's maximum). The
    # likelihood of the residual *vectors* (NoiseModel.vector_cost): the angles' density has a t^2 factor that
    # makes an edge fitted exactly (the robust answer fits some) infinitely unlikely.
    t0, om0 = subset(standardised(system.angles(q), lev), opts.seed, dofs)
    t2, om2 = subset(standardised(system.angles(q2), lev), opts.seed, dofs)
    pure = _pure_gaussian(t2, om2)
    joint = pure.vector_cost(t2, om2) - _with_outliers(t0, om0, model, opts.seed).vector_cost(t0, om0)
    info["outlier_test"]["joint_log_likelihood_gain"] = float(joint)
    if joint > penalty:
        return q, it + it1, "gauss", model
    return q2, it + it1, "gauss0", pure


def _with_outliers(t, om, model, seed) -> NoiseModel:
    """The Gaussian + outliers of residual angles ``t`` (counted ``om`` times each): EM from
    the robust stage's ``model`` and from the residuals' own median, the likelier kept. (An
    L2 step can move the residuals far from that model, consistent wrong pairs pulling it,
    where the warm start alone ended below the pure Gaussian: doppelganger projects called
    clean, 7 deg median error.)"""
    fits = (fit_gaussian(t, 1, start=model, seed=seed, weights=om), fit_gaussian(t, 1, seed=seed, weights=om))
    return max(fits, key=lambda m: m.log_likelihood(t, om))


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
    from .. import so3_rows
    from .single_iterative import geodesic_l1_means

    # every edge seen from both ends: (camera, neighbour, rotation neighbour -> camera)
    cam = np.concatenate([edges[:, 1], edges[:, 0]])
    nbr = np.concatenate([edges[:, 0], edges[:, 1]])
    rot = np.concatenate([qrel, so3_rows.qconj_rows(qrel)], axis=1)
    pick = np.flatnonzero(np.isin(cam, orphans))
    pick = pick[np.argsort(cam[pick], kind="stable")]
    pred = so3_rows.qmul_rows(rot[:, pick], q[:, nbr[pick]])
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
