"""One server per data folder: the lock a start takes before it reads or writes anything else.

A server holds ``<data dir>/wandcal.lock`` with ``flock`` for its process's life. The kernel
releases the lock when the process ends in any way (a SIGKILL, a power loss's reboot), so there
is never a stale lock to clear by hand. The file holds the owner's pid, machine, address, port
and start time, for the refusal a second start gives: that start exits (2 on the command line)
before the database is opened, so it recovers nothing, re-queues nothing and writes nothing
(issue 34: a second ``wandcal serve`` on the same folder re-queued the live server's running job
as if that server had crashed, and failed it at the next try).

Only the owner of a folder runs crash recovery (:mod:`wandcal.service.datafolder.recovery`, the job
re-queue of :meth:`wandcal.service.jobs.queue.SQLiteQueue.start`). Redis workers
(``rq worker``, :mod:`wandcal.service.jobs.redis_queue`) never open the data folder and take no
lock; the SQLite queue's solver processes are the owner's own children (spawned without the
lock's descriptor, and dying with the server).

Within one process the lock is shared: a second app built on a folder this process already
holds (tests build one per restart) reuses it, and the lock is let go when the last app holding
it is collected.
"""

from __future__ import annotations

import errno
import fcntl
import json
import logging
import os
import socket
import time
import weakref
from dataclasses import asdict, dataclass
from pathlib import Path

from wandcal.service.db import DataDirectoryError, check_data_dir
from wandcal.service.settings import Settings

log = logging.getLogger("wandcal.service")

LOCK_FILE = "wandcal.lock"
MAX_OWNER_BYTES = 4096  # the owner record is ~150 bytes; read no more of a file someone replaced


@dataclass(frozen=True)
class Owner:
    """Who holds a data folder: what a refused start tells its user."""

    pid: int
    machine: str  # socket.gethostname()
    host: str  # the address it binds
    port: int
    started: float  # Unix seconds

    def describe(self) -> str:
        since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.started))
        return f"pid {self.pid} on {self.machine}, serving {self.host}:{self.port}, since {since}"

    @classmethod
    def parse(cls, text: str) -> Owner | None:
        """The owner written in a lock file, or None if it is not (yet) a whole record."""
        try:
            fields = json.loads(text)
            return cls(pid=int(fields["pid"]), machine=str(fields["machine"]), host=str(fields["host"]),
                       port=int(fields["port"]), started=float(fields["started"]))
        except (ValueError, TypeError, KeyError, OverflowError):
            return None


class DataFolderInUse(DataDirectoryError):
    """Another process holds the data folder; the message names it and what to do."""


@dataclass(eq=False)
class FolderLock:
    """A held data folder; its descriptor closes (and the lock goes) when this is collected."""

    path: Path
    owner: Owner
    fd: int

    def __post_init__(self) -> None:
        weakref.finalize(self, os.close, self.fd)


_held: weakref.WeakValueDictionary[Path, FolderLock] = weakref.WeakValueDictionary()


def hold_data_folder(settings: Settings) -> FolderLock:
    """Take the data folder of ``settings`` for this process, or raise :class:`DataFolderInUse`
    naming the server that holds it. Keep the returned lock referenced for as long as the folder
    is used (``create_app`` stores it in ``app.state``)."""
    data_dir = settings.data_dir.resolve()
    held = _held.get(data_dir)
    if held is not None:
        return held
    check_data_dir(data_dir, settings.db_path)
    try:
        data_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataDirectoryError(f"{data_dir}: the data directory cannot be made ({exc.strerror or exc}); give "
                                 "a folder the server may write to") from None
    path = data_dir / LOCK_FILE
    fd = _open(path)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        holder = _read_owner(fd)
        os.close(fd)
        if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
            raise DataDirectoryError(f"{path}: cannot lock the data folder ({exc.strerror or exc}); put the data "
                                     "directory on a local file system") from None
        raise DataFolderInUse(_in_use(data_dir, holder)) from None
    owner = Owner(pid=os.getpid(), machine=socket.gethostname(), host=settings.host, port=settings.port,
                  started=time.time())
    _write_owner(fd, path, owner)
    lock = FolderLock(path=path, owner=owner, fd=fd)
    _held[data_dir] = lock
    log.info("holding the data folder %s (%s)", data_dir, path.name)
    return lock


def _open(path: Path) -> int:
    try:
        # O_NOFOLLOW: a link planted in the folder must not make the server lock (and write) elsewhere
        return os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        raise DataDirectoryError(f"{path}: the data folder's lock file cannot be opened ({exc.strerror or exc}); "
                                 "it must be a file the server may write (remove whatever is there, or give "
                                 "a folder the server may write to)") from None


def _read_owner(fd: int) -> Owner | None:
    try:
        return Owner.parse(os.pread(fd, MAX_OWNER_BYTES, 0).decode("utf-8", "replace"))
    except OSError:
        return None


def _write_owner(fd: int, path: Path, owner: Owner) -> None:
    """Record the owner for a refused start's message; a failure (a full disk) only costs that message."""
    data = json.dumps(asdict(owner)).encode() + b"\n"
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, data, 0)
    except OSError as exc:
        log.warning("%s: could not record this server in the lock file (%s); a second start is still refused, "
                    "without naming this one", path, exc.strerror or exc)


def _in_use(data_dir: Path, holder: Owner | None) -> str:
    who = (f"another wandcal server ({holder.describe()})" if holder is not None
           else "another process (it has not written its name in the lock file)")
    return (f"{data_dir}: the data folder is in use by {who}; this start changed nothing in it. Use that "
            "server, or stop it first and start again; to run a second server, give it its own "
            "--data-dir (WANDCAL_DATA_DIR). More solvers for the same jobs: raise the running server's "
            "--workers, or add rq workers (docs/deploy.md)")
