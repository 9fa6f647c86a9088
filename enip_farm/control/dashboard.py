"""The dashboard: one static page at / of the HTTP API (plain HTML, CSS and JavaScript shipped in
the package under control/web/, no CDN, no build step), which shows every device as a card and
drives it through the API's own endpoints (GET /devices, GET /state, PUT /devices/{name}/io,
POST and DELETE /devices/{name}/faults) and its event stream (GET /events).

The page and its scripts carry no farm data, so the guard serves them without the token
(control/guard.py, `public`); every request the page makes carries the token it was given
(`/#token=SECRET` in the URL, or asked for when the API answers 401).
"""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from starlette.responses import FileResponse
from starlette.staticfiles import StaticFiles

from enip_farm.control.guard import PUBLIC_PAGE, PUBLIC_PREFIX

WEB = Path(__file__).parent / "web"


def mount_dashboard(app: FastAPI) -> None:
    @app.get(PUBLIC_PAGE, include_in_schema=False)
    def dashboard() -> FileResponse:
        return FileResponse(WEB / "index.html", headers={"Cache-Control": "no-cache"})

    app.mount(PUBLIC_PREFIX.rstrip("/"), StaticFiles(directory=WEB), name="dashboard")
