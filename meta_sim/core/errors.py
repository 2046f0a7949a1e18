"""The one exception type for errors a user can cause."""


class MetaSimError(Exception):
    """A problem with the user's input (bad path, bad design, unreadable file).

    The message says what went wrong and what to do; the CLI prints it
    without a traceback and exits non-zero.
    """
