"""For tests that send a command Ctrl-C (SIGINT) as a terminal would."""

from __future__ import annotations

import signal


def ctrl_c_as_at_a_terminal() -> None:
    """In the child before it runs (``preexec_fn``): SIGINT as a terminal delivers it. A
    suite started as a background job of a non-interactive shell ignores SIGINT, and an
    ignored signal stays ignored across exec, so the command under test would not see it."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
