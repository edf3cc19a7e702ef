"""``wandcal serve``: run the service under uvicorn."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from wandcal.service.cli.support.args import arg_whole

if TYPE_CHECKING:
    from wandcal.service.settings import Settings

# Seconds uvicorn lets open requests finish after Ctrl-C / SIGINT / SIGTERM. The whole stop (this,
# the live capture's end and the workers', service/main.py and service/jobs/worker.py) must fit well in
# the 5 s a restart may take (issue 21; the systemd unit allows 20 before SIGKILL); requests are
# short, and a client whose upload is cut sends it again.
GRACEFUL_SHUTDOWN_S = 1  # whole seconds: uvicorn takes an int

MAX_PORT = 65_535
MAX_WORKERS = 64  # each solver process holds a capture and its solve: far past what one host can run

NO_TOKEN = (
    "refusing to listen on {host}: a non-loopback address needs a bearer token. Set WANDCAL_TOKEN "
    "(or 'token' in the settings file), or bind 127.0.0.1"
)


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("serve", help="run the HTTP API, the job workers and the rig page")
    p.set_defaults(run=run)
    if arguments:
        _arguments(p)
        p.epilog = environment()


def environment() -> str:
    """The environment ``serve`` reads, one variable a line: every setting as ``WANDCAL_<NAME>``
    (service/settings.py; an option given here wins over it), and ``WANDCAL_CONFIG``."""
    from wandcal.service.settings import Settings

    lines = ["environment (each also a key of the settings file; an option above wins over both):",
             "  WANDCAL_CONFIG: the settings TOML file (deploy/wandcal.toml shows every key)"]
    for name, field in Settings.model_fields.items():
        default = field.get_default(call_default_factory=False)
        shown = "" if field.description is None else f": {field.description}"
        if field.default_factory is None and name != "token":
            shown += f" (default {'unset' if default is None else default})"
        lines.append(f"  WANDCAL_{name.upper()}{shown}")
    return "\n".join(lines) + "\n"


def _arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", help="address to bind (default 127.0.0.1, or 'host' from the settings)")
    p.add_argument("--port", type=arg_whole(1, MAX_PORT), help="port, 1 to 65535 (default 8750)")
    p.add_argument("--config", type=Path, help="settings TOML file (default $WANDCAL_CONFIG)")
    p.add_argument("--data-dir", type=Path, help="data directory (default $WANDCAL_DATA_DIR or ./wandcal-data)")
    p.add_argument("--workers", type=arg_whole(0, MAX_WORKERS), metavar="N",
                   help=f"solver processes, 0 to {MAX_WORKERS} (0: jobs stay queued; default 1)")
    p.add_argument("--log-level", default="info", choices=("critical", "error", "warning", "info", "debug"),
                   help="the service's and uvicorn's log level (default info)")


def check_bind(settings: Settings) -> None:
    """A non-loopback bind without a token is refused: bad input (exit 2), like a taken port."""
    from wandcal.service.cli.support.exits import InputError

    if not settings.loopback and not settings.token:
        raise InputError(NO_TOKEN.format(host=settings.host))


def check_port(host: str, port: int) -> None:
    """Bind ``host:port`` once and let it go, so a taken port or an address this machine does not
    have is bad input (exit 2) with the option to change, before the service starts anything."""
    import socket

    from wandcal.service.cli.support.exits import InputError

    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        with socket.socket(family, kind, proto) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn binds: TIME_WAIT is no clash
            probe.bind(address)
    except OSError as exc:
        raise InputError(f"cannot listen on {host}:{port} ({exc.strerror or exc}): another program (another "
                         "'wandcal serve'?) holds the port, or the address is not this machine's; stop it, or give "
                         "--port N / --host (or WANDCAL_PORT / WANDCAL_HOST)") from None


def run(args: argparse.Namespace) -> int:
    import logging
    import tempfile

    import uvicorn

    from wandcal.service.connection_limits import server_options
    from wandcal.service.main import create_app
    from wandcal.service.settings import Settings

    overrides = {
        k: v for k, v in {"host": args.host, "port": args.port, "data_dir": args.data_dir, "workers": args.workers}.items()
        if v is not None
    }
    settings = Settings.load(args.config, **overrides)
    check_bind(settings)
    check_port(settings.host, settings.port)
    # uploads larger than 1 MB spool to temporary files: keep those inside the data directory too
    spool = _spool(settings.data_dir)
    tempfile.tempdir = str(spool)
    # the service's own log lines (recovery after a crash, the folder's lock) beside uvicorn's, at its level
    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    app = create_app(settings)
    uvicorn.run(app, host=settings.host, port=settings.port, log_level=args.log_level,
                timeout_graceful_shutdown=GRACEFUL_SHUTDOWN_S, **server_options(settings))
    end_without_teardown()


def end_without_teardown() -> NoReturn:
    """End the stopped server at once (exit 0), skipping the interpreter's teardown. By now the
    lifespan has stopped the workers, the live capture and the pruner, every record is committed
    and the remaining threads are daemons; what is left is freeing NumPy's, SciPy's, OpenCV's and
    FastAPI's modules, which took 1-4.5 s of a 5 s stop on a busy 2-core machine (decision 0109)."""
    import logging
    import os
    import sys

    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def _spool(data_dir: Path) -> Path:
    """The data directory's ``tmp/``, made here: a data directory that cannot be made or written
    (a typo, a read-only disk, a file of that name) is bad input, named."""
    from wandcal.service.cli.support.exits import InputError

    spool = data_dir.resolve() / "tmp"
    try:
        spool.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"data directory {data_dir}: cannot make {spool} ({exc.strerror or exc}); give --data-dir "
                         "(or WANDCAL_DATA_DIR) a folder this user can write") from None
    return spool
