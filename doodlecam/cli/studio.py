"""``doodlecam studio``: see, edit, plan, simulate and send a job in the browser (docs/studio.md)."""

from __future__ import annotations

import socket
from pathlib import Path

import click

from doodlecam.cli.options import job_kwargs, job_options

LOOPBACK = ("127.0.0.1", "localhost", "::1")


@click.command()
@click.argument("file", required=False, type=click.Path(path_type=Path))
@click.option("--port", type=click.IntRange(0, 65535), default=8765, show_default=True, help="Port to listen on (0 = any free one).")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on (every request needs the printed access token, whatever the address).")
@click.option("--no-browser", is_flag=True, help="Do not open a browser; only print the address.")
@click.option("--folder", "folders", multiple=True, type=click.Path(path_type=Path),
              help="A folder the studio may open files from and export to (repeatable). Default: the current folder.")
@click.option("--max-upload", type=click.FloatRange(min=0.1), default=20.0, show_default=True, help="Largest upload, in MB.")
@job_options
def studio(file, port, host, no_browser, folders, max_upload, **options):
    """Open a job in the browser: trace, edit curves, plan, simulate, export and send."""
    import threading
    import webbrowser

    from doodlecam.extras import require

    require("studio", "the studio")
    import uvicorn

    from doodlecam.errors import InputError
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings
    from doodlecam.studio.app import StudioConfig, check_folders, create_app
    from doodlecam.studio.session import Session

    kw = job_kwargs(**options)
    settings = Settings(**{**kw, "machine": load_machine(kw["machine"])})
    cfg = StudioConfig(folders=check_folders(folders or (Path.cwd(),)), hosts=own_host_names(host))
    session = Session(settings, max_upload=int(max_upload * 1e6))
    if file is not None:  # checked (and traced) before the server starts: a bad file is one line, no server
        if not file.is_file():
            raise InputError(f"{file}: no such file; check the path")
        click.echo(f"tracing and planning {file} ...")
        session.load(file.name, file.read_bytes(), background=False)  # planned too: its errors are one line here

    # the socket is bound here, so a busy port or a bad address is one line, not a server log
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except (OSError, OverflowError) as e:
        sock.close()
        raise InputError(f"cannot listen on {host}:{port} ({getattr(e, 'strerror', None) or e}); "
                         "pick another --port or --host") from None
    bound = sock.getsockname()[1]
    # a request still computing when Ctrl-C/SIGTERM arrives is not waited for beyond a second
    server = uvicorn.Server(uvicorn.Config(create_app(session, cfg), log_level="warning", timeout_graceful_shutdown=1))
    url_host = "127.0.0.1" if host in ("0.0.0.0", "::") else (f"[{host}]" if ":" in host else host)

    def announce():
        while not server.started:
            if not thread.is_alive():
                return
            threading.Event().wait(0.05)
        url = f"http://{url_host}:{bound}/?token={cfg.token}"
        click.echo(f"doodlecam studio: {url}")
        click.echo(f"  access token {cfg.token} (every request needs it; open the URL above); Ctrl-C stops")
        if not no_browser:
            webbrowser.open(url)

    thread = threading.Thread(target=announce, daemon=True)
    thread.start()
    server.run(sockets=[sock])


def own_host_names(host: str) -> tuple[str, ...]:
    """The names a browser may use for this studio besides the loopback ones: the address it listens on,
    and for a wildcard address this computer's name and addresses. Any other Host is refused."""
    if host in LOOPBACK:
        return ()
    if host not in ("0.0.0.0", "::"):
        return (host,)
    names = {socket.gethostname(), socket.getfqdn()}
    try:
        names.update(str(a[4][0]) for a in socket.getaddrinfo(socket.gethostname(), None))
    except OSError:
        pass
    return tuple(sorted(n for n in names if n))
