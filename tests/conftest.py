"""Shared fixtures for the mathematical tests of rotgraph.

Everything here is built on scipy (scalar-last quaternions) and plain numpy, never on
rotgraph itself, so that the tests compare rotgraph against an independent reference
(the one exception: :func:`rotgraph.source_checkout.find_cli`, so that ``python -m pytest``
in a source checkout finds the command line).

With ``--import-mode=importlib`` (see pyproject.toml) test modules cannot import this
file, so the helpers are handed out as fixtures.
"""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rotgraph.source_checkout import find_cli

find_cli()  # ``python -m pytest`` in a source checkout: rotgraph.cli is the top-level cli/

BASE_SEED = 20240607


@pytest.fixture
def rng(request) -> np.random.Generator:
    """A seeded generator, different (but reproducible) for every test item."""
    return np.random.default_rng([BASE_SEED, zlib.crc32(request.node.nodeid.encode())])


def make_noisy_cluster(n: int, sigma_rad: float, outlier_frac: float, rng: np.random.Generator):
    """Ground truth ``G`` (3, 3), data ``R`` (n, 3, 3) and the outlier mask (n,).

    Inliers are ``G exp(e)`` with ``e ~ N(0, sigma^2 I_3)``; ``round(outlier_frac * n)``
    randomly placed items are replaced by uniformly (Haar) distributed rotations.
    """
    G = Rotation.random(random_state=rng).as_matrix()
    e = sigma_rad * rng.standard_normal((n, 3))
    R = G @ Rotation.from_rotvec(e).as_matrix()
    n_out = int(round(outlier_frac * n))
    outlier = np.zeros(n, dtype=bool)
    outlier[rng.choice(n, size=n_out, replace=False)] = True
    if n_out:
        R[outlier] = Rotation.random(n_out, random_state=rng).as_matrix()
    return G, R, outlier


@pytest.fixture
def noisy_cluster():
    """``noisy_cluster(n, sigma_rad, outlier_frac, rng) -> (G, R, outlier_mask)``."""
    return make_noisy_cluster


#: A command run by a terminal in the foreground gets SIGINT's default disposition; one started in
#: the background of a non-interactive shell (``cmd &``, as CI scripts and nohup runs do) inherits
#: SIGINT *ignored*, which Python (and so rotgraph) rightly keeps: Ctrl-C tests run from such a
#: shell then saw the child finish with exit 0. This prefix restores the default, then execs.
_FOREGROUND = ("import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); "
               "os.execvp(sys.argv[1], sys.argv[1:])")


@pytest.fixture
def foreground():
    """``foreground(argv) -> argv``: ``argv`` run with SIGINT's default disposition, as a
    terminal's foreground job (what the Ctrl-C tests send their signal to)."""
    import sys

    return lambda argv: [sys.executable, "-c", _FOREGROUND, *map(str, argv)]
