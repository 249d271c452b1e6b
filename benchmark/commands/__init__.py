"""One module per ``trase-bench`` subcommand (registered in ``benchmark.cli.COMMANDS``)."""
