"""``python -m rotgraph``: the command line."""

from rotgraph.source_checkout import find_cli

find_cli()  # run from a source checkout: the command line is its top-level cli/

from rotgraph.cli.main import cli  # noqa: E402 - after find_cli

if __name__ == "__main__":  # pragma: no cover
    cli(prog_name="rotgraph")
