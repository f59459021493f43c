"""The pluggy markers of spherecal's hooks and the entry-point group plugins register
under; :mod:`spherecal.plugins` re-exports them."""

import pluggy

PROJECT_NAME = "spherecal"
#: Entry-point group that built-in and third-party plugins are registered under.
ENTRY_POINT_GROUP = "spherecal"

hookspec = pluggy.HookspecMarker(PROJECT_NAME)
hookimpl = pluggy.HookimplMarker(PROJECT_NAME)
