"""Multiple rotation averaging with gravity priors (issue #17, item 3).

Each image ``i`` may carry a gravity direction ``g_i``: a unit vector in the camera's frame,
the direction "down" as the camera sees it. COLMAP's convention (``PosePrior.gravity``,
``pycolmap.run_rotation_averaging(use_gravity=True)``): the world's down direction is
``d = (0, 1, 0)`` (:data:`GRAVITY_WORLD`) and a perfect prior satisfies ``g_i = R_i d``
with ``R_i`` = cam_from_world. With an exact gravity an image keeps one degree of freedom,
its yaw about ``d``; with a noisy one (``sigma`` degrees) its tilt may move within that noise.

Noise model (the one this module assumes and reports in ``diagnostics["gravity"]``):

* **tilt** - a measured ``g_i`` is the true one turned about an axis perpendicular to it by a
  2-D Gaussian vector of standard deviation ``sigma_i`` per axis (so the tilt angle is
  Rayleigh distributed: median 1.18 sigma, RMS 1.41 sigma). ``sigma_i = 0``: exact (a hard
  constraint). The prior term of image ``i`` is ``|t_i|^2 / (2 sigma_i^2)`` with ``t_i`` the
  rotation vector taking ``d`` to ``R_i^T g_i`` (information ``sigma^-2`` on the two tilt
  axes, none about gravity).
* **edges** - ``R_ij = R_j R_i^T exp(e)``, ``e`` isotropic with standard deviation
  ``sigma_edge`` per axis (estimated from the yaw residuals, whose first-order part is free
  of the gravity errors), under the robust loss of :mod:`rotgraph.losses` (``SolveOptions``:
  ``loss``, ``loss_scale_deg``, its re-fit to the inliers, ``outlier_threshold_deg``).

Algorithm
---------
1. **Gravity alignment.** ``A_i`` (COLMAP's ``GravityAlignedRotation``: ``A_i e_y = g_i``)
   and ``C`` with ``C e_y = d``. Every gravity image is ``R_i = A_i Y(theta_i) C^T``
   (``Y``: a rotation about ``e_y``), so an edge between two of them measures
   ``M_ij = A_j^T R_ij A_i = Y(theta_j - theta_i)``: its twist about ``e_y`` (swing-twist
   decomposition) is the yaw difference ``phi_ij``, its swing how far the pair disagrees
   with gravity.
2. **Robust 1-D synchronisation** (:mod:`.gravity_yaw`) of ``theta`` on the gravity edges'
   largest component:
   maximum spanning tree start (:func:`~.spanning_tree.spanning_tree_rotations` on the pure
   yaw rotations), an L1 stage, then IRLS with the robust loss (weights from each edge's
   full residual angle, twist and swing), its scale re-fitted to the inliers as in
   ``method="irls"``; residuals wrapped to ``(-pi, pi]``. Each step: one anchored scalar
   Laplacian solve (:class:`~.laplacian.AnchoredLaplacian`, one right-hand side).
2b. **Gravity noise estimate** (:mod:`.gravity_sigma`; images whose ``sigma`` is None / NaN).
3. **3-DOF refinement** (:mod:`.gravity_refine`) when some ``sigma_i > 0`` or some image has
   no gravity (mixed case): Gauss-Newton IRLS on the robust edge cost plus the gravity prior terms, the
   update ``R_i <- R_i exp(w_i)`` with ``w_i`` restricted to ``span(d)`` for exact gravity
   images (their tilt stays exact) and free otherwise; the gauge is the yaw of one gravity
   image. In the mixed case the images the 1-D stage does not reach start from their
   neighbours (a few of them) or from rotgraph's unconstrained solve (the same pipeline on
   the component without its priors), rotated into the gravity frame (geodesic L1 mean over the images of the 1-D stage); gravity images
   outside it are projected onto their gravity.

Without any gravity image in the largest component the result is that of
:func:`~.rotation_averaging.average_rotations` without gravity. Rigs are used by solving the
frame graph (each frame's gravity from its images'), not by this variant itself (a graph
with rigs solved image by image says so in ``diagnostics``), and per-edge information
matrices are not used.

Where things are
----------------
The priors travel with the graph (:attr:`~rotgraph.viewgraph.ViewGraph.gravity`,
:class:`~rotgraph.priors.GravityPriors`, :meth:`~rotgraph.viewgraph.ViewGraph.with_gravity`)
and go through the one pipeline (:func:`~.rotation_averaging.average_rotations`,
:mod:`.stages`), whose solve stages this variant replaces (:mod:`.gravity_solve`). This
module gathers the public names: the conventions and geometry (:mod:`.gravity_geometry`),
the tilt / yaw evaluation (:func:`rotgraph.evaluate.tilt_yaw_errors`) and
:func:`average_rotations_with_gravity`.
"""

from __future__ import annotations

from ..evaluate import TiltYawErrors, tilt_yaw_errors
from ..viewgraph import ViewGraph
from .gravity_geometry import GRAVITY_WORLD, gravity_aligned_rotations, gravity_of, perturb_gravity
from .rotation_averaging import average_rotations
from .types import AveragingResult, SolveOptions

__all__ = [
    "GRAVITY_WORLD",
    "TiltYawErrors",
    "average_rotations_with_gravity",
    "gravity_aligned_rotations",
    "gravity_of",
    "perturb_gravity",
    "tilt_yaw_errors",
]


def average_rotations_with_gravity(graph: ViewGraph, gravity, sigma_deg=None, options: SolveOptions | None = None, *,
                                   gravity_world=GRAVITY_WORLD, **overrides) -> AveragingResult:
    """Multiple rotation averaging of ``graph`` with per-image gravity priors: the earlier
    spelling of ``average_rotations(graph.with_gravity(gravity, sigma_deg, gravity_world),
    options, **overrides)``, which it is (new code: that, or
    ``average_rotations(graph, gravity=..., gravity_sigma_deg=...)``).

    Parameters
    ----------
    graph : ViewGraph
        The view graph (``n`` images).
    gravity : (n, 3) array_like
        Each image's gravity direction in its camera frame (normalised here; NaN rows: no
        gravity), COLMAP's ``PosePrior.gravity``: ``g_i ~ R_i gravity_world``.
    sigma_deg : float, (n,) array_like or None
        The gravity noise per tilt axis in degrees (0: exact, the tilt is held fixed; inf: no
        prior; None, the default, or NaN entries: estimated from the data, one value for all
        those images, given values win; 0 when not distinguishable from zero).
    options : SolveOptions, optional
        The solver options (``loss``, ``loss_scale_deg``, ``rescale``, ``l1_iterations``,
        ``max_iterations``, ``step_tol_deg``, ``stage_tol_deg``, ``outlier_threshold_deg``
        (None: 10 deg), ``use_weights``, ``linear_solver``; the mixed case's unconstrained
        start uses them all).
    gravity_world : (3,) array_like
        The world's down direction (default :data:`GRAVITY_WORLD`).
    **overrides
        Fields of :class:`SolveOptions` that replace those of ``options``.

    Returns
    -------
    AveragingResult
        In the gravity frame (``R_i gravity_world ~ g_i``), the gauge the yaw of
        ``result.anchor``; ``result.diagnostics["gravity"]`` reports the error model (tilt
        and yaw), the stages and the counts, the estimated noise (``sigma_deg_estimated``,
        ``sigma_estimation``) and the images whose gravity was found wrong and solved without
        it (``gravity_outliers``, node indices). See the module docstring.
    """
    return average_rotations(graph.with_gravity(gravity, sigma_deg, gravity_world), options, **overrides)
