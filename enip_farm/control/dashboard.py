"""The dashboard: one static page at / of the HTTP API (plain HTML, CSS and JavaScript shipped in
the package under control/web/, no CDN, no build step: the scripts are ES modules the browser
loads by their relative imports, served as text/javascript), which shows every device as a card
and drives it through the API's own endpoints (GET /devices, GET /state, PUT /devices/{name}/io,
GET /fault-kinds, POST and DELETE /devices/{name}/faults) and its event stream (GET /events).
control/web/dashboard.js lists the modules and what each does.

The page and its scripts carry no farm data, so the guard serves them without the token
(control/guard.py, `public`); every request the page makes carries the token it was given
(`/#token=SECRET` in the URL, or asked for when the API answers 401).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fastapi import FastAPI
from starlette.responses import FileResponse
from starlette.staticfiles import StaticFiles

from enip_farm.control.guard import PUBLIC_PAGE, PUBLIC_PREFIX

WEB = Path(__file__).parent / "web"
JAVASCRIPT = "text/javascript; charset=utf-8"  # what a module script needs, whatever the host's mime.types says


class _Assets(StaticFiles):
    """The page's files, a script as text/javascript."""

    def file_response(self, full_path: Any, *args: Any, **kwargs: Any) -> Any:
        response = super().file_response(full_path, *args, **kwargs)
        if str(full_path).endswith(".js"):
            response.headers["content-type"] = JAVASCRIPT
        return response


def mount_dashboard(app: FastAPI) -> None:
    @app.get(PUBLIC_PAGE, include_in_schema=False)
    def dashboard() -> FileResponse:
        return FileResponse(WEB / "index.html", headers={"Cache-Control": "no-cache"})

    app.mount(PUBLIC_PREFIX.rstrip("/"), _Assets(directory=WEB), name="dashboard")
