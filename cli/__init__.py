"""The ``evtools`` command line: one module per subcommand, ``main.py`` only builds the group."""

import os
import signal


def stop_early(signum, frame) -> None:
    """A stop signal before the command line's handling is installed: nothing is open yet (no output to close, no
    temporary to remove), so the process ends at once, with one line and ``128 + signal``."""
    os.write(2, b"evtools: interrupted\n")
    os._exit(128 + signum)


def run() -> None:
    """The console script: :func:`stop_early` handles SIGINT and SIGTERM while the command line's modules are
    imported (the first ~0.1 s: click, numpy; a Ctrl-C there printed a KeyboardInterrupt traceback, a SIGTERM left
    no word), then :func:`evtools.cli.main.main` installs the real handling (outputs closed complete). Only the
    interpreter's own start (~20 ms) comes before it."""
    signal.signal(signal.SIGINT, stop_early)
    signal.signal(signal.SIGTERM, stop_early)
    from evtools.cli.main import main

    main()
