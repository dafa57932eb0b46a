"""Output paths checked before any work: a file or folder a command will write must be writable.

Commands call :func:`check_output` on every output they are given, so that a path that cannot be
written fails at once with one line (exit status 2) instead of after the computation.
"""

from __future__ import annotations

import os
from pathlib import Path

from hbench.errors import InputError


def check_output(path: Path | str, option: str, folder: bool = False) -> Path:
    """Refuse, before any work, an output path that cannot be written.

    Nothing is created: the path must be writable as it is, or its nearest existing ancestor
    must be a folder one can create entries in (commands create missing parent folders, as
    ``reproduce --out`` and ``report --out`` do).

    Parameters
    ----------
    path : path-like
        The output file (or folder with ``folder=True``).
    option : str
        The option that named it (``"--json"``), for the message.
    folder : bool, default False
        Whether ``path`` is a folder to write files into.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        ``path`` is a folder where a file is wanted (or a file where a folder is wanted), is
        not writable, or lies under a file or a folder one cannot write in.
    """
    path = Path(path)
    where = f"{option}{path}" if option.endswith("=") else f"{option} {path}"
    if path.exists():
        if path.is_dir() != folder:
            what = "a file, not a folder" if folder else "a folder, not a file"
            raise InputError(f"{where}: is {what}")
        if not os.access(path, os.W_OK | (os.X_OK if folder else 0)):
            raise InputError(f"{where}: not writable (permission denied)")
        if folder or path.is_file():  # a file is replaced through a new one beside it
            _check_creatable(path if folder else path.parent, where)
        return path
    ancestor = path.parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise InputError(f"{where}: {ancestor} is not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise InputError(f"{where}: cannot create it in {ancestor} (permission denied)")
    _check_creatable(ancestor, where)
    return path


def _check_creatable(folder: Path, where: str) -> None:
    """Refuse a folder that takes no new files (``/proc``, a read-only file system), which
    permissions do not tell: an unnamed temporary file is made there and removed at once."""
    import tempfile

    try:
        tempfile.TemporaryFile(dir=folder).close()
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise InputError(f"{where}: cannot create files in {folder} ({reason})") from None
