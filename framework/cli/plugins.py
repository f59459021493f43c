"""``spherecal plugins``: prints the installed plugins (:mod:`spherecal.app.plugins`)."""

from __future__ import annotations

from spherecal.app.plugins import describe_plugins
from spherecal.cli.output import EXIT_OK
from spherecal.cli.session import Session


def run(args, session: Session) -> int:
    session.say(describe_plugins(session.host))
    return EXIT_OK
