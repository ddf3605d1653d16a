"""The ``evtools`` command line: one module per subcommand, ``main.py`` only builds the group."""
