"""Files written whole or not at all.

Every result file hbench writes goes through :func:`replacing`: the content is written under a
temporary name in the target's folder, flushed to disk (``fsync``), then renamed over the target
(``os.replace``, atomic on POSIX file systems) and the folder's entry flushed too. A reader sees
the old file or the new one, never a part; a write that fails (no space left, a killed process)
leaves the old file as it was and no temporary file behind (but for a killed process's, whose
name starts with ``.`` and ends with ``.tmp``).

An ``OSError`` while writing becomes an :class:`hbench.errors.OutputError` naming the file, so
the command line prints one line (exit status 2).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from hbench.errors import OutputError


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # a folder that cannot be opened (some platforms): the rename stands
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def replacing(path: Path | str) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; when the block ends without an exception, the
    file written there is flushed to disk and renamed to ``path``.

    A ``path`` that exists and is not a regular file (``/dev/stdout``, a FIFO) is yielded
    itself and written in place: it cannot be replaced, and must not be.

    Parameters
    ----------
    path : path-like
        The file to (re)place. Its folder must exist.

    Yields
    ------
    Path
        Where to write (a fresh, empty file in the same folder).

    Raises
    ------
    OutputError
        The temporary file could not be made, written, flushed or renamed (the message names
        ``path`` and the system's reason). The temporary file is removed.
    """
    path = Path(path)
    if path.exists() and not path.is_file():  # /dev/stdout, a FIFO: written in place
        try:
            yield path
        except OSError as exc:
            raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
        return
    try:
        fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def _umask() -> int:
    """The process's umask (read without changing it, where /proc tells it)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    return 0o022


def write_text(path: Path | str, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` whole or not at all (:func:`replacing`); return ``path``."""
    with replacing(path) as tmp:
        tmp.write_text(text, encoding=encoding)
    return Path(path)


def write_bytes(path: Path | str, data: bytes) -> Path:
    """Write ``data`` to ``path`` whole or not at all (:func:`replacing`); return ``path``."""
    with replacing(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)
