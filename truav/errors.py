"""The error a user sees: a mistake in a flag or a file, printed as one line with exit code 2.

Raised anywhere (config, fault plans, run directories); only the command-line modules catch it
(:func:`truav.cli.args.run_main`), so lower layers depend on this small module, not on the CLI.
"""

from __future__ import annotations

import signal

EXIT_USAGE = 2
EXIT_BROKEN_PIPE = 128 + signal.SIGPIPE
"""What a shell reports for a Unix tool killed by SIGPIPE (`truav log check FILE | head`)."""


class UserError(ValueError):
    """A user mistake: the message names the flag or file and says what is wrong."""
