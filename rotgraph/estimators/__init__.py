"""The numerical core: arrays in, arrays and result dataclasses out (no files, no pycolmap
import, no click, no progress bars).

* :mod:`.rotation_averaging` - multiple rotation averaging (IRLS, L1, L2, linear, node-wise);
* :mod:`.spanning_tree`, :mod:`.laplacian`, :mod:`.residuals` - its building blocks;
* :mod:`.refine` - Levenberg-Marquardt on the exact geodesic cost;
* :mod:`.single` - single rotation averaging (L1/L2 means, three metrics);
* :mod:`.handeye` - conjugate rotation averaging (hand-eye calibration).
"""
