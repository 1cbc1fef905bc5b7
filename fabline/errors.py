"""The one exception type for a user's mistake: the CLI prints its message on one line and exits 2."""


class FablineError(Exception):
    """A bad input or request, described in one line that names the file, line or element at fault."""
