"""The command line of a source checkout, for the two ways of running it from there.

In a source checkout the command line sits beside the package (``cli/``, installed as
``rotgraph.cli``; see pyproject.toml). ``python -m rotgraph`` or ``python -m pytest`` run in
the checkout import this source folder rather than the installed package, and it has no
``rotgraph/cli``. :func:`find_cli` makes ``rotgraph.cli`` resolve to ``../cli`` then; it is
called by ``rotgraph/__main__.py`` and ``tests/conftest.py``, never by ``import rotgraph``
(the package changes nothing at import).
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import os
import sys

__all__ = ["find_cli"]


def find_cli() -> None:
    """In a source checkout, let ``rotgraph.cli`` be found in the top-level ``cli/`` beside
    this package (a :data:`sys.meta_path` finder, first, once); installed, or not a
    checkout: nothing."""
    here = os.path.dirname(os.path.abspath(__file__))
    cli = os.path.join(os.path.dirname(here), "cli")
    if os.path.isdir(os.path.join(here, "cli")) or not os.path.isfile(os.path.join(cli, "__init__.py")):
        return  # installed (rotgraph/cli exists) or not a checkout
    if any(isinstance(f, _CliFinder) for f in sys.meta_path):
        return
    sys.meta_path.insert(0, _CliFinder(cli))  # first: the cli/ beside this package, not another install's


class _CliFinder(importlib.abc.MetaPathFinder):
    """Finds ``rotgraph.cli`` in the checkout's ``cli/`` folder."""

    def __init__(self, folder: str):
        self.folder = folder

    def find_spec(self, name, path=None, target=None):
        if name != "rotgraph.cli":
            return None
        return importlib.util.spec_from_file_location(name, os.path.join(self.folder, "__init__.py"),
                                                      submodule_search_locations=[self.folder])
