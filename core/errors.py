"""The one exception type for bad user input."""


class InputError(ValueError):
    """Bad input from the user: a file that is missing, malformed or inconsistent.

    The message is one plain sentence that names the file and the problem; the
    command line prints it as ``somacap: error: <message>`` and exits with status 2.
    """
