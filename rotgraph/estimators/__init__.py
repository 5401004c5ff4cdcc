"""The numerical core: arrays in, arrays and result dataclasses out (no files, no pycolmap
import, no click, no progress bars; estimators import neither :mod:`rotgraph.io` nor the
pipeline).

Multiple rotation averaging
    :mod:`.rotation_averaging` (``average_rotations``: IRLS, L1, L2, linear chordal and
    quaternion, node-wise), with its options and result in :mod:`.types`, the stages every
    solve shares in :mod:`.stages`, each method's function registered in :mod:`.methods` (the table of methods: ``rotgraph.choices``,
    ``METHOD_TABLE``), node-wise averaging in :mod:`.nodewise`; building blocks
    :mod:`.spanning_tree` (initialisation), :mod:`.laplacian` (the anchored graph-Laplacian
    solves), :mod:`.residuals` (edge errors in the quaternion row layout); rigs averaged at
    the frame level in :mod:`.rig_rotation_averaging`; :mod:`.refine` (Levenberg-Marquardt
    on the exact geodesic cost); gravity priors, a variant of the solve stages, in
    :mod:`.gravity` (:mod:`.gravity_solve` and its stages).
Two-view geometry
    :mod:`.relative_pose`: COLMAP's relative pose from E/F/H (vectorised for E and F).
Single rotation averaging
    :mod:`.single` (``mean``), :mod:`.single_iterative`, :mod:`.single_quaternion`.
Conjugate rotation averaging (hand-eye)
    :mod:`.handeye` (``solve_handeye``), :mod:`.handeye_rotation`, :mod:`.handeye_translation`.
"""
