"""Atomic file writing: a write either completes or leaves nothing behind.

Temporary files are hidden siblings of their target named
``.<target name>.<pid>.<random>.tmp``. They are removed when the write fails; a
process killed outright (SIGKILL, power loss) cannot clean up, so every later write
to the same target first removes the temporary files of processes that no longer
exist. :func:`atomic_group` places several files (a log, its sidecar and its model
spec) together: all of them appear, or none does.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

__all__ = [
    "atomic_group",
    "atomic_path",
    "atomic_write_text",
    "atomic_write_with",
    "check_parents",
    "finite_or_none",
    "strict_json",
]


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def _remove_stale(target: Path) -> None:
    """Remove ``.<name>.<pid>.*.tmp`` siblings left by processes that no longer run."""
    prefix = f".{target.name}."
    try:
        entries = list(os.scandir(target.parent))
    except OSError:
        return
    for entry in entries:
        name = entry.name
        if not (name.startswith(prefix) and name.endswith(".tmp")):
            continue
        pid_text = name[len(prefix):].split(".", 1)[0]
        if pid_text.isdigit() and not _pid_alive(int(pid_text)):
            with contextlib.suppress(OSError):
                os.unlink(entry.path)


def check_parents(target: Path) -> None:
    """Raise :class:`NotADirectoryError` naming ``target`` when its nearest existing
    ancestor is a file (nothing can be created below it)."""
    for parent in Path(target).parents:
        if parent.exists():
            if not parent.is_dir():
                raise NotADirectoryError(20, f"{parent} is not a directory", str(target))
            break


def _check_target(target: Path) -> None:
    """Raise a clear :class:`OSError` naming ``target`` when it cannot be written."""
    if target.is_dir():
        raise IsADirectoryError(21, "output path is a directory", str(target))
    check_parents(target)


def _new_temp(target: Path) -> Path:
    _check_target(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale(target)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.{os.getpid()}.", suffix=".tmp",
                               dir=target.parent)
    os.close(fd)
    return Path(tmp)


def _umask_mode() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it over ``path`` on success.

    On any exception the temporary file is removed and ``path`` is untouched.

    Raises
    ------
    OSError
        ``path`` is a directory, lies under a regular file, or its directory is not
        writable (the exception names the path).
    """
    with atomic_group([path]) as (tmp,):
        yield tmp


@contextlib.contextmanager
def atomic_group(paths: Sequence[str | os.PathLike[str]]) -> Iterator[list[Path]]:
    """Yield temporary paths for several files; place all of them on success, else none.

    The temporary files are renamed over their targets only once the ``with`` block
    has completed. If a rename fails, the targets already placed are restored to their
    previous content (or removed when they did not exist), so either every file is
    new or every file is as before. On any exception all temporary files are removed.
    """
    targets = [Path(p) for p in paths]
    tmps: list[Path] = []
    try:
        for target in targets:
            tmps.append(_new_temp(target))
        yield tmps
        mode = _umask_mode()
        for tmp in tmps:
            if tmp.exists():
                os.chmod(tmp, mode)
        _place(tmps, targets)
    except BaseException:
        for tmp in tmps:
            with contextlib.suppress(OSError):
                tmp.unlink()
        raise


def _place(tmps: list[Path], targets: list[Path]) -> None:
    if len(targets) == 1:
        os.replace(tmps[0], targets[0])
        return
    backups: dict[int, Path] = {}
    placed: list[int] = []
    try:
        for i, target in enumerate(targets):
            if target.exists():
                backup = _new_temp(target)
                os.unlink(backup)
                try:
                    os.link(target, backup)
                    backups[i] = backup
                except OSError:  # no hard links here: copy instead
                    import shutil

                    shutil.copy2(target, backup)
                    backups[i] = backup
        for i, (tmp, target) in enumerate(zip(tmps, targets, strict=True)):
            os.replace(tmp, target)
            placed.append(i)
    except BaseException:
        for i in placed:
            with contextlib.suppress(OSError):
                if i in backups:
                    os.replace(backups.pop(i), targets[i])
                else:
                    targets[i].unlink()
        raise
    finally:
        for backup in backups.values():
            with contextlib.suppress(OSError):
                backup.unlink()


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def atomic_write_with(path: str | os.PathLike[str], writer: Callable[[Path], None]) -> None:
    """Call ``writer(tmp_path)`` and move the result to ``path`` atomically."""
    with atomic_path(path) as tmp:
        writer(tmp)


def finite_or_none(obj: object) -> object:
    """Replace every non-finite float (NaN, ±inf) in nested dicts/lists by ``None``
    (numpy values as Python values): :func:`vesselid.core.jsonio.strict`, the one rule."""
    from vesselid.core.jsonio import strict

    return strict(obj)


def strict_json(obj: object, **kwargs: object) -> str:
    """``json.dumps`` that never writes ``NaN``/``Infinity``: non-finite numbers become
    ``null`` (:func:`vesselid.core.jsonio.dumps`, the one strict-JSON implementation)."""
    from vesselid.core.jsonio import dumps

    return dumps(obj, **kwargs)
