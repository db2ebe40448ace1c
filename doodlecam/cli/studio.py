"""``doodlecam studio``: see, edit, plan, simulate and send a job in the browser (docs/studio.md)."""

from __future__ import annotations

from pathlib import Path

import click

from doodlecam.cli.options import job_kwargs, job_options

LOOPBACK = ("127.0.0.1", "localhost", "::1")


@click.command()
@click.argument("file", required=False, type=click.Path(path_type=Path))
@click.option("--port", type=click.IntRange(0, 65535), default=8765, show_default=True, help="Port to listen on (0 = any free one).")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on. Any other than 127.0.0.1 requires the printed access token.")
@click.option("--no-browser", is_flag=True, help="Do not open a browser; only print the address.")
@click.option("--folder", "folders", multiple=True, type=click.Path(path_type=Path),
              help="A folder the studio may open files from and export to (repeatable). Default: the current folder.")
@click.option("--max-upload", type=click.FloatRange(min=0.1), default=20.0, show_default=True, help="Largest upload, in MB.")
@job_options
def studio(file, port, host, no_browser, folders, max_upload, **options):
    """Open a job in the browser: trace, edit curves, plan, simulate, export and send."""
    import threading
    import webbrowser

    import uvicorn

    from doodlecam.errors import InputError
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings
    from doodlecam.studio.app import StudioConfig, check_folders, create_app
    from doodlecam.studio.session import Session

    kw = job_kwargs(**options)
    settings = Settings(**{**kw, "machine": load_machine(kw["machine"])})
    cfg = StudioConfig(require_token=host not in LOOPBACK, folders=check_folders(folders or (Path.cwd(),)))
    session = Session(settings, max_upload=int(max_upload * 1e6))
    if file is not None:  # checked (and traced) before the server starts: a bad file is one line, no server
        if not file.is_file():
            raise InputError(f"{file}: no such file; check the path")
        click.echo(f"tracing and planning {file} ...")
        session.load(file.name, file.read_bytes())

    config = uvicorn.Config(create_app(session, cfg), host=host, port=port, log_level="warning")
    server = uvicorn.Server(config)
    url_host = "127.0.0.1" if host in ("0.0.0.0", "::") else host

    def announce():
        while not server.started:
            if not thread.is_alive():
                return
            threading.Event().wait(0.05)
        bound = server.servers[0].sockets[0].getsockname()[1] if server.servers else port
        url = f"http://{url_host}:{bound}/?token={cfg.token}"
        click.echo(f"doodlecam studio: {url}")
        need = "every request: listening beyond this computer" if cfg.require_token else "sending to a machine"
        click.echo(f"  access token {cfg.token} (needed for {need}); Ctrl-C stops")
        if not no_browser:
            webbrowser.open(url)

    thread = threading.Thread(target=announce, daemon=True)
    thread.start()
    server.run()
    if not server.started:
        raise InputError(f"cannot listen on {host}:{port}; is the port in use? pick another --port")
