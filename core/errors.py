"""The one exception type for bad user input, and the output-path check of the commands."""

from pathlib import Path


class InputError(ValueError):
    """Bad input from the user: a file that is missing, malformed or inconsistent.

    The message is one plain sentence that names the file and the problem; the
    command line prints it as ``somacap: error: <message>`` and exits with status 2.
    """


def check_output(path, what: str, suffix: str | None = None, makes_folder: bool = False):
    """Check, before any long work, that a command's output file can be written.

    Parameters
    ----------
    path : str or Path, the output file
    what : what the file holds, for the message (e.g. "the tracks")
    suffix : the extension it must carry (e.g. ``".npz"``, which numpy would otherwise
        append to a name without it), or None
    makes_folder : the writer creates a missing folder (then only a folder given as the
        file is refused)

    Returns
    -------
    Path

    Raises
    ------
    InputError
        when ``path`` is a folder, its folder does not exist (unless ``makes_folder``),
        or it lacks ``suffix``.
    """
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{p}: is a folder; give a file name for {what}")
    if not makes_folder and not p.parent.is_dir():
        raise InputError(f"{p}: its folder {p.parent} does not exist")
    if suffix is not None and p.suffix.lower() != suffix:
        raise InputError(f"{p}: the file for {what} must end in {suffix}")
    return p
