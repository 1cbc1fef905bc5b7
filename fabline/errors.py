"""The one exception type for a user's mistake: the CLI prints its message on one line and exits 2."""


class FablineError(Exception):
    """A bad input or request, described in one line that names the file, line or element at fault."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised as Ctrl-C is (the command line installs the handler), so that a stopped command unwinds
    the same way: its outputs are removed and the files they replaced put back."""

    def __init__(self, number: int = 15) -> None:
        super().__init__(number)
        self.number = number
