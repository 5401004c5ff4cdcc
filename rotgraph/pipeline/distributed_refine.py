"""Stage 5 of the distributed solve (:mod:`rotgraph.pipeline.distributed`, the client's side):
the adaptive method's refinement over the whole graph as map-reduce. Each IRLS step the
client broadcasts the rotations, fits the noise model to residuals sampled on the shards
(:func:`~rotgraph.pipeline.blocks.sample`), the shards assemble their parts of the weighted
Laplacian, and the client runs Jacobi-preconditioned conjugate gradients
(:func:`~rotgraph.estimators.laplacian.block_pcg`) whose matrix products are one exchange
with the shards each (:class:`_Laplacian`). Then the model choice of the adaptive method (a
t or two scales, cross-validated on the sample). ``run`` is the client's
:class:`~rotgraph.pipeline.distributed._Run` of the solve."""

from __future__ import annotations

import logging

import numpy as np

from . import blocks as bk

logger = logging.getLogger(__name__)


class _Laplacian:
    """The whole graph's anchored Laplacian of one IRLS step as :func:`block_pcg` uses it:
    ``L @ P`` is one exchange (``P`` to every worker, the shards' products summed on the workers
    and the sum back)."""

    def __init__(self, run, states: list, diagonal: np.ndarray):
        self.run, self.states, self.diag = run, states, diagonal

    def diagonal(self) -> np.ndarray:
        return self.diag

    def __matmul__(self, P: np.ndarray) -> np.ndarray:
        if not P.any():
            return np.zeros_like(P)
        p = self.run.scatter(np.ascontiguousarray(P))
        self.run.products += 1
        return self.run.total([self.run.client.submit(bk.state_matvec, st, p) for st in self.states])


# --------------------------------------------------------------------------- stage 5: the refinement


def _samples(run, qf, total: int, degrees=None, spec=None, q_fit=None) -> dict:
    """The shards' residual statistics (:func:`~rotgraph.pipeline.blocks.sample`), pooled."""
    got = run.gather(run.map(bk.sample, qf, total, run.opts.seed, degrees, spec, q_fit))
    return {"t": np.concatenate([g["t"] for g in got]), "dofs": np.concatenate([g["dofs"] for g in got]),
            "t2_dofs": sum(g["t2_dofs"] for g in got), "dofs_sum": sum(g["dofs_sum"] for g in got),
            "l1": sum(g["l1"] for g in got)}


def _irls(run, q: np.ndarray, inside: np.ndarray, policy, max_iterations: int, tol: float, stage: str,
          first_iteration: int = 1, cost=None) -> tuple[np.ndarray, int, bool]:
    """:func:`~rotgraph.estimators.irls.solve_weighted` over the shards: each iteration
    ``policy(qf)`` gives the weights' spec (after any exchange it needs: a noise model's
    fit), the shards assemble their weighted systems, conjugate gradients solve the whole
    one (each product an exchange), and the rotations move; the median step over the
    component's cameras below ``tol`` ends the stage. ``cost(q) -> float``: each step kept
    only if it does not raise it (:func:`~rotgraph.estimators.irls.damped_step`)."""
    from ..estimators.irls import damped_step
    from ..estimators.laplacian import RTOL, block_jacobi, block_pcg
    from ..estimators.residuals import update_rotations

    keep = np.ones(q.shape[1], dtype=bool)
    keep[run.anchor] = False
    c0 = None if cost is None else cost(q)
    for it in range(1, max_iterations + 1):
        qf = run.scatter(q)
        spec = policy(qf)
        states = run.map(bk.weighted_state, qf, spec)
        rhs, diagonal = run.total([run.client.submit(bk.state_rhs, st) for st in states])
        x = np.zeros((q.shape[1], 3))
        if diagonal.ndim == 1:
            x[keep] = block_pcg(_Laplacian(run, states, diagonal), rhs.T[keep], rtol=RTOL)[0]
        else:  # 3x3 blocks (information matrices): one node-major right-hand side, the inverse diagonal blocks
            x[keep] = block_pcg(_Laplacian(run, states, None), rhs.T[keep].reshape(-1, 1), rtol=RTOL,
                                precondition=block_jacobi(diagonal))[0].reshape(-1, 3)
        del states
        if cost is None:
            q, h = update_rotations(q, x)
        else:
            step = damped_step(q, x, update_rotations, cost, c0)
            if step is None:
                return q, it, True  # no descent along this step
            q, h, c0 = step
        step = 2.0 * float(np.median(h[inside]))
        run.callback(stage, it + first_iteration - 1, step)
        logger.debug("distributed %s iteration %d: median step %.3g rad", stage, it + first_iteration - 1, step)
        if step < tol:
            return q, it, True
    return q, max_iterations, False


def _robust_stages(run, q: np.ndarray, inside: np.ndarray, total: int, info: dict) -> tuple[np.ndarray, int, object]:
    """The adaptive method's stages 2-3 (:func:`~rotgraph.estimators.adaptive.solve_adaptive`)
    over the whole graph from the aligned blocks: L1, the graduated Gaussian + outliers, the
    Gaussian + outliers re-fitted every iteration to convergence, then again after cameras
    left without an inlier edge are re-seeded (``info["reseeded_cameras"]``). With information
    matrices L1 and the graduated stage weigh their isotropic parts (specs ending in
    ``"rough"``: :meth:`~rotgraph.pipeline.blocks.Shard.view`), the others the 3x3 blocks.
    Returns ``(q, iterations, model)``."""
    from ..estimators.adaptive import ANNEAL_FACTOR
    from ..estimators.noise_model import NoiseModel, fit_gaussian

    opts = run.opts
    tol = np.deg2rad(opts.step_tol_deg)
    stage_tol = max(np.deg2rad(opts.stage_tol_deg), tol)
    q, iterations, conv = _irls(run, q, inside, lambda qf: ("l1", "rough"), opts.l1_iterations, stage_tol, "l1")
    run.mark("l1", iterations, conv)
    state = {"model": None, "floor": 0.0, "view": ("rough",)}

    def gaussian(qf):
        s = _samples(run, qf, total, None, state["view"])
        state["model"] = fit_gaussian(s["t"], 1, start=state["model"], iterations=8 if state["model"] else 50,
                                      seed=opts.seed, weights=s["dofs"])
        m = state["model"]
        if state["floor"] > m.sigma[0]:  # graduated: the inlier scale no narrower than the floor
            m = NoiseModel("gauss", (state["floor"],), (1.0 - m.outlier_fraction,), m.outlier_fraction)
        return ("model", m, *state["view"])

    s = _samples(run, run.scatter(q), total, None, state["view"])
    state["floor"] = float(np.sqrt(s["t2_dofs"] / (3.0 * max(s["dofs_sum"], 1e-300))))
    it = 0
    while it < opts.max_iterations:
        q, one, conv = _irls(run, q, inside, gaussian, 1, 0.0, "graduated", it + 1)
        it += one
        if state["floor"] <= state["model"].sigma[0]:
            break
        state["floor"] *= ANNEAL_FACTOR
    iterations += it
    run.mark("graduated", it, True)
    state["floor"], state["view"] = 0.0, ()
    q, it, conv = _irls(run, q, inside, gaussian, opts.max_iterations, tol, "gaussian")
    run.mark("gaussian", it, conv)
    # cameras left with no inlier edge moved to the L1 mean of their neighbours' predictions, and on
    # (adaptive._gaussian_stage)
    q_new, moved = _reseed(run, q, state["model"])
    if moved:
        info["reseeded_cameras"] = moved
        q, more, conv = _irls(run, q_new, inside, gaussian, opts.max_iterations, tol, "gaussian", iterations + it + 1)
        run.mark("gaussian_reseeded", more, conv)
        it += more
    return q, iterations + it, state["model"]


def _reseed(run, q: np.ndarray, model) -> tuple[np.ndarray, int]:
    """The re-seeding of :func:`~rotgraph.estimators.adaptive._reseed_orphans` over the shards:
    the cameras without an inlier edge under ``model`` (the inlier degrees summed over the
    shards), each shard's predictions of them (a camera's edges may be on several shards), their
    L1 means on one worker (these predictions are the orphans' edges: they never reach the
    client). Returns ``(q, how many moved)``."""
    from ..estimators.adaptive import orphans_of

    qf = run.scatter(q)
    counts = run.total([run.client.submit(bk.pick, f, "inlier_degree") for f in run.map(bk.finish, qf, model, None, None, None)])
    orphans = orphans_of(run.degree, counts, run.anchor)
    if not len(orphans):
        return q, 0
    return run.gather([run.client.submit(bk.reseed, qf, orphans, *run.map(bk.orphan_predictions, qf, orphans))])[0]


def _final_model(run, q: np.ndarray, inside: np.ndarray, total: int, model, info: dict):
    """The adaptive method's stage 4 on the pooled sample: a t or two Gaussian scales when
    they predict held-out residuals better (:func:`~rotgraph.estimators.adaptive.choose_model`),
    then that model's rotations; when the Gaussian + outliers stays, the clean-data test
    (:func:`~rotgraph.estimators.adaptive.clean_or_not`: the L2 answer when the outliers do not
    pay for their parameter). Each residual counts its degrees of freedom in the robust fit at
    ``q`` throughout, as in one process. Returns ``(q, iterations, converged, model, flags
    model)``."""
    from ..estimators.adaptive import HEAVY_TAIL_NU, choose_model, clean_or_not
    from ..estimators.noise_model import fit_gaussian, fit_t

    opts = run.opts
    tol = np.deg2rad(opts.step_tol_deg)
    spec = ("model", model)
    q_robust, qr = q, run.scatter(q)
    degrees = run.total(run.map(bk.weighted_degrees, qr, spec))
    s = _samples(run, qr, total, degrees, spec)
    info["residual_dofs"] = {"fit_sample": round(float(s["dofs"].sum()), 3)}
    best, model, heavy, two = choose_model(s["t"], s["dofs"], model, run.information, opts.seed, info)

    def sampled(q0):  # the fit sample at q0 (rotations or their future), the degrees of freedom of the robust fit at q
        if q0 is q_robust:
            return s["t"], s["dofs"]
        got = _samples(run, run.scatter(q0) if isinstance(q0, np.ndarray) else q0, total, degrees, spec, qr)
        return got["t"], got["dofs"]

    if best == "gauss":
        def l2(q0, test):
            return _irls(run, q0, inside, lambda qf: ("l2",), 1 if test else opts.max_iterations, 0.0 if test else tol, "l2",
                         1 if test else 2)

        q, it, best, model = clean_or_not(q, l2, sampled, model, opts.seed, info)
        info["model"] = best
        if best == "gauss0":
            run.mark("l2", it, True)
        return q, it, True, model, model
    info["model"] = best
    state = {"model": two}

    def final(qf):
        if best == "t":
            return ("model", heavy)
        t, dofs = sampled(qf)
        state["model"] = fit_gaussian(t, 2, start=state["model"], iterations=8, seed=opts.seed, weights=dofs)
        return ("model", state["model"])

    cost = None
    if best == "t":  # a fixed t: its negative log-likelihood of the residual vectors is the cost no step may raise
        def cost(q0):
            return sum(run.gather(run.map(bk.model_cost, run.scatter(q0), heavy, degrees, spec, qr)))

    q, it, conv = _irls(run, q, inside, final, opts.max_iterations, tol, best, cost=cost)
    run.mark(best, it, conv)
    model = heavy if best == "t" else state["model"]
    flags = model
    if best == "t" and heavy.nu < HEAVY_TAIL_NU:  # which edges are outliers: a t of HEAVY_TAIL_NU dof + uniform
        t, dofs = sampled(q)
        flags = fit_t(t, seed=opts.seed, weights=dofs, nus=(HEAVY_TAIL_NU,))
    return q, it, conv, model, flags


def _information_test(run, q: np.ndarray, total: int, model, info: dict) -> tuple[float, float] | None:
    """The test of the information matrices (:func:`~rotgraph.estimators.methods.information_exponent`,
    one process's after the adaptive method) on the pooled sample of unwhitened residuals at
    ``q``, each counted its degrees of freedom in the fit weighted by ``model``: ``(the exponent
    to rescale the information by, the median mean-variance precision)`` when another exponent
    predicts the noise better (:func:`_weigh_information`), else None; ``info["information_test"]``
    says what was found."""
    from ..estimators.methods import INFORMATION_EXPONENT, information_exponent

    spec = ("model", model)
    qf = run.scatter(q)
    degrees = run.total(run.map(bk.weighted_degrees, qf, spec))
    got = run.gather(run.map(bk.sample, qf, total, run.opts.seed, degrees, spec, None, True))
    t, c, dofs = (np.concatenate([g[k] for g in got]) for k in ("t", "c", "dofs"))
    a, info["information_test"] = information_exponent(t, c, dofs, run.opts.seed, sum(g["dofs_sum"] for g in got))
    return (a - INFORMATION_EXPONENT, float(np.median(c))) if info["information_test"]["used"] else None


def _weigh_information(run, total: int, exponent: float = 0.0, c_median: float = 1.0) -> float:
    """The shards replaced by ones whose information matrices are times ``(c_e / c_median)^(2
    exponent)`` and normalised to a median isotropic precision of 1 (the median of the fit
    sample's: each shard's share of it), the leverages from the isotropic precisions' weighted
    degrees (:func:`~rotgraph.pipeline.blocks.with_information`); with another exponent than 0
    (the solve again after the information test) the rough stages weigh them uncapped, as in
    one process. Returns the median."""
    from ..estimators.stats import median

    stats = run.map(bk.information_stats, exponent, c_median, total, run.opts.seed)
    degrees = run.total([run.client.submit(bk.pick, st, 0) for st in stats])
    unit = float(median(np.concatenate(run.gather([run.client.submit(bk.pick, st, 1) for st in stats]))))
    deg = run.scatter(degrees)
    run.shards = [run.client.submit(bk.with_information, sh, exponent, c_median, deg, 1.0 / unit, exponent == 0.0)
                  for sh in run.shards]
    run.gather(run.map(bk.shard_edges))
    return unit


def _refine(run, q: np.ndarray, inside: np.ndarray, total: int, info: dict) -> tuple:
    """Stage 5 from the aligned blocks ``q``: the robust stages, the model choice and, with
    information matrices, their test; when it finds another exponent, the information
    rescaled and both again from the answer (one process's ``solve_again``; ``info`` then
    the second run's, with the test's report). Returns ``(q, iterations, converged, model,
    flags model)``."""
    q, iterations, model = _robust_stages(run, q, inside, total, info)
    q, it, converged, model, flags = _final_model(run, q, inside, total, model, info)
    iterations += it
    found = _information_test(run, q, total, model, info) if run.information else None
    if found is not None:
        again = {"start": "information_test", "information": info["information"]}
        again["information"]["median_sigma_deg"] = float(np.degrees(1.0 / np.sqrt(_weigh_information(run, total, *found))))
        q, it, model = _robust_stages(run, q, inside, total, again)
        q, more, converged, model, flags = _final_model(run, q, inside, total, model, again)
        iterations += it + more
        report = info["information_test"]
        info.clear()
        info.update(again, information_test=report)
    return q, iterations, converged, model, flags
