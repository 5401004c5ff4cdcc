"""``rotgraph certify`` and ``solve --certify``: files to a certificate of global optimality.

The certificate itself (the Lagrangian-duality test of the chordal cost) is
:func:`rotgraph.estimators.certify.certify`; this module matches a rotation file and an
optional ``--edges-out`` file to a view graph and hands them over.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..viewgraph import ViewGraph

__all__ = ["certify_files", "certify_result", "rotations_for_graph", "inliers_for_graph"]


def rotations_for_graph(graph: ViewGraph, path) -> np.ndarray:
    """The rotations of a rotation file (any format ``rotgraph eval`` reads) in ``graph``'s
    node order, matched as ``rotgraph eval`` matches (:func:`~rotgraph.evaluate.matching_keys`:
    by name when both carry names, else by id); NaN rows for cameras the file lacks. Raises
    :class:`InputError` when no camera matches."""
    from ..evaluate import camera_keys, matching_keys
    from ..io.rotations import read_absolute_rotations

    ids, names, R = read_absolute_rotations(path)
    keys, nodes, _ = matching_keys(camera_keys(ids, names), camera_keys(graph.node_ids, graph.names))
    pos = {k: p for p, k in enumerate(keys)}
    out = np.full((graph.n_nodes, 3, 3), np.nan)
    hit = [(a, pos[k]) for a, k in enumerate(nodes) if k in pos]
    if not hit:
        raise InputError("no camera of the rotations is in the edge file (matched by id and by name)", path=str(path))
    a, b = (np.array(x) for x in zip(*hit))
    out[a] = R[b]
    return out


def inliers_for_graph(graph: ViewGraph, path) -> tuple[np.ndarray, np.ndarray | None]:
    """The ``inlier`` and ``weight`` (or None) columns of an ``--edges-out`` file, in
    ``graph``'s edge order: rows are matched to edges by their unordered id pair and, for
    parallel edges, in file order.
    Raises :class:`InputError` for a row whose pair is not an edge, or edges without a row."""
    from ..io.edges import read_edge_flags

    ids_i, ids_j, flag, weight, lines = read_edge_flags(path)
    key = {str(k): p for p, k in enumerate(graph.node_ids)}

    def pair_keys(a_ids, b_ids, where):
        a = np.array([key.get(str(x), -1) for x in a_ids.tolist()])
        b = np.array([key.get(str(x), -1) for x in b_ids.tolist()])
        miss = (a < 0) | (b < 0)
        if miss.any():
            k = int(np.argmax(miss))
            raise InputError(f"edge ({a_ids[k]}, {b_ids[k]}) is not in the edge file", path=str(path), line=where(k))
        return np.minimum(a, b) * graph.n_nodes + np.maximum(a, b)

    file_keys = pair_keys(ids_i, ids_j, lambda k: int(lines[k]))
    g_keys = np.minimum(graph.edges[:, 0], graph.edges[:, 1]) * graph.n_nodes + np.maximum(graph.edges[:, 0], graph.edges[:, 1])
    # k-th occurrence of a pair in the file <-> k-th occurrence among the graph's edges
    fo = np.argsort(file_keys, kind="stable")
    go = np.argsort(g_keys, kind="stable")
    if len(fo) != len(go) or not np.array_equal(file_keys[fo], g_keys[go]):
        extra = np.setdiff1d(file_keys, g_keys)
        if len(extra):
            k = int(np.flatnonzero(file_keys == extra[0])[0])
            raise InputError(f"edge ({ids_i[k]}, {ids_j[k]}) is not in the edge file", path=str(path), line=int(lines[k]))
        raise InputError(f"{len(fo)} edges listed, the edge file has {len(go)}: give the --edges-out of a solve of it",
                         path=str(path))
    out = np.zeros(graph.n_edges, dtype=bool)
    out[go] = flag[fo]
    weights = None
    if weight is not None:
        weights = np.full(graph.n_edges, np.nan)
        weights[go] = weight[fo]
    return out, weights


def certify_files(rotations, edges, inliers=None, fmt: str = "auto", duplicates: str | None = None,
                  use_weights: bool = False, columns=None, refine: bool = False, output=None,
                  overwrite: bool = False, tol: float | None = None, gap_tol: float | None = None) -> dict:
    """``rotgraph certify ROTATIONS EDGES [--inliers FILE]``: the certificate of the rotations
    on the edges (all, or the inlier ones of an ``--edges-out`` file, weighted by its
    ``weight`` column, the solve's final weights, when it has one; else as
    :func:`_chordal_weights`) as a dict
    (:meth:`~rotgraph.estimators.certify.Certificate.to_dict`, plus ``n_cameras_matched``,
    the cameras of the file found in the graph). ``fmt``, ``duplicates`` and ``columns``
    read EDGES as :func:`~rotgraph.pipeline.read.read_view_graph` does.

    ``refine``: the rotations are first taken to the nearest critical point of that cost
    (:func:`~rotgraph.estimators.staircase.refine_chordal`) and certified there; the dict
    then has ``before`` (the certificate of the rotations as given: their bound and gap) and
    ``refine_iterations``. ``output``: the rotations certified are written there (rotgraph's
    CSV; the cameras matched), checked before any work (``overwrite`` as ``solve``'s). ``tol``
    and ``gap_tol``: as :func:`~rotgraph.estimators.certify.certify`'s."""
    from ..estimators.certify import certify
    from ..io.outputs import check_outputs
    from .read import read_view_graph

    check_outputs([output], [rotations, edges] + ([inliers] if inliers else []), overwrite=overwrite)
    graph = read_view_graph(edges, fmt=fmt, duplicates=duplicates, uncertainty=False, columns=columns)
    R = rotations_for_graph(graph, rotations)
    mask, weights = (None, None) if inliers is None else inliers_for_graph(graph, inliers)
    if weights is not None and not use_weights:  # the solve's own final weights: its chordal problem
        mask = mask & np.isfinite(weights) & (np.nan_to_num(weights) > 0)
        weights = np.where(mask, weights, 1.0)
        cost = "chordal, weighted by the solve's final weights (--inliers file)"
    else:
        weights = _chordal_weights(graph, use_weights, True)
        cost = _cost_words(graph, use_weights, True)
    cert = certify(R, graph.edges, graph.cam2_from_cam1, weights, inliers=mask, tol=tol, gap_tol=gap_tol)
    before, iterations = None, 0
    if refine:
        from ..estimators.staircase import refine_chordal

        before = cert.to_dict()
        R, iterations, _ = refine_chordal(R, graph.edges, graph.cam2_from_cam1, weights, inliers=mask)
        cert = certify(R, graph.edges, graph.cam2_from_cam1, weights, inliers=mask, tol=tol, gap_tol=gap_tol)
    out = cert.to_dict()
    out["cost"] = cost
    matched = np.isfinite(R).all(axis=(1, 2))
    out["n_cameras_matched"] = int(matched.sum())
    if refine:
        out.update(before=before, refine_iterations=int(iterations))
    if output is not None:
        from ..io.writers import write_rotations

        write_rotations(output, graph.node_ids[matched], None if graph.names is None else graph.names[matched], R[matched])
    return out


def _cost_words(graph: ViewGraph, use_weights: bool, use_information: bool) -> str:
    """Which chordal cost :func:`_chordal_weights` certifies, in words (the certificate's ``cost``)."""
    words = "chordal, " + ("weighted by the weight column" if use_weights else "unit weights")
    if graph.information is not None and use_information:
        words += (", times each edge's isotropic precision trace(H)/3: the certificate covers the isotropic part "
                  "of the information matrices, not the anisotropic cost")
    return words


def _chordal_weights(graph: ViewGraph, use_weights: bool, use_information: bool) -> np.ndarray | None:
    """The scalar edge weights of the chordal cost certified: the weight column when
    ``use_weights``, times each edge's isotropic precision ``trace(H) / 3`` when the edges
    carry information matrices (the certificate exists for scalar weights only)."""
    w = graph.weights.astype(np.float64) if use_weights else None
    if graph.information is not None and use_information:
        iso = np.trace(graph.information, axis1=1, axis2=2) / 3.0
        w = iso if w is None else w * iso
    return w


def _certified_stage(graph: ViewGraph, result, options):
    """``(rotations, certificate dict, iterations)``: ``result`` moved to the chordal optimum
    of its own fixed point on ``graph`` and certified there (see :func:`certify_result`):
    on the inlier edges for a robust method, on every edge for the others (chordal,
    quaternion, l2, ...: the cost the user chose is over every edge)."""
    from ..estimators.certify import certify
    from ..estimators.staircase import certified_chordal, refine_chordal
    from ..choices import ROBUST_METHODS

    weights, inliers = result.edge_weights, result.inliers
    if options.method not in ROBUST_METHODS:
        # A non-robust method asked for its cost over every edge: that is what is certified
        # (the 10-degree flags of its report are not a problem of their own).
        inliers = np.ones(graph.n_edges, dtype=bool)
    else:
        split = _inlier_components(graph, result)
        if split > 1:  # the chordal cost on those edges leaves each part a free rotation: not the user's problem
            cert = certify(result.cam_from_world, graph.edges, graph.cam2_from_cam1, inliers=inliers).to_dict()
            cert.update(certified=False, applicable=False, cost="chordal on the inlier edges, in parts: not the problem solved",
                        reason=f"no certificate applies: the inlier edges split the solved cameras into {split} components "
                               "(the outliers flagged were their only links), and a certificate of each part says nothing "
                               "of how they are turned to each other")
            return result.cam_from_world, cert, 0
    if weights is None:
        weights = _chordal_weights(graph, options.use_weights, options.use_information)
        cost = _cost_words(graph, options.use_weights, options.use_information)
    else:  # the solve's final weights: the chordal problem of its own fixed point
        inliers = inliers & np.isfinite(weights) & (np.nan_to_num(weights) > 0)
        weights = np.where(inliers, weights, 1.0)
        cost = "chordal, weighted by the solve's final weights (the problem of its fixed point)"
        if graph.information is not None and options.use_information:
            cost += "; each edge's information enters by its isotropic part trace(H)/3, not the anisotropic cost solved"
    cost += "; on every edge" if options.method not in ROBUST_METHODS else "; on the inlier edges"
    R, iterations, _ = refine_chordal(result.cam_from_world, graph.edges, graph.cam2_from_cam1, weights, inliers=inliers)
    cert = certify(R, graph.edges, graph.cam2_from_cam1, weights, inliers=inliers)
    if cert.certified or not cert.reason.startswith("negative eigenvalue"):
        return R, dict(cert.to_dict(), cost=cost), iterations
    # A critical point that is not the global minimum: climb the Riemannian staircase
    # (lift, descend, round) and keep the better answer, certified or with its proven gap.
    solution = certified_chordal(R, graph.edges, graph.cam2_from_cam1, weights, inliers=inliers)
    out = dict(solution.certificate.to_dict(), cost=cost)
    out["staircase"] = {"start_certificate_lambda_min": float(cert.lambda_min), "start_cost": float(solution.start_cost),
                        "cost": float(solution.cost), "lower_bound": float(solution.lower_bound),
                        "relative_gap": float(solution.relative_gap), "max_rank": int(solution.max_rank),
                        "relaxation_solved": bool(solution.relaxation_solved), "summary": solution.summary,
                        "seconds": float(solution.seconds)}
    return solution.cam_from_world, out, iterations


def _inlier_components(graph: ViewGraph, result) -> int:
    """How many connected components the inlier edges make of the solved cameras."""
    from ..graph_analysis import connected_components

    solved = np.isfinite(result.cam_from_world).all(axis=(1, 2))
    e = graph.edges[result.inliers & solved[graph.edges[:, 0]] & solved[graph.edges[:, 1]]]
    index = np.cumsum(solved) - 1
    return connected_components(int(solved.sum()), index[e])[0]


def certify_result(graph: ViewGraph, result, options):
    """``solve --certify``: the certified final stage of a solve. The rotations are moved to
    the nearest critical point of the weighted chordal cost on the solve's inlier edges
    (:func:`~rotgraph.estimators.staircase.refine_chordal`; a robust or geodesic solution is
    not one), then certified there, each inlier edge weighted by its weight in the solve's
    final iteration (``result.edge_weights``: the problem whose fixed point the result is;
    else as :func:`_chordal_weights`); a rig solve (``result.frames``) at the frame level,
    each image keeping its ``cam_from_rig`` (``frame_level`` in the certificate). Returns ``(result, certificate dict)``: the result with
    those rotations and their residuals (the same inliers), and the certificate with
    ``final_stage`` (iterations, the largest rotation change in degrees)."""
    from dataclasses import replace

    from .. import so3

    if result.frames is not None:
        # A rig solve: the frames are the unknowns (cam_from_rig fixed); certify the frame
        # problem and carry each image with its frame.
        fr = result.frames
        R_frames, cert, iterations = _certified_stage(fr.graph, fr.result, options)
        group = fr.frame_of_image
        S = result.cam_from_world @ np.swapaxes(fr.result.cam_from_world[group], 1, 2)  # cam_from_rig
        R = S @ R_frames[group]
        cert["frame_level"] = True
    else:
        R, cert, iterations = _certified_stage(graph, result, options)
    solved = np.isfinite(R).all(axis=(1, 2))
    change = so3.angle_between(R[solved], result.cam_from_world[solved]) if solved.any() else np.zeros(0)
    cert["final_stage"] = {"stage": "chordal_on_inliers", "iterations": int(iterations),
                           "max_change_deg": float(np.degrees(change.max())) if len(change) else 0.0}
    i, j = graph.edges[:, 0], graph.edges[:, 1]
    both = solved[i] & solved[j]
    residuals = np.array(result.residuals_deg, dtype=np.float64)
    residuals[both] = np.degrees(so3.angle_between(graph.cam2_from_cam1[both], R[j[both]] @ np.swapaxes(R[i[both]], 1, 2)))
    return replace(result, cam_from_world=R, residuals_deg=residuals), cert
