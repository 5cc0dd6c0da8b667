"""The ``decentral`` command line: one module per subcommand, dispatched by :mod:`sims.cli.main`."""

__all__: list[str] = []
