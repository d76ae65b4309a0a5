"""The web map: XYZ tiles of a georeferenced mosaic, the offline page and the map server.

One page and one set of URLs serve a finished run (``srmosaic serve OUT_DIR``) and the live graph
(``map_server``): both give the server a :class:`~srmosaic_ros.web.source.MapSource`.
"""
