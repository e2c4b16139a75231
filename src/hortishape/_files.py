"""Files: the checks every reader makes and the atomic writer every writer uses.

Private to the package: one place for what the readers and writers of
meshes, volumes, models, CAD files, pictures and logs share.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TypeAlias

#: A path argument: a string or anything ``os.fspath`` takes.
PathLike: TypeAlias = "str | os.PathLike[str]"

#: A progress wrapper: takes an iterable and yields its items (e.g. ``tqdm``).
Progress: TypeAlias = Callable[[Iterable], Iterable]


def full_suffix(path: Path) -> str:
    """Lower-case extension, treating ``.nii.gz`` as one extension."""
    name = path.name.lower()
    if name.endswith(".nii.gz"):
        return ".nii.gz"
    return path.suffix.lower()


def check_exists(path: Path, error: type[Exception]) -> None:
    if not path.exists():
        raise error(f"{path}: no such file")
    if path.is_dir():
        raise error(f"{path}: is a directory, not a file")


def check_not_empty(path: Path, error: type[Exception]) -> None:
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise error(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    if size == 0:
        raise error(f"{path}: the file is empty")


@contextlib.contextmanager
def atomic_path(path: Path, error: type[Exception]) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; move it onto ``path`` on success.

    Every hortishape file is written through this (meshes, volumes, models,
    pictures, logs), so no reader ever sees a half-written file.

    The temporary name starts with a dot (so folder scans skip it) and ends with
    the target's extension (SimpleITK picks its writer by extension). On any
    exception the temporary file is removed and ``path`` is left untouched.
    """
    if path.is_dir():
        raise error(f"{path}: is a directory")
    parent = path.parent
    if not parent.is_dir():
        raise error(f"{path}: cannot write, the folder {parent} does not exist")
    suffix = full_suffix(path)
    for _ in range(100):
        tmp = parent / f".{path.name}.{secrets.token_hex(4)}.tmp{suffix}"
        try:
            # O_EXCL: never clobber another writer's file; mode 0o666 lets the
            # umask give the file the permissions a normal open() would.
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        except OSError as exc:
            raise error(f"{path}: cannot write ({exc.strerror or exc})") from None
        os.close(fd)
        break
    else:  # pragma: no cover - 100 collisions of 32 random bits
        raise error(f"{path}: cannot create a temporary file next to it")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError):
            raise error(f"{path}: cannot write ({exc.strerror or exc})") from None
        raise


def atomic_text(path: Path, text: str, error: type[Exception]) -> Path:
    """Write ``text`` to ``path`` through :func:`atomic_path`; return ``path``."""
    with atomic_path(path, error) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path
