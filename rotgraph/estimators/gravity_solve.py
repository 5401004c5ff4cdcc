"""The gravity variant of the solve stages (the algorithm and noise model: :mod:`.gravity`).

The pipeline (:func:`.stages.run`) runs it in place of a method's stages when the
graph carries gravity priors (:attr:`~rotgraph.viewgraph.ViewGraph.gravity`), between the
shared first and last stages (:func:`.stages.prepare`, :func:`.stages.finish`)::

    s = GravitySolve(component, priors, world, options)   # 1. the gravity-aligned edges
    s.yaw_stage()                                         # 2. the 1-D synchronisation
    s.noise_estimate()                                    # 2b. the gravity noise not given
    if s.needs_refine:                                    # 3. noisy gravity, images without
        if not s.neighbour_start() and s.needs_start:
            s.unconstrained_start(<the plain solve of the component>)
        s.refine()
    solution = s.solution()                               # -> stages.finish

The 1-D stages are :mod:`.gravity_yaw`, the noise estimate :mod:`.gravity_sigma`, the 3-DOF
refinement :mod:`.gravity_refine`.
"""

from __future__ import annotations

import logging

import numpy as np

from .. import so3, so3_rows
from ..losses import loss_rho, positive_loss_weight
from ..priors import CheckedGravity
from ..graph_analysis import connected_components
from .gravity_geometry import (
    gravity_aligned_rotations,
    gravity_frame,
    tilt_residuals,
    unit_rows,
    wrap_angle,
    yaw_of,
    yaw_rotations,
)
from .gravity_refine import fill_from_neighbours, refine_3dof
from .gravity_sigma import estimate_gravity_sigma
from .gravity_yaw import MIN_EDGE_SIGMA_DEG, ModelWeight, YawEdges, approximate_leverage, linear_solver, solve_yaw
from .stage_types import OUTLIER_THRESHOLD_DEG, Component, Solution
from .stats import median
from .types import AveragingResult, SolveOptions

__all__ = ["GravitySolve", "GravitySolution"]

logger = logging.getLogger(__name__)

# Median of the half-normal distribution in units of sigma (the Maxwell's, the 3-D one:
# stats.MAXWELL_MEDIAN).
HALF_NORMAL_MEDIAN = 0.6745
#: Images outside the 1-D stage are started from their neighbours (no unconstrained solve)
#: when they are at most this fraction of the component.
NEIGHBOUR_START_FRACTION = 0.1


class GravitySolve:
    """The gravity variant's state between its stages (module docstring), on the component
    ``comp`` (the priors ``priors`` are the whole graph's, checked; ``world`` the world's down
    direction). After each stage: ``R`` (n, 3, 3) the rotations so far (NaN: not yet),
    ``in_yaw`` the images the 1-D stage solved, ``anchor`` the gauge (the yaw of one gravity
    image), ``diag`` the report (``diagnostics["gravity"]``)."""

    def __init__(self, comp: Component, priors: CheckedGravity, world, opts: SolveOptions):
        self.comp, self.opts = comp, opts
        sub, nodes = comp.sub, comp.nodes
        n = self.n = comp.n
        self.edges = comp.edges
        self.d = unit_rows(np.asarray(world, dtype=np.float64))
        self.g, self.has, self.sigma = priors.direction[nodes], priors.has[nodes], priors.sigma[nodes]
        self.diag: dict = {"n_images": n, "n_with_gravity": int(self.has.sum())}
        self.w = sub.weights / median(sub.weights) if opts.use_weights else np.ones(sub.n_edges)
        self.R = np.full((n, 3, 3), np.nan)
        self.in_yaw = np.zeros(n, dtype=bool)
        self.scale = np.deg2rad(opts.loss_scale_deg)
        self.iterations, self.converged, self.refined = 0, True, False
        self.anchor = self.sigma_edge = self.sigma_estimated = None
        self.flagged = np.zeros(n, dtype=bool)
        self.hard = self.has & (self.sigma == 0)  # exact gravity (again after the noise estimate)
        # 1. gravity alignment: R_i = A_i Y(theta_i) C^T; a gravity edge measures a yaw difference
        self.A = np.full((n, 3, 3), np.nan)
        self.A[self.has] = gravity_aligned_rotations(self.g[self.has])
        self.C = gravity_aligned_rotations(self.d[None])[0]

    def _aligned_edges(self):
        """The edges between gravity images ``ge``, their yaw differences ``phi`` and swings
        ``swing2`` (the twist and swing of ``M_ij = A_j^T R_ij A_i`` about ``e_y``)."""
        edges, A = self.edges, self.A
        ge = np.flatnonzero(self.has[edges[:, 0]] & self.has[edges[:, 1]])
        M = np.swapaxes(A[edges[ge, 1]], 1, 2) @ self.comp.sub.cam2_from_cam1[ge] @ A[edges[ge, 0]]
        qm = so3_rows.quaternion_rows_from_matrices(M)
        phi = wrap_angle(2.0 * np.arctan2(qm[2], qm[0]))
        swing2 = (qm[1] ** 2 + qm[3] ** 2) / np.maximum(qm[0] ** 2 + qm[2] ** 2 + qm[1] ** 2 + qm[3] ** 2, 1e-300)
        return ge, phi, swing2

    def yaw_stage(self) -> None:
        """2. The robust 1-D synchronisation on the gravity edges' largest component
        (:func:`.gravity_yaw.solve_yaw`), and the edge noise from its residuals."""
        ge, phi, swing2 = self._aligned_edges()
        n, edges, has = self.n, self.edges, self.has
        if len(ge):
            ncomp, lab = connected_components(n, edges[ge])
            big = int(np.argmax(np.bincount(lab[has], minlength=ncomp)))
            yaw_nodes = np.flatnonzero((lab == big) & has)
            if len(yaw_nodes) >= 2:
                remap = np.full(n, -1)
                remap[yaw_nodes] = np.arange(len(yaw_nodes))
                keep = (remap[edges[ge, 0]] >= 0) & (remap[edges[ge, 1]] >= 0)
                ye = ge[keep]
                theta, a_loc, self.scale, it, conv = solve_yaw(len(yaw_nodes), remap[edges[ye]], phi[keep], swing2[keep],
                                                               self.w[ye], self.comp.sub.weights[ye], self.opts, self.comp.mark)
                self.iterations += it
                self.converged = conv
                self.anchor = int(yaw_nodes[a_loc])
                self.R[yaw_nodes] = yaw_rotations(self.A[yaw_nodes], theta, self.C)
                self.in_yaw[yaw_nodes] = True
                self._edge_sigma(YawEdges(remap[edges[ye]], phi[keep], swing2[keep], a_loc), theta, len(yaw_nodes))
        self.diag["n_yaw_stage"] = int(self.in_yaw.sum())

    def _edge_sigma(self, p: YawEdges, theta, n_yaw: int) -> None:
        """The edge noise per axis from the yaw residuals of the inliers (one axis of it, less
        the leverage of the 1-D fit), with at least 10 of them."""
        res, r = p.residuals(theta)
        inl = r <= np.deg2rad(self.opts.outlier_threshold_deg or OUTLIER_THRESHOLD_DEG)
        m_in = int(inl.sum())
        dof = m_in - (n_yaw - 1)
        if m_in >= 10 and dof > 0:
            self.sigma_edge = median(np.abs(res[inl])) / HALF_NORMAL_MEDIAN * np.sqrt(m_in / dof)
            self.diag["edge_sigma_from"] = "yaw residuals"

    def noise_estimate(self) -> None:
        """2b. The gravity noise of the images without a given sigma
        (:func:`.gravity_sigma.estimate_gravity_sigma`); images whose gravity is found wrong
        are solved without it."""
        to_estimate = self.has & np.isnan(self.sigma)
        if to_estimate.any():
            if self.sigma_edge is None:
                self.sigma = np.where(to_estimate, 0.0, self.sigma)
                report = {"estimated": False, "reason": "too few gravity edges to estimate the edge noise from the yaw stage"}
            else:
                self.sigma, self.flagged, report = estimate_gravity_sigma(
                    self.edges, self.comp.sub.cam2_from_cam1, self.g, self.A, self.has, self.sigma,
                    max(self.sigma_edge, np.deg2rad(MIN_EDGE_SIGMA_DEG)))
            rest = to_estimate & ~self.flagged
            self.sigma_estimated = float(np.degrees(self.sigma[rest][0])) if rest.any() else 0.0
            report["n_images"] = int(to_estimate.sum())
            self.comp.mark("gravity_sigma_estimate", 0, True)
            if self.flagged.any():
                self._drop_wrong_gravity()
            self.diag["sigma_estimation"] = report
        self.hard = self.has & (self.sigma == 0)

    def _drop_wrong_gravity(self) -> None:
        """The flagged images solved without their gravity (a new anchor if it was one)."""
        flagged = self.flagged
        logger.warning("gravity: %d image(s) whose gravity disagrees with their neighbours' far beyond the noise: "
                       "solved without it", int(flagged.sum()))
        self.has &= ~flagged
        self.in_yaw &= ~flagged
        self.R[flagged] = np.nan
        self.sigma[flagged] = np.nan
        if self.anchor is not None and flagged[self.anchor]:
            cand = np.flatnonzero(self.in_yaw)
            self.anchor = int(cand[np.argmax(self.comp.sub.degrees()[cand])]) if len(cand) else None

    @property
    def needs_refine(self) -> bool:
        """3. is needed: noisy gravity, or images the 1-D stage did not reach."""
        return bool((self.has & ~self.hard).any() or (~self.in_yaw).any()) and self.n > 1

    @property
    def needs_start(self) -> bool:
        """Images outside the 1-D stage, to start before the refinement."""
        return bool((~self.in_yaw).any())

    def _project(self, proj: np.ndarray) -> None:
        """The rotations of the images ``proj`` onto their gravity: the yaw kept, the
        measured tilt taken."""
        if proj.any():
            self.R[proj] = yaw_rotations(self.A[proj], yaw_of(self.A[proj], self.R[proj], self.C), self.C)

    def neighbour_start(self) -> bool:
        """Few images outside the 1-D stage (wrong gravity, or a few without): each started
        from its neighbours (:func:`.gravity_refine.fill_from_neighbours`), no unconstrained
        solve. Whether it was done."""
        out = ~self.in_yaw
        if not (out.any() and self.in_yaw.any() and out.sum() <= NEIGHBOUR_START_FRACTION * self.n
                and fill_from_neighbours(self.R, self.in_yaw, self.edges, self.comp.sub.cam2_from_cam1)):
            return False
        self.comp.mark("neighbour_start", 0, True)
        self._project(out & self.has)
        return True

    def unconstrained_start(self, base: AveragingResult) -> None:
        """The images outside the 1-D stage started from ``base``, the solve of the component
        without gravity, rotated into the gravity frame (the geodesic L1 mean of its offsets
        to the 1-D stage's images; without those, the frame in which the gravity images
        agree on average); those with gravity projected onto it."""
        from .single import mean

        self.iterations += base.iterations
        self.comp.mark("unconstrained_start", base.iterations, base.converged)
        R0 = base.cam_from_world
        ok0 = np.isfinite(R0).all(axis=(1, 2))
        if not ok0.all():  # cameras the robust solve left out: chain them later from neighbours
            R0 = np.where(ok0[:, None, None], R0, np.eye(3))
        if self.in_yaw.any():
            both = self.in_yaw & ok0
            W = mean(np.swapaxes(R0[both], 1, 2) @ self.R[both], metric="geodesic", norm="l1").rotation
        else:  # no gravity edge: the chordal mean of the rotations taking R_i^T g_i to d
            has = self.has
            W = gravity_frame(R0[has & ok0], self.g[has & ok0], self.d)
            self.anchor = int(np.flatnonzero(has)[np.argmax(self.comp.sub.degrees()[has])])
        fill = ~self.in_yaw
        self.R[fill] = R0[fill] @ W
        self._project(fill & self.has)

    def refine(self) -> None:
        """3. The 3-DOF refinement (:func:`.gravity_refine.refine_3dof`) under the weights of a
        fitted noise model; its edge noise replaces the yaw stage's."""
        n, edges, opts = self.n, self.edges, self.opts
        weight = ModelWeight(self.w, approximate_leverage(n, edges, self.w), opts.seed)
        self.R, it, conv = refine_3dof(self.R, edges, self.comp.qrel, weight, self.g, self.has, self.hard, self.sigma,
                                       self.anchor, self.d, opts.max_iterations, np.deg2rad(opts.step_tol_deg),
                                       linear_solver(n, len(edges), opts.linear_solver) == "cg")
        self.sigma_edge = weight.sigma
        self.diag["edge_sigma_from"] = "noise model of the 3-DOF refinement"
        self.diag["noise_model"] = weight.model.describe()
        self.iterations += it
        self.converged = conv
        self.refined = True
        self.comp.mark("refine_3dof", it, conv)

    def solution(self) -> GravitySolution:
        """The :class:`GravitySolution` for the last stage."""
        return GravitySolution(self)


class GravitySolution(Solution):
    """The gravity variant's rotations, scored by its cost: the robust edge cost over the
    edge noise, plus the gravity prior terms; outliers by a threshold (robust)."""

    method = "gravity"
    robust = True
    model = None

    def __init__(self, s: GravitySolve):
        self.s = s
        self.anchor, self.iterations, self.converged = s.anchor, s.iterations, s.converged
        self.diagnostics = {"gravity": _report(s)}
        self._theta = None

    def theta(self) -> np.ndarray:
        if self._theta is None:
            R, edges = self.s.R, self.s.edges
            self._theta = so3.angle_between(self.s.comp.sub.cam2_from_cam1, R[edges[:, 1]] @ np.swapaxes(R[edges[:, 0]], 1, 2))
        return self._theta

    def rotations(self) -> np.ndarray:
        return self.s.R

    def residuals_deg(self) -> np.ndarray:
        return np.degrees(self.theta())

    def score(self, theta, marks) -> tuple[float, np.ndarray]:
        s = self.s
        prior_cost = 0.0
        soft = s.has & ~s.hard
        if soft.any():
            t = tilt_residuals(s.R[soft], s.g[soft], s.d)
            prior_cost = float(0.5 * ((t * t).sum(axis=1) / s.sigma[soft] ** 2).sum())
        edge_scale = 1.0 if s.sigma_edge is None else max(s.sigma_edge, np.deg2rad(MIN_EDGE_SIGMA_DEG))
        cost = float(s.w @ loss_rho(s.opts.loss, theta, s.scale)) / edge_scale**2 + prior_cost
        return cost, s.w * positive_loss_weight(s.opts.loss, np.maximum(theta, 1e-12), s.scale)


def _report(s: GravitySolve) -> dict:
    """``diagnostics["gravity"]``: the counts, the stages' findings and the error model."""
    has, hard, sub, opts = s.has, s.hard, s.comp.sub, s.opts
    sig_deg = np.degrees(s.sigma[has])
    diag = dict(s.diag)
    diag.update(
        used=True,
        gravity_world=s.d.tolist(),
        n_exact=int(hard.sum()),
        sigma_deg_estimated=s.sigma_estimated,
        gravity_outliers=s.comp.nodes[s.flagged].tolist() if s.sigma_estimated is not None else None,
        n_without_gravity=int((~has).sum()),
        refined_3dof=s.refined,
        error_model={
            "tilt": ("exact: the tilt is held to the gravity (1 DOF per image)" if hard[has].all() else
                     f"Gaussian per tilt axis, sigma {np.median(sig_deg):.3g} deg (median; information sigma^-2 on the "
                     "two axes perpendicular to gravity, none about it)"),
            "yaw": f"{opts.loss} on each edge's residual angle, scale {np.degrees(s.scale):.3g} deg" +
                   ("" if s.sigma_edge is None else
                    f"; isotropic edge noise {np.degrees(s.sigma_edge):.3g} deg per axis (estimated)"),
            "gravity_sigma_deg_median": float(np.median(sig_deg)),
            "edge_sigma_deg": None if s.sigma_edge is None else float(np.degrees(s.sigma_edge)),
            "loss": opts.loss,
            "loss_scale_deg": float(np.degrees(s.scale)),
        },
        information={"used": False} if sub.information is not None else None,
        rigs="not used (images solved one by one)" if sub.rigs is not None else None,
    )
    return {k: v for k, v in diag.items() if v is not None}
