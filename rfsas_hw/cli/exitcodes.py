"""Exit codes of every ``rfsas`` command, in one place.

======  ===========================================================================
code    meaning
======  ===========================================================================
0       the command did what it was asked to
1       the declared work failed: 0 bearings, nothing sent, a write failed,
        ``calibrate --check`` found the calibration inconsistent
2       bad input or usage: a file, option or configuration value is wrong (one
        line on stderr names what and where)
130     interrupted (Ctrl-C or SIGTERM) before the work was done; sensor commands
        still write their outputs and summary first
======  ===========================================================================

``live``, ``backend``, ``nonces serve`` and ``board emulate`` run until stopped:
for them Ctrl-C or SIGTERM is the normal end, and the exit code says whether
the run did its work (0) or not (1). A fault ridden out on the way (a broker
outage, sends that failed and then went out again) is counted in the summary and
logged when it starts and ends, but is not a failed run; a link still failing at
the end is.
"""

from __future__ import annotations

import click

OK = 0
"""The command did what it was asked to."""
FAILED = 1
"""The declared work failed (0 bearings, nothing sent, a write failed, check inconsistent)."""
BAD_INPUT = 2
"""Bad input or usage."""
INTERRUPTED = 130
"""Interrupted before the work was done (128 + SIGINT)."""

EPILOG = (
    "Exit codes: 0 ok; 1 the declared work failed (0 bearings, nothing sent, a write "
    "failed, calibration check inconsistent); 2 bad input or usage; 130 interrupted "
    "(Ctrl-C or SIGTERM; outputs and summary are still written)."
)
"""The ``--help`` epilog that lists the exit codes."""


class WorkFailed(click.ClickException):
    """The command ran but its declared work failed: one line on stderr, exit code 1."""

    exit_code = FAILED

    def show(self, file: object = None) -> None:
        """Print ``failed: MESSAGE`` on stderr."""
        click.echo(f"failed: {self.format_message()}", err=True)


class Interrupted(click.ClickException):
    """The run was interrupted before its work was done: exit code 130."""

    exit_code = INTERRUPTED

    def show(self, file: object = None) -> None:
        """Print ``interrupted: MESSAGE`` on stderr."""
        click.echo(f"interrupted: {self.format_message()}", err=True)
