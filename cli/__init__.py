"""The ``rotgraph`` command line (installed as ``rotgraph.cli``): a thin click layer over the library."""
