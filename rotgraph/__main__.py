"""``python -m rotgraph``: the command line."""

from rotgraph.cli.main import cli

if __name__ == "__main__":  # pragma: no cover
    cli(prog_name="rotgraph")
