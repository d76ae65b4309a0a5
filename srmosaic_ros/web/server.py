"""The map server: one read-only HTTP application over a :class:`~srmosaic_ros.web.source.MapSource`.

URLs (the contract of DESIGN.md, "Maps, viewers, accuracy and docs"):

- ``GET /``: the page (static/map.html; Leaflet served from the package, nothing from the internet);
- ``GET /tiles/{z}/{x}/{y}.png``: the mosaic layer, ``GET /sr/{z}/{x}/{y}.png``: the SR layer
  (XYZ tiles of EPSG:3857, 256x256 RGBA PNG; 404 where nothing is painted);
- ``GET /status.json``: ``source.status()``;
- what the page needs besides: ``GET /map_config.js`` (the page's settings, as the offline page has
  them in a file beside it), ``GET /map_files/{name}`` (the vendored Leaflet and the page's own
  script and style) and ``GET /events``, a stream of server-sent events: one ``version`` event on
  connecting and one whenever ``source.version()`` grows (polled ``EVENT_POLL_S`` apart), the
  page's cue to reload the tiles in view and the status.

Security: nothing here writes or runs anything; every route is a GET (another method on a known
URL is 405, an unknown URL 404). Tile paths are matched by a strict pattern of decimal integers and
checked against the zoom's grid (``0 <= x, y < 2**z``, ``z <= MAX_ZOOM``) before the source is
asked; a static file is looked up by its exact name in a fixed table (``STATIC_FILES``), never by
joining a URL path to a folder. ``serve`` binds 127.0.0.1 unless given another address. Every
response carries a Content-Security-Policy that lets the page reach this server only.

Why aiohttp (not FastAPI with uvicorn): one maintained package is the server, its router and the
streaming response the events need, with no ASGI server and no request-model layer beside it; the
application is a handful of GET routes whose arguments are integers from one regular expression,
so FastAPI's validation and OpenAPI add nothing. Tiles are rendered on a thread pool
(``loop.run_in_executor``), so a slow tile never holds the event loop or the event streams.
"""
from __future__ import annotations

import asyncio
import json
import logging
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from importlib import resources
from typing import Any

from aiohttp import web

from .source import LAYERS, MAX_ZOOM, MapSource

__all__ = ['ASSETS', 'EVENT_POLL_S', 'STATIC_FILES', 'RunningServer', 'make_app', 'page_config_js', 'serve', 'start_in_thread']

_LOG = logging.getLogger(__name__)

#: Seconds between two looks at ``source.version()`` by an event stream.
EVENT_POLL_S = 0.25
#: Seconds after which an idle event stream sends a comment line (keeps proxies and the browser from closing it).
EVENT_KEEPALIVE_S = 15.0
#: Threads rendering tiles.
TILE_THREADS = 4

#: URL folder (and the offline page's folder beside map.html) of the files the page loads.
ASSETS = 'map_files'
#: Static files the page loads: URL name under /map_files/ -> (file under web/static/, content type).
#: The only files the server reads from its package; a name not here is a 404.
STATIC_FILES: dict[str, tuple[str, str]] = {
    'leaflet.js': ('leaflet/leaflet.js', 'application/javascript'),
    'leaflet.css': ('leaflet/leaflet.css', 'text/css'),
    'images/layers.png': ('leaflet/images/layers.png', 'image/png'),
    'images/layers-2x.png': ('leaflet/images/layers-2x.png', 'image/png'),
    'images/marker-icon.png': ('leaflet/images/marker-icon.png', 'image/png'),
    'images/marker-icon-2x.png': ('leaflet/images/marker-icon-2x.png', 'image/png'),
    'images/marker-shadow.png': ('leaflet/images/marker-shadow.png', 'image/png'),
    'map.js': ('map.js', 'application/javascript'),
    'map.css': ('map.css', 'text/css'),
}
#: The page itself (GET /).
PAGE_FILE = 'map.html'

#: Tile URL path after the layer's prefix: z, x, y as decimal integers without sign, at most 2, 8 and 8 digits
#: (2**26 columns need 8); aiohttp matches the whole segment, so nothing else passes.
_Z = r'{z:(0|[1-9][0-9]?)}'
_XY = r'{%s:(0|[1-9][0-9]{0,7})}'
_TILE_PATH = f'/{_Z}/{_XY % "x"}/{_XY % "y"}.png'
#: URL prefix of each layer.
LAYER_PREFIX = {'mosaic': '/tiles', 'sr': '/sr'}

_SOURCE = web.AppKey('source', MapSource)
_EXECUTOR = web.AppKey('executor', ThreadPoolExecutor)
_CONFIG = web.AppKey('page_config', dict)
_CLOSING = web.AppKey('closing', asyncio.Event)


def static_bytes(name: str) -> bytes:
    """The bytes of a file under web/static/ (an installed package file)."""
    return resources.files(__package__).joinpath('static', *name.split('/')).read_bytes()


def page_config_js(config: dict[str, Any]) -> str:
    """The page's settings as the script map_config.js: ``window.SRMOSAIC_CONFIG = {...};``.

    The JSON is escaped for a script: ``<``, ``>`` and ``&`` as \\u escapes, so no value closes the
    script or opens a tag.
    """
    text = json.dumps(config, sort_keys=True)
    text = text.replace('<', '\\u003c').replace('>', '\\u003e').replace('&', '\\u0026')
    return f'window.SRMOSAIC_CONFIG = {text};\n'


def server_page_config(page_config: dict[str, Any] | None) -> dict[str, Any]:
    """The settings of the served page: the URLs of this server (relative), then ``page_config``."""
    config: dict[str, Any] = {'mode': 'server', 'title': 'srmosaic map', 'status_url': 'status.json',
                              'events_url': 'events',
                              'layers': {'mosaic': 'tiles/{z}/{x}/{y}.png', 'sr': 'sr/{z}/{x}/{y}.png'}}
    config.update(page_config or {})
    return config


def _tile_args(request: web.Request) -> tuple[int, int, int]:
    """z, x, y of a tile URL, or HTTPNotFound when off the grid (the router already took only digits)."""
    info = request.match_info
    z, x, y = int(info['z']), int(info['x']), int(info['y'])
    if z > MAX_ZOOM or x >= 1 << z or y >= 1 << z:
        raise web.HTTPNotFound(text=f'no tile {z}/{x}/{y}: z is 0..{MAX_ZOOM}, x and y are 0..2**z - 1\n')
    return z, x, y


def _tile_handler(layer: str):
    async def handler(request: web.Request) -> web.StreamResponse:
        z, x, y = _tile_args(request)
        app = request.app
        loop = asyncio.get_running_loop()
        # a source's exception is aiohttp's 500, logged with its traceback; the server stays up
        png = await loop.run_in_executor(app[_EXECUTOR], app[_SOURCE].tile_png, layer, z, x, y)
        if png is None:
            raise web.HTTPNotFound(text='nothing painted in this tile\n')
        return web.Response(body=png, content_type='image/png', headers={'Cache-Control': 'no-cache'})
    return handler


async def _page(request: web.Request) -> web.Response:
    return web.Response(body=static_bytes(PAGE_FILE), content_type='text/html', charset='utf-8',
                        headers={'Cache-Control': 'no-cache'})


async def _config(request: web.Request) -> web.Response:
    return web.Response(text=page_config_js(request.app[_CONFIG]), content_type='application/javascript',
                        headers={'Cache-Control': 'no-cache'})


async def _static(request: web.Request) -> web.Response:
    entry = STATIC_FILES.get(request.match_info['name'])
    if entry is None:
        raise web.HTTPNotFound()
    path, content_type = entry
    return web.Response(body=static_bytes(path), content_type=content_type)


async def _status(request: web.Request) -> web.Response:
    app = request.app
    status = await asyncio.get_running_loop().run_in_executor(app[_EXECUTOR], app[_SOURCE].status)
    return web.json_response(status, headers={'Cache-Control': 'no-cache'})


async def _events(request: web.Request) -> web.StreamResponse:
    """Server-sent events: ``event: version`` with ``{"version": n}`` now and whenever n grows."""
    app = request.app
    source, closing = app[_SOURCE], app[_CLOSING]
    response = web.StreamResponse(headers={'Content-Type': 'text/event-stream', 'Cache-Control': 'no-cache',
                                           'X-Accel-Buffering': 'no'})
    await response.prepare(request)
    sent: int | None = None
    idle = 0.0
    try:
        while not closing.is_set():
            version = int(source.version())
            if sent is None or version > sent:
                await response.write(f'event: version\ndata: {json.dumps({"version": version})}\n\n'.encode())
                sent, idle = version, 0.0
            elif idle >= EVENT_KEEPALIVE_S:
                await response.write(b': keep-alive\n\n')
                idle = 0.0
            try:
                await asyncio.wait_for(closing.wait(), EVENT_POLL_S)
            except TimeoutError:
                idle += EVENT_POLL_S
    except (ConnectionResetError, asyncio.CancelledError):
        pass
    return response


#: Headers of every response: the page may load, fetch and stream from this server only (no host on the
#: internet, no plug-in, no framing by another site), and no response is sniffed as another type.
SECURITY_HEADERS = {
    'Content-Security-Policy': "default-src 'self'; img-src 'self' data:; style-src 'self' 'unsafe-inline'; "
                               "script-src 'self'; connect-src 'self'; object-src 'none'; base-uri 'none'; "
                               "frame-ancestors 'none'",
    'X-Content-Type-Options': 'nosniff',
    'Referrer-Policy': 'no-referrer',
}


async def _security_headers(request: web.Request, response: web.StreamResponse) -> None:
    response.headers.update(SECURITY_HEADERS)


async def _on_shutdown(app: web.Application) -> None:
    app[_CLOSING].set()


async def _on_cleanup(app: web.Application) -> None:
    app[_EXECUTOR].shutdown(wait=False, cancel_futures=True)


def make_app(source: MapSource, *, page_config: dict[str, Any] | None = None) -> web.Application:
    """The web application serving ``source`` (read only; see the module docstring for the URLs).

    page_config: settings merged into the page's map_config.js (e.g. ``title``); the URLs of the
    layers, the status and the events are this server's unless given.
    """
    if not isinstance(source, MapSource):
        msg = f'make_app needs a MapSource (tile_png, status, version), not {type(source).__name__}.'
        raise TypeError(msg)
    app = web.Application()
    app[_SOURCE] = source
    app[_EXECUTOR] = ThreadPoolExecutor(TILE_THREADS, thread_name_prefix='map-tiles')
    app[_CONFIG] = server_page_config(page_config)
    app[_CLOSING] = asyncio.Event()
    routes = [web.get('/', _page), web.get('/map_config.js', _config), web.get('/status.json', _status),
              web.get('/events', _events), web.get(f'/{ASSETS}/{{name:.+}}', _static)]
    routes += [web.get(LAYER_PREFIX[layer] + _TILE_PATH, _tile_handler(layer)) for layer in LAYERS]
    app.add_routes(routes)
    app.on_response_prepare.append(_security_headers)
    app.on_shutdown.append(_on_shutdown)
    app.on_cleanup.append(_on_cleanup)
    return app


def serve(source: MapSource, *, port: int = 8080, bind: str = '127.0.0.1',
          page_config: dict[str, Any] | None = None) -> None:
    """Serve ``source`` at http://bind:port/ until interrupted (Ctrl-C)."""
    app = make_app(source, page_config=page_config)
    host = f'[{bind}]' if ':' in bind else bind
    print(f'srmosaic map: http://{host}:{port}/ (Ctrl-C to stop)', flush=True)
    web.run_app(app, host=bind, port=port, print=None, shutdown_timeout=1.0, access_log=None)


@dataclass
class RunningServer:
    """A server started by :func:`start_in_thread`: its URL (``http://127.0.0.1:PORT/``) and its stop."""

    url: str
    port: int
    _loop: asyncio.AbstractEventLoop
    _runner: web.AppRunner
    _thread: threading.Thread

    def stop(self) -> None:
        """Stop serving and join the server's thread."""
        if not self._thread.is_alive():
            return
        asyncio.run_coroutine_threadsafe(self._runner.cleanup(), self._loop).result(timeout=10)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=10)

    def __enter__(self) -> RunningServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def start_in_thread(source: MapSource, *, port: int = 0, bind: str = '127.0.0.1',
                    page_config: dict[str, Any] | None = None) -> RunningServer:
    """Serve ``source`` on a thread of its own (its own event loop) and return once it listens.

    port 0 takes a free port (``RunningServer.port`` says which). For tests and for a process that
    has other work on its main thread (the live map server's ROS executor).
    """
    loop = asyncio.new_event_loop()
    runner = web.AppRunner(make_app(source, page_config=page_config), access_log=None, shutdown_timeout=1.0)
    started: dict[str, Any] = {}
    ready = threading.Event()

    def run() -> None:
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(runner.setup())
            site = web.TCPSite(runner, bind, port)
            loop.run_until_complete(site.start())
            started['port'] = runner.addresses[0][1]
        except BaseException as exc:  # noqa: BLE001 -- handed to the caller
            started['error'] = exc
            ready.set()
            return
        ready.set()
        loop.run_forever()
        loop.close()

    thread = threading.Thread(target=run, name='map-server', daemon=True)
    thread.start()
    ready.wait()
    if 'error' in started:
        raise started['error']
    host = f'[{bind}]' if ':' in bind else bind
    return RunningServer(f'http://{host}:{started["port"]}/', started['port'], loop, runner, thread)
