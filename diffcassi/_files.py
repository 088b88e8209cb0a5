"""Writing a file whole: the package's one staged writer (the Python side of ``src/io/atomic.rs``).

:func:`write_staged` checks the destination as the command line's output policy does (docs/robustness.md, "Output
policy"): absent or a regular file — never a folder, a named pipe, a device or a socket (renamed over, the node itself
would be replaced), nor a symbolic link (written in its place, the link would be replaced) — and its folder must
exist. It then writes a hidden file beside it, renames it into place and removes it on any failure, so a reader
sees the old file or the complete new one. Errors name the destination, never the staged file.

>>> import os, tempfile
>>> d = tempfile.mkdtemp()
>>> write_staged("example", os.path.join(d, "a.txt"), lambda p: open(p, "w").write("x"))
>>> open(os.path.join(d, "a.txt")).read()
'x'
"""
from __future__ import annotations

import os
import secrets
import stat
import threading
from typing import Any, Callable

from ._errors import DiffcassiFileError


def _kind(mode: int) -> str:
    """What a file that is not a regular one is, for messages."""
    return ("a folder" if stat.S_ISDIR(mode) else "a named pipe (FIFO)" if stat.S_ISFIFO(mode)
            else "a character device" if stat.S_ISCHR(mode) else "a block device" if stat.S_ISBLK(mode)
            else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")


def check_input_file(where: str, path: Any) -> str:
    """``path`` as a string, when it is a regular file to read (following links); a missing file is left to the
    reader (its own "no such file"); a named pipe, a device, a socket or a folder is a :class:`DiffcassiFileError`
    naming ``where`` — a reader would wait on a pipe forever (``src/io/input.rs`` is the CLI's twin)."""
    target = os.fspath(path)
    try:
        st = os.stat(target)
    except OSError:
        return target
    if not stat.S_ISREG(st.st_mode):
        raise DiffcassiFileError(f"{where}: {target} is {_kind(st.st_mode)}, not a regular file: refusing to read it")
    return target


def check_output_file(where: str, path: Any) -> str:
    """``path`` as a string, when a file may be written there: absent or a regular file, in an existing folder;
    else a :class:`DiffcassiFileError` naming ``where``, the path and what it is."""
    target = os.fspath(path)
    try:
        st = os.lstat(target)
    except (FileNotFoundError, NotADirectoryError):  # absent, or under a path whose folder is a file (below)
        st = None
    if st is not None:
        if stat.S_ISLNK(st.st_mode):
            raise DiffcassiFileError(f"{where}: {target} is a symbolic link (to {os.readlink(target)}); a file written in its "
                                     "place would replace the link: give the link's target instead; nothing was written")
        if not stat.S_ISREG(st.st_mode):
            raise DiffcassiFileError(f"{where}: {target} is {_kind(st.st_mode)}, not a regular file; a file is never written over one: nothing was written")
    folder = os.path.dirname(os.path.abspath(target))
    if not os.path.isdir(folder):
        what = "is not a folder" if os.path.exists(folder) else "does not exist"
        raise DiffcassiFileError(f"{where}: cannot write {target}: its folder {folder} {what}")
    return target


def write_staged(where: str, path: Any, write: Callable[[str], Any], suffix: str = "") -> None:
    """Write ``path`` whole: checked by :func:`check_output_file`, then ``write(stage)`` fills a hidden file beside
    it (``.NAME.PID-THREAD-RANDOM.stage`` + ``suffix``: a writer that chooses its format by the extension gets it),
    which is renamed over ``path``; the staged file is removed on any failure. The stage is the call's own — two
    threads saving to one path each rename a whole file, the last one wins (with ``.PID.stage`` they wrote into one
    stage and renamed a corrupt file into place: a held-out battery, round 6). An ``OSError`` is re-raised as a
    :class:`DiffcassiFileError` naming ``path``."""
    target = check_output_file(where, path)
    tag = f"{os.getpid()}-{threading.get_ident()}-{secrets.token_hex(4)}"
    stage = os.path.join(os.path.dirname(os.path.abspath(target)), f".{os.path.basename(target)}.{tag}.stage{suffix}")
    try:
        write(stage)
        os.replace(stage, target)
    except OSError as e:
        if isinstance(e, DiffcassiFileError):
            raise
        raise DiffcassiFileError(f"{where}: cannot write {target}: {e.strerror or e}") from None
    finally:
        if os.path.exists(stage):
            os.remove(stage)
