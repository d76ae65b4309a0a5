"""What the map server serves: a finished run's outputs or the live graph's tiles, behind one protocol.

The server (web/server.py) knows only this protocol. ``RunSource`` (a ``process`` output folder)
and ``LiveMapSource`` (the tiles the mosaic and SR nodes publish) implement it.

Layers are ``'mosaic'`` and ``'sr'``; tiles are XYZ tiles of EPSG:3857 (Web Mercator, the grid of
Leaflet, OpenLayers and MapLibre: zoom ``z``, column ``x`` from the west, row ``y`` from the north),
256x256 pixels.
"""
from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

__all__ = ['LAYERS', 'TILE_SIZE', 'MAX_ZOOM', 'MapSource']

#: The layers a page shows, bottom first: the mosaic, then the super-resolved tiles where they exist.
LAYERS = ('mosaic', 'sr')
#: Pixels on a side of one XYZ tile.
TILE_SIZE = 256
#: The deepest zoom any URL may ask for (about 2 mm per pixel at the equator); deeper is a 404.
MAX_ZOOM = 26


@runtime_checkable
class MapSource(Protocol):
    """A georeferenced mosaic (and its SR tiles) as XYZ tiles, with a status and a change counter."""

    def tile_png(self, layer: str, z: int, x: int, y: int) -> bytes | None:
        """PNG (RGBA, 256x256) of tile (z, x, y) of ``layer``; None where nothing is painted (-> 404)."""
        ...

    def status(self) -> dict[str, Any]:
        """JSON-ready state: frames processed, the last pose, the footprint (GeoJSON), bounds, zooms.

        Keys: ``frames`` (int), ``pose`` ({lat, lon, alt, yaw_deg} or None), ``footprint`` (a GeoJSON
        Polygon in lon/lat or None), ``track`` (GeoJSON LineString or None), ``bounds``
        ([west, south, east, north] degrees or None), ``minzoom``, ``maxzoom`` (int),
        ``diagnostics`` (dict), ``version`` (as :meth:`version`), ``live`` (bool).

        The page also reads, where given: ``pose.heading_deg`` (clockwise from north, the arrow's
        direction; ``yaw_deg`` is ENU yaw as poses.csv, counter-clockwise from east, so heading =
        (90 - yaw) mod 360), and ``sr_minzoom``, ``sr_maxzoom`` (the SR layer's zooms; None: no SR
        layer). The page waits for ``bounds`` and ``maxzoom`` before it asks for tiles, and fits the
        map to the first bounds it gets.
        """
        ...

    def version(self) -> int:
        """A counter that grows whenever a tile or the status changes (the page's cue to refresh)."""
        ...
